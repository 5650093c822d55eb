"""Issue 18: `pkf reconstruct` validates the dataset on two threads (mc_hits scanned and the later
half of the consistency checks on a helper thread): the same plan, and the same first error, as
the serial validation; exit code 2 and nothing written on bad input (DESIGN §13). The local
workers take the partitions largest first; a process whose kernels are warm skips the warm-up."""

import json
import shutil
from concurrent.futures import CancelledError
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pkf.cli import main
from pkf.errors import InputError
from pkf.pipeline.executor import PartitionTask, kernel_kind, kernels_ready, largest_first
from pkf.pipeline.plan import plan_dataset

CORPUS = Path(__file__).resolve().parents[1] / "bad_inputs"
CASES = json.loads((CORPUS / "cases.json").read_text())


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "gun"
    assert main(["simulate", "--out", str(out), "--generator", "gun", "--events", "6", "--seed", "5"]) == 0
    return out


def _errors(path: Path, events_per_batch: int = 1) -> tuple[str, str]:
    """The InputError of the serial and of the parallel (two threads) validation of ``path``."""
    messages = []
    for parallel in (False, True):
        with pytest.raises(InputError) as caught:
            plan_dataset(path, events_per_batch, parallel=parallel)
        messages.append(str(caught.value))
    return messages[0], messages[1]


def _set_cell(file: Path, column: str, row: int, value) -> None:
    table = pq.read_table(file)
    values = table.column(column).to_numpy().copy()
    values[row] = value
    index = table.schema.get_field_index(column)
    table = table.set_column(index, table.schema.field(index), pa.array(values, table.schema.field(index).type))
    pq.write_table(table, file)


def _first_row_of_event(file: Path, event: int) -> int:
    return int(np.flatnonzero(pq.read_table(file, columns=["event_id"]).column(0).to_numpy() == event)[0])


def test_parallel_plan_equals_serial(dataset):
    serial = plan_dataset(dataset, 2, parallel=False)
    parallel = plan_dataset(dataset, 2)
    assert parallel.partitions == serial.partitions and len(serial.partitions) == 3
    assert parallel.content_hash == serial.content_hash
    assert set(parallel.tables) == set(serial.tables) == {"hits", "particles", "mc_hits"}
    for name, scan in serial.tables.items():
        other = parallel.tables[name]
        assert (other.files, other.file_rows, other.sha256, other.ignored_columns) == \
               (scan.files, scan.file_rows, scan.sha256, scan.ignored_columns)
        assert np.array_equal(other.events, scan.events) and np.array_equal(other.starts, scan.starts)


class _LateFuture:
    """A future whose work starts only when its result is asked for (a helper thread still busy)."""

    def __init__(self, fn, args):
        self.fn, self.args, self.cancelled = fn, args, False

    def cancel(self) -> bool:
        self.cancelled = True
        return True

    def result(self):
        if self.cancelled:
            raise CancelledError
        return self.fn(*self.args)


class _LateHelper:
    """A stand-in for the helper thread pool: runs nothing until asked (see :class:`_LateFuture`)."""

    def __init__(self, *args, **kwargs):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def submit(self, fn, *args):
        return _LateFuture(fn, args)


def test_helper_that_starts_late(dataset, tmp_path, monkeypatch):
    """Work not yet started on the helper is done, not cancelled, when this thread's part passed
    (a valid dataset plans as serially); with an error here first, that error is raised."""
    import pkf.pipeline.plan as plan_module

    serial = plan_dataset(dataset, 1, parallel=False)
    monkeypatch.setattr(plan_module, "ThreadPoolExecutor", _LateHelper)
    late = plan_dataset(dataset, 1)
    assert late.partitions == serial.partitions and late.content_hash == serial.content_hash
    copy = Path(shutil.copytree(dataset, tmp_path / "data"))
    for event in (1, 4):
        _set_cell(copy / "mc_hits.parquet", "hit_id", _first_row_of_event(copy / "mc_hits.parquet", event), 10**9)
    with pytest.raises(InputError) as caught:
        plan_dataset(copy, 1)
    assert f"row {_first_row_of_event(copy / 'mc_hits.parquet', 1)} " in str(caught.value)


