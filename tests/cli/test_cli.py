"""The command line contract: exit codes and one-line errors (DESIGN §1.1, §13)."""

import json
import os
import subprocess
import sys

import pytest

from pkf.cli import main


def _run(capsys, *args):
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_simulate_writes_a_dataset(tmp_path, capsys):
    out = tmp_path / "ds"
    code, stdout, _ = _run(capsys, "simulate", "--out", str(out), "--events", "3", "--generator", "gun",
                           "--species", "muon", "--particles", "5", "--seed", "4")
    assert code == 0
    assert "3 events" in stdout
    meta = json.loads((out / "meta.json").read_text())
    assert meta["generator"] == "gun" and meta["seed"] == 4 and meta["config"]["species"] == "muon"
    assert sorted(p.name for p in out.iterdir()) == sorted(["geometry.toml", "hits.parquet", "meta.json",
                                                     "mc_hits.parquet", "particles.parquet"])


@pytest.mark.parametrize(
    "args, message",
    [
        (["--events", "-5"], "--events"),
        (["--events", "0"], "--events"),
        (["--geometry", "atlas"], "unknown geometry"),
        (["--generator", "herwig"], "--generator"),
        (["--species", "tau"], "--species"),
        (["--pileup", "-1"], "--pileup"),
        (["--p-min", "5000", "--p-max", "100"], "--p-min"),
        (["--events", "ten"], "--events"),
    ],
)
def test_bad_options_exit_2_with_one_line(tmp_path, capsys, args, message):
    out = tmp_path / "ds"
    code, _, err = _run(capsys, "simulate", "--out", str(out), *args)
    assert code == 2
    assert message in err
    assert err.count("\n") == 1
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir()]  # no staging leftovers either


def test_unwritable_or_occupied_out(tmp_path, capsys):
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "keep.txt").write_text("mine")
    code, _, err = _run(capsys, "simulate", "--out", str(occupied), "--events", "1")
    assert code == 2 and "--overwrite" in err and err.count("\n") == 1
    assert (occupied / "keep.txt").read_text() == "mine"
    code, _, err = _run(capsys, "simulate", "--out", str(tmp_path / "no" / "such" / "dir"), "--events", "1")
    assert code == 2 and err.count("\n") == 1
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, _, err = _run(capsys, "simulate", "--out", str(blocker / "ds"), "--events", "1")
    assert code == 2 and err.count("\n") == 1


def test_console_script_runs(tmp_path):
    env = dict(os.environ)
    result = subprocess.run([sys.executable, "-m", "pkf.cli", "simulate", "--out", str(tmp_path / "d"),
                             "--events", "-1"], capture_output=True, text=True, env=env, check=False)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("command, hint", [("reconstruct", "rerun the same reconstruct command to resume"),
                                           ("simulate", "nothing was written")])
def test_ctrl_c_exits_130_with_what_to_do(tmp_path, capsys, monkeypatch, command, hint):
    """Issue 13 case 8: click turned Ctrl-C into Abort (exit 1, "aborted"); it is exit 130 with a
    hint that fits the command, on one line."""
    import pkf.pipeline.reconstruct
    import pkf.pipeline.simulate

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pkf.pipeline.reconstruct, "run_reconstruction", interrupted)
    monkeypatch.setattr(pkf.pipeline.simulate, "run_simulation", interrupted)
    args = {"reconstruct": ["reconstruct", str(tmp_path), "--out", str(tmp_path / "run")],
            "simulate": ["simulate", "--out", str(tmp_path / "ds")]}[command]
    assert main(args) == 130
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pkf: interrupted") and hint in err, err


@pytest.mark.parametrize("option, value", [("--gsf-weight-cut", "nan"), ("--gsf-sibling-merge", "NaN"),
                                           ("--gsf-product-merge", "inf"), ("--gsf-sibling-merge", "-1")])
def test_gsf_factors_out_of_range_are_usage_errors(tmp_path, capsys, option, value):
    """NaN passes click's FloatRange (no comparison is true); it was an internal error (exit 1)
    from the options' own check, and inf made the GSF's component count overflow."""
    code, _, err = _run(capsys, "reconstruct", str(tmp_path / "no-dataset"), "--out", str(tmp_path / "run"),
                        option, value)
    assert code == 2 and err.count("\n") == 1 and option in err
    assert not (tmp_path / "run").exists()
