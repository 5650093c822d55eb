"""Damaged runs (issue 13 case 9): a partition file that run.json lists is missing, changed or
joined by an unlisted one → `pkf report` refuses the run with one line naming the file, exit 2,
and writes nothing (DESIGN §13). Before, a deleted partition gave a report of part of the tracks."""

from __future__ import annotations

import json
import shutil

import pytest

from pkf.cli import main
from pkf.errors import InputError
from pkf.report.runs import load_run


@pytest.fixture()
def run_copy(telescope_runs, tmp_path):
    """A copy of a real two-partition run of `pkf reconstruct` (100 events, 50 per partition)."""
    run = tmp_path / "run"
    shutil.copytree(telescope_runs["parametrized"], run)
    return run


def _partition_files(run):
    info = json.loads((run / "run.json").read_text())
    return [run / f["path"] for p in info["partitions"] for f in p["files"].values()]


def _refused(capsys, run, tmp_path, *fragments):
    out = tmp_path / "report"
    code = main(["report", str(run), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("pkf: error: ") and err.count("\n") == 1, err
    for fragment in fragments:
        assert fragment in err, err
    assert "Traceback" not in err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".report")]
    return err


def test_intact_run_is_accepted(run_copy):
    files = _partition_files(run_copy)
    assert len(files) >= 6 and {f.parent.name for f in files} >= {"chi2", "states", "candidates", "pulls"}
    run = load_run(run_copy)
    assert run.table("chi2").num_rows > 0


def test_deleted_partition_is_refused(run_copy, tmp_path, capsys):
    victim = next(f for f in _partition_files(run_copy) if f.parent.name == "chi2")
    victim.unlink()
    _refused(capsys, run_copy, tmp_path, str(victim), "missing")


def test_deleted_candidates_partition_is_refused(run_copy, tmp_path, capsys):
    """The report does not read candidates, but the run is damaged all the same."""
    victim = next(f for f in _partition_files(run_copy) if f.parent.name == "candidates")
    victim.unlink()
    _refused(capsys, run_copy, tmp_path, str(victim), "missing")


def test_truncated_partition_is_refused(run_copy, tmp_path, capsys):
    victim = next(f for f in _partition_files(run_copy) if f.parent.name == "states")
    data = victim.read_bytes()
    victim.write_bytes(data[: len(data) // 2])
    _refused(capsys, run_copy, tmp_path, str(victim), "changed")


def test_one_modified_byte_is_refused(run_copy, tmp_path, capsys):
    """A flipped byte in the middle of a data page: the file may still read as Parquet."""
    victim = next(f for f in _partition_files(run_copy) if f.parent.name == "pulls")
    data = bytearray(victim.read_bytes())
    data[len(data) // 3] ^= 0x01
    victim.write_bytes(bytes(data))
    _refused(capsys, run_copy, tmp_path, str(victim), "changed", "SHA-256")


def test_stray_partition_is_refused(run_copy, tmp_path, capsys):
    source = next(f for f in _partition_files(run_copy) if f.parent.name == "chi2")
    stray = source.with_name("part-9999-99999.parquet")
    shutil.copy(source, stray)
    _refused(capsys, run_copy, tmp_path, str(stray), "not listed")


def test_stray_single_file_table_is_refused(run_copy, tmp_path, capsys):
    """A ``pulls.parquet`` beside ``pulls/`` is a file a reader could take for the table."""
    source = next(f for f in _partition_files(run_copy) if f.parent.name == "pulls")
    shutil.copy(source, run_copy / "pulls.parquet")
    _refused(capsys, run_copy, tmp_path, str(run_copy / "pulls.parquet"), "not listed")


def test_partition_list_pointing_outside_the_run_is_refused(run_copy):
    info = json.loads((run_copy / "run.json").read_text())
    record = info["partitions"][0]["files"]["chi2"]
    record["path"] = "../../etc/passwd"
    (run_copy / "run.json").write_text(json.dumps(info))
    with pytest.raises(InputError, match=r"run\.json: partitions\[0\]\.files\.chi2"):
        load_run(run_copy)


def test_a_run_written_before_the_track_type_column_is_still_reported(run_copy, tmp_path):
    """Runs of pkf before `chi2.track_type` (issue 15) have no such column: the report reads
    them (types from the hit counts) instead of refusing them as malformed."""
    import hashlib

    import pyarrow.parquet as pq

    with_types = tmp_path / "with-types"
    assert main(["report", str(run_copy), "--out", str(with_types)]) == 0
    typed = json.loads((with_types / "summary.json").read_text())["entries"]["run/parametrized"]
    info = json.loads((run_copy / "run.json").read_text())
    for partition in info["partitions"]:
        entry = partition["files"]["chi2"]
        path = run_copy / entry["path"]
        table = pq.read_table(path)
        pq.write_table(table.drop_columns(["track_type"]), path)
        entry["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    (run_copy / "run.json").write_text(json.dumps(info))
    out = tmp_path / "report"
    assert main(["report", str(run_copy), "--out", str(out)]) == 0
    entry = json.loads((out / "summary.json").read_text())["entries"]["run/parametrized"]
    assert entry["resolution"]["available"] and entry["tracks"]["matched"] > 0
    # the telescope: every track spans the detector, with or without the column (issue 17.2 by type)
    assert list(typed["chi2"]["by_type"]) == ["long"]
    assert entry["chi2"]["by_type"] == typed["chi2"]["by_type"]
    assert entry["efficiency"]["by_type"] == typed["efficiency"]["by_type"]
    assert entry["efficiency"]["by_type"]["long"]["found"] == entry["efficiency"]["found"] > 0
