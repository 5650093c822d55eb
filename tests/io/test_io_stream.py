"""Streamed validation (pkf.io.stream): checks that span batches and files, event index, row reads."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import pkf.io.stream as stream
from pkf.errors import InputError
from pkf.io.reader import read_table
from pkf.io.schemas import HITS


def _hits(events, per_event=5, first_hit=0):
    ev = np.repeat(np.asarray(events, dtype=np.int64), per_event)
    hit = np.tile(np.arange(first_hit, first_hit + per_event, dtype=np.int64), len(events))
    n = ev.size
    return pa.table({"event_id": ev, "hit_id": hit, "layer": np.zeros(n, np.int16), "z": np.zeros(n),
                     "u": np.arange(n, dtype=float), "v": np.zeros(n), "sigma_u": np.ones(n),
                     "sigma_v": np.ones(n)}, schema=HITS)


@pytest.fixture(autouse=True)
def tiny_batches(monkeypatch):
    monkeypatch.setattr(stream, "BATCH_ROWS", 3)  # every check crosses batch boundaries


def _scan(path):
    return stream.scan_table(path, HITS, "hits")


def test_event_index_and_row_reads_across_files(tmp_path):
    d = tmp_path / "hits"
    d.mkdir()
    pq.write_table(_hits([0, 1, 2]), d / "part-1.parquet", row_group_size=4)
    pq.write_table(_hits([2], first_hit=5), d / "part-2.parquet")  # event 2 goes on in the next file
    pq.write_table(_hits([7, 9]), d / "part-10.parquet", row_group_size=3)
    scan = _scan(d)
    assert scan.events.tolist() == [0, 1, 2, 7, 9]
    assert scan.starts.tolist() == [0, 5, 10, 20, 25, 30]
    assert scan.file_rows == (0, 15, 20, 30)
    whole = read_table(d, HITS, name="hits")
    for lo, hi in [(0, 30), (3, 17), (14, 16), (20, 21), (29, 30)]:
        assert stream.read_rows(scan, lo, hi).equals(whole.slice(lo, hi - lo))
    assert scan.rows_of_events(2, 8) == (10, 25)
    assert scan.rows_of_events(None, 1) == (0, 5)


def test_duplicate_across_files_names_the_later_file_and_row(tmp_path):
    d = tmp_path / "hits"
    d.mkdir()
    pq.write_table(_hits([0, 1]), d / "part-0.parquet")
    pq.write_table(_hits([1], first_hit=3), d / "part-1.parquet")  # hit_id 3, 4 again in event 1
    with pytest.raises(InputError) as err:
        _scan(d)
    msg = str(err.value)
    assert msg.startswith(f"{d / 'part-1.parquet'}: column 'hit_id': row 0 (event_id=1, hit_id=3) duplicates")
    assert "part-0.parquet row 8" in msg


def test_unsorted_across_batches_names_the_file_row(tmp_path):
    f = tmp_path / "hits.parquet"
    pq.write_table(pa.concat_tables([_hits([0, 1, 2]), _hits([1], first_hit=10)]), f)
    with pytest.raises(InputError, match=r"hits.parquet: column 'event_id': row 15 \(event_id=1, hit_id=10\) "
                                         r"comes after event_id=2"):
        _scan(f)


def test_nan_in_a_late_batch(tmp_path):
    t = _hits([0, 1, 2, 3])
    u = t.column("u").to_numpy().copy()
    u[13] = np.nan
    f = tmp_path / "hits.parquet"
    pq.write_table(t.set_column(4, HITS.field("u"), pa.array(u)), f)
    with pytest.raises(InputError, match=r"column 'u': row 13 \(event_id=2, hit_id=3\) is NaN"):
        _scan(f)


def test_row_reads_in_any_order_and_after_the_file_changes(tmp_path, monkeypatch):
    """read_rows keeps each file open at the end of its last read (decoding each row once when
    the ranges come in order); ranges behind it, in later row groups, of other column sets, or
    of a file rewritten since, give the same rows as a whole read."""
    monkeypatch.setattr(stream, "READ_BATCH_ROWS", 4)
    f = tmp_path / "hits.parquet"
    pq.write_table(_hits(range(8)), f, row_group_size=7)
    scan = _scan(f)
    whole = read_table(f, HITS, name="hits")
    ranges = [(0, 3), (3, 5), (5, 12), (12, 13), (30, 38), (2, 9), (9, 40), (0, 40), (21, 22), (1, 2)]
    for lo, hi in ranges:
        assert stream.read_rows(scan, lo, hi).equals(whole.slice(lo, hi - lo))
        cols = stream.read_rows(scan, lo, hi, ["hit_id", "event_id"])
        assert cols.equals(whole.select(["hit_id", "event_id"]).slice(lo, hi - lo))
    changed = _hits(range(8), first_hit=100)
    pq.write_table(changed, f, row_group_size=5)
    scan = _scan(f)
    for lo, hi in ranges:
        assert stream.read_rows(scan, lo, hi).equals(changed.slice(lo, hi - lo))
    stream.close_readers()


def test_a_forked_worker_does_not_use_the_parents_open_readers(tmp_path):
    """Local workers are forked after the parent has read a partition (the kernels' warm-up):
    they must read with their own files, not continue the parent's decoders."""
    import multiprocessing
    import os

    if not hasattr(os, "register_at_fork"):
        pytest.skip("no fork")
    f = tmp_path / "hits.parquet"
    pq.write_table(_hits(range(6)), f, row_group_size=10)
    scan = _scan(f)
    whole = read_table(f, HITS, name="hits")
    assert stream.read_rows(scan, 0, 4).equals(whole.slice(0, 4))  # the parent's reader stops at row 4
    context = multiprocessing.get_context("fork")
    with context.Pool(1) as pool:
        assert pool.apply(_open_readers_in_child) == 0
    assert stream.read_rows(scan, 4, 30).equals(whole.slice(4, 26))
    stream.close_readers()


def _open_readers_in_child() -> int:
    return len(getattr(stream._READERS, "open", {}))


def test_threaded_hashes_are_those_of_the_files_and_their_concatenation(tmp_path):
    import hashlib

    from pkf.io.hashing import FileHasher, file_sha256
    from pkf.pipeline.inputs import files_content_hash

    files = []
    for k, size in enumerate([0, 3, (1 << 20) + 17, 0, 5000]):  # empty files first and inside, > one block
        files.append(tmp_path / f"f{k}")
        files[-1].write_bytes(np.random.default_rng(k).bytes(size))
    for content in (hashlib.sha256(), None):
        with FileHasher(content) as hasher:
            for f in files:
                hasher.submit(f)
            own = [hasher.sha256(f) for f in files]
        assert own == [file_sha256(f) for f in files]
        if content is not None:
            assert content.hexdigest()[:16] == files_content_hash(files)


def test_a_failed_scan_leaves_no_hashing_behind(tmp_path):
    import threading

    d = tmp_path / "hits"
    d.mkdir()
    pq.write_table(_hits([1, 0]), d / "part-0.parquet")  # unsorted
    with pytest.raises(InputError, match="must be sorted by event_id"):
        _scan(d)
    assert not [t for t in threading.enumerate() if t.name.startswith("pkf-sha256")]
    pq.write_table(_hits([0, 1]), d / "part-0.parquet")
    assert _scan(d).sha256 == (stream.file_sha256(d / "part-0.parquet"),)
