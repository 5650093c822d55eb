"""The Kalman core with tracks in SIMD lanes (`pkf.fit.kalman_lanes`) gives the scalar loop's outputs, bit for bit."""

import numpy as np
import pytest
from fit_helpers import TruthSample

from pkf.fit.driver import FitOutputs, OutlierRule, TrackNodes, fit_tracks_no_refcount, max_nodes
from pkf.fit.kalman import SMOOTHER_NONE, SMOOTHER_WEIGHTED_MEAN, kalman_fitter
from pkf.fit.kalman_lanes import GROUP, fit_tracks_in_lanes, lane_order
from pkf.fit.tracks import FitResult, TrackBatch
from pkf.geometry import load_geometry

FIELDS = ("offsets", "z", "layer", "hit_row", "n_meas", "hx", "hy", "m", "sigma")
OUTPUTS = ("node_state", "node_cov", "node_chi2", "node_active", "status", "chi2", "ndf", "n_outliers")


@pytest.fixture(scope="module")
def sample():
    """Telescope tracks of unequal lengths (the last 0–6 nodes of each dropped) and broken
    seeds: NaN (scalar path), q/p ×300 (curls away: a failing extrapolation)."""
    s = TruthSample(load_geometry("telescope"), events=12, seed=7)
    b = s.batch
    rng = np.random.default_rng(2)
    lengths = np.diff(b.offsets)
    keep_n = np.maximum(1, lengths - rng.integers(0, 7, lengths.size))
    node_track = np.repeat(np.arange(lengths.size), lengths)
    keep = (np.arange(b.z.size) - b.offsets[node_track]) < keep_n[node_track]
    fields = {f: getattr(b, f)[keep] for f in FIELDS if f != "offsets"}
    offsets = np.concatenate([[0], np.cumsum(keep_n)]).astype(b.offsets.dtype)
    batch = TrackBatch(offsets, *(fields[f] for f in FIELDS[1:]))
    seeds = s.seeds.copy()
    seeds[1, 4] = np.nan
    seeds[2::17, 4] *= 300.0
    return s, batch, seeds


def _fit(loop, fitter, batch, seeds, seed_covs, max_outliers):
    r = FitResult.empty(batch)
    loop(
        fitter,
        TrackNodes.of(batch, seeds, seed_covs),
        OutlierRule(np.array([9.0, 11.83]), max_outliers),
        FitOutputs.of(r),
    )
    r.set_failed_nodes_nan(batch)  # as `pkf.fit.tracks.run_fitter`: a failed track's nodes are not written
    return r


@pytest.mark.parametrize("smoother", (SMOOTHER_WEIGHTED_MEAN, SMOOTHER_NONE))
@pytest.mark.parametrize("iterations,max_outliers", ((1, 0), (2, 3)))
def test_lanes_give_the_scalar_outputs_bitwise(sample, smoother, iterations, max_outliers):
    s, batch, seeds = sample
    order, n_grouped = lane_order(TrackNodes.of(batch, seeds, s.seed_covs))
    lengths = np.diff(batch.offsets)
    assert n_grouped > 4 * GROUP and np.unique(lengths[order[:n_grouped]]).size > 3  # unequal lengths in lanes
    fitter = kalman_fitter(s.extrapolator, max_nodes(batch.offsets), iterations, smoother)
    scalar = _fit(fit_tracks_no_refcount, fitter, batch, seeds, s.seed_covs, max_outliers)
    lanes = _fit(fit_tracks_in_lanes, fitter, batch, seeds, s.seed_covs, max_outliers)
    assert np.any(scalar.status != 0) and np.sum(scalar.status == 0) > 0.8 * batch.n_tracks  # failing tracks too
    for name in OUTPUTS:
        a, b = getattr(scalar, name), getattr(lanes, name)
        assert a.tobytes() == b.tobytes(), name


def test_lane_order_is_a_stable_sort_by_length_within_windows(sample):
    """The tracks that take the lanes keep their order within each window but for a stable
    sort by number of nodes; the others (a NaN seed, ndf ≤ 0) follow in their own order."""
    s, batch, seeds = sample
    nodes = TrackNodes.of(batch, seeds, s.seed_covs)
    window = 8
    order, n_grouped = lane_order(nodes, window)
    lengths = np.diff(batch.offsets)
    dims = np.add.reduceat(batch.n_meas, batch.offsets[:-1]) - 5
    grouped = np.flatnonzero((dims > 0) & np.isfinite(seeds).all(axis=1))
    assert n_grouped == grouped.size and n_grouped < batch.n_tracks  # the NaN seed is left out
    expected = np.concatenate([
        w[np.argsort(lengths[w], kind="stable")] for w in np.split(grouped, np.arange(window, grouped.size, window))
    ])
    assert np.array_equal(order[:n_grouped], expected)
    assert np.array_equal(order[n_grouped:], np.setdiff1d(np.arange(batch.n_tracks), grouped))
