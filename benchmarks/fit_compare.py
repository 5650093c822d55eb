"""Fit speed of two checkouts on the same tracks, interleaved (the speed protocol of the refactors).

Simulates once (with the checkout this script runs from) a lhcb-like π gun (2–100 GeV,
2 < η < 5), keeps the long truth tracks and their least-squares seeds in an ``.npz``, then
runs the fits of both checkouts in alternating subprocesses (``PYTHONPATH=<checkout>/src``,
each with its own numba cache), ``--rounds`` times, order swapped every round. Each
subprocess warms its kernels up on 5 tracks and times every fitter ``--repeat`` times
(CPU time, ``time.process_time``). Prints ns per node, min and median per fitter and
checkout, the new/old ratio of each, and whether the two checkouts' node states and
covariances are bitwise identical (SHA-256 of the arrays).

    python benchmarks/fit_compare.py --old /tmp/old --new . [--fitters reference,gx2f] \
        [--events 300] [--rounds 7] [--repeat 1] [--fresh] [--json out.json]

numba's cache does not notice a change in another file than the cached function's own
(an inlined or called kernel): after editing the new checkout, pass ``--fresh`` (deletes its
cache first, so every kernel is compiled from the current source), or the "new" timings may
be those of stale code.

Fitters: ``reference`` and ``parametrized`` (the Kalman core, one pass, weighted mean),
``gx2f``, ``gsf``. Each fit runs through the checkout's own Python entry point, so the
comparison holds across API changes of the options (see `_options`).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
BATCH_FIELDS = ("offsets", "z", "layer", "hit_row", "n_meas", "hx", "hy", "m", "sigma")


def make_dataset(path: Path, events: int, generator: str = "gun") -> None:
    """Simulate the π gun (``generator="minbias"``: minimum bias at ν = 7.6, seed 31), keep
    the long truth tracks and their seeds in `path` (.npz)."""
    sys.path.insert(0, str(HERE.parents[1] / "tests" / "fit"))
    from fit_helpers import TruthSample

    from pkf.geometry import load_geometry

    if generator == "minbias":
        sample = TruthSample(load_geometry("lhcb-like"), events=events, seed=31, generator="minbias", pileup=7.6)
    else:
        sample = TruthSample(
            load_geometry("lhcb-like"),
            events=events,
            seed=101,
            particles=10,
            p_min=2000.0,
            p_max=100000.0,
            eta_min=2.0,
            eta_max=5.0,
        )
    long = np.flatnonzero(sample.long_tracks())
    b = sample.batch
    nodes = np.concatenate([np.arange(b.offsets[t], b.offsets[t + 1]) for t in long])
    arrays = {f: getattr(b, f)[nodes] for f in BATCH_FIELDS if f != "offsets"}
    arrays["offsets"] = np.concatenate([[0], np.cumsum(b.n_nodes[long])]).astype(np.int64)
    np.savez(path, seeds=sample.seeds[long], seed_covs=sample.seed_covs[long], **arrays)


def _options(fitter: str):
    """The checkout's options for a one-pass, weighted-mean fit (old API: flat FitOptions)."""
    from pkf.fit.tracks import FitOptions

    if hasattr(FitOptions, "from_flat"):
        return FitOptions.from_flat(iterations=1, smoother="weighted-mean")
    return FitOptions(iterations=1)


#: The samples of fit_core.py and kernel_profile.py: (default file, events, generator).
SAMPLES = {"pigun": ("/tmp/fit-compare-pigun-300.npz", 300, "gun"),
           "minbias": ("/tmp/fit-compare-minbias-40.npz", 40, "minbias")}


def sample_path(sample: str, path: Path | None = None) -> Path:
    """`path`, or the default file of `SAMPLES[sample]`."""
    return Path(path or SAMPLES[sample][0])


def load_sample(sample: str, path: Path | None = None):
    """(TrackBatch, the .npz with its seeds and seed_covs) of `SAMPLES[sample]`, read from
    `sample_path(sample, path)`, made there first if absent."""
    from pkf.fit.tracks import TrackBatch

    _, events, generator = SAMPLES[sample]
    path = sample_path(sample, path)
    if not path.is_file():
        make_dataset(path, events, generator=generator)
    d = np.load(path)
    return TrackBatch(*(d[f] for f in BATCH_FIELDS)), d


def _fit_function(name: str, geometry):
    from pkf.fit.reference import reference_extrapolator

    if name == "reference":
        from pkf.fit.tracks import fit_batch

        return reference_extrapolator(geometry), fit_batch
    if name == "parametrized":
        from pkf.fit.tracks import fit_batch
        from pkf.params.parameter_set import shipped_parameters

        return shipped_parameters(geometry).extrapolator(geometry), fit_batch
    if name == "gx2f":
        from pkf.fit.gx2f import fit_batch_gx2f

        return reference_extrapolator(geometry), fit_batch_gx2f
    if name == "gsf":
        from pkf.fit.gsf import fit_batch_gsf, gsf_extrapolator

        return gsf_extrapolator(geometry), fit_batch_gsf
    raise ValueError(name)


