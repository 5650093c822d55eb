"""Cost of pkf's Parquet files by codec: zstd at level 1 against LZ4 (issue 18.4), to write and to decode.

Reads each table given (a dataset directory: hits, particles, mc_hits; a run directory: its four
tables, all partitions as one) into memory, writes it to a temporary directory with pkf's options
(`pkf.io.atomic.parquet_write_options`) under each codec, then decodes each file as `pkf reconstruct`
reads its inputs (``iter_batches``, one thread, no pre-buffering, `pkf.io.stream.BATCH_ROWS` rows),
codecs interleaved over --rounds rounds in one process. Reports the median CPU seconds to write
and to decode and the file sizes per table and codec; printed and as JSON::

    python benchmarks/parquet_codecs.py DATASET_OR_RUN [...] [--rounds 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pkf.io.atomic import parquet_write_options
from pkf.io.stream import BATCH_ROWS

DATASET_TABLES = ("hits", "particles", "mc_hits")
RUN_TABLES = ("candidates", "chi2", "states", "pulls")
CODECS = {"zstd-1": {"compression": "zstd", "compression_level": 1}, "lz4": {"compression": "lz4"}}


def tables_of(directory: Path) -> dict[str, pa.Table]:
    """name → table of a dataset's or a run's Parquet files (all of a table's files as one)."""
    out = {}
    for name in DATASET_TABLES + RUN_TABLES:
        files = sorted(p for p in directory.rglob("*.parquet") if p.stem == name or p.parent.name == name)
        if files:
            out[f"{directory.name}:{name}"] = pa.concat_tables([pq.read_table(f) for f in files])
    return out


def write(table: pa.Table, path: Path, codec: str) -> float:
    """CPU seconds to write `table` with pkf's options and `codec`."""
    options = {k: v for k, v in parquet_write_options(table.schema).items() if k != "compression_level"}
    options.update(CODECS[codec])
    t0 = time.process_time()
    pq.write_table(table, path, **options)
    return time.process_time() - t0


def decode(path: Path) -> float:
    """CPU seconds to decode every batch of `path` as pkf's scan does."""
    t0 = time.process_time()
    pf = pq.ParquetFile(path, pre_buffer=False, buffer_size=1 << 20)
    for _ in pf.iter_batches(batch_size=BATCH_ROWS, use_threads=False):
        pass
    return time.process_time() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dirs", type=Path, nargs="+", help="dataset or run directories")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    results = {}
    print(f"{'table':<28}{'codec':>8}{'MB':>9}{'write s':>9}{'decode s':>10}")
    with tempfile.TemporaryDirectory() as tmp:
        for directory in args.dirs:
            for name, table in tables_of(directory).items():
                times = {c: {"write": [], "decode": []} for c in CODECS}
                for _ in range(args.rounds):
                    for codec in CODECS:
                        path = Path(tmp) / f"{codec}.parquet"
                        times[codec]["write"].append(write(table, path, codec))
                        times[codec]["decode"].append(decode(path))
                        times[codec]["mb"] = path.stat().st_size / 1e6
                results[name] = {
                    c: {
                        "mb": t["mb"],
                        "write_s": float(np.median(t["write"])),
                        "decode_s": float(np.median(t["decode"])),
                    }
                    for c, t in times.items()
                }
                for codec, r in results[name].items():
                    print(f"{name:<28}{codec:>8}{r['mb']:>9.1f}{r['write_s']:>9.3f}{r['decode_s']:>10.3f}")
    if args.json:
        args.json.write_text(json.dumps({"rounds": args.rounds, "tables": results}, indent=2) + "\n")


if __name__ == "__main__":
    main()
