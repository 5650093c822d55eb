"""Reconstruct on a Dask cluster: the same command as a local run, with `--scheduler ADDRESS`.

On a batch farm, start `dask scheduler` on one node and `dask worker tcp://SCHEDULER:8786` on
the others (all with pkf installed and the dataset and output on a shared filesystem), then run
`pkf reconstruct DATASET --out RUN --scheduler tcp://SCHEDULER:8786`. This script does the same
on this machine with a local cluster of worker processes, and checks that the tables equal those
of a run without Dask:

    python examples/dask_run.py --out dask_demo [--events 40] [--workers 2]

Needs the dask extra: pip install "pkf[dask]".
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pyarrow as pa
import pyarrow.dataset as ds
from _pkf import pkf


def table_bytes(run: Path, name: str) -> bytes:
    """A run table's content, sorted by its keys, as Arrow IPC bytes (NaN compares equal to NaN)."""
    data = ds.dataset(run / name, format="parquet").to_table()
    keys = [k for k in ("event_id", "track_id", "fitter", "location", "hit_id") if k in data.column_names]
    data = data.sort_by([(k, "ascending") for k in keys]).combine_chunks()
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, data.schema) as writer:
        writer.write_table(data)
    return sink.getvalue().to_pybytes()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--events", type=int, default=40)
    parser.add_argument("--workers", type=int, default=2, help="Dask worker processes")
    args = parser.parse_args()
    from dask.distributed import LocalCluster

    args.out.mkdir(parents=True, exist_ok=True)
    dataset = args.out / "dataset"
    pkf("simulate", "--out", str(dataset), "--generator", "minbias", "--pileup", "2", "--events", str(args.events),
        "--overwrite")
    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster:
        print(f"Dask scheduler at {cluster.scheduler_address}")
        pkf("reconstruct", str(dataset), "--out", str(args.out / "run_dask"), "--scheduler", cluster.scheduler_address,
            "--events-per-batch", "10", "--overwrite")
    pkf("reconstruct", str(dataset), "--out", str(args.out / "run_local"), "--workers", "1", "--overwrite")
    for name in ("candidates", "chi2", "states", "pulls"):
        same = table_bytes(args.out / "run_dask", name) == table_bytes(args.out / "run_local", name)
        print(f"{name}: {'identical' if same else 'DIFFERENT'} to the local run")
        if not same:
            raise SystemExit(f"{name} differs between the Dask and the local run")


if __name__ == "__main__":
    main()
