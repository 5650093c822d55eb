"""Every script in examples/ runs at a small size and produces what its docstring promises."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def run_example(name: str, *args: str) -> str:
    result = subprocess.run([sys.executable, str(EXAMPLES / name), *args], capture_output=True, text=True,
                            timeout=900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return result.stdout


def test_examples_are_all_tested():
    scripts = {p.name for p in EXAMPLES.glob("*.py") if not p.name.startswith("_")}
    tested = {"paper_figures.py", "tune_and_compare.py", "downstream_analysis.py", "dask_run.py",
              "bring_your_own_data.py"}
    assert scripts == tested


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    printed = run_example("paper_figures.py", "--out", str(out), "--events", "15")
    return out, printed


def test_paper_figures(paper):
    out, printed = paper
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert summary["entry_order"] == ["paper/parametrized", "paper/reference"]
    assert (out / "report" / "resolution.png").is_file() and "speed-up vs reference" in printed


def test_downstream_analysis(paper, tmp_path):
    out, _ = paper
    printed = run_example("downstream_analysis.py", str(out / "run"), "--out", str(tmp_path))
    assert {p.name for p in tmp_path.glob("*.png")} == {"pull_qop.png", "dp_over_p.png", "chi2_ndf.png"}
    width = float(printed.split("core width ")[1].split(";")[0])
    assert 0.7 < width < 1.4, printed


def test_tune_and_compare(tmp_path):
    printed = run_example("tune_and_compare.py", "--out", str(tmp_path), "--tune-events", "40",
                          "--test-events", "20", "--geometry", "telescope")
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    assert summary["reference"] == "shipped/parametrized"
    assert set(summary["entry_order"]) == {"shipped/parametrized", "tuned/parametrized"}
    assert "tuned/parametrized: pull widths" in printed


def test_dask_run(tmp_path):
    pytest.importorskip("dask.distributed")
    printed = run_example("dask_run.py", "--out", str(tmp_path), "--events", "12", "--workers", "2")
    assert printed.count("identical to the local run") == 4


def test_bring_your_own_data(tmp_path):
    """A dataset written with plain pyarrow (no meta.json, an extra column, NaN truth on noise
    rows) validates, reconstructs with --geometry and gives finite pulls for both fitters."""
    printed = run_example("bring_your_own_data.py", "--out", str(tmp_path), "--events", "10")
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    assert summary["entry_order"] == ["mine/parametrized", "mine/reference"]
    for name in summary["entry_order"]:
        pulls = summary["entries"][name]["pulls"]["parameters"]
        assert pulls["x"]["n"] == 100 and 0.7 < pulls["x"]["width"] < 1.2, pulls["x"]
    assert "pull widths" in printed
