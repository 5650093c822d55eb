"""The φ-window lookup of the VELO search (pkf.seeding.velo_search) and the φ sort of its
hits. The φ sort (`_stable_sort_by_key`, in place, one scratch buffer) must give the
permutation of numpy's stable argsort, ties included. The cheap window
(`fast_atan2` for its centre, the tangent bound `_angular_half_width` for its width) must
hand the search every hit of the box it asks for, in the order the search has always
visited them (φ order around the box), whatever the bin count; the found tracks then
cannot depend on how wide the window is. Each check compares with a brute-force scan of
all the module's hits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pkf.seeding.velo_search import (
    FAST_ATAN2_ERROR,
    N_PHI_BINS,
    _angular_half_width,
    _bin_ranges,
    _fill_bins,
    _stable_sort_by_key,
    _window_ranges,
    fast_atan2,
)

# columns of the kernel's hit table (velo_search._H_X, _H_Y, _H_PHI)
_X, _Y, _PHI, _N_H = 0, 1, 3, 7


def test_fast_atan2_is_within_its_error_bound():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(200_000, 2)) * rng.choice([1e-3, 1.0, 50.0], size=(200_000, 1))
    axes = np.array([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0], [-1.0, 1e-300], [-1.0, -1e-300],
                     [3.0, 3.0], [-3.0, 3.0], [-3.0, -3.0], [3.0, -3.0]])
    pts = np.vstack([pts, axes])
    worst = max(abs(fast_atan2(y, x) - math.atan2(y, x)) for y, x in pts)
    assert worst < FAST_ATAN2_ERROR / 10  # 4.1e-8 rad: the polynomial's error, and rounding
    assert fast_atan2(0.0, 0.0) == 0.0


def test_angular_half_width_bounds_the_arcsine():
    rng = np.random.default_rng(2)
    r = rng.uniform(0.5, 60.0, 100_000)
    w = r * rng.uniform(0.0, 0.999999, r.size)
    bound = np.array([_angular_half_width(a, b) for a, b in zip(w, r)])
    assert np.all(bound >= np.arcsin(w / r))
    small = w < 0.3 * r  # the windows of the search: tight there (tan θ = θ + θ³/3 + …)
    theta = np.arcsin(w[small] / r[small])
    assert np.all(bound[small] <= theta * (1.0 + 0.5 * theta**2))
    assert _angular_half_width(5.0, 5.0) > math.pi and _angular_half_width(6.0, 5.0) > math.pi
    assert _angular_half_width(4.999, 5.0) == 0.5 * math.pi  # below π like the arcsine: a window, not the module


def _module(rng, n):
    """n hits of one module (a VELO-like ring 5–45 mm, some clustered near φ = ±π and
    along lines), sorted by φ as `_prepare_hits` sorts them, with the module's bin table."""
    r = rng.uniform(5.0, 45.0, n)
    phi = np.where(rng.random(n) < 0.3, rng.choice([-1.0, 1.0], n) * rng.uniform(3.0, math.pi, n),
                   rng.uniform(-math.pi, math.pi, n))
    hit = np.zeros((n, _N_H))
    hit[:, _X] = r * np.cos(phi)
    hit[:, _Y] = r * np.sin(phi)
    hit[:, _PHI] = np.arctan2(hit[:, _Y], hit[:, _X])
    hit = hit[np.argsort(hit[:, _PHI], kind="stable")]
    bin_off = np.empty(N_PHI_BINS + 1, dtype=np.int64)
    _fill_bins(bin_off, np.array([0, n], dtype=np.int64), hit, 0, 1)
    return hit, bin_off


def _visited_box_hits(hit, bin_off, xp, yp, wx, wy):
    a0, a1, c0, c1 = _window_ranges(bin_off, 0, xp, yp, wx, wy)
    rows = list(range(a0, a1)) + list(range(c0, c1))
    return [c for c in rows if abs(hit[c, _X] - xp) <= wx and abs(hit[c, _Y] - yp) <= wy]


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_window_returns_every_box_hit_in_phi_order_around_the_box(seed):
    """Brute force: all hits of the box, ordered by their φ offset from the box centre
    (the order of the search's φ-sorted scan, also when the window wraps at ±π)."""
    rng = np.random.default_rng(seed)
    hit, bin_off = _module(rng, 400)
    checked = 0
    for _ in range(3000):
        c = hit[rng.integers(hit.shape[0])]
        xp, yp = c[_X] + rng.normal(0, 0.5), c[_Y] + rng.normal(0, 0.5)
        if rng.random() < 0.2:  # boxes on the negative x axis: windows across φ = ±π
            xp, yp = -rng.uniform(4.0, 45.0), rng.normal(0, 0.3)
        wx, wy = rng.uniform(0.01, 3.0, 2) * rng.choice([1.0, 10.0])
        in_box = np.flatnonzero((np.abs(hit[:, _X] - xp) <= wx) & (np.abs(hit[:, _Y] - yp) <= wy))
        if 1.4143 * max(wx, wy) >= math.hypot(xp, yp):
            expected = in_box.tolist()  # the box holds the origin: the whole module, in φ order
        else:
            offset = np.angle(np.exp(1j * (hit[in_box, _PHI] - math.atan2(yp, xp))))
            expected = in_box[np.argsort(offset, kind="stable")].tolist()
        assert _visited_box_hits(hit, bin_off, xp, yp, wx, wy) == expected
        checked += len(expected)
    assert checked > 3000  # the boxes did hold hits


@pytest.mark.parametrize("n", [0, 1, 2, 15, 16, 17, 33, 100, 1000])
def test_phi_sort_is_numpys_stable_argsort(n):
    """Keys with many ties (also −0.0 against 0.0, equal for a comparison) sorted in a
    slice of a larger array: the same permutation as np.argsort(kind="stable"), the
    elements outside the slice untouched."""
    rng = np.random.default_rng(n)
    key = rng.choice(np.array([-0.0, 0.0, 1.5, -2.0, 3.0, math.pi, -math.pi]), n + 10)
    key[5:5 + n] = np.where(rng.random(n) < 0.5, key[5:5 + n], rng.uniform(-math.pi, math.pi, n))
    val = np.arange(n + 10, dtype=np.int64) * 7
    want_val = val.copy()
    want_val[5:5 + n] = val[5:5 + n][np.argsort(key[5:5 + n], kind="stable")]
    want_key = key.copy()
    want_key[5:5 + n] = np.sort(key[5:5 + n], kind="stable")
    _stable_sort_by_key(key, val, 5, 5 + n, np.empty(n + 10), np.empty(n + 10, dtype=np.int64))
    assert np.array_equal(val, want_val)
    assert np.array_equal(key, want_key) and np.array_equal(np.signbit(key), np.signbit(want_key))


def test_a_window_that_is_not_a_number_is_the_whole_module():
    """A NaN or infinite window centre or width (from a prediction that is not finite)
    visits every hit of the module once, instead of bins from an undefined integer
    conversion."""
    hit, bin_off = _module(np.random.default_rng(6), 300)
    for phi, w in ((math.nan, 0.1), (0.3, math.nan), (math.inf, 0.1), (-math.inf, 0.1), (math.nan, math.nan)):
        assert _bin_ranges(bin_off, 0, phi, w) == (0, 300, 0, 0)
    a0, a1, c0, c1 = _bin_ranges(bin_off, 0, 0.3, 0.1)  # a finite window: part of the module
    assert 0 < a1 - a0 < 300 and c0 == c1 == 0
