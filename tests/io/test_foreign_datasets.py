"""Issue 16: datasets of other producers (plain pyarrow, a geometry name or --geometry, no
meta.json, NaN truth on noise rows, extra columns) and `pkf validate`."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from pkf.cli import main
from pkf.errors import InputError
from pkf.geometry import load_geometry
from pkf.pipeline.inputs import load_dataset

RUN_TABLES = ("candidates", "chi2", "states", "pulls")
CORPUS = Path(__file__).resolve().parents[1] / "bad_inputs"
CASES = json.loads((CORPUS / "cases.json").read_text())


def _run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def pkf_dataset(tmp_path_factory) -> Path:
    """pkf's own layout: `pkf simulate --generator minbias --pileup 2 --events 10`."""
    out = tmp_path_factory.mktemp("pkf") / "ds"
    assert main(["simulate", "--generator", "minbias", "--pileup", "2", "--events", "10", "--out", str(out)]) == 0
    return out


def _plain(table: pa.Table) -> pa.Table:
    """The table as another program would write it: no pkf schema metadata, nullable fields."""
    return pa.table({name: table.column(name) for name in table.column_names})


def write_foreign(pkf_dataset: Path, out: Path) -> Path:
    """The same events written with plain pyarrow: meta.json only `{"geometry": "lhcb-like"}`,
    no geometry.toml, `layer` as int64, NaN truth on noise rows, an extra column `time` in
    hits, and mc_hits as a directory of two files, each with an extra column `cluster_size`."""
    out.mkdir()
    hits = _plain(pq.read_table(pkf_dataset / "hits.parquet"))
    hits = hits.set_column(hits.column_names.index("layer"), "layer", hits.column("layer").cast(pa.int64()))
    pq.write_table(hits.append_column("time", pa.array(np.full(hits.num_rows, 0.5))), out / "hits.parquet")
    mc = _plain(pq.read_table(pkf_dataset / "mc_hits.parquet"))
    for name in ("tx", "ty", "qop"):
        mc = mc.set_column(mc.column_names.index(name), name, pc.fill_null(mc.column(name), math.nan))
    mc = mc.append_column("cluster_size", pa.array(np.ones(mc.num_rows, np.int32)))
    (out / "mc_hits").mkdir()
    half = int(np.searchsorted(mc.column("event_id").to_numpy(), 5))
    pq.write_table(mc.slice(0, half), out / "mc_hits" / "part-0.parquet")
    pq.write_table(mc.slice(half), out / "mc_hits" / "part-1.parquet")
    pq.write_table(_plain(pq.read_table(pkf_dataset / "particles.parquet")), out / "particles.parquet")
    (out / "meta.json").write_text(json.dumps({"geometry": "lhcb-like"}))
    return out


@pytest.fixture(scope="module")
def foreign(pkf_dataset, tmp_path_factory) -> Path:
    return write_foreign(pkf_dataset, tmp_path_factory.mktemp("foreign") / "ds")


