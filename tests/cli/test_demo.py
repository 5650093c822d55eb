"""`pkf demo`, the README's first command, end to end at a small size."""

import json

from pkf.cli import main


def test_demo_runs_and_reports_both_fitters(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--events", "20"]) == 0
    printed = capsys.readouterr().out
    assert "momentum resolution parametrized/reference" in printed and "fit speed-up" in printed
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert summary["entry_order"] == ["demo/parametrized", "demo/reference"]
    assert summary["reference"] == "demo/reference"
    for name in summary["entry_order"]:
        widths = [p["width"] for p in summary["entries"][name]["pulls"]["parameters"].values()]
        assert all(0.8 < w < 1.25 for w in widths), (name, widths)
    assert (out / "report" / "index.html").is_file()
