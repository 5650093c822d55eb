"""Every fitter writes every node output of the tracks it fits; the others' are NaN.

`FitResult.empty` leaves the node arrays unset (no NaN fill first, issue 18.4): the fitters
must write the state, covariance and χ² of every node of each track whose status is ok, and
`pkf.fit.tracks.run_fitter` sets those of the failed tracks to NaN. Here the node arrays
start filled with a value no fit produces (`UNSET_NODE_FILL`): none may remain, on 60 minimum-
bias-like π gun tracks of the lhcb-like detector per fitter, with outlier removal, displaced
hits, non-finite seeds and seeds that fail in the fit.
"""

import numpy as np
import pytest
from fit_helpers import TruthSample

import pkf.fit.tracks as tracks
from pkf.fit.fitters import get_fitter
from pkf.fit.options import FitOptions
from pkf.fit.status import STATUS_OK
from pkf.geometry import load_geometry

SENTINEL = 7.25e300


@pytest.fixture(scope="module")
def sample():
    s = TruthSample(load_geometry("lhcb-like"), events=6, seed=19, particles=10, p_min=1500.0, p_max=20000.0)
    seeds = s.seeds.copy()
    seeds[3, 0] = np.nan  # no seed
    seeds[7, 4] *= -400.0  # far off in q/p: fails in the fit (or ends below the momentum limit)
    batch = s.batch
    m = batch.m.copy()
    m[batch.offsets[5:40:6] + 2, 0] += 0.5  # displaced hits: outliers to remove
    return s, tracks.TrackBatch(**{**vars(batch), "m": m}), seeds


@pytest.mark.parametrize("name", ["parametrized", "reference", "gx2f", "gsf"])
def test_every_node_of_a_fitted_track_is_written(sample, name, monkeypatch):
    s, batch, seeds = sample
    monkeypatch.setattr(tracks, "UNSET_NODE_FILL", SENTINEL)
    fitter = get_fitter(name)
    options = FitOptions.from_flat(max_outliers=3, max_components=4) if name == "gsf" else FitOptions(max_outliers=3)
    result = fitter.fit(fitter.extrapolator(s.geometry), batch, options, seeds, s.seed_covs)
    ok = np.repeat(result.status == STATUS_OK, batch.n_nodes)
    assert 0.5 * batch.n_tracks < np.sum(result.status == STATUS_OK) < batch.n_tracks
    assert np.sum(result.n_outliers) > 0
    for array in (result.node_state, result.node_cov, result.node_chi2):
        assert not np.any(array == SENTINEL)
        values = array.reshape(array.shape[0], -1)
        assert np.all(np.isnan(values[~ok]))
        assert np.all(np.isfinite(values[ok]))
