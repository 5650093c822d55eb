"""Kernel-only speed of the Kalman core: the compiled track loop alone, ns per node.

Fits the tracks of `benchmarks/fit_compare.py`'s dataset (``--data``, made by it if absent:
a lhcb-like π gun, or with ``--sample minbias`` 40 minimum-bias events at ν = 7.6, long
truth tracks and their seeds) once per repeat with one pass and no
outlier removal, with the weighted-mean combination ("full") and without it ("forward":
the forward filter only; full − forward = backward filter + combination). Each runs the
loop `pkf.fit.driver.track_loop` gives: for the full fit the Kalman core's tracks in SIMD
lanes (`pkf.fit.kalman_lanes`, with its order of the tracks), forward only the scalar loop. No Python around
the loop (no result allocation, no beamline), so differences between checkouts are those
of the kernels. Prints the minimum over ``--repeat`` of the CPU time (time.process_time)
per node.

``--against CHECKOUT`` compares checkouts in one process: CHECKOUT's pkf, imported beside
this one as ``pkf_base_<digest>`` (`twin.load_twin`), fits the same tracks with its own
kernels, the two alternating for ``--rounds`` rounds (`twin.side_by_side`: each the
minimum over ``--repeat`` fits); it prints both versions' minimum and median and the median
over the rounds of new/base. Runs in separate processes differ by up to ±30 % on this
machine (steal time), side by side by a few per cent; ``--against .`` (this checkout against
itself) gives the null ratio to read a difference against.

    python benchmarks/fit_core.py [--fitters parametrized,reference] [--repeat 15] \
        [--sample pigun|minbias] [--data /tmp/fit-compare-pigun-300.npz] [--json out.json]
    python benchmarks/fit_core.py --sample minbias --against ../base [--rounds 6] [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fit_compare  # noqa: E402
from twin import best_of, side_by_side, submodule  # noqa: E402

from pkf.fit.tracks import TrackBatch  # noqa: E402


def core_fit(pkg, name: str, batch, seeds: np.ndarray, covs: np.ndarray, smoother: str):
    """One fit of `batch` by `pkg`'s (pkf or a twin) Kalman core loop with fitter `name`'s
    extrapolator, with the weighted mean (`smoother` "full") or forward only ("forward"): a
    function of no arguments (the first call compiles or loads the kernels)."""
    def module(name):
        return submodule(pkg, name)

    geometry = module("geometry").load_geometry("lhcb-like")
    if name == "parametrized":
        ext = module("params.parameter_set").shipped_parameters(geometry).extrapolator(geometry)
    elif name == "reference":
        ext = module("fit.reference").reference_extrapolator(geometry)
    else:
        raise SystemExit(f"error: fit_core times the Kalman fitters (parametrized, reference), not {name!r}")
    driver, kalman, tracks = module("fit.driver"), module("fit.kalman"), module("fit.tracks")
    code = {"full": kalman.SMOOTHER_WEIGHTED_MEAN, "forward": kalman.SMOOTHER_NONE}[smoother]
    batch = tracks.TrackBatch(*(getattr(batch, f) for f in fit_compare.BATCH_FIELDS))
    fitter = kalman.kalman_fitter(ext, driver.max_nodes(batch.offsets), 1, code)
    loop = driver.track_loop(fitter)
    args = (fitter, driver.TrackNodes.of(batch, seeds, covs), driver.OutlierRule(np.array([9.0, 11.83]), 0),
            driver.FitOutputs.of(tracks.FitResult.empty(batch)))
    return lambda: loop(*args)


def time_core(name: str, batch: TrackBatch, seeds: np.ndarray, covs: np.ndarray, smoother: str, repeat: int) -> float:
    """Minimum CPU ns per node of `repeat` fits of `batch` by this pkf's core loop with fitter
    `name`'s extrapolator (`core_fit`; after one warm-up fit)."""
    import pkf

    run = core_fit(pkf, name, batch, seeds, covs, smoother)
    run()
    return 1e9 * best_of(run, repeat) / batch.z.size


