"""The paper's figures (Billoir et al., CPC 265 (2021) 108026, Figs. 1–4) in three commands.

Simulates B_s⁰ → φφ events in the lhcb-like detector, reconstructs them with the default
triplet pattern recognition and both Kalman fitters (parametrized and the Runge–Kutta
reference), and writes the report: resolution vs momentum with the ratio to the reference
(Fig. 1), pulls (Fig. 2), χ²/ndf of real and ghost tracks (Fig. 3), the B_s mass peak (Fig. 4)
and the fit speed.

    python examples/paper_figures.py --out figures [--events 500] [--pileup 1]

Open ``figures/report/index.html``; every number is also in ``figures/report/summary.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from _pkf import pkf


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="directory for dataset, run and report")
    parser.add_argument("--events", type=int, default=500, help="B_s → φφ events (the paper used far more)")
    parser.add_argument("--pileup", default="1", help="mean pp interactions per event (Run 3: 7.6)")
    parser.add_argument("--seed", default="1")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    dataset, run, report = args.out / "dataset", args.out / "run", args.out / "report"

    pkf("simulate", "--out", str(dataset), "--generator", "bs2phiphi", "--events", str(args.events),
        "--pileup", args.pileup, "--seed", args.seed, "--overwrite")
    pkf("reconstruct", str(dataset), "--out", str(run), "--fitter", "parametrized", "--fitter", "reference",
        "--overwrite")
    pkf("report", f"{run}:paper", "--out", str(report), "--overwrite")

    summary = json.loads((report / "summary.json").read_text())
    for name in summary["entry_order"]:
        entry = summary["entries"][name]
        qop = (entry["pulls"].get("parameters") or {}).get("qop") or {}
        speed = entry["timing"].get("speed_up_vs_reference")
        print(f"{name}: q/p pull width {qop.get('width')}, speed-up vs reference "
              f"{'n/a' if speed is None else f'{speed:.1f}x'}")
    print(f"report: {report / 'index.html'}")


if __name__ == "__main__":
    main()
