"""Executors of `pkf reconstruct`: run partitions in this process, in local worker processes,
or on an existing Dask distributed scheduler (the import floors of tests/test_import_floors.py).

The unit of work is :func:`run_partition`: it reads one partition's rows, reconstructs
them, writes the partition's table files atomically into the staging directory and
then its journal entry, and returns that entry (file hashes and a small summary).
Workers therefore need the dataset and the run's staging directory on a shared
filesystem. This module imports nothing heavy at the top, so a worker can point numba
at the parent's on-disk cache before any kernel is imported (no recompilation).
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from pkf.errors import CtrlC

__all__ = ["PartitionTask", "run_partition", "execute", "default_workers"]


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


@dataclass(frozen=True)
class PartitionTask:
    """Everything a worker needs for one partition (picklable, small).

    Attributes:
        name, key: the partition's name and key (see :class:`pkf.pipeline.plan.Partition`).
        dataset: dataset directory (its geometry is read from there).
        config: `ReconstructionConfig.to_dict()` (plain types: unpickling it imports nothing heavy).
        tables: per table name, (TableScan without event index, row lo, row hi).
        staging: the run's staging directory.
        numba_cache_dir: the parent's numba cache directory, used when it exists here.
    """

    name: str
    key: str
    dataset: str
    config: dict
    tables: dict
    staging: str
    numba_cache_dir: str | None = None


def _use_numba_cache(cache_dir: str | None) -> None:
    """In a worker process: use the parent's numba cache (if it exists here) before any kernel
    is imported. Set in the environment too: numba re-reads its configuration from there."""
    if cache_dir and not os.environ.get("NUMBA_CACHE_DIR") and os.path.isdir(cache_dir):
        import numba

        os.environ["NUMBA_CACHE_DIR"] = cache_dir
        numba.config.CACHE_DIR = cache_dir


_GEOMETRIES: dict = {}


def _geometry(dataset: str, option: str | None = None):
    """The dataset's geometry (``option``: ``--geometry``), cached per process."""
    if (dataset, option) not in _GEOMETRIES:
        from pkf.io.reader import read_meta
        from pkf.pipeline.inputs import resolve_geometry

        _GEOMETRIES.clear()
        _GEOMETRIES[dataset, option] = resolve_geometry(Path(dataset), read_meta(Path(dataset), required=False),
                                                        option)
    return _GEOMETRIES[dataset, option]


#: Hits per sub-batch of a partition: a worker reconstructs a partition in groups of whole events
#: of about this many hits and reports progress after each (4 events at ν = 7.6: ~0.3 s with the
#: parametrized fitter, ~1 s with parametrized and reference; CPU time unchanged). The
#: tables do not depend on it: a batch's rows depend only on its own events (pkf.pipeline.batch).
PROGRESS_HITS = 40_000


def event_groups(event_id, max_hits: int) -> list[tuple[int, int]]:
    """Row ranges [lo, hi) of consecutive whole events, each of at most ``max_hits`` rows
    unless a single event has more. ``event_id``: the hit rows' events, grouped by event."""
    import numpy as np

    event_id = np.asarray(event_id)
    if event_id.size == 0:
        return []
    starts = np.flatnonzero(np.r_[True, event_id[1:] != event_id[:-1]])
    ends = np.r_[starts[1:], event_id.size]
    groups, lo = [], 0
    for start, end in zip(starts.tolist(), ends.tolist()):
        if end - lo > max_hits and start > lo:
            groups.append((lo, start))
            lo = start
    groups.append((lo, int(event_id.size)))
    return groups


def _slice_events(table, first_event: int, next_event: int | None, e=None):
    """The rows of events [first_event, next_event) of a table sorted by event (None: to the end).

    e: the table's event_id column as numpy, if at hand (a table of several chunks is copied
    into one array to make it).
    """
    import numpy as np

    e = table.column("event_id").to_numpy() if e is None else e
    lo = int(np.searchsorted(e, first_event, side="left"))
    hi = e.size if next_event is None else int(np.searchsorted(e, next_event, side="left"))
    return table.slice(lo, hi - lo)


