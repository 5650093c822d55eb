"""Streaming validation and row-range reading of big tables (docs/formats.md, docs/cli.md#exit-codes-and-messages), in bounded memory.

A table (one Parquet file or a directory of them) is scanned record batch by record
batch: every check of :mod:`pkf.io.reader` is applied to each batch, and the checks
that span rows (sorted by ``event_id``, unique ids) also across batch and file
boundaries by carrying the rows of the last event into the next batch. The scan keeps
only an index of events (first row of each event, 16 bytes per event) and a SHA-256
of each file (computed on a thread beside the scan, :mod:`pkf.io.hashing`); :func:`read_rows`
then reads any row range back, touching only the row groups that hold it. Messages name
the file and the 0-based row within that file.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyarrow as pa

from pkf.errors import InputError
from pkf.io.hashing import FileHasher, file_sha256
from pkf.io.reader import (
    TableSource,
    _list_parquet_files,
    _one_line,
    _validate_values,
    convert_to_schema,
    extra_columns,
    find_table,
    open_checked,
)
from pkf.io.schemas import spec_for

__all__ = ["OffsetSource", "TableScan", "scan_table", "scan_unhashed", "table_files", "read_rows", "close_readers",
           "file_sha256", "with_sha256", "BATCH_ROWS"]

#: Rows per record batch of a scan (about 15 MB of hits): bounds the scan's memory.
BATCH_ROWS = 1 << 18


@dataclass(frozen=True)
class OffsetSource(TableSource):
    """A :class:`TableSource` for a slice of files: ``bases[k]`` is the file row of the
    first table row that comes from ``files[k]`` (so messages give rows within the file)."""

    bases: tuple[int, ...] = ()

    def locate(self, row: int) -> tuple[str, int]:
        k = int(np.searchsorted(np.asarray(self.offsets), row, side="right")) - 1
        k = min(max(k, 0), len(self.files) - 1)
        return str(self.files[k]), self.bases[k] + row - self.offsets[k]


@dataclass(frozen=True)
class TableScan:
    """What a validated scan of one table found.

    Attributes:
        name: table name (``hits``, ``particles``, ``mc_hits``).
        schema: its pkf schema.
        files: Parquet files in reading order.
        file_rows: table row of the first row of each file, plus the total (len(files) + 1).
        events: the distinct event ids, in order.
        starts: table row of the first row of each event, plus the total (len(events) + 1).
        sha256: hex SHA-256 of each file.
        ignored_columns: the files' columns beyond the schema (not read), in order of first appearance.
    """

    name: str
    schema: pa.Schema
    files: tuple[Path, ...]
    file_rows: tuple[int, ...]
    events: np.ndarray
    starts: np.ndarray
    sha256: tuple[str, ...]
    ignored_columns: tuple[str, ...] = ()

    @property
    def n_rows(self) -> int:
        return self.file_rows[-1]

    def rows_of_events(self, first_event: int | None, stop_event: int | None) -> tuple[int, int]:
        """Table rows [lo, hi) of the events in [first_event, stop_event) (None: unbounded)."""
        lo = 0 if first_event is None else int(self.starts[np.searchsorted(self.events, first_event)])
        hi = self.n_rows if stop_event is None else int(self.starts[np.searchsorted(self.events, stop_event)])
        return lo, hi

    def source(self, lo: int, hi: int) -> OffsetSource:
        """The source of table rows [lo, hi), for messages naming the file and its row."""
        files, offsets, bases = [], [], []
        for k, file in enumerate(self.files):
            a, b = max(lo, self.file_rows[k]), min(hi, self.file_rows[k + 1])
            if a < b or (not files and k == len(self.files) - 1):
                files.append(file)
                offsets.append(a - lo)
                bases.append(a - self.file_rows[k])
        return OffsetSource(self.files[0] if len(self.files) == 1 else Path(os.path.commonpath(self.files)),
                            tuple(files), tuple(offsets) + (hi - lo,), tuple(bases))


def scan_table(location: Path, schema: pa.Schema, name: str,
               check: Callable[[pa.Table, OffsetSource], None] | None = None, content_digest=None,
               hasher: FileHasher | None = None) -> TableScan:
    """Validate the table at ``location`` (a file or a directory of files) batch by batch.

    Args:
        location: the table, as found by :func:`~pkf.io.reader.find_table`.
        schema: its pkf schema (validation rules from :data:`~pkf.io.schemas.TABLE_SPECS`).
        name: table name for messages.
        check: an extra check of each batch (e.g. hits against the geometry's layers),
            called with the batch (with the previous batch's last event in front) and its source.
        content_digest: a hash object that is fed the bytes of every file, in order.
        hasher: hash the files on this :class:`~pkf.io.hashing.FileHasher`'s thread (its
            content digest, not ``content_digest``, is fed) and leave ``sha256`` empty, for
            :func:`with_sha256` once the caller's other work is done; without it, the files
            are hashed on a thread of this scan, beside the decoding and checks.

    Raises:
        InputError: one line naming the file, the column and the first bad row.
    """
    if hasher is None:
        with FileHasher(content_digest) as own:
            return with_sha256(_scan(location, schema, name, check, own), own)
    return _scan(location, schema, name, check, hasher)


class _NoHashing:
    """A stand-in for :class:`~pkf.io.hashing.FileHasher` that hashes nothing (:func:`scan_unhashed`)."""

    def submit(self, file: Path) -> None:
        pass


def scan_unhashed(location: Path, schema: pa.Schema, name: str) -> TableScan:
    """:func:`scan_table` without hashing the files (``sha256`` left empty): for a scan on another
    thread while the caller hashes the files (:func:`table_files`) in its own order."""
    return _scan(location, schema, name, None, _NoHashing())


def table_files(location: Path) -> list[Path]:
    """The Parquet files of a table found at ``location`` (a file, or a directory of them), in reading order."""
    return _list_parquet_files(location) if location.is_dir() else [location]


def with_sha256(scan: TableScan, hasher: FileHasher) -> TableScan:
    """The scan with the SHA-256 of each of its files, from the hasher it was scanned with."""
    return replace(scan, sha256=tuple(hasher.sha256(file) for file in scan.files))


def _scan(location: Path, schema: pa.Schema, name: str, check, hasher: FileHasher) -> TableScan:
    """:func:`scan_table`, its files submitted to ``hasher`` (``sha256`` left empty)."""
    spec = spec_for(schema)
    key = spec.unique_key if spec is not None else ("event_id",)
    files = table_files(location)
    if not files and (spec is None or not spec.allow_empty):
        raise InputError(f"{location}: directory contains no Parquet files ({name} must not be empty)")
    for file in files:  # hashed on the hasher's thread while this one decodes and checks
        hasher.submit(file)
    file_rows, events, starts, ignored = [0], [], [], {}
    carry: list[tuple[Path, int, pa.Table]] = []  # (file, file row, rows) of the last event so far
    total = 0
    for file in files:
        # unbuffered reads: iter_batches on a default ParquetFile keeps growing in memory
        pf = open_checked(file, schema, name, pre_buffer=False, buffer_size=1 << 20)
        base = 0
        try:
            ignored.update(dict.fromkeys(extra_columns(pf.schema_arrow, schema)))
            # one decoding thread: the hashes take the other core (pyarrow's threads cost ~0.25 s more
            # CPU per 1,000 minbias events at ν = 7.6, for no shorter validation beside the hashing)
            batches = pf.iter_batches(batch_size=BATCH_ROWS, columns=schema.names, use_threads=False)
            while True:
                try:
                    batch = next(batches)
                except StopIteration:
                    break
                except (pa.ArrowException, OSError) as exc:
                    raise InputError(f"{file}: corrupt or truncated Parquet file ({_one_line(exc)})") from None
                raw = pa.Table.from_batches([batch])
                table = convert_to_schema(raw, schema, OffsetSource(file, (file,), (0, raw.num_rows), (base,)), key)
                if table.num_rows == 0:
                    continue
                segments = carry + [(file, base, table)]
                both = pa.concat_tables([t for _, _, t in segments]) if carry else table
                offsets = tuple(int(x) for x in np.cumsum([0] + [t.num_rows for _, _, t in segments]))
                source = OffsetSource(file, tuple(f for f, _, _ in segments), offsets,
                                      tuple(r for _, r, _ in segments))
                extra = [lambda: check(both, source)] if check is not None else []
                _validate_values(both, schema, spec, source, extra)  # the first bad row of all checks
                ev = table.column("event_id").to_numpy()
                new = np.flatnonzero(np.r_[True, ev[1:] != ev[:-1]])
                if events and ev[0] == events[-1]:
                    new = new[1:]  # the event goes on from the previous batch
                events.extend(ev[new].tolist())
                starts.extend((total + new).tolist())
                last_start = int(np.flatnonzero(ev == ev[-1])[0])
                tail = (file, base + last_start, table.slice(last_start))
                carry = carry + [tail] if last_start == 0 and carry and events[-1] == ev[0] and not new.size else [tail]
                total += table.num_rows
                base += table.num_rows
        finally:
            pf.close()
        file_rows.append(total)
    if total == 0 and spec is not None and not spec.allow_empty:
        raise InputError(f"{location}: table is empty (no rows)")
    return TableScan(name, schema, tuple(files), tuple(file_rows), np.asarray(events, dtype=np.int64),
                     np.asarray(starts + [total], dtype=np.int64), (), tuple(ignored))


def find_and_scan(dataset: Path, name: str, schema: pa.Schema, required: bool,
                  check: Callable[[pa.Table, OffsetSource], None] | None = None,
                  content_digest=None, hasher: FileHasher | None = None) -> TableScan | None:
    """Locate table ``name`` of a dataset directory and scan it; None if absent and not required."""
    location = find_table(dataset, name)
    if location is None:
        if required:
            raise InputError(f"{dataset}: table {name!r} not found (expected {name}.parquet or {name}/)")
        return None
    return scan_table(location, schema, name, check, content_digest, hasher)


#: Rows per record batch when :func:`read_rows` decodes a file: the rows decoded beyond the
#: range asked for are at most this many (kept for the next call, see :class:`_ForwardReader`).
READ_BATCH_ROWS = 1 << 16

#: Open files per thread that :func:`read_rows` keeps positioned (hits, particles, mc_hits, and
#: their key columns for the consistency checks).
OPEN_READERS = 8


class _ForwardReader:
    """One Parquet file (and column set) decoded forward, batch by batch, from a row group on.

    The rows of a partition are a small part of a row group (a simulated ν = 7.6 dataset has
    ~1.6 million hits per row group, 200 events; a partition is 50 of them): reading the
    row groups that hold each partition decoded every row group four times, and the
    consistency checks as often again (1,000 events: 7.4 s of CPU for 18 s of decoded rows
    in `pkf reconstruct`). A reader keeps its position and the decoded rest of its last batch, so
    the partitions of a file read in order decode each row once; a range behind the position
    or in a later row group is reached by starting again at its row group.
    """

    def __init__(self, file: Path, names: tuple[str, ...], stamp: tuple):
        import pyarrow.parquet as pq

        self.file, self.names, self.stamp = file, names, stamp
        self.pf = pq.ParquetFile(file, pre_buffer=False, buffer_size=1 << 20)
        sizes = [self.pf.metadata.row_group(i).num_rows for i in range(self.pf.num_row_groups)]
        self.edges = np.cumsum([0] + sizes)
        self.batches = None
        self.pos = 0  # file row of the first row of ``pending``
        self.pending: pa.RecordBatch | None = None

    def _group(self, row: int) -> int:
        return int(np.searchsorted(self.edges, row, side="right")) - 1

    def _start_at_group(self, group: int) -> None:
        self.batches = self.pf.iter_batches(batch_size=READ_BATCH_ROWS, row_groups=range(group, len(self.edges) - 1),
                                            columns=list(self.names), use_threads=False)
        self.pos, self.pending = int(self.edges[group]), None

    def read(self, a: int, b: int) -> list[pa.RecordBatch]:
        """File rows [a, b), as slices of decoded batches."""
        if self.batches is None or a < self.pos or self._group(a) > self._group(self.pos):
            self._start_at_group(self._group(a))
        parts = []
        while self.pos < b:
            batch = self.pending if self.pending is not None else next(self.batches)
            n = batch.num_rows
            lo, hi = max(a - self.pos, 0), min(b - self.pos, n)
            if hi > lo:
                parts.append(batch.slice(lo, hi - lo))
            if hi < n:  # the rest is kept for the next call
                self.pending, self.pos = batch.slice(hi), self.pos + hi
            else:
                self.pending, self.pos = None, self.pos + n
        return parts

    def close(self) -> None:
        self.pf.close()


_READERS = threading.local()  # per thread (Dask runs tasks in threads): {(file, names): _ForwardReader}


def _forget_readers_after_fork() -> None:
    """In a forked worker: start without the parent's readers (their open files and positions
    are the parent's; a worker reads its partitions with its own)."""
    global _READERS
    _READERS = threading.local()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_readers_after_fork)


