"""Issue 8: partitioned runs — any batch size, 2 local workers and a Dask LocalCluster give the
same tables; an interrupted (SIGKILL) run resumes to the same output; --overwrite redoes all."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numba
import numpy as np
import pytest

from pkf.cli import main
from pkf.io.reader import read_table
from pkf.io.schemas import CANDIDATES, CHI2, PULLS, STATES
from pkf.io.stream import file_sha256
from pkf.pipeline.reconstruct import ReconstructionConfig, run_reconstruction

SCHEMAS = {"candidates": CANDIDATES, "chi2": CHI2, "states": STATES, "pulls": PULLS}
ARGS = ["--pattern", "truth", "--fitter", "parametrized"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "gun"
    assert main(["simulate", "--out", str(out), "--generator", "gun", "--events", "24", "--seed", "4"]) == 0
    return out


@pytest.fixture(scope="module")
def reference(dataset, tmp_path_factory):
    """One uninterrupted run in this process, 4 events per partition."""
    out = tmp_path_factory.mktemp("runs") / "ref"
    assert main(["reconstruct", str(dataset), "--out", str(out), "--workers", "1", "--events-per-batch", "4",
                 *ARGS]) == 0
    return out


def assert_same_tables(a: Path, b: Path) -> None:
    for name, schema in SCHEMAS.items():
        ta, tb = read_table(a, schema, name=name), read_table(b, schema, name=name)
        assert ta.num_rows == tb.num_rows > 0, name
        for col in schema.names:
            x = ta.column(col).to_numpy(zero_copy_only=False)
            y = tb.column(col).to_numpy(zero_copy_only=False)
            if x.dtype.kind == "f":
                assert np.array_equal(x, y, equal_nan=True), (name, col)
            else:
                assert np.array_equal(x, y), (name, col)


def partition_files(run: Path) -> dict:
    return {p.relative_to(run).as_posix(): file_sha256(p) for p in sorted(run.glob("*/part-*.parquet"))}


def test_partitioned_layout_and_run_json(dataset, reference):
    from pkf.io.reader import open_dataset
    from pkf.pipeline.inputs import content_hash

    info = json.loads((reference / "run.json").read_text())
    assert info["input"]["content_hash"] == content_hash(open_dataset(dataset))  # what reports check
    parts = info["partitions"]
    assert [p["name"] for p in parts] == [f"part-0000-{i:05d}" for i in range(6)]
    assert sum(p["events"] for p in parts) == info["counts"]["events"] == 24
    for p in parts:
        for table, record in p["files"].items():
            assert record["path"] == f"{table}/{p['name']}.parquet"
            assert file_sha256(reference / record["path"]) == record["sha256"]
    assert set(partition_files(reference)) == {r["path"] for p in parts for r in p["files"].values()}
    assert info["pattern"]["efficiency"] > 0.95
    assert not [p for p in reference.parent.iterdir() if p.name.startswith(".")]  # no staging left


def test_batch_size_does_not_change_tables(dataset, reference, tmp_path):
    out = tmp_path / "one_batch"
    run = run_reconstruction(dataset, out, ReconstructionConfig(pattern="truth"), events_per_batch=1000)
    assert len(run["partitions"]) == 1
    assert_same_tables(reference, out)
    ref = json.loads((reference / "run.json").read_text())
    assert run["counts"] == ref["counts"] and run["pattern"] == ref["pattern"]


def test_two_workers_write_identical_files(dataset, reference, tmp_path):
    out = tmp_path / "two"
    assert main(["reconstruct", str(dataset), "--out", str(out), "--workers", "2", "--events-per-batch", "4",
                 *ARGS]) == 0
    assert json.loads((out / "run.json").read_text())["execution"]["workers"] == 2
    assert partition_files(out) == partition_files(reference)


def test_dask_local_cluster_gives_identical_tables(dataset, reference, tmp_path):
    from distributed import LocalCluster

    out = tmp_path / "dask"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        assert main(["reconstruct", str(dataset), "--out", str(out), "--scheduler", cluster.scheduler_address,
                     "--events-per-batch", "4", *ARGS]) == 0
    assert json.loads((out / "run.json").read_text())["execution"]["scheduler"] == cluster.scheduler_address
    assert_same_tables(reference, out)
    assert partition_files(out) == partition_files(reference)


def test_unreachable_scheduler_is_one_line(dataset, tmp_path, capsys, monkeypatch):
    import pkf.pipeline.executor

    monkeypatch.setattr(pkf.pipeline.executor, "CONNECT_TIMEOUT_S", 1)
    code = main(["reconstruct", str(dataset), "--out", str(tmp_path / "r"), "--scheduler", "tcp://127.0.0.1:9",
                 *ARGS])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--scheduler" in err
    assert list(tmp_path.iterdir()) == []  # neither the run nor a staging directory


def test_sigkill_then_rerun_gives_the_uninterrupted_output(dataset, tmp_path, capsys):
    out = tmp_path / "killed"
    partial = tmp_path / ".killed.partial"
    cmd = [sys.executable, "-m", "pkf.cli", "reconstruct", str(dataset), "--out", str(out), "--workers", "1",
           "--events-per-batch", "1", *ARGS]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(numba.config.CACHE_DIR))  # kernels are cached already
    proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            journal = partial / "_journal"
            if journal.is_dir() and len(list(journal.glob("*.json"))) >= 3:
                break
            time.sleep(0.005)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL, "the run ended before it could be killed midway"
    assert not out.exists()  # nothing looks complete
    done = sorted(p.stem for p in (partial / "_journal").glob("*.json"))
    assert 3 <= len(done) < 24
    # a finished partition whose file was damaged since is redone, not trusted
    damaged = partial / "chi2" / f"{done[0]}.parquet"
    damaged.write_bytes(damaged.read_bytes() + b"x")

    assert main(["reconstruct", str(dataset), "--out", str(out), "--workers", "1", "--events-per-batch", "1",
                 *ARGS]) == 0
    assert "resuming" in capsys.readouterr().err
    info = json.loads((out / "run.json").read_text())
    assert info["execution"]["resumed_partitions"] == len(done) - 1
    assert not partial.exists()
    uninterrupted = tmp_path / "whole"
    assert main(["reconstruct", str(dataset), "--out", str(uninterrupted), "--workers", "1",
                 "--events-per-batch", "1", *ARGS]) == 0
    assert partition_files(out) == partition_files(uninterrupted)
    assert_same_tables(out, uninterrupted)
    whole = json.loads((uninterrupted / "run.json").read_text())
    assert info["counts"] == whole["counts"] and info["pattern"] == whole["pattern"]


def test_rerun_of_complete_run_and_overwrite(dataset, reference, tmp_path, capsys):
    out = tmp_path / "again"
    base = ["reconstruct", str(dataset), "--out", str(out), "--workers", "1", "--events-per-batch", "4"]
    assert main([*base, *ARGS]) == 0
    before = (out / "run.json").read_text()
    capsys.readouterr()
    assert main([*base, *ARGS]) == 0  # complete and intact: nothing to redo
    assert "is complete" in capsys.readouterr().err
    assert (out / "run.json").read_text() == before
    assert main([*base, "--pattern", "truth", "--fitter", "reference"]) == 2  # another configuration
    assert "--overwrite" in capsys.readouterr().err
    assert main([*base, *ARGS, "--overwrite"]) == 0
    info = json.loads((out / "run.json").read_text())
    assert info["execution"]["resumed_partitions"] == 0
    assert partition_files(out) == partition_files(reference)


@pytest.mark.parametrize("damage", ["delete", "modify", "stray"])
def test_rerun_of_a_damaged_complete_run_names_the_file(dataset, reference, tmp_path, capsys, damage):
    """Issue 13 case 9: a rerun re-uses a complete run only if its files match run.json;
    a damaged one is refused naming the file (exit 2), and nothing is changed."""
    out = tmp_path / "copy"
    shutil.copytree(reference, out)
    victim = out / "states" / "part-0000-00001.parquet"
    assert victim.is_file()
    if damage == "delete":
        victim.unlink()
    elif damage == "modify":
        data = bytearray(victim.read_bytes())
        data[len(data) // 2] ^= 0x01
        victim.write_bytes(bytes(data))
    else:
        victim = victim.with_name("part-0000-00099.parquet")
        shutil.copy(out / "states" / "part-0000-00000.parquet", victim)
    before = {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    capsys.readouterr()
    code = main(["reconstruct", str(dataset), "--out", str(out), "--workers", "1", "--events-per-batch", "4", *ARGS])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("pkf: error: ") and err.count("\n") == 1 and str(victim) in err, err
    assert {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} == before
    assert not (tmp_path / ".copy.partial").exists()
