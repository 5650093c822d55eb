"""Cost of the GSF vs its number of components, and of the GX2F vs the Kalman fitters (issue 7).

1. GSF: an electron gun (2–50 GeV, 2 < η < 5) in the lhcb-like detector, the long
   truth tracks fitted with `--max-components` 4, 8, 12, 16 (shared Jacobians, the
   default: within bends of 0.03 rad, `pkf.fit.gsf._share_jacobians`), 12 with the
   leading component's Jacobian for all (the rule before 2026-12), 12 with a Jacobian
   per component and 12 with the mixture product at every node
   (``--gsf-mixture-smoothing-everywhere``, the smoothing before 2026-12-07): time per track (best of --repeat, after JIT warm-up, one process), mean
   number of components of the smoothed mixture at the first hit, δp/p Gaussian core and
   q/p pull core at the first and last hit, with the reference Kalman fitter on the same
   tracks for comparison. Also the difference each sharing rule makes to the fit with a
   Jacobian per component (RMS of the state difference in σ, over the tracks every fit fits).
2. GX2F: a pion gun (2–100 GeV), long tracks: time per track of the parametrized and
   reference Kalman fitters and of the GX2F, and the GX2F's mean Gauss–Newton updates.
3. Passes of the reference Kalman fitter (`pkf.fit.fitters.REFERENCE_ITERATIONS`): a
   2–5 GeV pion gun, long tracks, fitted with 1, 2 and 3 passes and by the GX2F: the
   first-hit q/p difference from the GX2F's χ² minimum (RMS and max, in σ), the δp/p
   Gaussian core per momentum bin, the q/p pull core and the time per track.

Prints tables and writes JSON:

    python benchmarks/gsf_components.py [--events 100] [--repeat 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "fit"))
from fit_helpers import TruthSample  # noqa: E402

from pkf.fit.gsf import fit_batch_gsf, gsf_extrapolator  # noqa: E402
from pkf.fit.gx2f import fit_batch_gx2f  # noqa: E402
from pkf.fit.tracks import FitOptions, TrackBatch, fit_batch  # noqa: E402
from pkf.geometry import load_geometry  # noqa: E402
from pkf.params.parameter_set import shipped_parameters  # noqa: E402
from pkf.params.gauss import gaussian_core  # noqa: E402

COMPONENTS = (4, 8, 12, 16)


def subset(batch: TrackBatch, tracks: np.ndarray) -> TrackBatch:
    nodes = np.concatenate([np.arange(batch.offsets[t], batch.offsets[t + 1]) for t in tracks])
    offsets = np.concatenate([[0], np.cumsum(batch.n_nodes[tracks])])
    return TrackBatch(offsets, batch.z[nodes], batch.layer[nodes], batch.hit_row[nodes], batch.n_meas[nodes],
                      batch.hx[nodes], batch.hy[nodes], batch.m[nodes], batch.sigma[nodes])


def best_of(repeat, fn):
    times = []
    result = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return min(times), result


def resolution(sample, batch, tracks, result, ok):
    """δp/p core and q/p pull core at the first and last hit (local truth)."""
    out = {}
    for loc, nodes in (("first_hit", batch.offsets[:-1]), ("last_hit", batch.offsets[1:] - 1)):
        _, state, cov = result.locations[loc]
        truth = sample.truth[batch.hit_row[nodes]]
        dpp = np.abs(truth[ok, 4]) / np.abs(state[ok, 4]) - 1.0
        pull = (state[ok, 4] - truth[ok, 4]) / np.sqrt(cov[ok, 4, 4])
        core = gaussian_core(dpp)
        out[loc] = {"dp_over_p_core": core.sigma, "dp_over_p_rms": core.rms,
                    "qop_pull_core": gaussian_core(pull).sigma}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    geometry = load_geometry("lhcb-like")
    options = FitOptions()
    results: dict = {"gsf": {}, "gx2f": {}}

    # ---- 1. GSF vs number of components (electrons)
    electrons = TruthSample(geometry, events=args.events, seed=202, particles=10, p_min=2000.0, p_max=50000.0,
                            eta_min=2.0, eta_max=5.0, species="electron")
    long = np.flatnonzero(electrons.long_tracks())
    batch = subset(electrons.batch, long)
    seeds, covs = electrons.seeds[long], electrons.seed_covs[long]
    warm = subset(batch, np.arange(3))
    kalman = fit_batch(electrons.extrapolator, batch, options, seeds, covs, electrons.beamline)
    wall_kalman, kalman = best_of(args.repeat, lambda: fit_batch(electrons.extrapolator, batch, options, seeds,
                                                                 covs, electrons.beamline))
    configs = [(f"gsf-{m}", {}, {"max_components": m}) for m in COMPONENTS]
    configs.append(("gsf-12-lead-jacobian-for-all", {"jacobian_share_kick": np.inf}, {}))
    configs.append(("gsf-12-own-jacobians", {"share_jacobians": False}, {}))
    configs.append(("gsf-12-mixture-smoothing-everywhere", {}, {"mixture_smoothing_everywhere": True}))
    fits = {}
    for name, kw, option in configs:
        ctx = gsf_extrapolator(geometry, **kw)
        opts = FitOptions.from_flat(**{"max_components": 12, **option})
        fit_batch_gsf(ctx, warm, opts, seeds[:3], covs[:3], electrons.beamline)
        wall, fits[name] = best_of(args.repeat, lambda ctx=ctx, opts=opts: fit_batch_gsf(ctx, batch, opts, seeds, covs,
                                                                                         electrons.beamline))
        results["gsf"][name] = {"tracks": int(batch.n_tracks), "ms_per_track": 1e3 * wall / batch.n_tracks,
                                "mean_components_first_hit": float(fits[name].n_components.mean())}
    ok = kalman.status == 0
    for r in fits.values():
        ok &= r.status == 0
    results["gsf"]["reference-kalman"] = {"tracks": int(batch.n_tracks),
                                          "ms_per_track": 1e3 * wall_kalman / batch.n_tracks}
    for name, r in list(fits.items()) + [("reference-kalman", kalman)]:
        results["gsf"][name].update(resolution(electrons, batch, long, r, ok))
        results["gsf"][name]["ok_fraction"] = float(np.mean(r.status == 0))
    own = fits["gsf-12-own-jacobians"]
    sharing = {}
    for rule in ("gsf-12", "gsf-12-lead-jacobian-for-all"):
        sharing[rule] = {}
        for loc in ("first_hit", "last_hit"):
            _, s_a, c_a = fits[rule].locations[loc]
            _, s_b, _ = own.locations[loc]
            d = (s_a[ok] - s_b[ok]) / np.sqrt(np.einsum("nii->ni", c_a[ok]))
            sharing[rule][loc] = dict(zip(("x", "y", "tx", "ty", "qop"), np.sqrt(np.mean(d**2, axis=0)).tolist()))
    results["gsf"]["jacobian_sharing_rms_difference_sigma"] = sharing

    # ---- 2. GX2F vs the Kalman fitters (pions)
    pions = TruthSample(geometry, events=args.events, seed=203, particles=10, p_min=2000.0, p_max=100000.0,
                        eta_min=2.0, eta_max=5.0)
    long = np.flatnonzero(pions.long_tracks())
    batch = subset(pions.batch, long)
    seeds, covs = pions.seeds[long], pions.seed_covs[long]
    warm = subset(batch, np.arange(3))
    runs = {
        "parametrized": (shipped_parameters(geometry).extrapolator(geometry), fit_batch, options),
        "reference": (pions.extrapolator, fit_batch, options),
        "reference-2-iterations": (pions.extrapolator, fit_batch, FitOptions.from_flat(iterations=2)),
        "gx2f": (pions.extrapolator, fit_batch_gx2f, options),
    }
    for name, (ext, fit, opts) in runs.items():
        fit(ext, warm, opts, seeds[:3], covs[:3], pions.beamline)
        wall, r = best_of(args.repeat, lambda fit=fit, ext=ext, opts=opts: fit(ext, batch, opts, seeds, covs,
                                                                               pions.beamline))
        results["gx2f"][name] = {"tracks": int(batch.n_tracks), "ms_per_track": 1e3 * wall / batch.n_tracks,
                                 "ns_per_node": 1e9 * wall / batch.z.size, "ok_fraction": float(np.mean(r.status == 0))}
        if name == "gx2f":
            good = r.status == 0
            results["gx2f"][name]["mean_updates"] = float(r.iterations[good].mean())
            results["gx2f"][name]["converged_fraction"] = float(r.converged[good].mean())
    ref = results["gx2f"]["reference"]["ms_per_track"]
    for name in runs:
        results["gx2f"][name]["cost_vs_reference"] = results["gx2f"][name]["ms_per_track"] / ref

    # ---- 3. passes of the reference fitter at low momentum (pions)
    slow = TruthSample(geometry, events=args.events, seed=205, particles=10, p_min=2000.0, p_max=5000.0,
                       eta_min=2.0, eta_max=5.0)
    long = np.flatnonzero(slow.long_tracks())
    batch = subset(slow.batch, long)
    seeds, covs = slow.seeds[long], slow.seed_covs[long]
    warm = subset(batch, np.arange(3))
    passes = {f"reference-{i}": (fit_batch, FitOptions.from_flat(iterations=i)) for i in (1, 2, 3)}
    passes["gx2f"] = (fit_batch_gx2f, options)
    fits = {}
    walls = {}
    for name, (fit, opts) in passes.items():
        fit(slow.extrapolator, warm, opts, seeds[:3], covs[:3], slow.beamline)
        walls[name], fits[name] = best_of(args.repeat, lambda fit=fit, opts=opts: fit(
            slow.extrapolator, batch, opts, seeds, covs, slow.beamline))
    ok = np.all([r.status == 0 for r in fits.values()], axis=0)
    truth = slow.truth[batch.hit_row[batch.offsets[:-1]]][ok]
    p_true = 1.0 / np.abs(truth[:, 4])
    _, s_min, _ = fits["gx2f"].locations["first_hit"]
    bins = ((2000, 2500), (2500, 3000), (3000, 4000), (4000, 5000))
    results["passes"] = {}
    for name, r in fits.items():
        _, state, cov = r.locations["first_hit"]
        sigma = np.sqrt(cov[ok, 4, 4])
        d = (state[ok, 4] - s_min[ok, 4]) / sigma
        dpp = np.abs(truth[:, 4]) / np.abs(state[ok, 4]) - 1.0
        results["passes"][name] = {
            "tracks": int(ok.sum()), "ms_per_track": 1e3 * walls[name] / batch.n_tracks,
            "cost_vs_one_pass": walls[name] / walls["reference-1"],
            "qop_minus_gx2f_rms_sigma": float(np.sqrt(np.mean(d**2))), "qop_minus_gx2f_max_sigma": float(np.abs(d).max()),
            "qop_pull_core": gaussian_core((state[ok, 4] - truth[:, 4]) / sigma).sigma,
            "dp_over_p_core": {f"{lo / 1000:g}-{hi / 1000:g} GeV": gaussian_core(dpp[(p_true >= lo) & (p_true < hi)]).sigma
                               for lo, hi in bins}}

    # ---- tables
    g = results["gsf"]
    print(f"GSF on lhcb-like electrons (2–50 GeV, long tracks, {g['gsf-12']['tracks']} tracks)")
    print(f"{'fit':<36}{'ms/track':>9}{'comp@1st':>9}   first hit: δp/p core, rms, q/p pull   "
          "last hit: δp/p core, rms, q/p pull")
    for name in [c[0] for c in configs] + ["reference-kalman"]:
        r = g[name]
        f, la = r["first_hit"], r["last_hit"]
        comp = f"{r['mean_components_first_hit']:.1f}" if "mean_components_first_hit" in r else "1"
        print(f"{name:<36}{r['ms_per_track']:>9.2f}{comp:>9}   "
              f"{100 * f['dp_over_p_core']:6.2f}% {100 * f['dp_over_p_rms']:6.1f}% {f['qop_pull_core']:6.2f}      "
              f"{100 * la['dp_over_p_core']:6.2f}% {100 * la['dp_over_p_rms']:6.1f}% {la['qop_pull_core']:6.2f}")
    print("fits failed:", {name: int(round(g[name]["tracks"] * (1.0 - g[name]["ok_fraction"])))
                           for name in [c[0] for c in configs]})
    for rule, diffs in g["jacobian_sharing_rms_difference_sigma"].items():
        print(f"{rule} against a Jacobian per component, RMS state difference / σ:",
              {k: {p: round(v, 4) for p, v in d.items()} for k, d in diffs.items()})
    print()
    x = results["gx2f"]
    print(f"GX2F vs the Kalman fitters on lhcb-like pions ({x['gx2f']['tracks']} long tracks)")
    print(f"{'fitter':<24}{'ms/track':>9}{'ns/node':>9}{'× reference':>12}")
    for name in runs:
        r = x[name]
        print(f"{name:<24}{r['ms_per_track']:>9.3f}{r['ns_per_node']:>9.0f}{r['cost_vs_reference']:>12.2f}")
    print(f"GX2F: mean Gauss–Newton updates {x['gx2f']['mean_updates']:.2f}, "
          f"converged {100 * x['gx2f']['converged_fraction']:.2f}%")
    x = results["passes"]
    print()
    print(f"Reference Kalman passes vs the GX2F on lhcb-like pions 2–5 GeV ({x['gx2f']['tracks']} long tracks)")
    print(f"{'fit':<14}{'ms/track':>9}{'×1 pass':>8}{'Δq/p vs GX2F rms, max [σ]':>28}{'q/p pull':>9}   δp/p core [%] "
          + " ".join(next(iter(x.values()))["dp_over_p_core"]))
    for name, r in x.items():
        print(f"{name:<14}{r['ms_per_track']:>9.3f}{r['cost_vs_one_pass']:>8.2f}"
              f"{r['qop_minus_gx2f_rms_sigma']:>20.3f}, {r['qop_minus_gx2f_max_sigma']:6.2f}{r['qop_pull_core']:>9.3f}   "
              + " ".join(f"{100 * v:.3f}" for v in r["dp_over_p_core"].values()))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
