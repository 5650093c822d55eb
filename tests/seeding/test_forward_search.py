"""The combinatorial Kalman filter of the forward extension (`pkf.seeding.forward.search`).

Its branch and bound leaves out a branch only when no leaf below it can rank: the best
leaf of a search that collects no leaves (K = 0, bounded by the best so far) must be the
one of the same search collecting more leaves than the tree has (never bounded: the
exhaustive search), path, hit counts, χ², state and covariance bit for bit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from pkf.geometry import load_geometry
from pkf.seeding.forward.kernel import _kf_work, _ranked
from pkf.seeding.forward.prepare import layout
from pkf.seeding.forward.records import MODE_OFF, MODE_SEARCH, Filter, Hits, Leaf, Reference, SearchRules
from pkf.seeding.forward.search import search

sys.path.insert(0, str(Path(__file__).resolve().parent))
from forward_helpers import random_reference  # noqa: E402

#: the searched layers: the first SciFi station and two layers of the second
N_SEARCHED = 6


def _ambiguous_event(lay, j0, j1, rng):
    """A filter around the reference of `forward_helpers.random_reference` with a VELO-like
    prior and, on each searched layer, the track's hit and two decoys 0.5–3 σ away on
    either side: many leaves pass the cuts, and the best is not simply the nearest hits."""
    n_fwd = lay.layer.size
    ref_s, F, Q = random_reference(n_fwd, rng)
    u_true = lay.cos * ref_s[:, 0] + lay.sin * ref_s[:, 1]
    u, sigma, offsets = [], [], [0]
    for j in range(n_fwd):
        if j0 <= j < j1:
            s = lay.sigma[j]
            layer_u = u_true[j] + s * np.concatenate([rng.normal(size=1), rng.choice([-1, 1], 2) * rng.uniform(0.5, 3.0, 2)])
            u += sorted(layer_u)
            sigma += [s] * 3
        offsets.append(len(u))
    hits = Hits(np.array(offsets, dtype=np.int64), np.array(u), np.array(sigma), np.zeros(len(u), dtype=np.bool_))
    mode = np.full(n_fwd, MODE_OFF, dtype=np.int64)
    mode[j0:j1] = MODE_SEARCH
    filt = Filter(
        ref=Reference(ref_s, F, Q),
        ws=_kf_work(n_fwd),
        mode=mode,
        fixed=np.full(n_fwd, -1, dtype=np.int64),
        x0=np.zeros(5),
        P0=np.diag([0.3**2, 0.3**2, 1e-3**2, 1e-3**2, (10.0 / 1500.0) ** 2]),
    )
    return filt, hits


@pytest.mark.parametrize("seed", range(1, 9))
def test_bounded_search_finds_the_exhaustive_best(seed):
    geometry = load_geometry("lhcb-like")
    _, lay = layout(geometry)
    n_fwd = lay.layer.size
    j0 = lay.n_ut
    j1 = j0 + N_SEARCHED
    filt, hits = _ambiguous_event(lay, j0, j1, np.random.default_rng(seed))
    rules = SearchRules(5.0, 3, 3, 2, N_SEARCHED - 2, False, 0, np.full(40, 60.0), 10**7, 9.0, -1, 0.0, 1.0)
    results = []
    for k in (0, 4096):  # 4096 > the 4^6 leaves the tree can have: never bounded
        best = Leaf(np.full(n_fwd, -1, dtype=np.int64), np.zeros(5), np.zeros((5, 5)))
        top = _ranked(k, n_fwd)
        results.append((search(j0, j1, filt, hits, lay, rules, best, top), best, top))
    (bounded, best_b, _), (exhaustive, best_e, top_e) = results
    assert top_e.count[0] > 20  # ambiguous: many leaves pass
    assert bounded == exhaustive and exhaustive[0] >= N_SEARCHED - 2
    np.testing.assert_array_equal(best_b.path, best_e.path)
    np.testing.assert_array_equal(best_b.path[j0:j1], top_e.paths[0, j0:j1])
    np.testing.assert_array_equal(best_b.x, best_e.x)
    np.testing.assert_array_equal(best_b.P, best_e.P)
