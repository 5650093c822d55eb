"""Issue 17 (4): progress bars advance per group of events inside a partition (also from worker
processes), stay quiet when stderr is not a terminal, and do not change any output."""

import io
import os
import re
import subprocess
import sys

import numba
import pytest

from pkf.cli import main
from pkf.io.stream import file_sha256
from pkf.pipeline import executor, progress, simulate
from pkf.pipeline.config import ReconstructionConfig
from pkf.pipeline.reconstruct import run_reconstruction

EVENTS = 16
PER_PARTITION = 8


class FakeTerminal(io.StringIO):
    """stderr as a terminal: tqdm draws its bars on it."""

    def isatty(self):
        return True


def drawn_counts(text: str, total: int) -> list[int]:
    """The counts ``n/total`` of every redraw of a bar."""
    return [int(n) for n in re.findall(rf"(\d+)/{total}\b", text)]


@pytest.fixture(scope="module")
def minbias(tmp_path_factory):
    """16 minimum-bias events at ν = 7.6 (~9,000 hits each: ~4 events per group of PROGRESS_HITS)."""
    out = tmp_path_factory.mktemp("progress") / "mb"
    assert main(["simulate", "--out", str(out), "--generator", "minbias", "--pileup", "7.6",
                 "--events", str(EVENTS), "--seed", "7"]) == 0
    return out


def terminal(monkeypatch) -> FakeTerminal:
    """stderr replaced by a terminal, redrawn at every update (called in the test body: pytest's
    own capture replaces sys.stderr again between a fixture's setup and the test call)."""
    fake = FakeTerminal()
    monkeypatch.setattr(sys, "stderr", fake)
    monkeypatch.setattr(progress, "MIN_INTERVAL_S", 0.0)
    return fake


def run_files(run) -> dict:
    return {p.relative_to(run).as_posix(): file_sha256(p) for p in sorted(run.glob("*/part-*.parquet"))}


def test_event_groups_are_whole_events_of_bounded_hits():
    events = [0, 0, 0, 1, 1, 2, 3, 3, 3, 3, 3, 4]
    assert executor.event_groups(events, 4) == [(0, 3), (3, 6), (6, 11), (11, 12)]  # event 3 alone: 5 hits
    assert executor.event_groups(events, 6) == [(0, 6), (6, 12)]
    assert executor.event_groups(events, 1) == [(0, 3), (3, 5), (5, 6), (6, 11), (11, 12)]
    assert executor.event_groups(events, 100) == [(0, 12)]
    assert executor.event_groups([], 4) == []


@pytest.mark.parametrize("workers", [1, 2])
def test_bar_advances_within_partitions(minbias, tmp_path, monkeypatch, workers):
    """The bar is redrawn at counts between partition ends: in this process and with 2 worker processes."""
    screen = terminal(monkeypatch)
    run = run_reconstruction(minbias, tmp_path / "run", ReconstructionConfig(), workers=workers,
                             events_per_batch=PER_PARTITION)
    assert len(run["partitions"]) == EVENTS // PER_PARTITION
    counts = drawn_counts(screen.getvalue(), EVENTS)
    assert counts[-1] == EVENTS and counts == sorted(counts)
    within = {c for c in counts if c % PER_PARTITION}
    assert len(within) >= 2, counts  # advanced more than once inside partitions


def test_groups_do_not_change_tables(minbias, tmp_path, monkeypatch):
    """Partitions reconstructed as one batch or in groups of one event give identical files and run.json counts."""
    runs = {}
    for hits in (10**9, 1):
        monkeypatch.setattr(executor, "PROGRESS_HITS", hits)
        runs[hits] = run_reconstruction(minbias, tmp_path / str(hits), ReconstructionConfig(), progress=False,
                                        events_per_batch=PER_PARTITION)
    assert run_files(tmp_path / "1") == run_files(tmp_path / str(10**9))
    assert runs[1]["counts"] == runs[10**9]["counts"] and runs[1]["pattern"] == runs[10**9]["pattern"]
    assert runs[1]["timing"]["fit"]["parametrized"]["nodes"] == runs[10**9]["timing"]["fit"]["parametrized"]["nodes"]


def test_simulate_bar_advances_within_a_row_group(tmp_path, monkeypatch):
    screen = terminal(monkeypatch)
    cfg = simulate.SimulationConfig(generator="gun", events=60, seed=3)
    simulate.run_simulation(cfg, tmp_path / "split")
    counts = drawn_counts(screen.getvalue(), 60)
    assert {25, 50} <= set(counts) and counts[-1] == 60  # inside one row group of 60 events
    monkeypatch.setattr(simulate, "PROGRESS_EVENTS", simulate.EVENTS_PER_BATCH)
    simulate.run_simulation(cfg, tmp_path / "whole", progress=False)
    for name in ("hits", "particles", "mc_hits"):
        assert file_sha256(tmp_path / "split" / f"{name}.parquet") == file_sha256(tmp_path / "whole" / f"{name}.parquet")


def test_nothing_printed_when_stderr_is_not_a_terminal(minbias, tmp_path):
    """A pipe (a batch job's log, CI) gets no bar: simulate and reconstruct write nothing to stderr."""
    for args in (["simulate", "--out", str(tmp_path / "ds"), "--generator", "gun", "--events", "30"],
                 ["reconstruct", str(minbias), "--out", str(tmp_path / "run"), "--events-per-batch", "8"]):
        done = subprocess.run([sys.executable, "-m", "pkf.cli", *args], capture_output=True, text=True, timeout=600,
                              env={**os.environ, "NUMBA_CACHE_DIR": numba.config.CACHE_DIR})  # this process's kernels
        assert done.returncode == 0, done.stderr
        assert done.stderr == ""
        assert "wrote" in done.stdout