@pytest.fixture(scope="module")
def pkf_run(pkf_dataset, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("runs") / "pkf"
    assert main(["reconstruct", str(pkf_dataset), "--out", str(out), "--workers", "1", "--events-per-batch", "4"]) == 0
    return json.loads((out / "run.json").read_text())


def _table_files(run: dict) -> list[dict]:
    """Per partition, per run table: the file and its SHA-256."""
    return [{name: (f["path"], f["sha256"]) for name, f in p["files"].items()} for p in run["partitions"]]


def test_foreign_layout_gives_the_same_run_tables(foreign, pkf_run, tmp_path, capsys):
    assert not (foreign / "geometry.toml").exists()
    code, _, err = _run(capsys, "reconstruct", foreign, "--out", tmp_path / "run", "--workers", "1",
                        "--events-per-batch", "4")
    assert code == 0, err
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert len(run["partitions"]) == 3
    assert set(run["partitions"][0]["files"]) == set(RUN_TABLES)
    assert _table_files(run) == _table_files(pkf_run)  # byte-identical candidates, chi2, states, pulls
    # one warning line per table with extra columns, not one per file or partition
    warnings = [line for line in err.splitlines() if line.startswith("pkf: warning: ")]
    assert warnings == [
        f"pkf: warning: {foreign / 'hits.parquet'}: column 'time' not part of the hits schema: ignored",
        f"pkf: warning: {foreign / 'mc_hits'}: column 'cluster_size' not part of the mc_hits schema: ignored",
    ]
    assert run["input"]["ignored_columns"] == {"hits": ["time"], "mc_hits": ["cluster_size"]}
    assert (run["input"]["geometry"], run["input"]["geometry_from"]) == ("lhcb-like", "meta.json")


def test_no_meta_json_with_geometry_option(foreign, pkf_run, tmp_path, capsys):
    dataset = Path(shutil.copytree(foreign, tmp_path / "ds"))
    (dataset / "meta.json").unlink()
    code, _, err = _run(capsys, "reconstruct", dataset, "--out", tmp_path / "run", "--workers", "1",
                        "--events-per-batch", "4", "--geometry", "lhcb-like")
    assert code == 0, err
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    assert _table_files(run) == _table_files(pkf_run)
    assert run["input"]["geometry_from"] == "--geometry lhcb-like"
    assert run["input"]["geometry_hash"] == load_geometry("lhcb-like").content_hash
    assert run["config"]["geometry"] == "lhcb-like"
    # the report reads the run's dataset with the run's --geometry (before: "not a dataset (no meta.json)")
    from pkf.pipeline.report import load_truth
    from pkf.report.runs import load_run

    truth = load_truth(load_run(tmp_path / "run"))
    assert (truth.status, truth.n_events) == ("ok", 10)


@pytest.mark.parametrize("command", ["reconstruct", "tune", "validate"])
def test_no_meta_json_and_no_geometry_is_one_line(foreign, tmp_path, capsys, command):
    dataset = Path(shutil.copytree(foreign, tmp_path / "ds"))
    (dataset / "meta.json").unlink()
    out = {"reconstruct": ["--out", tmp_path / "run"], "tune": ["--out", tmp_path / "p.json"], "validate": []}
    code, _, err = _run(capsys, command, dataset, *out[command])
    assert code == 2
    if command == "validate":  # it also lists the extra columns it would ignore
        err = "".join(line + "\n" for line in err.splitlines() if not line.startswith("pkf: warning: "))
    assert err == (f"pkf: error: {dataset}: no meta.json to say which detector the hits come from: give "
                   "--geometry NAME|FILE.toml (built in: lhcb-like, telescope)\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]  # nothing written


def _geometry_file(tmp_path: Path, change: str | None = None) -> Path:
    """lhcb-like as a TOML file, optionally with one value changed (another content hash)."""
    text = load_geometry("lhcb-like").text
    if change is not None:
        assert change in text
        text = text.replace(change, change.replace("0.055", "0.056"))
    path = tmp_path / "detector.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("command", ["reconstruct", "tune", "validate"])
def test_meta_json_and_geometry_option_disagree(foreign, pkf_dataset, tmp_path, capsys, command):
    other = _geometry_file(tmp_path, "sigma = 0.055")  # same name, other detector
    for dataset, geometry in ((foreign, "telescope"), (pkf_dataset, "telescope"), (foreign, other)):
        out = {"reconstruct": ["--out", tmp_path / "run"], "tune": ["--out", tmp_path / "p.json"],
               "validate": []}[command]
        code, _, err = _run(capsys, command, dataset, *out, "--geometry", geometry)
        assert code == 2
        if command == "validate":
            err = "".join(line + "\n" for line in err.splitlines() if not line.startswith("pkf: warning: "))
        assert err.count("\n") == 1 and err.startswith(f"pkf: error: {dataset / 'meta.json'}: geometry 'lhcb-like'")
        assert f"disagrees with --geometry {geometry} (" in err
        assert not (tmp_path / "run").exists() and not (tmp_path / "p.json").exists()


def test_geometry_option_that_agrees_with_meta_json(foreign, pkf_dataset, tmp_path, capsys):
    same = _geometry_file(tmp_path)
    for dataset in (foreign, pkf_dataset):
        for geometry in ("lhcb-like", same):
            code, out, err = _run(capsys, "validate", dataset, "--geometry", geometry)
            assert code == 0, err
            assert out.endswith(": valid\n")


def test_unknown_geometry_option(foreign, tmp_path, capsys):
    code, _, err = _run(capsys, "reconstruct", foreign, "--out", tmp_path / "run", "--geometry", "lhcb-ish")
    assert code == 2
    assert err == ("pkf: error: --geometry: unknown geometry 'lhcb-ish': not a built-in (lhcb-like, telescope) "
                   "and no such file\n")
    assert list(tmp_path.iterdir()) == []


def test_nan_truth_on_noise_rows_is_read_as_null(foreign, pkf_dataset):
    geometry, theirs = load_dataset(foreign)
    _, ours = load_dataset(pkf_dataset)
    assert geometry.name == "lhcb-like"
    noise = pc.equal(theirs.mc_hits.column("particle_id"), 0)
    assert pc.sum(noise).as_py() > 0
    for name in ("tx", "ty", "qop"):
        assert theirs.mc_hits.column(name).null_count == pc.sum(noise).as_py()
    assert theirs.mc_hits.equals(ours.mc_hits)
    assert theirs.hits.equals(ours.hits)
    assert theirs.ignored_columns == {"hits": ("time",), "mc_hits": ("cluster_size",)}


def test_tune_reads_a_dataset_without_meta_json_with_geometry(foreign, tmp_path):
    from pkf.pipeline.tune import pion_pairs

    dataset = Path(shutil.copytree(foreign, tmp_path / "ds"))
    (dataset / "meta.json").unlink()
    lines = []
    geometry, _, _, pairs, events = pion_pairs(dataset, "lhcb-like", lines.append)
    assert (geometry.name, events) == ("lhcb-like", 10) and pairs.x1.shape[0] > 1000
    assert len(lines) == 2 and all(line.startswith("pkf: warning: ") for line in lines)


def test_validate_good_dataset(pkf_dataset, capsys):
    code, out, err = _run(capsys, "validate", pkf_dataset)
    assert (code, err) == (0, "")
    n_hits = pq.read_metadata(pkf_dataset / "hits.parquet").num_rows
    assert out == f"{pkf_dataset}: 10 events, {n_hits} hits, tables hits, particles, mc_hits: valid\n"


@pytest.mark.parametrize("case", sorted(c for c in CASES if not CASES[c]["args"]))
def test_validate_names_the_problem_of_each_corpus_case(case, tmp_path, capsys):
    """`pkf validate` says what `pkf reconstruct` says (tests/bad_inputs), and writes nothing."""
    expect = CASES[case]
    dataset = Path(shutil.copytree(CORPUS / case, tmp_path / case))
    code, out, err = _run(capsys, "validate", dataset)
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("pkf: error: "), err
    assert str(dataset / expect["file"]) in err
    if expect["column"] is not None:
        assert f"column {expect['column']!r}" in err
    if expect["row"] is not None:
        assert f": row {expect['row']} (" in err
    with pytest.raises(InputError) as in_memory:
        load_dataset(dataset)
    assert str(in_memory.value) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [case]


def test_validate_goes_on_past_a_failing_table(pkf_dataset, tmp_path, capsys):
    """A problem in hits, in particles and in mc_hits: three lines, one per table."""
    dataset = Path(shutil.copytree(pkf_dataset, tmp_path / "ds"))

    def spoil(name, column, row, value):
        table = pq.read_table(dataset / f"{name}.parquet")
        values = table.column(column).to_pylist()
        values[row] = value
        i = table.column_names.index(column)
        pq.write_table(table.set_column(i, table.field(i).with_nullable(True), pa.array(values, table.field(i).type)),
                       dataset / f"{name}.parquet")

    spoil("hits", "u", 17, math.nan)
    spoil("particles", "mass", 3, -1.0)
    particle_row = int(np.flatnonzero(pq.read_table(dataset / "mc_hits.parquet").column("particle_id")
                                      .to_numpy() != 0)[5])
    spoil("mc_hits", "tx", particle_row, None)
    code, out, err = _run(capsys, "validate", dataset)
    assert code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 3 and all(line.startswith("pkf: error: ") for line in lines), err
    assert f"{dataset / 'hits.parquet'}: column 'u': row 17 (" in lines[0]
    assert f"{dataset / 'particles.parquet'}: column 'mass': row 3 (" in lines[1]
    assert f"{dataset / 'mc_hits.parquet'}: column 'tx': row {particle_row} (" in lines[2]
    assert "is null on a particle's hit" in lines[2]
