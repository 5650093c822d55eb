"""Bad input to the report: a one-line InputError and nothing written (DESIGN §13)."""

from __future__ import annotations

import json
import shutil

import pytest
from report_helpers import write_synthetic_run

from pkf.errors import InputError
from pkf.pipeline.report import run_report


@pytest.fixture()
def good_run(tmp_path):
    run = tmp_path / "run"
    write_synthetic_run(run, fitters=("parametrized", "reference"), n_tracks=200)
    return run


def _assert_refused(runs, out, *fragments):
    with pytest.raises(InputError) as err:
        run_report(runs, out)
    message = str(err.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    assert not out.exists()
    leftovers = [p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]
    assert leftovers == []
    return message


def test_missing_run_json(good_run, tmp_path):
    (good_run / "run.json").unlink()
    _assert_refused([good_run], tmp_path / "report", "run.json", "not found")


def test_missing_chi2(good_run, tmp_path):
    (good_run / "chi2.parquet").unlink()
    _assert_refused([good_run], tmp_path / "report", "chi2", "not found")


def test_chi2_of_another_schema(good_run, tmp_path):
    shutil.copy(good_run / "candidates.parquet", good_run / "chi2.parquet")
    _assert_refused([good_run], tmp_path / "report", "chi2.parquet", "column")


def test_truncated_table(good_run, tmp_path):
    data = (good_run / "states.parquet").read_bytes()
    (good_run / "states.parquet").write_bytes(data[: len(data) // 2])
    _assert_refused([good_run], tmp_path / "report", "states.parquet")


def test_run_json_of_another_kind(good_run, tmp_path):
    info = json.loads((good_run / "run.json").read_text())
    info["kind"] = "dataset"
    (good_run / "run.json").write_text(json.dumps(info))
    _assert_refused([good_run], tmp_path / "report", "run.json", "dataset")


def test_run_json_not_json(good_run, tmp_path):
    (good_run / "run.json").write_text("{not json")
    _assert_refused([good_run], tmp_path / "report", "run.json", "not valid JSON")


def test_dataset_instead_of_run(tmp_path):
    dataset = tmp_path / "data"
    dataset.mkdir()
    (dataset / "meta.json").write_text("{}")
    _assert_refused([dataset], tmp_path / "report", "run.json")


def test_missing_directory(tmp_path):
    _assert_refused([tmp_path / "nope"], tmp_path / "report", "does not exist")


def test_same_label_twice(good_run, tmp_path):
    """The same run twice (or two folders of one name) needs labels to tell the entries apart."""
    _assert_refused([good_run, good_run], tmp_path / "report", "label", "RUN:LABEL")


def test_bad_label_or_reference(good_run, tmp_path):
    _assert_refused([f"{good_run}:a/b"], tmp_path / "report", "without '/'")
    _assert_refused([f"{good_run}:"], tmp_path / "report", "non-empty")
    with pytest.raises(InputError, match="--reference nope: no such entry"):
        run_report([good_run], tmp_path / "report", reference="nope")


def test_no_runs(tmp_path):
    _assert_refused([], tmp_path / "report", "at least one run")


def test_out_overlapping_a_run(good_run):
    with pytest.raises(InputError, match="the input"):
        run_report([good_run], good_run / "report")
    with pytest.raises(InputError, match="the input"):
        run_report([good_run], good_run, overwrite=True)
    assert (good_run / "chi2.parquet").is_file() and not (good_run / "report").exists()


def test_existing_output_needs_overwrite(good_run, tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "old.txt").write_text("x")
    with pytest.raises(InputError, match="overwrite"):
        run_report([good_run], out)
    assert (out / "old.txt").is_file()
    run_report([good_run], out, overwrite=True)
    assert not (out / "old.txt").exists() and (out / "summary.json").is_file()
