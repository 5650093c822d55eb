"""Per-fitter option objects (issue 14, deliverable 2): held by `ReconstructionConfig`, one
serialisation, and reachable from `pkf reconstruct` (GX2F updates, GSF weight cut and output,
Kalman smoother)."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from pkf.cli import main
from pkf.fit.fitters import get_fitter
from pkf.fit.options import FitOptions, GSFOptions, GX2FOptions, KalmanOptions
from pkf.pipeline.config import ReconstructionConfig


def test_config_round_trips_and_resolves_each_fitters_passes():
    config = ReconstructionConfig(fitters=("reference", "parametrized", "gx2f", "gsf"),
                                  kalman=KalmanOptions(smoother="rts"), gx2f=GX2FOptions(max_updates=3),
                                  gsf=GSFOptions(max_components=4, weight_cut=1e-3, output="mode"))
    data = json.loads(json.dumps(config.to_dict()))  # what run.json and the workers hold
    assert ReconstructionConfig.from_dict(data) == config
    assert config.fit_options(get_fitter("reference")).kalman.iterations == 2
    assert config.fit_options(get_fitter("parametrized")).kalman.iterations == get_fitter("parametrized").iterations
    assert ReconstructionConfig(kalman=KalmanOptions(iterations=3)).fit_options(get_fitter("reference")).kalman \
        .iterations == 3
    options = config.fit_options(get_fitter("gsf"))
    assert options == FitOptions(9.0, 2, KalmanOptions(1, "rts"), GX2FOptions(3), GSFOptions(4, 1e-3, "mode"))
    with pytest.raises(ValueError):
        GX2FOptions(max_updates=0)
    with pytest.raises(TypeError):
        FitOptions.from_flat(max_update=3)


def _states(run, fitter):
    table = pq.read_table(run / "states")
    keep = np.asarray(table.column("fitter").to_pylist()) == fitter
    return np.column_stack([table.column(c).to_numpy()[keep] for c in ("x", "tx", "qop", "c44")])


def test_gx2f_and_gsf_options_reach_their_fitters(tmp_path, capsys):
    data = tmp_path / "data"
    assert main(["simulate", "--out", str(data), "--geometry", "telescope", "--generator", "gun", "--events", "3",
                 "--species", "electron", "--particles", "5", "--seed", "5"]) == 0
    common = ["--pattern", "truth", "--fitter", "gx2f", "--fitter", "gsf", "--workers", "1"]
    assert main(["reconstruct", str(data), "--out", str(tmp_path / "default"), *common]) == 0
    assert main(["reconstruct", str(data), "--out", str(tmp_path / "tuned"), *common, "--gx2f-max-updates", "1",
                 "--gsf-output", "mean", "--gsf-weight-cut", "0.01", "--gsf-sibling-merge", "0",
                 "--gsf-product-merge", "0", "--gsf-mixture-smoothing-everywhere"]) == 0
    config = json.loads((tmp_path / "tuned" / "run.json").read_text())["config"]
    assert config["gx2f"]["max_updates"] == 1
    assert config["gsf"] == {"max_components": 12, "weight_cut": 0.01, "output": "mean", "sibling_merge": 0.0,
                             "product_merge": 0.0, "mixture_smoothing_everywhere": True}
    for fitter in ("gx2f", "gsf"):
        default, tuned = _states(tmp_path / "default", fitter), _states(tmp_path / "tuned", fitter)
        assert default.shape == tuned.shape and not np.allclose(default, tuned), fitter
    capsys.readouterr()
    assert main(["reconstruct", str(data), "--out", str(tmp_path / "bad"), "--gsf-output", "median"]) == 2
    assert "--gsf-output" in capsys.readouterr().err


def test_the_electron_hypothesis_reaches_the_kalman_fitters_only(tmp_path, capsys):
    """`--hypothesis electron` (issue 15) is recorded in run.json and widens the Kalman
    fitters' q/p covariances (Bethe–Heitler variance at every plane); the GX2F keeps the pion."""
    data = tmp_path / "data"
    assert main(["simulate", "--out", str(data), "--geometry", "telescope", "--generator", "gun", "--events", "3",
                 "--species", "electron", "--particles", "5", "--seed", "5"]) == 0
    common = ["--pattern", "truth", "--fitter", "reference", "--fitter", "parametrized", "--fitter", "gx2f",
              "--workers", "1"]
    assert main(["reconstruct", str(data), "--out", str(tmp_path / "pion"), *common]) == 0
    assert main(["reconstruct", str(data), "--out", str(tmp_path / "electron"), *common, "--hypothesis", "electron"]) == 0
    config = json.loads((tmp_path / "electron" / "run.json").read_text())["config"]
    assert config["kalman"]["hypothesis"] == "electron"
    for fitter in ("reference", "parametrized"):
        pion, electron = _states(tmp_path / "pion", fitter), _states(tmp_path / "electron", fitter)
        assert pion.shape == electron.shape
        assert np.median(electron[:, 3] / pion[:, 3]) > 2.0, fitter
    np.testing.assert_array_equal(_states(tmp_path / "pion", "gx2f"), _states(tmp_path / "electron", "gx2f"))
    capsys.readouterr()
    assert main(["reconstruct", str(data), "--out", str(tmp_path / "bad"), "--hypothesis", "muon"]) == 2
    assert "--hypothesis" in capsys.readouterr().err