def add_summaries(total: dict | None, part: dict) -> dict:
    """The summary of two batches of events (:func:`pkf.pipeline.batch.reconstruct_batch`): counts,
    timing and pattern counts add up, the first crowded event ids are kept (at most 10)."""
    if total is None:
        return part
    out = dict(total)
    for key, value in part.items():
        if key not in out:
            out[key] = value
        elif key == "limit":
            continue
        elif isinstance(value, dict):
            out[key] = add_summaries(out[key], value)
        elif isinstance(value, list):
            out[key] = (out[key] + value)[:10]
        else:
            out[key] = out[key] + value
    return out


#: The kinds of partition (:func:`kernel_kind`) this process has reconstructed: its kernels are
#: compiled or loaded for them, and forked workers inherit them.
_WARM: set = set()


def kernel_kind(task: PartitionTask) -> str:
    """What decides which kernels (and argument types) a partition needs: the configuration and
    which tables it has (MC matching only with truth)."""
    return json.dumps([task.config, sorted(task.tables)], sort_keys=True)


def kernels_ready(task: PartitionTask) -> bool:
    """Whether this process has already reconstructed a partition of the same kind as ``task``
    (then a warm-up before forking workers would only cost time: 0.07 s for 400 minbias events)."""
    return kernel_kind(task) in _WARM


def reconstruct_task(task: PartitionTask, max_events: int | None = None,
                     progress: Callable[[int], None] | None = None):
    """Read a partition's rows and reconstruct them: (tables, summary); see :func:`reconstruct_batch`.

    The partition is reconstructed in groups of whole events of about :data:`PROGRESS_HITS`
    hits; ``progress(n_events)`` is called after each group. The rows are those of one
    batch of the whole partition: the groups' rows in event order, each table built and
    sorted once (:func:`~pkf.pipeline.batch.run_tables`).

    The summary's ``timing`` also has the CPU and wall seconds of reading the rows (``read``),
    of reconstructing the groups (``batches``: pattern and fit kernels, MC matching, rows) and
    of building the tables (``tables``).

    max_events: only the first events (used to warm up numba's cache before starting workers).
    """
    import numpy as np

    from pkf.io.reader import Dataset
    from pkf.io.stream import read_rows
    from pkf.pipeline.allocator import keep_freed_memory
    from pkf.pipeline.batch import StageClock, batch_rows, context_for, reconstruct_batch, run_tables
    from pkf.pipeline.rows import RowBlocks
    from pkf.pipeline.config import ReconstructionConfig

    keep_freed_memory()  # in a Dask worker too (pkf.pipeline.allocator)
    config = ReconstructionConfig.from_dict(task.config)
    ctx = context_for(_geometry(task.dataset, config.geometry), config)
    timing: dict = {}
    with StageClock(timing, "read"):
        parts = {name: read_rows(scan, lo, hi) for name, (scan, lo, hi) in task.tables.items()}
    if max_events is not None:
        ev = parts["hits"].column("event_id").to_numpy()
        last = np.unique(ev)[:max_events][-1]
        for name, table in parts.items():
            e = table.column("event_id").to_numpy()
            parts[name] = table.slice(0, int(np.searchsorted(e, last, side="right")))
    events = {name: table.column("event_id").to_numpy() for name, table in parts.items()}  # once per partition
    hit_events = events["hits"]
    groups = event_groups(hit_events, PROGRESS_HITS)
    if not groups:  # a partition without hits
        return reconstruct_batch(ctx, Dataset(Path(task.dataset), {}, parts["hits"], parts.get("particles"),
                                              parts.get("mc_hits")))
    rows = RowBlocks()
    summary = None
    for i, (lo, hi) in enumerate(groups):
        first = int(hit_events[lo])
        following = int(hit_events[groups[i + 1][0]]) if i + 1 < len(groups) else None
        part = {name: (table.slice(lo, hi - lo) if name == "hits" else
                       _slice_events(table, first, following, events[name]))
                for name, table in parts.items()}
        data = Dataset(Path(task.dataset), {}, part["hits"], part.get("particles"), part.get("mc_hits"))
        with StageClock(timing, "batches"):
            group_rows, group_summary = batch_rows(ctx, data)
        rows.extend(group_rows)
        summary = add_summaries(summary, group_summary)
        if progress is not None:
            progress(group_summary["events"])
        CtrlC.check()
    with StageClock(timing, "tables"):
        tables = run_tables(rows)
    _WARM.add(kernel_kind(task))
    return tables, add_summaries(summary, {"timing": timing})


