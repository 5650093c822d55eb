"""Planning a streamed reconstruction: validate a dataset in bounded memory and cut it into partitions.

A partition is a batch of at most ``events_per_batch`` consecutive events of one input
hits file (an event that goes on into the next file stays whole); it is the unit of
work of the executors and of the output (one Parquet file per run table and partition).
Partitions depend only on the data and ``events_per_batch``, never on the number of
workers, so the run tables are the same whatever executes them (docs/formats.md, docs/cli.md#exit-codes-and-messages).
"""

from __future__ import annotations

import hashlib
import json
import os
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pkf.errors import InputError
from pkf.geometry.detector import Geometry
from pkf.io.reader import (
    check_dataset_dir,
    extra_columns_warning,
    find_truth_tables,
    read_meta,
    validate_consistency,
    validate_hit_layers,
)
from pkf.io.schemas import HITS, MC_HITS, PARTICLES
from pkf.io.hashing import FileHasher
from pkf.io.stream import (
    TableScan,
    close_readers,
    find_and_scan,
    read_rows,
    scan_table,
    scan_unhashed,
    table_files,
    with_sha256,
)
from pkf.pipeline.inputs import hit_layer_checks, resolve_geometry

__all__ = ["DatasetPlan", "Partition", "plan_dataset"]


@dataclass(frozen=True)
class Partition:
    """One batch of events: its name, input rows and events.

    Attributes:
        name: ``part-FFFF-BBBBB`` (input file index, batch index within that file).
        file_index: index of the hits file where its first event starts.
        hits_rows: (lo, hi) rows of the hits table (all files together).
        first_event, last_event: its first and last event id (inclusive).
        n_events: number of events.
        key: SHA-256 of everything its output depends on (inputs, rows, configuration).
    """

    name: str
    file_index: int
    hits_rows: tuple[int, int]
    first_event: int
    last_event: int
    n_events: int
    key: str = ""


@dataclass(frozen=True)
class DatasetPlan:
    """A validated dataset ready for streamed reconstruction."""

    path: Path
    meta: dict
    geometry: Geometry
    tables: dict  # name -> TableScan (hits always; particles, mc_hits when present)
    partitions: tuple[Partition, ...]
    content_hash: str = ""  # as pkf.pipeline.inputs.content_hash: SHA-256 of all table files, 16 hex digits

    @property
    def has_mc(self) -> bool:
        return "mc_hits" in self.tables

    @property
    def n_events(self) -> int:
        return int(self.tables["hits"].events.size)

    @property
    def n_hits(self) -> int:
        return self.tables["hits"].n_rows

    def warnings(self) -> list[str]:
        """One line per table with extra columns (ignored), naming them."""
        return table_warnings(self.tables)


def table_warnings(tables: dict) -> list[str]:
    """One line per scanned table (name -> TableScan) with extra columns (ignored), naming them."""
    return [extra_columns_warning(table_path(scan), name, scan.ignored_columns)
            for name, scan in tables.items() if scan.ignored_columns]


def table_path(scan: TableScan) -> Path:
    """The table as found on disk: its one file, or the directory of its files."""
    return scan.files[0] if len(scan.files) == 1 else Path(os.path.commonpath(scan.files))


def cut_partitions(hits: TableScan, events_per_batch: int) -> list[Partition]:
    """Cut the events of each hits file into batches of at most ``events_per_batch``."""
    starts = hits.starts[:-1]
    file_of_event = np.searchsorted(np.asarray(hits.file_rows), starts, side="right") - 1
    out = []
    for f in np.unique(file_of_event):
        idx = np.flatnonzero(file_of_event == f)
        for b, first in enumerate(range(0, idx.size, events_per_batch)):
            sel = idx[first:first + events_per_batch]
            lo, hi = int(hits.starts[sel[0]]), int(hits.starts[sel[-1] + 1])
            out.append(Partition(f"part-{int(f):04d}-{b:05d}", int(f), (lo, hi), int(hits.events[sel[0]]),
                                 int(hits.events[sel[-1]]), int(sel.size)))
    return out


def check_consistency(tables: dict, partitions: list[Partition], which: range | None = None) -> None:
    """MC truth against hits, one partition's event range at a time (ranges tile all event ids).

    which: the indices of the partitions to check, in order (default: all).
    """
    hits, mc, particles = tables["hits"], tables.get("mc_hits"), tables.get("particles")
    if mc is None and particles is None:
        return
    bounds = [None] + [p.first_event for p in partitions[1:]] + [None]
    for k in range(len(partitions)) if which is None else which:
        lo_ev, hi_ev = bounds[k], bounds[k + 1]
        parts, sources = {}, {}
        for name, scan, cols in (("hits", hits, ["event_id", "hit_id"]),
                                 ("mc_hits", mc, ["event_id", "hit_id", "particle_id"]),
                                 ("particles", particles, ["event_id", "particle_id", "parent_id"])):
            if scan is None:
                parts[name] = None
                continue
            lo, hi = scan.rows_of_events(lo_ev, hi_ev)
            parts[name] = read_rows(scan, lo, hi, cols)
            sources[name] = scan.source(lo, hi)
        validate_consistency(parts["hits"], parts["particles"], parts["mc_hits"], sources=sources)


