"""Tests of pkf.io.atomic: deterministic Parquet, JSON format, atomic replacement, staged output directories."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from io_helpers import make_tables, raises_input_error

from pkf.errors import CtrlC, InputError
from pkf.io import HITS, atomic_write_json, atomic_write_table, check_output_dir, staged_output_dir
from pkf.io import atomic as atomic_module
from pkf.io.writer import StreamingTableWriter


def test_parquet_bytes_are_deterministic(tmp_path):
    hits = make_tables(20)["hits"]
    a = atomic_write_table(hits, tmp_path / "a.parquet")
    b = atomic_write_table(make_tables(20)["hits"], tmp_path / "b.parquet")
    # the same data in another chunk layout and column order
    rechunked = pa.concat_tables([hits.slice(0, 7), hits.slice(7, 50), hits.slice(57)])
    shuffled = rechunked.select(list(reversed(HITS.names)))
    c = atomic_write_table(shuffled, tmp_path / "c.parquet", schema=HITS)
    assert a.read_bytes() == b.read_bytes() == c.read_bytes()
    assert pq.read_table(a).equals(hits)
    assert pq.ParquetFile(a).metadata.row_group(0).column(0).compression == "LZ4"  # LZ4_RAW


def test_atomic_write_table_replaces_and_leaves_no_temp(tmp_path):
    tables = make_tables(2)
    path = tmp_path / "t.parquet"
    atomic_write_table(tables["hits"], path)
    atomic_write_table(tables["particles"], path)
    assert pq.read_table(path).equals(tables["particles"])
    assert [p.name for p in tmp_path.iterdir()] == ["t.parquet"]


def test_atomic_write_table_refuses_nulls_in_required_columns(tmp_path):
    hits = make_tables(1)["hits"]
    u = hits.column("u").to_pylist()
    u[0] = None
    bad = hits.set_column(4, "u", pa.array(u))
    with pytest.raises(ValueError, match="'u' with null"):
        atomic_write_table(bad, tmp_path / "hits.parquet", schema=HITS)
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_table_failure_keeps_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "hits.parquet"
    atomic_write_table(make_tables(1)["hits"], path)
    before = path.read_bytes()

    def crash(table, where, **kwargs):
        Path(where).write_bytes(b"PAR1 partial")
        raise OSError("disk full")

    monkeypatch.setattr(atomic_module.pq, "write_table", crash)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_table(make_tables(3)["hits"], path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["hits.parquet"]


def test_atomic_write_json_format(tmp_path):
    path = atomic_write_json(
        {"b": np.float64(1.5), "a": [np.int64(3), (1, 2)], "c": {"nan": float("nan"), "inf": np.inf},
         "d": np.arange(2), "e": tmp_path / "x", "f": np.bool_(True)},
        tmp_path / "run.json",
    )
    text = path.read_text()
    assert text.endswith("}\n") and not text.endswith("\n\n")
    assert text.startswith('{\n  "a": [\n    3,')
    data = json.loads(text)
    assert list(data) == ["a", "b", "c", "d", "e", "f"]
    assert data == {"a": [3, [1, 2]], "b": 1.5, "c": {"inf": None, "nan": None}, "d": [0, 1],
                    "e": str(tmp_path / "x"), "f": True}
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]
    with pytest.raises(TypeError):
        atomic_write_json({"x": object()}, tmp_path / "bad.json")
    assert not (tmp_path / "bad.json").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["run.json"]


def test_staged_output_dir_success(tmp_path):
    out = tmp_path / "run"
    with staged_output_dir(out, overwrite=False) as staging:
        assert staging.parent == tmp_path and staging.name.startswith(".run.")
        assert not out.exists()
        atomic_write_json({"ok": True}, staging / "run.json")
    assert json.loads((out / "run.json").read_text()) == {"ok": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert (out.stat().st_mode & 0o777) == (0o777 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_staged_output_dir_exception_leaves_nothing(tmp_path, exc):
    out = tmp_path / "run"
    with pytest.raises(type(exc)):
        with staged_output_dir(out, overwrite=False) as staging:
            (staging / "partial.parquet").write_bytes(b"x")
            raise exc
    assert list(tmp_path.iterdir()) == []


def test_staged_output_dir_does_not_commit_after_a_swallowed_ctrl_c(tmp_path, monkeypatch):
    """A library that caught the KeyboardInterrupt (a bare except) let the command run on:
    the output must still not appear (the CLI then exits 130)."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.txt").write_text("old")
    monkeypatch.setattr(CtrlC, "seen", True)
    with pytest.raises(KeyboardInterrupt):
        with staged_output_dir(out, overwrite=True) as staging:
            (staging / "new.txt").write_text("new")
    assert [p.name for p in tmp_path.iterdir()] == ["run"]
    assert [p.name for p in out.iterdir()] == ["old.txt"]


def test_staged_output_dir_exception_keeps_previous_output(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with pytest.raises(RuntimeError):
        with staged_output_dir(out, overwrite=True) as staging:
            (staging / "new.txt").write_text("new")
            raise RuntimeError("crash")
    assert [p.name for p in tmp_path.iterdir()] == ["run"]
    assert [p.name for p in out.iterdir()] == ["old.txt"]


def test_staged_output_dir_refuses_non_empty_without_overwrite(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.txt").write_text("old")
    entered = []

    def enter():
        with staged_output_dir(out, overwrite=False):
            entered.append(True)

    raises_input_error(enter, str(out), "not empty", "--overwrite")
    assert not entered
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert (out / "old.txt").read_text() == "old"


def test_staged_output_dir_overwrite_replaces(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with staged_output_dir(out, overwrite=True) as staging:
        (staging / "new.txt").write_text("new")
    assert [p.name for p in out.iterdir()] == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_staged_output_dir_accepts_empty_existing_dir(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    with staged_output_dir(out, overwrite=False) as staging:
        (staging / "a").write_text("a")
    assert [p.name for p in out.iterdir()] == ["a"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_output_dir_checks(tmp_path):
    (tmp_path / "file").write_text("x")
    raises_input_error(lambda: check_output_dir(tmp_path / "file", overwrite=True), "file", "not a directory")
    raises_input_error(
        lambda: check_output_dir(tmp_path / "missing" / "run", overwrite=False), "run", "does not exist"
    )
    assert check_output_dir(tmp_path / "new", overwrite=False) == tmp_path / "new"
    with pytest.raises(InputError):
        with staged_output_dir(tmp_path / "file", overwrite=True):
            pass  # pragma: no cover
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_output_dir_parent_not_writable(tmp_path):
    parent = tmp_path / "ro"
    parent.mkdir()
    parent.chmod(0o500)
    try:
        raises_input_error(lambda: check_output_dir(parent / "run", overwrite=False), "not writable")
    finally:
        parent.chmod(0o700)


def test_streaming_writer_is_deterministic(tmp_path):
    hits = make_tables(6)["hits"]
    paths = []
    for name in ("a.parquet", "b.parquet"):
        writer = StreamingTableWriter(tmp_path / name, HITS)
        assert not (tmp_path / name).exists()
        writer.write(hits.slice(0, 20))
        writer.write(hits.slice(20))
        paths.append(writer.close())
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert pq.read_table(paths[0]).equals(hits)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.parquet", "b.parquet"]
