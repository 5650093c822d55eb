"""Cost of writing a run's tables: dictionary encoding everywhere against non-float columns only.

Reads every table of an existing run (``pkf reconstruct`` output) into memory and writes each one
to a temporary directory with pkf's Parquet options, once with ``use_dictionary=True`` for every
column (pkf before issue 18) and once with `pkf.io.atomic.parquet_write_options` (dictionary
pages for the non-float columns only), interleaved over --rounds rounds in one process; reports
the median CPU time per table and variant, the file sizes and whether the two files read back
to equal tables (NaN equal to NaN). Printed and as JSON::

    python benchmarks/parquet_write.py RUN_DIR [--rounds 5] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from pkf.io.atomic import PARQUET_WRITE_OPTIONS, parquet_write_options

TABLES = ("candidates", "chi2", "states", "pulls")


def _same(a, b) -> bool:
    """Equal tables, NaN equal to NaN (failed fits have NaN χ²)."""
    if not a.schema.equals(b.schema):
        return False
    for name in a.column_names:
        x, y = (t[name].to_numpy(zero_copy_only=False) for t in (a, b))
        if not (np.array_equal(x, y, equal_nan=True) if x.dtype.kind == "f" else np.array_equal(x, y)):
            return False
    return True


def _write(table, path: Path, options: dict) -> tuple[float, int]:
    start = time.process_time()
    pq.write_table(table, path, **options)
    return time.process_time() - start, path.stat().st_size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    variants = {"dictionary everywhere": lambda schema: {**PARQUET_WRITE_OPTIONS, "use_dictionary": True},
                "non-float columns only": parquet_write_options}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in TABLES:
            if not (args.run / name).exists():
                continue
            table = ds.dataset(args.run / name, format="parquet").to_table().combine_chunks()
            times = {v: [] for v in variants}
            sizes = {}
            for _ in range(args.rounds):
                for v, options in variants.items():
                    path = Path(tmp) / f"{name}.{len(sizes)}.parquet"
                    cpu, sizes[v] = _write(table, path, options(table.schema))
                    times[v].append(cpu)
            same = _same(pq.read_table(Path(tmp) / f"{name}.0.parquet"), pq.read_table(Path(tmp) / f"{name}.1.parquet"))
            old, new = (float(np.median(times[v])) for v in variants)
            rows.append({"table": name, "rows": table.num_rows, "cpu_s": {v: float(np.median(times[v])) for v in variants},
                         "bytes": sizes, "speed_up": old / new, "size_ratio": sizes["non-float columns only"]
                         / sizes["dictionary everywhere"], "same_content": bool(same)})
    print(f"{'table':<11} {'rows':>9} {'CPU s (dict all)':>17} {'CPU s (non-float)':>18} {'speed-up':>9} "
          f"{'size ratio':>11} same")
    for r in rows:
        c = list(r["cpu_s"].values())
        print(f"{r['table']:<11} {r['rows']:>9} {c[0]:>17.3f} {c[1]:>18.3f} {r['speed_up']:>9.2f} "
              f"{r['size_ratio']:>11.2f} {r['same_content']}")
    total = [sum(r["cpu_s"][v] for r in rows) for v in variants]
    print(f"{'all':<11} {'':>9} {total[0]:>17.3f} {total[1]:>18.3f} {total[0] / total[1]:>9.2f}")
    if args.json:
        args.json.write_text(json.dumps({"run": str(args.run), "rounds": args.rounds, "tables": rows}, indent=1))


if __name__ == "__main__":
    main()
