"""`pkf reconstruct --pattern truth` end to end: the run tables of DESIGN §6."""

import json
import shutil

import numpy as np
import pytest

from pkf.cli import main
from pkf.io.reader import read_table
from pkf.io.schemas import CANDIDATES, CHI2, PULLS, STATES


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "gun"
    assert main(["simulate", "--out", str(out), "--generator", "gun", "--events", "20", "--seed", "2"]) == 0
    return out


@pytest.fixture(scope="module")
def run(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "run"
    assert main(["reconstruct", str(dataset), "--out", str(out), "--fitter", "reference", "--pattern", "truth"]) == 0
    return out


def test_run_tables(run):
    chi2 = read_table(run, CHI2, name="chi2").to_pydict()
    states = read_table(run, STATES, name="states").to_pydict()
    pulls = read_table(run, PULLS, name="pulls").to_pydict()
    candidates = read_table(run, CANDIDATES, name="candidates").to_pydict()
    n_tracks = len(chi2["track_id"])
    assert n_tracks > 150
    assert set(chi2["fitter"]) == {"reference"}
    assert len(set(zip(candidates["event_id"], candidates["track_id"]))) == n_tracks
    ok = np.array(chi2["status"]) == "ok"
    assert ok.mean() > 0.95
    assert len(states["track_id"]) == 3 * ok.sum()
    assert set(states["location"]) == {"first_hit", "last_hit", "beamline"}
    assert np.all(np.array(chi2["mc_particle_id"])[ok] > 0)
    assert not np.any(np.array(chi2["is_ghost"]))
    pull_x = np.array(pulls["pull_x"])
    assert np.all(np.isfinite(pull_x)) and 0.7 < np.std(pull_x) < 1.3
    # the beamline is near the luminous region (σ_z = 45 mm)
    beam_z = np.array(states["z"])[np.array(states["location"]) == "beamline"]
    assert np.median(np.abs(beam_z)) < 100


def test_run_json(run):
    info = json.loads((run / "run.json").read_text())
    assert info["config"]["pattern"] == "truth" and info["config"]["fitters"] == ["reference"]
    timing = info["timing"]["fit"]["reference"]
    assert timing["tracks"] > 0 and timing["tracks_per_s"] > 0 and timing["ns_per_node"] > 0
    # speeds from the kernels' CPU time, so that they do not depend on --workers (issue 17)
    assert timing["tracks_per_s"] == pytest.approx(timing["tracks"] / timing["cpu_s"])
    assert timing["ns_per_node"] == pytest.approx(1e9 * timing["cpu_s"] / timing["nodes"])
    assert info["pattern"]["efficiency"] > 0.95
    assert info["input"]["geometry"] == "lhcb-like"


def test_reconstruct_bad_input(dataset, tmp_path, capsys):
    code = main(["reconstruct", str(tmp_path / "missing"), "--out", str(tmp_path / "r"), "--fitter",
                 "reference", "--pattern", "truth"])
    assert code == 2
    capsys.readouterr()
    no_mc = tmp_path / "no_mc"
    shutil.copytree(dataset, no_mc)
    (no_mc / "mc_hits.parquet").unlink()
    code = main(["reconstruct", str(no_mc), "--out", str(tmp_path / "r"), "--fitter", "reference",
                 "--pattern", "truth"])
    err = capsys.readouterr().err
    assert code == 2 and "mc_hits" in err and err.count("\n") == 1
    broken = tmp_path / "broken"
    shutil.copytree(dataset, broken)
    (broken / "hits.parquet").write_bytes((dataset / "hits.parquet").read_bytes()[:1000])
    code = main(["reconstruct", str(broken), "--out", str(tmp_path / "r"), "--fitter", "reference",
                 "--pattern", "truth"])
    assert code == 2
    assert not (tmp_path / "r").exists()


def test_a_detector_the_triplet_pattern_cannot_search_is_refused_before_any_work(tmp_path, capsys):
    """The telescope has no UT and SciFi: the default --pattern triplet stops with one line
    that names --pattern truth, exit 2, and no run directory; --pattern truth reconstructs it."""
    data = tmp_path / "telescope"
    assert main(["simulate", "--out", str(data), "--geometry", "telescope", "--generator", "gun", "--events", "3",
                 "--seed", "4"]) == 0
    capsys.readouterr()
    code = main(["reconstruct", str(data), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--pattern truth" in err and "telescope" in err
    assert not (tmp_path / "r").exists()
    assert main(["reconstruct", str(data), "--out", str(tmp_path / "r"), "--pattern", "truth"]) == 0


def test_gx2f_and_gsf_write_the_same_tables(dataset, tmp_path):
    """--fitter gx2f and --fitter gsf (issue 7) run through the same pipeline and tables."""
    out = tmp_path / "r"
    assert main(["reconstruct", str(dataset), "--out", str(out), "--pattern", "truth",
                 "--fitter", "reference", "--fitter", "gx2f", "--fitter", "gsf"]) == 0
    chi2 = read_table(out, CHI2, name="chi2").to_pydict()
    fitter = np.array(chi2["fitter"])
    assert set(fitter) == {"reference", "gx2f", "gsf"}
    for name in ("gx2f", "gsf"):
        ok = np.array(chi2["status"])[fitter == name] == "ok"
        assert ok.mean() > 0.95, name
    states = read_table(out, STATES, name="states").to_pydict()
    assert set(states["fitter"]) == {"reference", "gx2f", "gsf"}
    info = json.loads((out / "run.json").read_text())
    assert set(info["timing"]["fit"]) == {"reference", "gx2f", "gsf"}
