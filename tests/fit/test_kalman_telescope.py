"""Kalman core + reference extrapolator on the telescope: exact helices (DESIGN §3.2, §8)."""

import numpy as np
import pytest
from fit_helpers import TruthSample, telescope_without_material
from scipy import stats

from pkf.fit.tracks import FitResult, TrackBatch, fit_locations
from pkf.geometry import load_geometry
from pkf.params.gauss import gaussian_core

GUN = dict(particles=10, p_min=1000.0, p_max=50000.0, eta_min=2.0, eta_max=4.0)


@pytest.fixture(scope="module")
def no_material():
    return TruthSample(telescope_without_material(), events=600, seed=21, **GUN)


def test_pulls_and_chi2_without_material(no_material):
    result = no_material.fit(max_outliers=0)
    assert np.all(result.status == 0)
    pulls, _, _ = no_material.first_hit_pulls(result)
    assert pulls.shape[0] >= 5000
    for i, name in enumerate(("x", "y", "tx", "ty", "qop")):
        core = gaussian_core(pulls[:, i])
        assert abs(core.mean) < 0.05, name
        assert core.sigma == pytest.approx(1.0, abs=0.05), name
    probability = stats.chi2.sf(result.chi2, result.ndf)
    assert stats.kstest(probability, "uniform").pvalue > 0.01
    assert np.all(result.ndf == 2 * no_material.batch.n_nodes - 5)


def test_weighted_mean_equals_rts_smoother():
    """Both combinations are exact for the linearised model. The RTS smoother loses
    digits at the first nodes with a diffuse seed (it subtracts covariances of ~100 mm²
    to get ~1e-4 mm²), so the comparison uses a seed 100× tighter in position and slope;
    the default weighted mean is stable either way (checked below)."""
    sample = TruthSample(load_geometry("telescope"), events=30, seed=3, **GUN)
    diffuse = sample.fit(smoother="weighted-mean", max_outliers=0)
    sample.seed_covs[:, :4, :4] *= 1e-4
    two_filter = sample.fit(smoother="weighted-mean", max_outliers=0)
    rts = sample.fit(smoother="rts", max_outliers=0)
    assert np.all(two_filter.status == 0) and np.all(rts.status == 0)
    scale = np.sqrt(np.einsum("nii->ni", rts.node_cov))
    # states agree to 1e-6 of their errors, covariances to 1e-6 relative
    assert np.max(np.abs(two_filter.node_state - rts.node_state) / scale) < 1e-6
    rel = np.abs(two_filter.node_cov - rts.node_cov) / (scale[:, :, None] * scale[:, None, :])
    assert np.max(rel) < 1e-6
    assert np.allclose(two_filter.chi2, rts.chi2, rtol=1e-12)
    # the weighted mean hardly depends on how diffuse the seed is
    first = sample.batch.offsets[:-1]
    assert np.allclose(diffuse.node_cov[first, 3, 3], two_filter.node_cov[first, 3, 3], rtol=0.01)


def test_smoothed_state_beats_the_filter_upstream(no_material):
    """The optimal state at the first hit uses all hits: its q/p error is far below the seed's."""
    result = no_material.fit(max_outliers=0)
    _, _, cov = result.locations["first_hit"]
    assert np.all(np.sqrt(cov[:, 4, 4]) < 0.2 * np.sqrt(no_material.seed_covs[:, 4, 4]))


def test_exact_helix_gives_zero_residuals():
    """Hits exactly on the simulated helix (no smearing, no material): the fit returns the
    true state at every node and χ² ≈ 0. Two iterations: the second re-centres the seed
    prior on the first fit, so the prior pulls nothing at convergence."""
    sample = TruthSample(telescope_without_material(), events=20, seed=5, **GUN)
    first = sample.batch.offsets[:-1]
    rows = sample.batch.hit_row
    exact = sample.batch.m.copy()
    exact[:, 0] = sample.truth[rows, 0]
    exact[:, 1] = sample.truth[rows, 1]
    sample.batch.m = exact
    result = sample.fit(max_outliers=0, iterations=2)
    assert np.all(result.status == 0)
    # limited by the Runge–Kutta accuracy of simulation and fit (~0.1 µm over 1 m)
    assert np.max(result.chi2) < 1e-3
    assert np.max(np.abs(result.node_state[:, :2] - sample.truth[rows, :2])) < 2e-4  # mm
    rel_qop = np.abs(result.node_state[first, 4] / sample.truth[rows[first], 4] - 1)
    assert np.max(rel_qop) < 1e-5
    # and a 1 µm displacement of one hit is seen
    sample.batch.m[first[0], 0] += 0.001
    assert sample.fit(max_outliers=0, iterations=2).chi2[0] > 10 * result.chi2[0]


def test_fit_locations_take_each_tracks_end_nodes_and_nan_without_nodes():
    """`fit_locations`: first_hit / last_hit are the first and last node of each track (z,
    state, covariance), NaN for a track without nodes."""
    offsets = np.array([0, 3, 3, 5])
    z = np.arange(5.0) * 100.0
    ints, pairs = np.zeros(5, dtype=np.int64), np.zeros((5, 2))
    batch = TrackBatch(offsets, z, ints, ints, ints + 2, pairs, pairs, pairs, pairs)
    result = FitResult.empty(batch)
    result.node_state[:] = np.arange(25.0).reshape(5, 5)
    result.node_cov[:] = np.arange(125.0).reshape(5, 5, 5)
    fit_locations(result, batch)
    for name, rows in (("first_hit", [0, 3]), ("last_hit", [2, 4])):
        zs, state, cov = result.locations[name]
        assert np.array_equal(zs[[0, 2]], z[rows])
        assert np.array_equal(state[[0, 2]], result.node_state[rows])
        assert np.array_equal(cov[[0, 2]], result.node_cov[rows])
        assert np.isnan(zs[1]) and np.isnan(state[1]).all() and np.isnan(cov[1]).all()
