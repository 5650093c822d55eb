"""Content hashes of a run's tables, to prove that a refactor leaves every output bitwise identical.

Builds (once, under --work) the three reference samples of the refactoring protocol and
reconstructs them with the code on ``sys.path`` (run it with ``PYTHONPATH=src`` from a
checkout to test that checkout):

- ``pion``: π gun, lhcb-like, 40 events × 10 particles (2–100 GeV), truth pattern, all four fitters;
- ``minbias``: minimum bias ν = 7.6, 20 events, triplet pattern, parametrized and reference;
- ``electron``: electron gun, 30 events × 5 particles (2–50 GeV), truth pattern, GSF.

For each run and table (``candidates``, ``chi2``, ``states``, ``pulls``) it prints the SHA-256 of
the table's content: all partition files read as one table, sorted by its key columns, written
as Arrow IPC. Timing and paths (``run.json``) are not hashed. Compare two checkouts with::

    PYTHONPATH=src python benchmarks/table_hashes.py --work /tmp/hashes --json before.json
    # change the code, then
    PYTHONPATH=src python benchmarks/table_hashes.py --work /tmp/hashes --json after.json --compare before.json

Datasets are simulated once and reused (the simulation is not what is being tested); runs are
redone every time.

Where a change is meant to alter the arithmetic (e.g. fused multiply-adds), ``--against OTHER_WORK``
compares every table with the same run under another work directory value by value: the rows
(by their keys) and every non-floating-point column must be equal, and for each floating-point
column it prints the largest relative difference |a − b| / max(|a|, |b|) and the largest
difference in units of the column's RMS (relative differences of quantities near zero, e.g. a
residual that is the difference of two positions, are large where the absolute ones are not).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds

TABLES = ("candidates", "chi2", "states", "pulls")
SORT_KEYS = ("event_id", "track_id", "fitter", "location", "hit_id")

SAMPLES = {
    "pion": {
        "simulate": ["--generator", "gun", "--species", "pion", "--events", "40", "--particles", "10",
                     "--p-min", "2000", "--p-max", "100000", "--seed", "21"],
        "reconstruct": ["--pattern", "truth", "--fitter", "parametrized", "--fitter", "reference",
                        "--fitter", "gx2f", "--fitter", "gsf"],
    },
    "minbias": {
        "simulate": ["--generator", "minbias", "--pileup", "7.6", "--events", "20", "--seed", "31"],
        "reconstruct": ["--pattern", "triplet", "--fitter", "parametrized", "--fitter", "reference"],
    },
    "electron": {
        "simulate": ["--generator", "gun", "--species", "electron", "--events", "30", "--particles", "5",
                     "--p-min", "2000", "--p-max", "50000", "--seed", "4"],
        "reconstruct": ["--pattern", "truth", "--fitter", "gsf"],
    },
}


def _pkf(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "pkf.cli", *args], check=True)


def sorted_table(table_dir: Path) -> pa.Table:
    """The Parquet table directory read as one table, sorted by its key columns."""
    table = ds.dataset(table_dir, format="parquet").to_table()
    keys = [(k, "ascending") for k in SORT_KEYS if k in table.column_names]
    return table.sort_by(keys).combine_chunks()


def table_hash(table_dir: Path) -> str | None:
    """SHA-256 of the sorted content of the Parquet table directory (None if absent)."""
    if not table_dir.is_dir():
        return None
    table = sorted_table(table_dir)
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, table.schema) as writer:
        writer.write_table(table)
    return hashlib.sha256(sink.getvalue().to_pybytes()).hexdigest()


def run_sample(name: str, work: Path) -> dict[str, str | None]:
    spec = SAMPLES[name]
    dataset = work / f"{name}-dataset"
    if not (dataset / "meta.json").is_file():
        shutil.rmtree(dataset, ignore_errors=True)
        _pkf("simulate", "--out", str(dataset), *spec["simulate"])
    run = work / f"{name}-run"
    _pkf("reconstruct", str(dataset), "--out", str(run), "--overwrite", "--workers", "1", *spec["reconstruct"])
    return {table: table_hash(run / table) for table in TABLES}


def value_differences(table_dir: Path, other_dir: Path) -> tuple[str | None, list[tuple[str, float, float]]]:
    """Compare two runs' table value by value: (a reason they are not comparable, or None;
    per floating-point column that differs, (column, largest relative difference, largest
    difference in units of the column's RMS))."""
    a, b = sorted_table(table_dir), sorted_table(other_dir)
    if a.schema != b.schema or a.num_rows != b.num_rows:
        return f"{a.num_rows} vs {b.num_rows} rows or different columns", []
    columns = []
    for name in a.column_names:
        if not pa.types.is_floating(a.schema.field(name).type):
            if not a[name].equals(b[name]):
                return f"column {name} differs", []
            continue
        x = a[name].to_numpy(zero_copy_only=False).astype(float)
        y = b[name].to_numpy(zero_copy_only=False).astype(float)
        if not np.array_equal(np.isnan(x), np.isnan(y)):
            return f"column {name}: different NaNs", []
        ok = ~np.isnan(x)
        x, y = x[ok], y[ok]
        delta = np.abs(x - y)
        if not delta.any():
            continue
        scale = np.maximum(np.abs(x), np.abs(y))
        relative = np.max(np.divide(delta, scale, out=np.zeros_like(delta), where=scale > 0))
        rms = np.sqrt(np.mean(x * x))
        columns.append((name, float(relative), float(delta.max() / rms) if rms > 0 else float("inf")))
    return None, columns


def compare_values(work: Path, other: Path, samples: list[str]) -> int:
    """Print `value_differences` of every table of the runs under `work` and `other`; 1 if
    any table is not comparable (different rows or non-float values), else 0."""
    incomparable = 0
    for name in samples:
        for table in TABLES:
            here, there = work / f"{name}-run" / table, other / f"{name}-run" / table
            if not here.is_dir() or not there.is_dir():
                continue
            reason, columns = value_differences(here, there)
            if reason:
                incomparable += 1
                print(f"{name:10s} {table:11s} NOT COMPARABLE: {reason}")
            elif not columns:
                print(f"{name:10s} {table:11s} equal")
            else:
                worst = max(columns, key=lambda c: c[1])
                print(f"{name:10s} {table:11s} {len(columns)} float column(s) differ; largest relative "
                      f"{worst[1]:.2e} ({worst[0]}), largest in RMS units {max(c[2] for c in columns):.2e}")
    return 1 if incomparable else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="directory for the datasets and runs")
    parser.add_argument("--samples", nargs="+", default=list(SAMPLES), choices=list(SAMPLES))
    parser.add_argument("--json", type=Path, help="write the hashes here")
    parser.add_argument("--compare", type=Path, help="hashes of another checkout: report differences")
    parser.add_argument("--against", type=Path, help="another work directory: compare the runs value by value")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    hashes = {name: run_sample(name, args.work) for name in args.samples}
    print(f"{'sample':10s} {'table':11s} sha256")
    for name, tables in hashes.items():
        for table, digest in tables.items():
            print(f"{name:10s} {table:11s} {digest}")
    if args.json:
        args.json.write_text(json.dumps(hashes, indent=1, sort_keys=True) + "\n")
    if args.against:
        status = compare_values(args.work, args.against, args.samples)
        if not args.compare:
            return status
    if args.compare:
        other = json.loads(args.compare.read_text())
        differ = [(n, t) for n, tables in hashes.items() for t, d in tables.items()
                  if n in other and other[n].get(t) != d]
        for n, t in differ:
            print(f"DIFFERENT: {n} {t}")
        print("identical" if not differ else f"{len(differ)} table(s) differ")
        return 1 if differ else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
