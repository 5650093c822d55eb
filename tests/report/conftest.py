"""Run directories for the report tests, made once per session with the real command line.

- ``telescope_runs``: a telescope gun dataset, one run per fitter (parametrized,
  reference), so the report merges fitters from two runs.
- ``bs_run``: an lhcb-like B_s⁰ → φφ dataset (30 events) fitted by the reference
  fitter, for the mass peak and the efficiency of long particles.
- ``telescope_report`` / ``bs_report``: the reports of those runs.
"""

from __future__ import annotations

import pytest

from pkf.cli import main
from pkf.pipeline.report import run_report


@pytest.fixture(scope="session")
def telescope_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("report-telescope")
    data = base / "data"
    assert main(["simulate", "--out", str(data), "--geometry", "telescope", "--generator", "gun",
                 "--events", "100", "--seed", "1"]) == 0
    runs = {}
    for fitter in ("parametrized", "reference"):
        runs[fitter] = base / f"run_{fitter}"
        assert main(["reconstruct", str(data), "--out", str(runs[fitter]), "--pattern", "truth",
                     "--fitter", fitter]) == 0
    return runs


@pytest.fixture(scope="session")
def bs_run(tmp_path_factory):
    base = tmp_path_factory.mktemp("report-bs")
    data, run = base / "data", base / "run"
    assert main(["simulate", "--out", str(data), "--generator", "bs2phiphi", "--events", "30", "--seed", "3"]) == 0
    assert main(["reconstruct", str(data), "--out", str(run), "--pattern", "truth", "--fitter", "reference"]) == 0
    return run


@pytest.fixture(scope="session")
def telescope_report(telescope_runs, tmp_path_factory):
    out = tmp_path_factory.mktemp("report-out") / "telescope"
    summary = run_report([telescope_runs["parametrized"], telescope_runs["reference"]], out)
    return out, summary


@pytest.fixture(scope="session")
def bs_report(bs_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("report-out") / "bs"
    summary = run_report([bs_run], out)
    return out, summary
