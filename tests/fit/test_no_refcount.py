"""The fit kernels that allocate nothing run without reference counting (pkf.jit.NO_REFCOUNT)."""

import numba as nb
import numpy as np
import pytest

from pkf.fit.driver import fit_tracks_no_refcount, node_chi2, track_loop
from pkf.fit.gsf import GsfFitter
from pkf.fit.gx2f import gx2f_fitter
from pkf.fit.kalman import SMOOTHER_NONE, kalman_fitter
from pkf.fit.kalman_lanes import fit_tracks_in_lanes
from pkf.fit.reference import reference_extrapolator
from pkf.geometry import load_geometry


def test_kalman_gx2f_and_gsf_use_the_loop_without_reference_counts():
    ext = reference_extrapolator(load_geometry("telescope"))
    assert track_loop(kalman_fitter(ext, 4)) is fit_tracks_in_lanes  # its own loop, in SIMD lanes
    assert track_loop(kalman_fitter(ext, 4), own=False) is fit_tracks_no_refcount
    assert track_loop(kalman_fitter(ext, 4, smoother=SMOOTHER_NONE)) is fit_tracks_no_refcount
    assert track_loop(gx2f_fitter(ext, 4, 1)) is fit_tracks_no_refcount
    assert track_loop(tuple.__new__(GsfFitter, ())) is fit_tracks_no_refcount  # the type decides


@nb.njit
def _chi2(state, cov, n_meas, hx, hy, m, sigma, active, with_cov):
    return node_chi2(state, cov, n_meas, hx, hy, m, sigma, active, with_cov)


@pytest.mark.parametrize("n_meas", (1, 2))
@pytest.mark.parametrize("active", (True, False))
def test_measurement_only_chi2_equals_the_chi2_with_a_zero_covariance(n_meas, active):
    """find_outlier's fallback (R = V) no longer builds a zero covariance: same value, bit for bit."""
    rng = np.random.default_rng(3)
    state = rng.normal(size=5)
    cov = rng.normal(size=(5, 5))
    hx = np.array([0.98, -0.2])
    hy = np.array([0.2, 0.98])
    m = rng.normal(size=2)
    sigma = np.array([0.012, 0.03])
    without = _chi2(state, cov, n_meas, hx, hy, m, sigma, active, False)
    zero = _chi2(state, np.zeros((5, 5)), n_meas, hx, hy, m, sigma, active, True)
    assert without == zero and without > 0.0