@pytest.mark.parametrize("events", [[0], [4], [1, 5], [2, 3]])
def test_first_consistency_error_whichever_process_checks_it(dataset, tmp_path, events):
    """One partition per event: events 0-2 are checked on this thread, 3-5 on the helper."""
    copy = Path(shutil.copytree(dataset, tmp_path / "data"))
    for event in events:
        _set_cell(copy / "mc_hits.parquet", "hit_id", _first_row_of_event(copy / "mc_hits.parquet", event), 10**9)
    serial, parallel = _errors(copy)
    assert serial == parallel
    row = _first_row_of_event(copy / "mc_hits.parquet", min(events))
    assert "mc_hits.parquet" in serial and f"row {row} " in serial, serial


def test_bad_hits_reported_before_bad_mc_hits(dataset, tmp_path, capsys):
    """The helper finds the truncated mc_hits first; the error is still the first bad row of hits."""
    copy = Path(shutil.copytree(dataset, tmp_path / "data"))
    _set_cell(copy / "hits.parquet", "u", 5, np.nan)
    data = (copy / "mc_hits.parquet").read_bytes()
    (copy / "mc_hits.parquet").write_bytes(data[: len(data) // 2])
    serial, parallel = _errors(copy)
    assert serial == parallel and "hits.parquet" in serial and "row 5 " in serial, serial
    out_parent = tmp_path / "out"
    out_parent.mkdir()
    assert main(["reconstruct", str(copy), "--out", str(out_parent / "run"), "--workers", "2"]) == 2
    err = capsys.readouterr().err
    assert err == f"pkf: error: {serial}\n"
    assert list(out_parent.iterdir()) == []  # no run, no staging directory


def test_bad_mc_hits_alone(dataset, tmp_path):
    copy = Path(shutil.copytree(dataset, tmp_path / "data"))
    data = (copy / "mc_hits.parquet").read_bytes()
    (copy / "mc_hits.parquet").write_bytes(data[: len(data) // 2])
    serial, parallel = _errors(copy)
    assert serial == parallel and "mc_hits.parquet" in serial, serial


@pytest.mark.parametrize("case", sorted(c for c in CASES if not CASES[c]["args"]))
def test_corpus_parallel_validation_says_what_serial_says(case, tmp_path):
    """Every bad input of the corpus, one event per partition: the same one line."""
    dataset = Path(shutil.copytree(CORPUS / case, tmp_path / case))
    serial, parallel = _errors(dataset)
    assert serial == parallel


def _task(name: str, lo: int, hi: int, config: dict | None = None, tables=("hits",)) -> PartitionTask:
    return PartitionTask(name, "", "", config or {}, {t: (None, lo, hi) for t in tables}, "")


def test_largest_first():
    tasks = [_task("a", 0, 10), _task("b", 10, 30), _task("c", 30, 40), _task("d", 40, 45)]
    assert [t.name for t in largest_first(tasks)] == ["b", "a", "c", "d"]


def test_warm_up_skipped_only_for_a_kind_already_reconstructed(dataset, tmp_path, monkeypatch):
    """After a run in this process, a partition of the same configuration and tables is warm;
    another configuration, or the same without truth tables, is not. (Starts from a process in
    which nothing is warm: other tests of the suite reconstruct other kinds before this one.)"""
    import pkf.pipeline.executor as executor
    from pkf.pipeline.reconstruct import ReconstructionConfig, run_reconstruction

    monkeypatch.setattr(executor, "_WARM", set())
    assert not kernels_ready(_task("p", 0, 1, ReconstructionConfig(pattern="truth").to_dict(), ("hits",)))

    config = ReconstructionConfig(pattern="truth", fitters=("parametrized",))
    run_reconstruction(dataset, tmp_path / "run", config, workers=1, events_per_batch=6, progress=False)
    task = _task("p", 0, 1, config.to_dict(), ("hits", "particles", "mc_hits"))
    assert kernels_ready(task)
    assert not kernels_ready(_task("p", 0, 1, config.to_dict(), ("hits",)))
    other = ReconstructionConfig(pattern="truth", fitters=("reference",)).to_dict()
    assert not kernels_ready(_task("p", 0, 1, other, ("hits", "particles", "mc_hits")))
    assert kernel_kind(task) == kernel_kind(_task("q", 5, 9, config.to_dict(), ("mc_hits", "particles", "hits")))
