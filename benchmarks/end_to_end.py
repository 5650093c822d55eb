"""Where `pkf reconstruct` spends its CPU: the share in the pattern and fit kernels (issue 18.4).

Runs ``pkf reconstruct DATASET --workers 1`` (the default parametrized fitter, or
``--fitter``) as a user would, in a subprocess, once untimed per checkout (kernels compiled
or loaded into that checkout's numba cache), then ``--rounds`` timed runs per checkout,
alternating (``--checkouts A B``: an A/B of two source trees, ``PYTHONPATH=<checkout>/src``).
Per run:

- **total CPU**: user + system seconds of the whole command (``resource.getrusage`` of the
  waited-for child: start-up, imports, kernel loading, validation, reading, pattern, fit,
  matching, tables, Parquet writing, hashing);
- **kernel CPU**: run.json ``timing`` — the CPU seconds of the ``pattern`` stage (VELO
  search, forward extension, upstream pass, seeds: compiled kernels and their thin Python
  glue) plus every ``fit.<fitter>`` stage;
- **share** = kernel / total, and events per CPU second;
- **the rest, by stage** (run.json ``timing`` of checkouts that record them): ``validate`` (the
  dataset's scan, hashes and consistency, before any work), ``read`` (the partitions' rows),
  ``batch`` (in the groups' reconstruction but outside the kernels: MC matching, truth, rows),
  ``tables`` (building the run tables), ``write`` (Parquet files and their SHA-256), and
  ``start+`` = total − all of them (Python, imports, kernel loading from numba's cache, run.json).

The start-up (Python, imports, loading ~40 cached kernels: 2–4 s) is paid once per
command, so the share grows with the number of events: measure it on the acceptance's
1,000 events, or print the fixed part with ``--events 0``-like small datasets to subtract.

    python benchmarks/end_to_end.py --events 200 [--pileup 7.6] [--rounds 2] \
        [--checkouts /tmp/old .] [--fitter parametrized] [--json out.json]
    python benchmarks/end_to_end.py --dataset DATASET [--cache-root DIR [--no-warm-up]] ...
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path


def _simulate(args, scratch: Path) -> Path:
    out = scratch / "dataset"
    subprocess.run([sys.executable, "-m", "pkf.cli", "simulate", "--generator", "minbias", "--pileup",
                    str(args.pileup), "--events", str(args.events), "--seed", str(args.seed), "--out", str(out)],
                   check=True, stdout=subprocess.DEVNULL)
    return out


def _env(checkout: Path, scratch: Path, index: int) -> dict:
    """The child's environment: `checkout`'s pkf, its own numba and pkf caches, and Python's
    bytecode cache on (under `scratch`), as for an installed pkf (pip writes an installed
    package's bytecode; with PYTHONDONTWRITEBYTECODE set, as on the machine of issue 18, every
    run compiled pkf's ~80 modules from source: 0.16 s of CPU counted in ``start+``)."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env["PYTHONPYCACHEPREFIX"] = str(scratch / f"pycache-{index}")
    env["PYTHONPATH"] = str(checkout / "src")
    env["NUMBA_CACHE_DIR"] = str(scratch / f"numba-{index}")
    env["PKF_CACHE_DIR"] = str(scratch / f"pkfcache-{index}")
    return env


def _run(dataset: Path, out: Path, env: dict, fitters: list[str]) -> dict:
    """One `pkf reconstruct`: (total CPU s, run.json timing, events)."""
    shutil.rmtree(out, ignore_errors=True)
    command = [sys.executable, "-m", "pkf.cli", "reconstruct", str(dataset), "--out", str(out), "--workers", "1"]
    for fitter in fitters:
        command += ["--fitter", fitter]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(command, check=True, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    run = json.loads((out / "run.json").read_text())
    timing = run["timing"]
    pattern = timing.get("pattern", {}).get("cpu_s", 0.0)
    fit = sum(f["cpu_s"] for f in timing.get("fit", {}).values())
    row = {"total_cpu_s": total, "pattern_cpu_s": pattern, "fit_cpu_s": fit,
           "kernel_share": (pattern + fit) / total, "events": run["counts"]["events"]}
    stages = {s: timing[s]["cpu_s"] for s in STAGES if s in timing}
    if len(stages) == len(STAGES):
        row["stages_cpu_s"] = stages | {"batch": stages["batches"] - pattern - fit}
    return row


#: run.json timing stages outside the kernels (recorded since issue 18.4); ``batches`` holds the kernels.
STAGES = ("validate", "read", "batches", "tables", "write")
#: the columns of the split: ``batch`` = batches − pattern − fit, ``start+`` = total − the others.
SPLIT = ("validate", "read", "batch", "tables", "write")


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, help="an existing dataset (else minbias is simulated)")
    parser.add_argument("--events", type=int, default=200)
    parser.add_argument("--pileup", type=float, default=7.6)
    parser.add_argument("--seed", type=int, default=18)
    parser.add_argument("--checkouts", type=Path, nargs="+", default=[Path(__file__).resolve().parents[1]])
    parser.add_argument("--fitter", action="append", default=None)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--cache-root", type=Path, help="keep the numba caches here between invocations")
    parser.add_argument("--no-warm-up", action="store_true", help="the caches under --cache-root are warm: "
                        "skip the untimed first run of each checkout")
    args = parser.parse_args(argv)
    fitters = args.fitter or ["parametrized"]
    checkouts = [c.resolve() for c in args.checkouts]
    with tempfile.TemporaryDirectory(prefix="pkf-e2e-") as tmp:
        scratch = Path(tmp)
        dataset = args.dataset or _simulate(args, scratch)
        envs = [_env(c, args.cache_root or scratch, i) for i, c in enumerate(checkouts)]
        for env in envs if not (args.no_warm_up and args.cache_root) else []:  # compile or load kernels: not timed
            _run(dataset, scratch / "warm", env, fitters)
        rows = []
        for r in range(args.rounds):
            order = list(range(len(checkouts)))
            if r % 2:
                order.reverse()
            for i in order:
                row = _run(dataset, scratch / "run", envs[i], fitters)
                row.update(checkout=str(checkouts[i]), round=r)
                rows.append(row)
    print(f"pkf reconstruct --workers 1, fitters {','.join(fitters)}: CPU seconds per run")
    print(f"{'checkout':30s} {'round':>5s} {'events':>6s} {'total':>7s} {'pattern':>7s} {'fit':>6s} "
          f"{'other':>6s} {'share':>6s} {'ev/CPU s':>8s} | " + " ".join(f"{s:>8s}" for s in SPLIT + ("start+",)))
    for row in rows:
        other = row["total_cpu_s"] - row["pattern_cpu_s"] - row["fit_cpu_s"]
        split = row.get("stages_cpu_s")
        parts = [split[s] for s in SPLIT] + [other - sum(split[s] for s in SPLIT)] if split else []
        print(f"{row['checkout'][-30:]:30s} {row['round']:5d} {row['events']:6d} {row['total_cpu_s']:7.2f} "
              f"{row['pattern_cpu_s']:7.2f} {row['fit_cpu_s']:6.2f} {other:6.2f} {row['kernel_share']:6.3f} "
              f"{row['events'] / row['total_cpu_s']:8.2f} | " + " ".join(f"{x:8.2f}" for x in parts))
    if args.json:
        args.json.write_text(json.dumps({"fitters": fitters, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
