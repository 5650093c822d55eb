"""Tuning closure (issue 4): `pkf tune` on a fresh sample reproduces the shipped set's fit
quality, and the tuned parameters have the physics values they should."""

import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pkf.cli import main
from pkf.fit.tracks import FitOptions, fit_batch
from pkf.geometry import load_geometry
from pkf.params.parameter_set import ParameterSet, shipped_parameters
from pkf.params.gauss import gaussian_core

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fit"))
from fit_helpers import TruthSample  # noqa: E402


@pytest.fixture(scope="module")
def fresh_tune(tmp_path_factory):
    """Tune on a fresh 600-event B_s → φφ sample (≈ 20k long pion tracks)."""
    base = tmp_path_factory.mktemp("closure")
    data, params = base / "data", base / "params.json"
    assert main(["simulate", "--out", str(data), "--generator", "bs2phiphi", "--events", "600",
                 "--seed", "4242"]) == 0
    started = time.perf_counter()
    assert main(["tune", str(data), "--out", str(params)]) == 0
    return ParameterSet.load(params), time.perf_counter() - started


def _dp_over_p_core(sample, params, p_lo, p_hi):
    geometry = sample.geometry
    result = fit_batch(params.extrapolator(geometry), sample.batch, FitOptions(), sample.seeds, sample.seed_covs)
    first = sample.batch.offsets[:-1]
    rows = sample.batch.hit_row[first]
    qop_true = sample.production_qop[rows]
    fitted = result.locations["first_hit"][1][:, 4]
    p = 1 / np.abs(qop_true)
    ok = (result.status == 0) & sample.long_tracks() & (p >= p_lo) & (p < p_hi)
    return gaussian_core(np.abs(qop_true[ok]) / np.abs(fitted[ok]) - 1).sigma


def test_closure_against_the_shipped_parameters(fresh_tune):
    params, seconds = fresh_tune
    assert seconds < 600
    geometry = load_geometry("lhcb-like")
    sample = TruthSample(geometry, events=300, seed=99, particles=10, p_min=3000.0, p_max=100000.0,
                         eta_min=2.0, eta_max=5.0)
    shipped = shipped_parameters(geometry)
    for lo, hi in ((3000.0, 10000.0), (10000.0, 100000.0)):
        fresh = _dp_over_p_core(sample, params, lo, hi)
        reference = _dp_over_p_core(sample, shipped, lo, hi)
        assert fresh == pytest.approx(reference, rel=0.05), (lo, hi, fresh, reference)


def test_tuned_values_are_physical(fresh_tune):
    params, _ = fresh_tune
    fits = params.metadata["fits"]
    assert all(info["noise"]["valid"] for info in fits.values())
    velo_slot = fits["velo"]["slots"][0]
    # Highland for x/X0 = 0.01 of silicon at β = 1: θ0·p = 13.6 MeV·0.1·(1 + 0.038 ln 0.01) = 1.12 MeV
    assert params.noise[velo_slot, 0] == pytest.approx(1.12, rel=0.1)
    # energy lost upstream of the magnet by a pion (VELO modules, RICH1, UT): ~10 MeV
    ut_to_scifi = next(v for v in fits.values() if v["kind"] == 3)
    assert 3.0 < ut_to_scifi["extrapolation"]["delta_e_mev"] < 25.0
    # the metadata records what the parameters were made from
    assert params.metadata["sample"]["events"] == 600
    assert params.geometry_hash == load_geometry("lhcb-like").content_hash
    json.dumps(params.to_json_dict())
