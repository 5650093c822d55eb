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
per node. Compare checkouts by running it alternately with each on PYTHONPATH (and its own
NUMBA_CACHE_DIR):

    python benchmarks/fit_core.py [--fitters parametrized,reference] [--repeat 15] \
        [--sample pigun|minbias] [--data /tmp/fit-compare-pigun-300.npz] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fit_compare  # noqa: E402

from pkf.fit.driver import FitOutputs, OutlierRule, TrackNodes, max_nodes, track_loop  # noqa: E402
from pkf.fit.kalman import SMOOTHER_NONE, SMOOTHER_WEIGHTED_MEAN, kalman_fitter  # noqa: E402
from pkf.fit.tracks import FitResult, TrackBatch  # noqa: E402
from pkf.geometry import load_geometry  # noqa: E402


def time_core(ext, batch: TrackBatch, seeds: np.ndarray, covs: np.ndarray, smoother: int, repeat: int) -> float:
    """Minimum CPU ns per node of `repeat` fits of `batch` (after one warm-up fit)."""
    fitter = kalman_fitter(ext, max_nodes(batch.offsets), 1, smoother)
    r = FitResult.empty(batch)
    loop = track_loop(fitter)
    args = (fitter, TrackNodes.of(batch, seeds, covs), OutlierRule(np.array([9.0, 11.83]), 0), FitOutputs.of(r))
    loop(*args)
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        loop(*args)
        times.append(time.process_time() - t0)
    return 1e9 * min(times) / batch.z.size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fitters", default="parametrized")
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--sample", choices=("pigun", "minbias"), default="pigun")
    parser.add_argument("--data", type=Path, default=None, help="dataset .npz (default /tmp/fit-compare-<sample>.npz)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    batch, d = fit_compare.load_sample(args.sample, args.data)
    args.data = fit_compare.sample_path(args.sample, args.data)
    geometry = load_geometry("lhcb-like")
    results = {"data": str(args.data), "tracks": int(batch.n_tracks), "nodes": int(batch.z.size), "fitters": {}}
    for name in args.fitters.split(","):
        ext, _ = fit_compare._fit_function(name, geometry)
        full = time_core(ext, batch, d["seeds"], d["seed_covs"], SMOOTHER_WEIGHTED_MEAN, args.repeat)
        forward = time_core(ext, batch, d["seeds"], d["seed_covs"], SMOOTHER_NONE, args.repeat)
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
