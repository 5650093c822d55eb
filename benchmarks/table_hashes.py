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
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

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


def table_hash(table_dir: Path) -> str | None:
    """SHA-256 of the sorted content of the Parquet table directory (None if absent)."""
    if not table_dir.is_dir():
        return None
    table = ds.dataset(table_dir, format="parquet").to_table()
    keys = [(k, "ascending") for k in SORT_KEYS if k in table.column_names]
    table = table.sort_by(keys).combine_chunks()
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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="directory for the datasets and runs")
    parser.add_argument("--samples", nargs="+", default=list(SAMPLES), choices=list(SAMPLES))
    parser.add_argument("--json", type=Path, help="write the hashes here")
    parser.add_argument("--compare", type=Path, help="hashes of another checkout: report differences")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    hashes = {name: run_sample(name, args.work) for name in args.samples}
    print(f"{'sample':10s} {'table':11s} sha256")
    for name, tables in hashes.items():
        for table, digest in tables.items():
            print(f"{name:10s} {table:11s} {digest}")
    if args.json:
        args.json.write_text(json.dumps(hashes, indent=1, sort_keys=True) + "\n")
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
