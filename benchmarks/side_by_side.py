"""Two checkouts side by side in one process: the CPU time of one workload, alternating (issue 18).

CHECKOUT's pkf is imported beside this one as ``pkf_base_<digest>`` (`twin.load_twin`); each
workload is built from both packages on the same inputs, and the two are timed
alternately for ``--rounds`` rounds (`twin.side_by_side`: each round the minimum over
``--repeat`` runs, CPU time, `time.process_time`; which goes first alternates by round). Prints both
versions' minimum and median and the median and range over the rounds of new/base; JSON
with ``--json``. Workloads:

- ``fit``: the Kalman core loop of `fit_core.py` on its tracks (``--sample``), full fit
  (forward, backward, combination), ``--fitter`` parametrized or reference [ns per node];
- ``pattern``: `pkf.pipeline.triplet_pattern.triplet_candidates` (VELO search, forward
  extension, upstream tracks) on ``--events`` minimum-bias events at ``--pileup``, simulated
  by this checkout with ``--seed`` [ms per event];
- ``gsf``: `pkf.fit.gsf.fit_batch_gsf` with 12 components on `gsf_components.py`'s
  electrons (2–50 GeV, long truth tracks of ``--events`` events, seed 202) [ms per track].

This machine's separate processes differ by up to ±30 % (steal time); side by side, by
a few per cent. Placement in memory alone moves a kernel's time by a few per cent between
two copies of the same code, so read a ratio against the null comparison (``--against .``).
Null ratios measured (2026-12-06; median over the rounds, range): fit, parametrized, minimum
bias, 6 rounds of 3: 1.022 (1.006–1.132); gsf, 60 events (571 tracks), 4 rounds of 2: 0.986
(0.956–1.111); pattern, 50 events at ν = 7.6, 4 rounds of 2: 1.039 (0.874–1.144) — rounds of
~3 s each, so use more of them for the pattern.

    python benchmarks/side_by_side.py --against ../base --workload pattern [--events 100] [--rounds 6]
    python benchmarks/side_by_side.py --against . --workload gsf [--events 60]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fit_compare  # noqa: E402
import twin  # noqa: E402


module = twin.submodule


def fit_workload(args):
    """(build, nodes, 1e9, unit): `build(package)` gives `fit_core.core_fit`'s full fit of its tracks."""
    import fit_core

    batch, d = fit_compare.load_sample(args.sample, args.data)

    def build(pkg):
        return fit_core.core_fit(pkg, args.fitter, batch, d["seeds"], d["seed_covs"], "full")

    return build, batch.z.size, 1e9, "ns per node"


def pattern_workload(args):
    """(build, events, 1e3, unit): `build(package)` gives the package's `triplet_candidates` on the events."""
    from pkf.geometry import load_geometry
    from pkf.pipeline.simulate import SimulationConfig, simulate_batch

    config = SimulationConfig(generator="minbias", events=args.events, pileup=args.pileup, seed=args.seed)
    hits = simulate_batch(load_geometry("lhcb-like"), config, 0, args.events)[0]
    h = {c: hits.column(c).to_numpy(zero_copy_only=False) for c in hits.column_names}

    def build(pkg):
        geometry = module(pkg, "geometry").load_geometry("lhcb-like")
        ext = module(pkg, "params.parameter_set").shipped_parameters(geometry).extrapolator(geometry)
        candidates = module(pkg, "pipeline.triplet_pattern").triplet_candidates
        call = (geometry, ext, h["event_id"], h["layer"], h["u"], h["v"], h["z"], h["sigma_u"], h["sigma_v"])
        return lambda: candidates(*call)

    return build, args.events, 1e3, "ms per event"


def gsf_workload(args):
    """(build, tracks, 1e3, unit): `build(package)` gives the package's GSF (12 components) of the electrons."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "fit"))
    from fit_helpers import TruthSample
    from gsf_components import subset

    from pkf.geometry import load_geometry

    electrons = TruthSample(load_geometry("lhcb-like"), events=args.events, seed=202, particles=10, p_min=2000.0,
                            p_max=50000.0, eta_min=2.0, eta_max=5.0, species="electron")
    long = np.flatnonzero(electrons.long_tracks())
    batch = subset(electrons.batch, long)
    seeds, covs = electrons.seeds[long], electrons.seed_covs[long]

    def build(pkg):
        geometry = module(pkg, "geometry").load_geometry("lhcb-like")
        gsf = module(pkg, "fit.gsf")
        own = module(pkg, "fit.tracks").TrackBatch(*(getattr(batch, f) for f in fit_compare.BATCH_FIELDS))
        ctx = gsf.gsf_extrapolator(geometry)
        options = module(pkg, "fit.options").FitOptions.from_flat(max_components=12)
        beamline = module(pkg, "fit.beamline").straight_line_extrapolator(geometry)
        return lambda: gsf.fit_batch_gsf(ctx, own, options, seeds, covs, beamline)

    return build, batch.n_tracks, 1e3, "ms per track"


WORKLOADS = {"fit": fit_workload, "pattern": pattern_workload, "gsf": gsf_workload}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, required=True, help="the pkf checkout to compare with")
    parser.add_argument("--workload", choices=tuple(WORKLOADS), default="fit")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--fitter", default="parametrized", help="fit: parametrized or reference")
    parser.add_argument("--sample", choices=("pigun", "minbias"), default="minbias", help="fit: fit_core's sample")
    parser.add_argument("--data", type=Path, default=None, help="fit: fit_core's dataset file")
    parser.add_argument("--events", type=int, default=100, help="pattern, gsf: events simulated")
    parser.add_argument("--pileup", type=float, default=7.6, help="pattern: ν")
    parser.add_argument("--seed", type=int, default=2024, help="pattern: simulation seed")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    import pkf

    base = twin.load_twin(args.against)
    build, count, scale, unit = WORKLOADS[args.workload](args)
    times = twin.side_by_side({"base": build(base), "new": build(pkf)}, args.rounds, args.repeat)
    per = {side: [scale * t / count for t in values] for side, values in times.items()}
    ratios = np.array(times["new"]) / np.array(times["base"])
    print(f"{args.workload} ({count} {unit.split()[-1]}s), {unit}, CPU, min of {args.repeat} per round, "
          f"{args.rounds} rounds; base = {args.against}")
    print(f"{'':8}{'min':>9}{'median':>9}   rounds")
    for side in ("base", "new"):
        print(f"{side:<8}{min(per[side]):>9.3f}{np.median(per[side]):>9.3f}   "
              + " ".join(f"{v:.3f}" for v in per[side]))
    print(f"new/base: median {np.median(ratios):.3f}, range {ratios.min():.3f}–{ratios.max():.3f}")
    if args.json:
        args.json.write_text(json.dumps({
            "workload": args.workload, "against": str(args.against), "unit": unit, "count": int(count),
            "rounds": args.rounds, "repeat": args.repeat, "setup": {k: str(v) for k, v in vars(args).items()},
            "base": per["base"], "new": per["new"], "new_over_base_median": float(np.median(ratios)),
            "new_over_base_range": [float(ratios.min()), float(ratios.max())]}, indent=2) + "\n")


if __name__ == "__main__":
    main()
