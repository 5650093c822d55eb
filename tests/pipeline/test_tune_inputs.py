"""Bad input to `pkf tune` (issue 13 cases 7 and 12): the output is checked before any work,
and too little data is refused naming the steps, instead of a parameter file with zeros in
the steps that could not be fitted. Each case: exit 2, one line, nothing written."""

from __future__ import annotations

import os

import pytest

from pkf.cli import main

#: a dataset that does not exist: an --out problem must be reported before the dataset is read
NO_DATASET = "/nonexistent/pkf-dataset"


@pytest.fixture(scope="module")
def one_event(tmp_path_factory):
    out = tmp_path_factory.mktemp("tune") / "gun1"
    assert main(["simulate", "--out", str(out), "--generator", "gun", "--events", "1", "--seed", "1"]) == 0
    return out


def _refused(capsys, args, *fragments):
    code = main(["tune", *map(str, args)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("pkf: error: ") and err.count("\n") == 1, err
    for fragment in fragments:
        assert fragment in err, err
    return err


def test_out_is_an_existing_directory(tmp_path, capsys):
    folder = tmp_path / "params"
    folder.mkdir()
    for flags in ([], ["--overwrite"]):
        _refused(capsys, [NO_DATASET, "--out", folder, *flags], f"--out {folder}", "is a directory")
    assert list(folder.iterdir()) == []


def test_out_exists_needs_overwrite(tmp_path, capsys):
    out = tmp_path / "params.json"
    out.write_text("mine")
    _refused(capsys, [NO_DATASET, "--out", out], "--overwrite")
    assert out.read_text() == "mine"


def test_out_in_a_missing_folder(tmp_path, capsys):
    _refused(capsys, [NO_DATASET, "--out", tmp_path / "nope" / "params.json"], "does not exist")


def test_out_in_a_folder_without_write_permission(tmp_path, capsys, monkeypatch):
    """As os.access reports it (root may write anyway; the next test checks a real chmod)."""
    folder = tmp_path / "locked"
    folder.mkdir()
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if os.fspath(p) == str(folder) else real_access(p, mode))
    _refused(capsys, [NO_DATASET, "--out", folder / "params.json"], str(folder), "not writable")
    assert list(folder.iterdir()) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_out_in_a_read_only_folder(tmp_path, capsys):
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        _refused(capsys, [NO_DATASET, "--out", folder / "params.json"], "not writable")
    finally:
        folder.chmod(0o700)


def test_out_inside_the_dataset(one_event, capsys):
    before = {p: p.read_bytes() for p in one_event.iterdir()}
    _refused(capsys, [one_event, "--out", one_event / "hits.parquet", "--overwrite"], "inside the input")
    _refused(capsys, [one_event, "--out", one_event / "params.json"], "inside the input")
    assert {p: p.read_bytes() for p in one_event.iterdir()} == before


def test_one_event_is_too_little_data(one_event, tmp_path, capsys):
    """Before: a parameter file with 14 fits "NOT VALID" (zeros), q/p pull width 2.27."""
    out = tmp_path / "params.json"
    err = _refused(capsys, [one_event, "--out", out], str(one_event), "too little data", "slot 52 9/270",
                   "at least 30 events", "no parameter file written")
    assert "velo" not in err  # the shared VELO set has pairs enough
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_a_fit_that_is_not_valid_writes_no_file(tmp_path, capsys, monkeypatch):
    """Before: "NOT VALID" was printed and the parameter file written all the same."""
    import pkf.pipeline.tune as tune

    data = tmp_path / "tel"
    assert main(["simulate", "--out", str(data), "--geometry", "telescope", "--generator", "gun",
                 "--events", "40", "--seed", "2"]) == 0
    real = tune.tune_slots

    def one_invalid(*args, **kwargs):
        result = real(*args, **kwargs)
        result.reports["slot 3"]["noise"]["valid"] = False
        return result

    monkeypatch.setattr(tune, "tune_slots", one_invalid)
    out = tmp_path / "params.json"
    code = main(["tune", str(data), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.splitlines()[-1].startswith("pkf: error: ") and "slot 3 noise" in err.splitlines()[-1], err
    assert not out.exists()
    monkeypatch.setattr(tune, "tune_slots", real)
    assert main(["tune", str(data), "--out", str(out)]) == 0  # the same sample, every fit valid
    assert out.is_file()
