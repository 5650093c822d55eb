"""The pieces of `benchmarks/vs_acts.py` that need no `pyacts` (CI has no bench extra):
the conversion of ACTS's fitted parameters to pkf's state, and pkf's Bethe–Heitler
mixture in ACTS's JSON format."""

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.special import expit, ndtr

from pkf.params.bethe_heitler import Z_GRID, load_bethe_heitler_mixture

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "vs_acts.py"


@pytest.fixture(scope="module")
def vs_acts():
    spec = importlib.util.spec_from_file_location("vs_acts", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _pkf_state(bound):
    x, y, phi, theta, qop_gev = bound[:5]
    return np.array([x, y, math.tan(theta) * math.cos(phi), math.tan(theta) * math.sin(phi), qop_gev / 1000.0])


def test_acts_bound_parameters_to_pkf_state_and_covariance(vs_acts):
    """(loc0, loc1, φ, θ, q/p [e/GeV], t) on a z plane → (x, y, tx, ty, q/p [1/MeV]); the
    covariance through the Jacobian, checked against central finite differences."""
    bound = np.array([12.0, -3.0, 0.7, 0.2, -0.25, 0.0])
    rng = np.random.default_rng(1)
    a = rng.normal(size=(6, 6))
    cov = a @ a.T * 1e-4
    state, state_cov = vs_acts.acts_state_to_pkf(bound, cov)
    assert state == pytest.approx(_pkf_state(bound), rel=1e-12)
    assert state[4] == pytest.approx(-0.25e-3)
    jac = np.zeros((5, 6))
    for j in range(6):
        h = np.zeros(6)
        h[j] = 1e-6
        jac[:, j] = (_pkf_state(bound + h) - _pkf_state(bound - h)) / 2e-6
    assert state_cov == pytest.approx(jac @ cov @ jac.T, rel=1e-6, abs=1e-18)


def test_bethe_heitler_mixture_in_acts_format(vs_acts, tmp_path):
    """Evaluating the written file as ACTS does (Horner, highest order first; logistic
    weight and mean, exponential variance; weights normalised) gives pkf's mixture's CDF
    within 0.005 at the path lengths of the benchmark (0.01 X0 per plane)."""
    info = vs_acts.acts_bethe_heitler_json(tmp_path / "bh.json")
    data = json.loads((tmp_path / "bh.json").read_text())
    (rng,) = data["ranges"]
    assert rng["transform"] and rng["low_x0"] <= 0.01 <= rng["high_x0"]
    mixture = load_bethe_heitler_mixture()
    for t in (0.010, 0.0102, 0.0104):
        comps = rng["components"]
        assert len(comps) == mixture.n_components
        w = np.array([expit(np.polyval(c["weight_coeffs"], t)) for c in comps])
        mu = np.array([expit(np.polyval(c["mean_coeffs"], t)) for c in comps])
        sd = np.sqrt([math.exp(np.polyval(c["var_coeffs"], t)) for c in comps])
        cdf = (w / w.sum() * ndtr((Z_GRID[:, None] - mu) / sd)).sum(-1)
        assert np.abs(cdf - mixture.cdf(Z_GRID, t)).max() < 0.005
    assert info["max_cdf_difference"] < 0.005
