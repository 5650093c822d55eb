"""Health of every written state and covariance of a run (issue 15: "10⁶ fitted tracks").

Reads the ``states`` table of one or more runs partition file by partition file (bounded
memory) and counts, per fitter × location:

- rows, and rows whose state (x, y, tx, ty, qop) or covariance (c00 … c44) holds a NaN or ±inf;
- covariances that are not positive definite: a negative smallest eigenvalue or a failing
  Cholesky factorisation of the 5×5 matrix, scaled to unit diagonal first (the correlation matrix: positions in mm and q/p in 1/MeV differ
  by ~10⁸, so the factorisation is judged on the correlations), fails, or a diagonal element is ≤ 0;
- the smallest eigenvalue of the correlation matrix (a near-singular covariance shows here first).

Fitted tracks are counted from the ``first_hit`` rows (one per fitted track and fitter). Prints one
table and, with --json, writes it::

    python benchmarks/covariance_health.py RUN [RUN ...] [--json out.json]

Exit code 1 when any row is non-finite or not positive definite, so it can gate a long run.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from pkf.io.schemas import COV_COLUMNS, STATE_COLUMNS, unpack_covariance


def state_files(run: Path) -> list[Path]:
    """Every Parquet file of the run's ``states`` table (a file or a folder of partitions)."""
    base = run / "states"
    if base.is_file():
        return [base]
    if base.with_suffix(".parquet").is_file():
        return [base.with_suffix(".parquet")]
    return sorted(base.rglob("*.parquet"))


def check_block(table) -> dict[str, np.ndarray]:
    """Per row: finite flag, positive-definite flag, smallest correlation eigenvalue."""
    state = np.column_stack([table.column(c).to_numpy() for c in STATE_COLUMNS])
    cov = unpack_covariance(table)
    finite = np.isfinite(state).all(axis=1) & np.isfinite(cov).all(axis=(1, 2))
    diag = np.diagonal(cov, axis1=1, axis2=2)
    positive_diag = finite & (diag > 0).all(axis=1)
    scale = np.where(positive_diag[:, None], 1.0 / np.sqrt(np.where(positive_diag[:, None], diag, 1.0)), 0.0)
    corr = cov * scale[:, :, None] * scale[:, None, :]
    corr[~positive_diag] = np.eye(5)
    min_eig = np.linalg.eigvalsh(corr)[:, 0]
    pd = positive_diag & (min_eig > 0.0)
    try:  # the whole block at once; row by row only if some matrix fails
        np.linalg.cholesky(corr[pd])
    except np.linalg.LinAlgError:
        for k in np.flatnonzero(pd):
            try:
                np.linalg.cholesky(corr[k])
            except np.linalg.LinAlgError:
                pd[k] = False
    min_eig[~positive_diag] = np.nan
    return {"finite": finite, "pd": pd, "min_eig": min_eig}


def health(runs: list[Path]) -> dict:
    """Counts per fitter × location over every states file of ``runs``."""
    counts: dict[tuple[str, str], dict] = defaultdict(
        lambda: {"rows": 0, "non_finite": 0, "not_pd": 0, "min_corr_eigenvalue": np.inf})
    columns = ["fitter", "location", *STATE_COLUMNS, *COV_COLUMNS]
    for run in runs:
        for file in state_files(run):
            table = pq.read_table(file, columns=columns)
            if table.num_rows == 0:
                continue
            flags = check_block(table)
            fitter = table.column("fitter").to_numpy(zero_copy_only=False)
            location = table.column("location").to_numpy(zero_copy_only=False)
            for key in set(zip(fitter, location)):
                rows = (fitter == key[0]) & (location == key[1])
                entry = counts[key]
                entry["rows"] += int(rows.sum())
                entry["non_finite"] += int((~flags["finite"][rows]).sum())
                entry["not_pd"] += int((flags["finite"][rows] & ~flags["pd"][rows]).sum())
                eig = flags["min_eig"][rows]
                if np.isfinite(eig).any():
                    entry["min_corr_eigenvalue"] = min(entry["min_corr_eigenvalue"], float(np.nanmin(eig)))
    table = [{"fitter": f, "location": loc, **v} for (f, loc), v in sorted(counts.items())]
    tracks = sum(row["rows"] for row in table if row["location"] == "first_hit")
    return {"runs": [str(r) for r in runs], "fitted_tracks": tracks,
            "rows": sum(row["rows"] for row in table),
            "bad_rows": sum(row["non_finite"] + row["not_pd"] for row in table), "table": table}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    result = health(args.runs)
    print(f"{'fitter':<13}{'location':<10}{'rows':>11}{'non-finite':>12}{'not PD':>8}{'min eig(corr)':>15}")
    for row in result["table"]:
        print(f"{row['fitter']:<13}{row['location']:<10}{row['rows']:>11,}{row['non_finite']:>12}"
              f"{row['not_pd']:>8}{row['min_corr_eigenvalue']:>15.3g}")
    print(f"fitted tracks (first_hit rows): {result['fitted_tracks']:,}; rows: {result['rows']:,}; "
          f"bad rows: {result['bad_rows']}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 1 if result["bad_rows"] else 0


if __name__ == "__main__":
    sys.exit(main())