def run_partition(task: PartitionTask, progress: Callable[[int], None] | None = None) -> dict:
    """Reconstruct one partition and write its files and journal entry; return the entry.

    progress: called with a number of events after each group of events is reconstructed.
    """
    from pkf.io.atomic import atomic_write_json, atomic_write_table
    from pkf.io.stream import file_sha256
    from pkf.pipeline.batch import RUN_SCHEMAS, StageClock
    from pkf.pipeline.resume import JOURNAL

    tables, summary = reconstruct_task(task, progress=progress)
    root = Path(task.staging)
    files = {}
    timing: dict = {}
    with StageClock(timing, "write"):  # the Parquet files and their SHA-256
        for table_name, table in tables.items():
            rel = Path(table_name) / f"{task.name}.parquet"
            (root / table_name).mkdir(exist_ok=True)
            atomic_write_table(table, root / rel, schema=RUN_SCHEMAS[table_name])
            files[table_name] = {"path": rel.as_posix(), "sha256": file_sha256(root / rel), "rows": table.num_rows}
    entry = {"name": task.name, "key": task.key, "files": files,
             "summary": add_summaries(summary, {"timing": timing})}
    atomic_write_json(entry, root / JOURNAL / f"{task.name}.json")
    return entry


#: The queue a local worker process puts its progress reports on (set by :func:`_init_worker`).
_PROGRESS_QUEUE = None


def _init_worker(cache_dir: str | None, progress_queue=None) -> None:
    global _PROGRESS_QUEUE
    _use_numba_cache(cache_dir)
    _PROGRESS_QUEUE = progress_queue


def _run_partition_in_pool(task: PartitionTask) -> dict:
    """:func:`run_partition` in a local worker process: progress goes to the parent through a queue."""
    queue = _PROGRESS_QUEUE
    return run_partition(task, None if queue is None else lambda n: queue.put((task.name, n)))


#: Topic of the Dask events that carry progress (one per run: the suffix is random).
PROGRESS_TOPIC = "pkf-progress"


def run_partition_remote(task: PartitionTask, topic: str | None = None) -> dict:
    """:func:`run_partition` on a Dask worker: first point numba at the client's cache if it is here;
    progress goes to the client as events of ``topic`` (through the scheduler)."""
    _use_numba_cache(task.numba_cache_dir)
    progress = None
    if topic is not None:
        from distributed import get_worker

        worker = get_worker()
        progress = lambda n: worker.log_event(topic, [task.name, int(n)])  # noqa: E731
    return run_partition(task, progress)


#: Seconds between looks at the progress reports while waiting for partitions.
PROGRESS_POLL_S = 0.2


def execute(tasks: Iterable[PartitionTask], workers: int, scheduler: str | None,
            on_done: Callable[[dict], None], on_progress: Callable[[str, int], None] | None = None) -> None:
    """Run every task; call ``on_done(entry)`` in this process as each one finishes, and
    ``on_progress(partition name, events)`` as groups of its events are reconstructed
    (:data:`PROGRESS_HITS`; from local or Dask workers too). Both are called in this thread.

    workers: local processes (1: in this process); ignored when ``scheduler`` is given.
    scheduler: address of a Dask distributed scheduler (needs the ``dask`` extra).
    """
    tasks = list(tasks)
    on_progress = on_progress or (lambda name, n: None)
    if scheduler is not None:
        _execute_dask(tasks, scheduler, on_done, on_progress)
    elif workers <= 1 or len(tasks) <= 1:
        for task in tasks:
            on_done(run_partition(task, lambda n, name=task.name: on_progress(name, n)))
    else:
        _execute_local(tasks, workers, on_done, on_progress)


