"""The pieces of `benchmarks/vs_acts.py` that need no `pyacts` (CI has no bench extra):
the conversion of ACTS's fitted parameters to pkf's state, pkf's Bethe–Heitler
mixture in ACTS's JSON format, and the timing rule (the same CPU budget on both sides)."""

import json
import math
import time

import numpy as np
import pytest
from bench_helpers import load_benchmark
from scipy.special import expit, ndtr

from pkf.params.bethe_heitler import Z_GRID, load_bethe_heitler_mixture


@pytest.fixture(scope="module")
def vs_acts():
    return load_benchmark("vs_acts")


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


def test_timing_fills_the_same_cpu_budget_on_both_sides(vs_acts):
    """Short calls are repeated until they fill min_seconds of CPU (pkf's ~5 ms fits), long
    ones at least `repeat` times; ACTS's Sequencer gets the events the same rule asks for."""
    calls = []

    def burn():  # ~1 ms of CPU
        calls.append(1)
        t0 = time.process_time()
        while time.process_time() - t0 < 1e-3:
            pass
        return len(calls)

    best, median, last = vs_acts.best_cpu(3, burn, min_seconds=0.03)
    assert last == len(calls) and 25 <= len(calls) - 1 <= 40  # after the warm-up call
    assert 1e-3 <= best <= median < 5e-3
    assert vs_acts.calls_for_budget(7, 0.055, 2.0) == 37  # ACTS's KF events
    assert vs_acts.calls_for_budget(7, 1.9, 2.0) == 7  # its GSF events