def worker(data: Path, fitters: list[str], repeat: int) -> dict:
    """Time each fitter on the dataset with the pkf on sys.path: CPU seconds per repeat,
    and the SHA-256 of the node states and covariances."""
    from pkf.fit.tracks import TrackBatch
    from pkf.geometry import load_geometry

    d = np.load(data)
    batch = TrackBatch(*(d[f] for f in BATCH_FIELDS))
    warm_nodes = int(batch.offsets[5])
    warm = TrackBatch(batch.offsets[:6], *(getattr(batch, f)[:warm_nodes] for f in BATCH_FIELDS[1:]))
    seeds, covs = d["seeds"], d["seed_covs"]
    geometry = load_geometry("lhcb-like")
    out = {"nodes": int(batch.z.size), "tracks": int(batch.n_tracks)}
    for name in fitters:
        ext, fit = _fit_function(name, geometry)
        options = _options(name)
        fit(ext, warm, options, seeds[:5], covs[:5])
        times = []
        for _ in range(repeat):
            t0 = time.process_time()
            result = fit(ext, batch, options, seeds, covs)
            times.append(time.process_time() - t0)
        digest = hashlib.sha256(
            np.ascontiguousarray(result.node_state).tobytes() + np.ascontiguousarray(result.node_cov).tobytes()
        ).hexdigest()
        out[name] = {"cpu_s": times, "hash": digest}
    return out


def run_checkout(checkout: Path, data: Path, fitters: list[str], repeat: int, cache: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout / "src"), NUMBA_CACHE_DIR=cache)
    cmd = [
        sys.executable,
        str(HERE),
        "--worker",
        "--data",
        str(data),
        "--fitters",
        ",".join(fitters),
        "--repeat",
        str(repeat),
    ]
    done = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", type=Path)
    parser.add_argument("--new", type=Path, default=HERE.parents[1])
    parser.add_argument("--fitters", default="reference,gx2f")
    parser.add_argument("--events", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--data", type=Path, default=None, help="dataset .npz (made if absent)")
    parser.add_argument("--cache", default="/tmp/numba-fit-compare", help="numba cache prefix")
    parser.add_argument("--fresh", action="store_true", help="delete the new checkout's numba cache first")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    fitters = args.fitters.split(",")
    data = args.data or Path(f"/tmp/fit-compare-pigun-{args.events}.npz")
    if args.worker:
        print(json.dumps(worker(data, fitters, args.repeat)))
        return
    if not data.is_file():
        make_dataset(data, args.events)
    checkouts = {"old": args.old.resolve(), "new": args.new.resolve()}
    if args.fresh:
        shutil.rmtree(f"{args.cache}-new", ignore_errors=True)
    times = {c: {f: [] for f in fitters} for c in checkouts}
    hashes = {c: {} for c in checkouts}
    nodes = 0
    for r in range(args.rounds):
        order = ["old", "new"] if r % 2 == 0 else ["new", "old"]
        for c in order:
            out = run_checkout(checkouts[c], data, fitters, args.repeat, f"{args.cache}-{c}")
            nodes = out["nodes"]
            for f in fitters:
                times[c][f] += out[f]["cpu_s"]
                hashes[c][f] = out[f]["hash"]
    summary = {"nodes": nodes, "rounds": args.rounds, "repeat": args.repeat, "fitters": {}}
    print(f"{nodes} nodes; ns/node, CPU, {args.rounds} rounds × {args.repeat}: min / median")
    for f in fitters:
        row = {}
        for c in checkouts:
            ns = [1e9 * t / nodes for t in times[c][f]]
            row[c] = {"min": min(ns), "median": statistics.median(ns), "all": ns}
        row["ratio_min"] = row["new"]["min"] / row["old"]["min"]
        row["ratio_median"] = row["new"]["median"] / row["old"]["median"]
        row["identical"] = hashes["old"][f] == hashes["new"][f]
        summary["fitters"][f] = row
        print(
            f"{f:<13} old {row['old']['min']:8.0f} / {row['old']['median']:8.0f}   "
            f"new {row['new']['min']:8.0f} / {row['new']['median']:8.0f}   "
            f"new/old {row['ratio_min']:.3f} / {row['ratio_median']:.3f}   "
            f"states {'identical' if row['identical'] else 'DIFFER'}"
        )
    if args.json:
        args.json.write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
