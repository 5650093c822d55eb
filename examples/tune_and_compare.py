"""Tune the parametrized extrapolations on your own simulation and compare them with the shipped set.

`pkf tune` reproduces the paper's procedure (§4): extrapolation parameters from true state
pairs against the Runge–Kutta reference, noise parameters against the true states. This script
tunes on a pion gun, reconstructs an independent sample with the shipped and with the tuned
parameters, and writes one report with both, the shipped set as the reference:

    python examples/tune_and_compare.py --out tuning [--tune-events 200] [--test-events 100]

The tuned set is good when its pulls are as close to 1 as the shipped set's and the
resolution ratio is 1 within errors (``tuning/report/index.html``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from _pkf import pkf


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--tune-events", type=int, default=200, help="gun events for the tuning (≥ 30)")
    parser.add_argument("--test-events", type=int, default=100, help="independent gun events to compare on")
    parser.add_argument("--geometry", default="lhcb-like", help="built-in geometry name or a TOML file")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    tune_data, test_data = args.out / "tune_data", args.out / "test_data"
    params = args.out / "tuned.json"

    gun = ["--generator", "gun", "--geometry", args.geometry, "--p-min", "2000", "--p-max", "100000"]
    pkf("simulate", "--out", str(tune_data), *gun, "--events", str(args.tune_events), "--seed", "11", "--overwrite")
    pkf("simulate", "--out", str(test_data), *gun, "--events", str(args.test_events), "--seed", "12", "--overwrite")
    pkf("tune", str(tune_data), "--out", str(params), "--overwrite")
    runs = {"shipped": args.out / "run_shipped", "tuned": args.out / "run_tuned"}
    pkf("reconstruct", str(test_data), "--out", str(runs["shipped"]), "--pattern", "truth", "--overwrite")
    pkf("reconstruct", str(test_data), "--out", str(runs["tuned"]), "--pattern", "truth", "--params", str(params),
        "--overwrite")
    report = args.out / "report"
    pkf("report", f"{runs['shipped']}:shipped", f"{runs['tuned']}:tuned", "--reference", "shipped",
        "--out", str(report), "--overwrite")

    summary = json.loads((report / "summary.json").read_text())
    for name in summary["entry_order"]:
        pulls = summary["entries"][name]["pulls"]["parameters"]
        print(f"{name:>22}: pull widths " + ", ".join(f"{p} {pulls[p]['width']:.3f}" for p in pulls))
    print(f"report: {report / 'index.html'}")


if __name__ == "__main__":
    main()
