"""The reference Kalman fit on the lhcb-like detector: pulls, χ², outliers (issue 3)."""

from dataclasses import replace

import numpy as np
import pytest
from fit_helpers import TruthSample

from pkf.geometry import load_geometry
from pkf.params.gauss import gaussian_core


@pytest.fixture(scope="module")
def pions():
    return TruthSample(load_geometry("lhcb-like"), events=300, seed=31, particles=10,
                       p_min=2000.0, p_max=100000.0, eta_min=2.0, eta_max=5.0)


def test_pulls_and_chi2_of_long_tracks(pions):
    result = pions.fit()
    long = pions.long_tracks()
    assert long.sum() > 2000
    assert np.mean(result.status[long] == 0) > 0.999
    pulls, _, _ = pions.first_hit_pulls(result, long)
    for i, name in enumerate(("x", "y", "tx", "ty", "qop")):
        core = gaussian_core(pulls[:, i])
        assert 0.95 <= core.sigma <= 1.10, (name, core)
        assert abs(core.mean) < 0.1, (name, core)
    ok = long & (result.status == 0)
    assert 0.9 <= np.mean(result.chi2[ok] / result.ndf[ok]) <= 1.15


def test_displaced_hits_are_removed_as_outliers(pions):
    """One hit per long track moved by 10σ: ≥ 99% of them are removed, pulls stay good."""
    batch = pions.batch
    long = np.flatnonzero(pions.long_tracks())
    rng = np.random.default_rng(4)
    # a random node of each track, not the first or last (those anchor the states)
    pick = batch.offsets[long] + 1 + (rng.random(long.size) * (batch.n_nodes[long] - 2)).astype(int)
    moved = replace(batch, m=batch.m.copy())
    moved.m[pick, 0] += 10.0 * moved.sigma[pick, 0] * rng.choice([-1.0, 1.0], size=pick.size)
    result = pions.fit(batch=moved)
    removed = ~result.node_active[pick]
    assert removed.mean() >= 0.99
    select = np.zeros(batch.n_tracks, dtype=bool)
    select[long] = True
    pulls, _, _ = pions.first_hit_pulls(result, select)
    for i in range(5):
        assert 0.95 <= gaussian_core(pulls[:, i]).sigma <= 1.10


def test_momentum_resolution_is_a_few_permille(pions):
    result = pions.fit()
    _, res, truth = pions.first_hit_pulls(result, pions.long_tracks())
    dp_over_p = (np.abs(truth[:, 4]) / np.abs(truth[:, 4] + res[:, 4])) - 1.0
    core = gaussian_core(dp_over_p)
    assert 0.002 < core.sigma < 0.008  # LHCb: 0.4–0.6% (paper Fig. 1)
