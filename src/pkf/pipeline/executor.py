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

import os
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

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


def reconstruct_task(task: PartitionTask, max_events: int | None = None):
    """Read a partition's rows and reconstruct them: (tables, summary); see :func:`reconstruct_batch`.

    max_events: only the first events (used to warm up numba's cache before starting workers).
    """
    from pkf.io.reader import Dataset
    from pkf.io.stream import read_rows
    from pkf.pipeline.batch import context_for, reconstruct_batch
    from pkf.pipeline.config import ReconstructionConfig

    config = ReconstructionConfig.from_dict(task.config)
    ctx = context_for(_geometry(task.dataset, config.geometry), config)
    parts = {}
    for name, (scan, lo, hi) in task.tables.items():
        parts[name] = read_rows(scan, lo, hi)
    if max_events is not None:
        import numpy as np

        ev = parts["hits"].column("event_id").to_numpy()
        last = np.unique(ev)[:max_events][-1]
        for name, table in parts.items():
            e = table.column("event_id").to_numpy()
            parts[name] = table.slice(0, int(np.searchsorted(e, last, side="right")))
    data = Dataset(Path(task.dataset), {}, parts["hits"], parts.get("particles"), parts.get("mc_hits"))
    return reconstruct_batch(ctx, data)


def run_partition(task: PartitionTask) -> dict:
    """Reconstruct one partition and write its files and journal entry; return the entry."""
    from pkf.io.atomic import atomic_write_json, atomic_write_table
    from pkf.io.stream import file_sha256
    from pkf.pipeline.batch import RUN_SCHEMAS
    from pkf.pipeline.resume import JOURNAL

    tables, summary = reconstruct_task(task)
    root = Path(task.staging)
    files = {}
    for table_name, table in tables.items():
        rel = Path(table_name) / f"{task.name}.parquet"
        (root / table_name).mkdir(exist_ok=True)
        atomic_write_table(table, root / rel, schema=RUN_SCHEMAS[table_name])
        files[table_name] = {"path": rel.as_posix(), "sha256": file_sha256(root / rel), "rows": table.num_rows}
    entry = {"name": task.name, "key": task.key, "files": files, "summary": summary}
    atomic_write_json(entry, root / JOURNAL / f"{task.name}.json")
    return entry


def _init_worker(cache_dir: str | None) -> None:
    _use_numba_cache(cache_dir)


def run_partition_remote(task: PartitionTask) -> dict:
    """:func:`run_partition` on a Dask worker: first point numba at the client's cache if it is here."""
    _use_numba_cache(task.numba_cache_dir)
    return run_partition(task)


def execute(tasks: Iterable[PartitionTask], workers: int, scheduler: str | None,
            on_done: Callable[[dict], None]) -> None:
    """Run every task; call ``on_done(entry)`` in this process as each one finishes.

    workers: local processes (1: in this process); ignored when ``scheduler`` is given.
    scheduler: address of a Dask distributed scheduler (needs the ``dask`` extra).
    """
    tasks = list(tasks)
    if scheduler is not None:
        _execute_dask(tasks, scheduler, on_done)
    elif workers <= 1 or len(tasks) <= 1:
        for task in tasks:
            on_done(run_partition(task))
    else:
        _execute_local(tasks, workers, on_done)


def _start_method() -> str:
    """'fork' where safe (Linux, Python < 3.12): workers inherit this process's imported modules
    and the kernels it has compiled or loaded, so they start in milliseconds; else 'spawn'
    (each worker imports pkf and loads the kernels from numba's on-disk cache)."""
    import multiprocessing

    if sys.platform.startswith("linux") and sys.version_info < (3, 12) \
            and "fork" in multiprocessing.get_all_start_methods():
        return "fork"
    return "spawn"


def _execute_local(tasks, workers, on_done) -> None:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    cache_dir = tasks[0].numba_cache_dir if tasks else None
    context = multiprocessing.get_context(_start_method())
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=context,
                             initializer=_init_worker, initargs=(cache_dir,)) as pool:
        pending = {pool.submit(run_partition, t) for t in tasks}
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    on_done(future.result())
        except BaseException:  # Ctrl-C or a failed partition: stop now, not after the running ones
            pool.shutdown(wait=False, cancel_futures=True)
            _terminate_workers(pool)
            raise


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


def _execute_dask(tasks, scheduler, on_done) -> None:
    from pkf.errors import InputError

    try:
        from distributed import Client, as_completed
    except ImportError:
        raise InputError("--scheduler: needs Dask distributed (pip install 'pkf[dask]')") from None
    try:
        client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"--scheduler {scheduler}: cannot connect ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    with client:
        futures = [client.submit(run_partition_remote, t, pure=False) for t in tasks]
        try:
            for future in as_completed(futures, loop=client.loop):
                on_done(future.result())
        except BaseException:
            client.cancel(futures)
            raise
