"""DESIGN §13: an output never equals, contains or sits inside an input, with or without
--overwrite (issue 13, cases 1–2: `--overwrite` used to delete a dataset that sat inside --out).

Every command that takes --out is run with --overwrite and every relation of --out to each of its
inputs (equal, parent, child, sibling); afterwards the input's bytes are compared with a digest
taken before. Every refused case exits 2 with one line naming the option and the input; the
sibling case (a legitimate output) succeeds.
"""

import hashlib
import shutil
from pathlib import Path

import pytest

from pkf.cli import main

RELATIONS = ("equal", "parent", "child", "sibling")


def digest(path: Path) -> str:
    """SHA-256 over every file's relative path and bytes below ``path`` (or of the file itself)."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        h.update(str(f.relative_to(path) if path.is_dir() else f.name).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def stock(tmp_path_factory):
    """A tiny dataset, a run of it and a geometry file, made once and copied per test."""
    root = tmp_path_factory.mktemp("stock")
    dataset = root / "ds"
    assert main(["simulate", "--out", str(dataset), "--generator", "gun", "--events", "2", "--particles", "2",
                 "--seed", "3"]) == 0
    run = root / "run"
    assert main(["reconstruct", str(dataset), "--out", str(run), "--pattern", "truth", "--workers", "1"]) == 0
    return {"dataset": dataset, "run": run, "geometry": dataset / "geometry.toml"}


def place(stock_item: Path, relation: str, tmp_path: Path) -> tuple[Path, Path]:
    """Copy an input under tmp_path and return (input, out) in the given relation."""
    parent = tmp_path / "par"
    parent.mkdir()
    inp = parent / "input"
    if stock_item.is_dir():
        shutil.copytree(stock_item, inp)
    else:
        inp = inp.with_suffix(stock_item.suffix)
        shutil.copy(stock_item, inp)
    out = {"equal": inp, "parent": parent, "child": inp / "out", "sibling": parent / "out"}[relation]
    return inp, out


def check(args: list[str], inp: Path, relation: str, capsys) -> None:
    before = digest(inp)
    code = main(args)
    err = capsys.readouterr().err
    assert digest(inp) == before, f"{relation}: the input changed"
    if relation == "sibling":
        assert code == 0, err
    else:
        assert code == 2, err
        assert err.count("\n") == 1 and err.startswith("pkf: error: --out "), err
        assert str(inp) in err and "Traceback" not in err


@pytest.mark.parametrize("relation", RELATIONS)
def test_reconstruct_dataset(stock, relation, tmp_path, capsys):
    inp, out = place(stock["dataset"], relation, tmp_path)
    check(["reconstruct", str(inp), "--out", str(out), "--overwrite", "--pattern", "truth", "--workers", "1"],
          inp, relation, capsys)


@pytest.mark.parametrize("relation", ["equal", "parent", "child"])
def test_reconstruct_params_file(stock, relation, tmp_path, capsys):
    """--params is an input too: a run directory that holds it must not replace it."""
    from pkf.params.parameter_set import shipped_parameters
    from pkf.geometry import load_geometry

    params_file = tmp_path / "shipped.json"
    shipped_parameters(load_geometry("lhcb-like")).save(params_file)
    inp, out = place(params_file, relation, tmp_path)
    if relation == "parent":  # the run directory holds the parameter file
        out = inp.parent
    check(["reconstruct", str(stock["dataset"]), "--out", str(out), "--overwrite", "--params", str(inp),
           "--workers", "1"], inp, relation, capsys)


@pytest.mark.parametrize("relation", RELATIONS)
def test_report_run(stock, relation, tmp_path, capsys):
    inp, out = place(stock["run"], relation, tmp_path)
    check(["report", str(inp), "--out", str(out), "--overwrite"], inp, relation, capsys)


@pytest.mark.parametrize("relation", ["equal", "parent", "child"])
def test_tune_dataset(stock, relation, tmp_path, capsys):
    inp, out = place(stock["dataset"], relation, tmp_path)
    check(["tune", str(inp), "--out", str(out), "--overwrite"], inp, relation, capsys)


@pytest.mark.parametrize("relation", ["equal", "parent", "child"])
def test_simulate_geometry_file(stock, relation, tmp_path, capsys):
    inp, out = place(stock["geometry"], relation, tmp_path)
    check(["simulate", "--geometry", str(inp), "--out", str(out), "--overwrite", "--events", "1"],
          inp, relation, capsys)


def test_symlinked_spelling_of_the_dataset(stock, tmp_path, capsys):
    """The same place by another name (a symbolic link to the folder that holds the dataset)."""
    parent = tmp_path / "par"
    shutil.copytree(stock["dataset"], parent / "ds")
    link = tmp_path / "alias"
    link.symlink_to(parent)
    check(["reconstruct", str(parent / "ds"), "--out", str(link / "."), "--overwrite", "--pattern", "truth"],
          parent / "ds", "parent", capsys)