def _drain(queue, on_progress, timeout: float = 0.0) -> None:
    """Pass every (partition, events) report waiting on ``queue`` to ``on_progress``; wait up to
    ``timeout`` seconds for the first one."""
    import queue as queues

    try:
        item = queue.get(timeout=timeout) if timeout > 0 else queue.get_nowait()
        while True:
            on_progress(*item)
            item = queue.get_nowait()
    except queues.Empty:
        pass


def _start_method() -> str:
    """'fork' where safe (Linux, Python < 3.12): workers inherit this process's imported modules
    and the kernels it has compiled or loaded, so they start in milliseconds; else 'spawn'
    (each worker imports pkf and loads the kernels from numba's on-disk cache)."""
    import multiprocessing

    if sys.platform.startswith("linux") and sys.version_info < (3, 12) \
            and "fork" in multiprocessing.get_all_start_methods():
        return "fork"
    return "spawn"


def _execute_local(tasks, workers, on_done, on_progress) -> None:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    cache_dir = tasks[0].numba_cache_dir if tasks else None
    context = multiprocessing.get_context(_start_method())
    queue = context.Queue()
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=context,
                             initializer=_init_worker, initargs=(cache_dir, queue)) as pool:
        pending = {pool.submit(_run_partition_in_pool, t) for t in largest_first(tasks)}
        try:
            while pending:
                done, pending = wait(pending, timeout=PROGRESS_POLL_S, return_when=FIRST_COMPLETED)
                _drain(queue, on_progress)
                for future in done:
                    on_done(future.result())
        except BaseException:  # Ctrl-C or a failed partition: stop now, not after the running ones
            pool.shutdown(wait=False, cancel_futures=True)
            _terminate_workers(pool)
            raise
        finally:
            queue.close()


def largest_first(tasks: list[PartitionTask]) -> list[PartitionTask]:
    """The tasks by decreasing number of hits rows (stable): the workers end their last partitions
    closer together (partitions of 25 minbias events at ν = 7.6 hold 166k to 225k hits): the
    two workers' last ends 0.17, 0.22 s apart in file order -> 0.05, 0.09 s (400 events, 16
    partitions, machine under load)."""

    def hit_rows(task: PartitionTask) -> int:
        _, lo, hi = task.tables["hits"]
        return hi - lo

    return sorted(tasks, key=hit_rows, reverse=True)


def _terminate_workers(pool) -> None:
    """Stop a ProcessPoolExecutor's worker processes now: a worker inside a compiled kernel
    would otherwise finish its partition first (minutes for a large one). Their partitions
    are not journaled, so a rerun does them again. Python ≥ 3.14 has this as
    ``terminate_workers``; before, the processes are the executor's ``_processes``."""
    if hasattr(pool, "terminate_workers"):
        pool.terminate_workers()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        if process.is_alive():
            process.terminate()


#: Seconds to wait for a Dask scheduler to answer.
CONNECT_TIMEOUT_S = 10


def _execute_dask(tasks, scheduler, on_done, on_progress) -> None:
    import queue as queues
    import uuid

    from pkf.errors import InputError

    try:
        from distributed import Client, as_completed
    except ImportError:
        raise InputError("--scheduler: needs Dask distributed (pip install 'pkf[dask]')") from None
    try:
        client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"--scheduler {scheduler}: cannot connect ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    reports: queues.Queue = queues.Queue()  # filled by the client's event-loop thread
    topic = f"{PROGRESS_TOPIC}-{uuid.uuid4().hex}"
    with client:
        client.subscribe_topic(topic, lambda event: reports.put(tuple(event[1])))
        futures = [client.submit(run_partition_remote, t, topic, pure=False) for t in tasks]
        try:
            finished = as_completed(futures, loop=client.loop)
            while not finished.is_empty():
                _drain(reports, on_progress, timeout=PROGRESS_POLL_S)
                for future in finished.next_batch(block=False):
                    on_done(future.result())
        except BaseException:
            client.cancel(futures)
            raise
        finally:
            client.unsubscribe_topic(topic)
