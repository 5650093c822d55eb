"""Fit throughput and resolution of the Kalman fitters on the same tracks (DESIGN §12).

Simulates a pion gun (2–100 GeV, 2 < η < 5) in the lhcb-like detector, groups the hits
by MC particle, and fits the same long tracks with every built fitter in one process,
after JIT warm-up. Prints a table and writes JSON: tracks/s, ns/node, and δp/p at the
first hit (RMS and Gaussian core) in bins of true momentum.

    python benchmarks/fit_throughput.py [--events 1000] [--repeat 3] [--json out.json]
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

from pkf.fit.tracks import TrackBatch, fit_batch  # noqa: E402
from pkf.geometry import load_geometry  # noqa: E402
from pkf.report.gauss import gaussian_core  # noqa: E402

P_BINS = (2000.0, 5000.0, 10000.0, 20000.0, 50000.0, 100000.0)


def subset(batch: TrackBatch, tracks: np.ndarray) -> TrackBatch:
    nodes = np.concatenate([np.arange(batch.offsets[t], batch.offsets[t + 1]) for t in tracks])
    offsets = np.concatenate([[0], np.cumsum(batch.n_nodes[tracks])])
    return TrackBatch(offsets, batch.z[nodes], batch.layer[nodes], batch.hit_row[nodes], batch.n_meas[nodes],
                      batch.hx[nodes], batch.hy[nodes], batch.m[nodes], batch.sigma[nodes])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    sample = TruthSample(load_geometry("lhcb-like"), events=args.events, seed=101, particles=10,
                         p_min=2000.0, p_max=100000.0, eta_min=2.0, eta_max=5.0)
    long = np.flatnonzero(sample.long_tracks())
    batch = subset(sample.batch, long)
    seeds, covs = sample.seeds[long], sample.seed_covs[long]
    fitters = {"reference": sample.extrapolator}
    rows = {}
    for name, ext in fitters.items():
        fit_batch(ext, subset(batch, np.arange(5)), _options(), seeds[:5], covs[:5])  # JIT warm-up
        walls = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            result = fit_batch(ext, batch, _options(), seeds, covs)
            walls.append(time.perf_counter() - t0)
        wall = min(walls)
        first = batch.offsets[:-1]
        truth = sample.truth[batch.hit_row[first]]
        state = result.locations["first_hit"][1]
        ok = result.status == 0
        p_true = 1.0 / np.abs(truth[:, 4])
        dp = np.abs(truth[:, 4]) / np.abs(state[:, 4]) - 1.0
        bins = []
        for lo, hi in zip(P_BINS[:-1], P_BINS[1:]):
            sel = ok & (p_true >= lo) & (p_true < hi)
            core = gaussian_core(dp[sel])
            bins.append({"p_min": lo, "p_max": hi, "tracks": int(sel.sum()),
                         "dp_over_p_rms": float(np.sqrt(np.mean(dp[sel] ** 2))), "dp_over_p_core": core.sigma})
        rows[name] = {"tracks": int(batch.n_tracks), "nodes": int(batch.z.size), "wall_s": wall,
                      "tracks_per_s": batch.n_tracks / wall, "ns_per_node": 1e9 * wall / batch.z.size,
                      "ok_fraction": float(ok.mean()), "resolution": bins}
    print(f"{'fitter':<14}{'tracks':>8}{'tracks/s':>12}{'ns/node':>10}")
    for name, r in rows.items():
        print(f"{name:<14}{r['tracks']:>8}{r['tracks_per_s']:>12.0f}{r['ns_per_node']:>10.0f}")
    print()
    print(f"{'fitter':<14}{'p range [GeV]':>16}{'tracks':>8}{'δp/p RMS':>11}{'δp/p core':>11}")
    for name, r in rows.items():
        for b in r["resolution"]:
            rng = f"{b['p_min'] / 1000:.0f}–{b['p_max'] / 1000:.0f}"
            print(f"{name:<14}{rng:>16}{b['tracks']:>8}{100 * b['dp_over_p_rms']:>10.3f}%{100 * b['dp_over_p_core']:>10.3f}%")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


def _options():
    from pkf.fit.tracks import FitOptions

    return FitOptions()


if __name__ == "__main__":
    main()
