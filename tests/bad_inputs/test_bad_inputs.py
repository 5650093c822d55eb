"""DESIGN §13: every bad input of the corpus → exit 2, one line naming file, column and first
bad row, no traceback, nothing written (neither the run nor its hidden staging directory)."""

import json
import shutil
from pathlib import Path

import pytest

from pkf.cli import main
from pkf.errors import InputError
from pkf.pipeline.inputs import load_dataset

HERE = Path(__file__).resolve().parent
CASES = json.loads((HERE / "cases.json").read_text())


def _copy(case: str, tmp_path: Path) -> Path:
    """The case's dataset, copied so its path does not depend on where tests run."""
    return Path(shutil.copytree(HERE / case, tmp_path / case))


def test_corpus_covers_design_13():
    needed = {"missing_column", "wrong_dtype", "nan_value", "inf_value", "unknown_layer",
              "duplicate_hit", "unsorted_events", "empty_dataset", "truncated_file", "not_parquet",
              "params_other_geometry",
              # issue 13
              "sigma_too_small", "sigma_larger_than_layer", "hit_outside_area", "hit_at_1e300",
              "hit_in_beam_hole", "mc_hits_without_particles", "particles_without_mc_hits",
              "hits_without_truth", "zero_momentum", "particle_id_too_large", "geometry_toml_missing",
              "geometry_string_number", "params_nan_coefficient", "params_missing_slots",
              "params_short_coefficients",
              # issue 16: missing truth only on noise rows
              "null_truth_on_particle_row", "nan_truth_on_particle_row"}
    assert needed <= set(CASES)
    assert all((HERE / case).is_dir() for case in CASES)
    assert "extra_column" not in CASES  # issue 16: ignored with a warning (test_extra_column_is_ignored_...)


def test_extra_column_is_ignored_with_one_warning(tmp_path, capsys):
    """Issue 16: an extra column (here `charge` in hits) is no longer an error: the run
    succeeds and says once, on stderr, which columns it ignored."""
    dataset = _copy("extra_column", tmp_path)
    code = main(["reconstruct", str(dataset), "--out", str(tmp_path / "run"), "--workers", "1",
                 "--events-per-batch", "1"])
    err = capsys.readouterr().err
    assert code == 0, err
    warnings = [line for line in err.splitlines() if "warning" in line]
    assert warnings == [f"pkf: warning: {dataset / 'hits.parquet'}: column 'charge' not part of the hits schema: ignored"]
    assert json.loads((tmp_path / "run" / "run.json").read_text())["input"]["ignored_columns"] == {"hits": ["charge"]}


@pytest.mark.parametrize("case", sorted(CASES))
def test_reconstruct_rejects_bad_input(case, tmp_path, capsys):
    expect = CASES[case]
    dataset = _copy(case, tmp_path)
    out_parent = tmp_path / "out"
    out_parent.mkdir()
    args = [a.replace("{case}", str(dataset)) for a in expect["args"]]
    code = main(["reconstruct", str(dataset), "--out", str(out_parent / "run"), "--workers", "1", *args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("pkf: error: "), err
    assert "Traceback" not in err
    assert str(dataset / expect["file"]) in err
    if expect["column"] is not None:
        assert f"column {expect['column']!r}" in err
    if expect["row"] is not None:
        assert f": row {expect['row']} (" in err
    assert list(out_parent.iterdir()) == []  # no run, no staging directory


@pytest.mark.parametrize("case", sorted(c for c in CASES if not CASES[c]["args"]))
def test_streamed_and_in_memory_readers_agree(case, tmp_path, capsys):
    """The streaming validation of `pkf reconstruct` says exactly what the in-memory reader
    (used by `pkf tune` and reports, with the dataset's geometry and its layers' areas) says."""
    dataset = _copy(case, tmp_path)
    with pytest.raises(InputError) as in_memory:
        load_dataset(dataset)
    assert main(["reconstruct", str(dataset), "--out", str(tmp_path / "run"), "--workers", "1"]) == 2
    assert capsys.readouterr().err == f"pkf: error: {in_memory.value}\n"


@pytest.mark.parametrize("case, late_column, late_value", [
    ("hit_outside_area", "sigma_u", 1e4),  # u = 1e5 mm at row 7; an error larger than any layer
    ("unknown_layer", "u", float("nan")),  # layer 99 at row 11; a value rule of the table
    ("duplicate_hit", "event_id", 0),  # a duplicate at row 41; rows no longer sorted
    ("nan_value", "layer", 99),  # NaN at row 17; a check against the geometry
])
def test_readers_agree_on_the_first_bad_row_across_batches(tmp_path, monkeypatch, capsys, case, late_column,
                                                            late_value):
    """Issue 13: two defects found by different checks, the later row in a later record batch
    of the streamed scan: both readers name the earlier row (the first bad row over all checks)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    import pkf.io.stream

    dataset = _copy(case, tmp_path)
    hits = pq.read_table(dataset / "hits.parquet")
    i = hits.column_names.index(late_column)
    values = hits.column(late_column).to_pylist()
    values[700] = late_value  # in event 2
    hits = hits.set_column(i, hits.field(i), pa.array(values, hits.field(i).type))
    pq.write_table(hits, dataset / "hits.parquet")
    monkeypatch.setattr(pkf.io.stream, "BATCH_ROWS", 100)
    with pytest.raises(InputError) as in_memory:
        load_dataset(dataset)
    assert f"column {CASES[case]['column']!r}: row {CASES[case]['row']} (" in str(in_memory.value)
    assert main(["reconstruct", str(dataset), "--out", str(tmp_path / "run"), "--workers", "1"]) == 2
    assert capsys.readouterr().err == f"pkf: error: {in_memory.value}\n"