def compare(base_pkg, batch, d, names, rounds: int, repeat: int) -> dict:
    """Base (`base_pkg`) and this pkf alternating (`twin.side_by_side`): per fitter and
    loop (full, forward), each round's minimum over `repeat` fits of both; printed and returned."""
    import pkf

    results = {}
    print(f"{'fitter, loop':<24}{'base min':>10}{'median':>9}{'new min':>10}{'median':>9}"
          f"{'new/base':>10}{'rounds':>18}")
    for name in names:
        for loop_name in ("full", "forward"):
            runs = {side: core_fit(pkg, name, batch, d["seeds"], d["seed_covs"], loop_name)
                    for side, pkg in (("base", base_pkg), ("new", pkf))}
            seconds = side_by_side(runs, rounds, repeat)
            times = {side: [1e9 * t / batch.z.size for t in values] for side, values in seconds.items()}
            ratios = np.array(times["new"]) / np.array(times["base"])
            row = {side: {"min": min(t), "median": float(np.median(t)), "rounds": t} for side, t in times.items()}
            row["new_over_base_median"] = float(np.median(ratios))
            row["new_over_base_range"] = [float(ratios.min()), float(ratios.max())]
            results[f"{name} {loop_name}"] = row
            print(f"{name + ', ' + loop_name:<24}{row['base']['min']:>10.1f}{row['base']['median']:>9.1f}"
                  f"{row['new']['min']:>10.1f}{row['new']['median']:>9.1f}{row['new_over_base_median']:>10.3f}"
                  f"{'  ' + f'{ratios.min():.3f}–{ratios.max():.3f}':>18}")
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fitters", default="parametrized")
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--sample", choices=("pigun", "minbias"), default="pigun")
    parser.add_argument("--data", type=Path, default=None, help="dataset .npz (default /tmp/fit-compare-<sample>.npz)")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--against", type=Path, default=None, help="a pkf checkout to compare with, in this process")
    parser.add_argument("--rounds", type=int, default=6, help="alternating rounds of --against")
    args = parser.parse_args()
    batch, d = fit_compare.load_sample(args.sample, args.data)
    args.data = fit_compare.sample_path(args.sample, args.data)
    if args.against is not None:
        import twin

        print(f"{args.sample}: {batch.n_tracks} tracks, {batch.z.size} nodes; ns per node (CPU), min of "
              f"{args.repeat} per round, {args.rounds} rounds; base = {args.against}")
        results = {"data": str(args.data), "tracks": int(batch.n_tracks), "nodes": int(batch.z.size),
                   "against": str(args.against), "rounds": args.rounds, "repeat": args.repeat,
                   "comparison": compare(twin.load_twin(args.against), batch, d, args.fitters.split(","), args.rounds,
                                         args.repeat)}
        if args.json:
            args.json.write_text(json.dumps(results, indent=2) + "\n")
        return
    results = {"data": str(args.data), "tracks": int(batch.n_tracks), "nodes": int(batch.z.size), "fitters": {}}
    for name in args.fitters.split(","):
        full = time_core(name, batch, d["seeds"], d["seed_covs"], "full", args.repeat)
        forward = time_core(name, batch, d["seeds"], d["seed_covs"], "forward", args.repeat)
        results["fitters"][name] = {"full_ns_per_node": full, "forward_ns_per_node": forward}
        print(
            f"{name:<13} {batch.z.size} nodes  ns/node: full {full:6.0f}  forward {forward:6.0f}  "
            f"backward+combination {full - forward:6.0f}"
        )
    fitters = results["fitters"]
    if "parametrized" in fitters and "reference" in fitters:
        ratio = fitters["reference"]["full_ns_per_node"] / fitters["parametrized"]["full_ns_per_node"]
        results["reference_over_parametrized_full"] = ratio
        print(f"reference/parametrized (full): {ratio:.1f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
