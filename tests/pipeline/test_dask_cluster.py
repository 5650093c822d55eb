"""Issue 18 (6): a real Dask cluster, started as a user would on a farm — `dask scheduler` and two
`dask worker` processes (one thread each) on 127.0.0.1 — runs `pkf reconstruct --scheduler` and
writes the same partition files as a run in this process; progress comes back from the workers
per group of events; everything is torn down even when the test fails."""

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time

import numba
import pytest

from pkf.cli import main
from pkf.io.stream import file_sha256
from pkf.pipeline import progress
from pkf.pipeline.config import ReconstructionConfig
from pkf.pipeline.reconstruct import run_reconstruction

EVENTS = 16
PER_PARTITION = 4
START_TIMEOUT_S = 40


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop(processes) -> None:
    """Stop the processes we started (each in its own session: a worker's nanny and its child)."""
    for proc in processes:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
    deadline = time.monotonic() + 10
    for proc in processes:
        try:
            proc.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.fixture(scope="module")
def scheduler(tmp_path_factory):
    """``dask scheduler`` and two ``dask worker --nthreads 1`` on free ports of 127.0.0.1."""
    from distributed import Client

    logs = tmp_path_factory.mktemp("dask-logs")
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m", "dask"]
    commands = [[*dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"]]
    commands += [[*dask, "worker", address, "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard",
                  "--name", f"w{i}", "--local-directory", str(logs / f"w{i}")] for i in range(2)]
    processes = []
    try:
        for i, command in enumerate(commands):
            with open(logs / f"{i}.log", "w") as log:  # the process keeps its own descriptor
                processes.append(subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT,
                                                  start_new_session=True))
            if i == 0:
                _wait_for_port(port, processes[0], logs / "0.log")
        with Client(address, timeout="10s", set_as_default=False) as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT_S)
            assert len(client.scheduler_info()["workers"]) == 2
        yield address
    finally:
        stop(processes[::-1])


def _wait_for_port(port: int, proc, log) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"dask scheduler exited: {open(log).read()[-2000:]}"
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise AssertionError(f"dask scheduler did not listen on port {port}")


@pytest.fixture(scope="module")
def minbias(tmp_path_factory):
    """16 minimum-bias events at ν = 7.6: several groups of events per partition of 4... and per worker."""
    out = tmp_path_factory.mktemp("cluster") / "mb"
    assert main(["simulate", "--out", str(out), "--generator", "minbias", "--pileup", "7.6",
                 "--events", str(EVENTS), "--seed", "11"]) == 0
    return out


def run_files(run) -> dict:
    return {p.relative_to(run).as_posix(): file_sha256(p) for p in sorted(run.glob("*/part-*.parquet"))}


def test_cluster_run_is_identical_to_a_local_run(scheduler, minbias, tmp_path):
    local = tmp_path / "local"
    assert main(["reconstruct", str(minbias), "--out", str(local), "--workers", "1",
                 "--events-per-batch", str(PER_PARTITION)]) == 0
    cluster = tmp_path / "cluster"
    done = subprocess.run([sys.executable, "-m", "pkf.cli", "reconstruct", str(minbias), "--out", str(cluster),
                           "--scheduler", scheduler, "--events-per-batch", str(PER_PARTITION)],
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "NUMBA_CACHE_DIR": numba.config.CACHE_DIR})  # this process's kernels
    assert done.returncode == 0, done.stderr
    assert run_files(cluster) == run_files(local)
    assert len(run_files(cluster)) == 4 * EVENTS // PER_PARTITION
    info = json.loads((cluster / "run.json").read_text())
    assert info["execution"]["scheduler"] == scheduler
    assert info["counts"] == json.loads((local / "run.json").read_text())["counts"]


def test_progress_comes_back_from_the_workers(scheduler, minbias, tmp_path, monkeypatch):
    """Partitions of 8 events (~70k hits) are reconstructed in groups: the bar moves inside them."""

    class Terminal:
        text = ""

        def write(self, s):
            Terminal.text += s

        def flush(self):
            pass

        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    monkeypatch.setattr(progress, "MIN_INTERVAL_S", 0.0)
    run_reconstruction(minbias, tmp_path / "run", ReconstructionConfig(), scheduler=scheduler, events_per_batch=8)
    counts = [int(n) for n in re.findall(rf"(\d+)/{EVENTS}\b", Terminal.text)]
    assert counts[-1] == EVENTS
    assert {c for c in counts if c % 8}, counts  # a count between partition ends: a worker's report