def _scan_tables(path: Path, truth: dict, check_layers, hasher: FileHasher, helper: Executor | None) -> dict:
    """Scan hits, particles and mc_hits (name -> TableScan, ``sha256`` left to ``hasher``).

    With a ``helper`` thread, mc_hits (the largest table: 132 of the 178 MB of 400 minbias events
    at ν = 7.6) is scanned there while this thread scans hits and particles (Parquet decoding, most
    of a scan, releases the GIL); its files are still hashed after theirs (the content hash's
    order), and a bad mc_hits is reported only once hits and particles passed, as in a serial scan.
    """
    location = truth["mc_hits"]
    mc = helper.submit(scan_unhashed, location, MC_HITS, "mc_hits") if helper is not None and location else None
    try:
        tables = {"hits": find_and_scan(path, "hits", HITS, True, check_layers, hasher=hasher)}
        if truth["particles"] is not None:
            tables["particles"] = scan_table(truth["particles"], PARTICLES, "particles", hasher=hasher)
        if location is not None and mc is None:
            tables["mc_hits"] = scan_table(location, MC_HITS, "mc_hits", hasher=hasher)
        elif mc is not None:
            for file in table_files(location):
                hasher.submit(file)
            tables["mc_hits"] = mc.result()
    except BaseException:
        if mc is not None:
            mc.cancel()  # if not started yet: not needed after an error above
        raise
    return tables


def _check_and_close(tables: dict, partitions: list[Partition], which: range) -> None:
    """:func:`check_consistency` on a helper thread, which then closes the files it read."""
    try:
        check_consistency(tables, partitions, which)
    finally:
        close_readers()


def _check_consistency_on(tables: dict, partitions: list[Partition], helper: Executor | None) -> None:
    """:func:`check_consistency`, the later half of the partitions on the ``helper`` thread (if given)
    while this one checks the first half; the error of the first bad partition is raised."""
    n = len(partitions)
    if helper is None or n < 2 or ("mc_hits" not in tables and "particles" not in tables):
        check_consistency(tables, partitions)
        return
    later = helper.submit(_check_and_close, tables, partitions, range(n // 2, n))
    try:
        check_consistency(tables, partitions, range(n // 2))
    except BaseException:
        later.cancel()  # if not started yet: the error above comes first
        raise
    later.result()


def plan_dataset(path: str | Path, events_per_batch: int, geometry: str | None = None,
                 parallel: bool = True) -> DatasetPlan:
    """Validate the dataset at ``path`` in bounded memory (docs/cli.md#exit-codes-and-messages) and cut it into partitions.

    geometry: ``--geometry`` NAME|FILE.toml, if given (:func:`~pkf.pipeline.inputs.resolve_geometry`).
    parallel: share the scans and checks with a helper thread (:func:`_scan_tables`,
        :func:`_check_consistency_on`): the same plan and the same first error as without.
        400 minbias events at ν = 7.6 (178 MB, 25 events per partition), 2 cores, 6 alternating
        calls each: 0.549 (min) / 0.578 (median) s serial -> 0.463 / 0.531 s. The helper is a
        thread, not a forked worker: after a fork every write of this process into its kept heap
        (pkf.pipeline.allocator) copies the page, and the scan on forked workers cost 0.52-0.70 s.

    Raises:
        InputError: one line naming the file, the column and the first bad row.
    """
    if events_per_batch < 1:
        raise InputError(f"--events-per-batch: must be >= 1, not {events_per_batch}")
    path = check_dataset_dir(path)
    meta = read_meta(path, required=False)
    found = resolve_geometry(path, meta, geometry)
    truth = find_truth_tables(path)
    layer_checks = hit_layer_checks(found)

    def check_layers(table, source):
        validate_hit_layers(table, **layer_checks, source=source)

    digest = hashlib.sha256()  # over every file, hits then particles then mc_hits (as content_hash)
    # the files are hashed on a thread while this one decodes and checks them (pkf.io.hashing)
    with FileHasher(digest) as hasher, ThreadPoolExecutor(1, thread_name_prefix="pkf-validate") as helper:
        helper = helper if parallel else None
        tables = _scan_tables(path, truth, check_layers, hasher, helper)
        partitions = cut_partitions(tables["hits"], events_per_batch)
        _check_consistency_on(tables, partitions, helper)
        tables = {name: with_sha256(scan, hasher) for name, scan in tables.items()}
    return DatasetPlan(path, meta or {}, found, tables, tuple(partitions), digest.hexdigest()[:16])


def _source_digest() -> str:
    """SHA-256 of pkf's source files: a partition made by other code is not reused."""
    import pkf

    root = Path(pkf.__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def with_keys(plan: DatasetPlan, run_config: dict) -> DatasetPlan:
    """The plan with each partition's ``key``: SHA-256 of the configuration, pkf's source, the
    input files' hashes, and the partition's rows and events (what decides its output)."""
    common = json.dumps({"config": run_config, "geometry": plan.geometry.content_hash, "pkf": _source_digest(),
                         "inputs": {name: scan.sha256 for name, scan in sorted(plan.tables.items())}},
                        sort_keys=True)
    parts = []
    for p in plan.partitions:
        text = common + json.dumps([p.name, p.hits_rows, p.first_event, p.last_event, p.n_events])
        parts.append(Partition(p.name, p.file_index, p.hits_rows, p.first_event, p.last_event, p.n_events,
                               hashlib.sha256(text.encode()).hexdigest()))
    return DatasetPlan(plan.path, plan.meta, plan.geometry, plan.tables, tuple(parts), plan.content_hash)