def _reader(file: Path, names: tuple[str, ...]) -> _ForwardReader:
    """This thread's reader of ``file`` and ``names`` (a new one if the file changed on disk)."""
    readers = getattr(_READERS, "open", None)
    if readers is None:
        readers = _READERS.open = {}
    st = os.stat(file)
    stamp = (st.st_ino, st.st_size, st.st_mtime_ns)
    key = (str(file), names)
    reader = readers.pop(key, None)
    if reader is not None and reader.stamp != stamp:
        reader.close()
        reader = None
    if reader is None:
        reader = _ForwardReader(file, names, stamp)
    readers[key] = reader  # most recently used last
    while len(readers) > OPEN_READERS:
        readers.pop(next(iter(readers))).close()
    return reader


def close_readers() -> None:
    """Close the files :func:`read_rows` keeps open in this thread."""
    for reader in getattr(_READERS, "open", {}).values():
        reader.close()
    _READERS.open = {}


def read_rows(scan: TableScan, lo: int, hi: int, columns: Sequence[str] | None = None) -> pa.Table:
    """Table rows [lo, hi) of a scanned table, decoding only from the row group that holds ``lo``
    (or from where this thread's previous read of the file ended: :class:`_ForwardReader`).

    Returns the rows with the table's schema (or only ``columns``, in that order), in the chunks
    they were decoded in (copying them into one cost 0.45 s of CPU per 1,000 events at ν = 7.6).
    """
    names = tuple(columns) if columns is not None else tuple(scan.schema.names)
    schema = pa.schema([scan.schema.field(n) for n in names])
    parts = []
    for k, file in enumerate(scan.files):
        a, b = max(lo, scan.file_rows[k]), min(hi, scan.file_rows[k + 1])
        if a >= b:
            continue
        batches = _reader(file, names).read(a - scan.file_rows[k], b - scan.file_rows[k])
        raw = pa.Table.from_batches(batches)  # chunks of the decoded batches: not copied into one
        parts.append(convert_to_schema(raw, schema, str(file), (), spec_for(scan.schema)))
    if not parts:
        return schema.empty_table()
    return pa.concat_tables(parts) if len(parts) > 1 else parts[0]
