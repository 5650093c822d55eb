"""Events/s of `pkf reconstruct` with 1 and with 2 local worker processes (issue 8, DESIGN §12).

Both settings run in this one invocation on the same dataset, alternating, `--repeat`
times; kernels are compiled (or loaded from numba's cache) before the first timing.
Two rates per run, from run.json ``execution``:

- ``work``: events / wall time of executing the partitions (workers started, data read,
  reconstructed and written) — what the workers scale;
- ``end_to_end``: events / wall time of the whole command, including the validation of
  the dataset and hashing of its files in the main process (before any work, on three
  threads: `pkf.pipeline.plan.plan_dataset`).

Prints a table and writes JSON (``--json``). Example::

    python benchmarks/workers.py --events 400 --pileup 7.6 --events-per-batch 25 --repeat 3
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path


def _dataset(args, scratch: Path) -> Path:
    if args.dataset:
        return Path(args.dataset)
    from pkf.pipeline.simulate import SimulationConfig, run_simulation

    out = scratch / "dataset"
    run_simulation(SimulationConfig(generator="minbias", events=args.events, pileup=args.pileup, seed=args.seed),
                   out, progress=False)
    return out


def _warm_up(args, scratch: Path) -> None:
    """Compile (or load from cache) every kernel on a 2-event dataset before any timing."""
    from pkf.pipeline.simulate import SimulationConfig, run_simulation

    run_simulation(SimulationConfig(generator="minbias", events=2, pileup=args.pileup, seed=1), scratch / "warm_data",
                   progress=False)
    _run(scratch / "warm_data", scratch / "warm_run", 1, args)


def _run(dataset: Path, out: Path, workers: int, args) -> dict:
    from pkf.pipeline.reconstruct import ReconstructionConfig, run_reconstruction

    t0 = time.perf_counter()
    run = run_reconstruction(dataset, out, ReconstructionConfig(pattern=args.pattern), overwrite=True,
                             progress=False, workers=workers, events_per_batch=args.events_per_batch)
    wall = time.perf_counter() - t0
    ex = run["execution"]
    shutil.rmtree(out)
    return {"workers": workers, "events": run["counts"]["events"], "partitions": ex["partitions"],
            "work_wall_s": ex["wall_s"], "end_to_end_wall_s": wall,
            "work_events_per_s": run["counts"]["events"] / ex["wall_s"],
            "end_to_end_events_per_s": run["counts"]["events"] / wall}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", help="existing dataset (default: simulate minimum bias)")
    parser.add_argument("--events", type=int, default=400)
    parser.add_argument("--pileup", type=float, default=7.6)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--pattern", default="triplet")
    parser.add_argument("--events-per-batch", type=int, default=25)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", default="workers_benchmark.json")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="pkf_workers_") as tmp:
        scratch = Path(tmp)
        dataset = _dataset(args, scratch)
        _warm_up(args, scratch)
        rows = []
        for rep in range(args.repeat):
            for workers in (1, 2):
                row = _run(dataset, scratch / f"run_{rep}_{workers}", workers, args)
                row["repeat"] = rep
                rows.append(row)
                print(f"repeat {rep} workers {workers}: {row['events']} events in {row['partitions']} partitions, "
                      f"work {row['work_events_per_s']:.2f} ev/s, end-to-end {row['end_to_end_events_per_s']:.2f} ev/s",
                      flush=True)
    ratios = []
    for rep in range(args.repeat):
        one, two = [r for r in rows if r["repeat"] == rep]
        ratios.append({"repeat": rep,
                       "work": two["work_events_per_s"] / one["work_events_per_s"],
                       "end_to_end": two["end_to_end_events_per_s"] / one["end_to_end_events_per_s"]})
    best = {k: max(r[k] for r in ratios) for k in ("work", "end_to_end")}
    print()
    print(f"{'repeat':>6} {'2w/1w work':>12} {'2w/1w end-to-end':>18}")
    for r in ratios:
        print(f"{r['repeat']:>6} {r['work']:>12.3f} {r['end_to_end']:>18.3f}")
    print(f"{'best':>6} {best['work']:>12.3f} {best['end_to_end']:>18.3f}")
    result = {"benchmark": "workers", "args": vars(args), "cores": os.cpu_count(), "machine": platform.platform(),
              "runs": rows, "ratios": ratios, "best": best}
    Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
