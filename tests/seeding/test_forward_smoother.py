"""The UT outlier check's smoother (pkf.seeding.forward.outliers.smooth_ut_chi2) against a
Rauch–Tung–Striebel smoother written out in numpy on the same Kalman filter.

The check smooths the final fit of an extension (`kalman.fit_fixed`, UT and SciFi layers)
back to the UT with the modified Bryson–Frazier recursion (no matrix inverse per layer);
its smoothed states, covariances and the χ² of each UT hit against the rest of the track
must be those of the textbook RTS smoother, x_d + A·(x_{d+1}^s − x⁻_{d+1}) with
A = P_d·Fᵀ·(P⁻_{d+1})⁻¹, to rounding: the covariance is ill-conditioned (q/p against
position, as in the search); here (seeds 1–3) the two agree to ≤ 2e-14 σ in the states,
≤ 6e-7 of √(C_ii·C_jj) in the covariances (5e-12 for seeds 1 and 2) and ≤ 1e-7 relative
in the χ².
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from pkf.geometry import load_geometry
from pkf.seeding.forward.kalman import fit_fixed
from pkf.seeding.forward.kernel import _kf_work, _smoother
from pkf.seeding.forward.outliers import smooth_ut_chi2
from pkf.seeding.forward.prepare import layout
from pkf.seeding.forward.records import Filter, Hits, Leaf, Reference

sys.path.insert(0, str(Path(__file__).resolve().parent))
from forward_helpers import random_reference  # noqa: E402


def _random_filter(lay, rng):
    """A filter over the forward layers of lhcb-like around a straight reference at
    (x, y) = (300, 200) mm, Jacobians near the identity with q/p kept (row 4 = e₄), process
    noise in position and slope, a VELO-like prior, and one hit per layer (u = cos α·x +
    sin α·y of the reference plus noise; the UT layers' hits a few σ off on two layers)."""
    n_fwd = lay.layer.size
    ref_s, F, Q = random_reference(n_fwd, rng)
    F[:, 0, 4] += 5e5
    F[:, 2, 4] += 0.3
    sigma = lay.sigma
    u_true = lay.cos * ref_s[:, 0] + lay.sin * ref_s[:, 1]
    u = u_true + rng.normal(size=n_fwd) * sigma
    u[1] += 3.0 * sigma[1]
    u[2] -= 2.0 * sigma[2]
    offsets = np.arange(n_fwd + 1, dtype=np.int64)
    hits = Hits(offsets, u, sigma.copy(), np.zeros(n_fwd, dtype=np.bool_))
    P0 = np.diag([0.01**2, 0.01**2, 3e-5**2, 3e-5**2, (10.0 / 1500.0) ** 2])
    filt = Filter(
        ref=Reference(ref_s, F, Q),
        ws=_kf_work(n_fwd),
        mode=np.zeros(n_fwd, dtype=np.int64),
        fixed=np.arange(n_fwd, dtype=np.int64),
        x0=np.zeros(5),
        P0=P0,
    )
    return filt, hits


def _rts_ut(filt, lay, hits, path):
    """Smoothed states, covariances and UT-hit χ² by RTS steps from the fit's scratch."""
    ws, F = filt.ws, filt.ref.F
    n_fwd, n_ut = lay.layer.size, lay.n_ut
    x, C = ws.post_x[n_fwd - 1].copy(), ws.post_P[n_fwd - 1].copy()
    xs, Cs, chi2 = np.zeros((n_ut, 5)), np.zeros((n_ut, 5, 5)), np.full(n_ut, np.nan)
    for d in range(n_fwd - 2, -1, -1):
        A = ws.post_P[d] @ F[d + 1].T @ np.linalg.inv(ws.pred_P[d + 1])
        x = ws.post_x[d] + A @ (x - ws.pred_x[d + 1])
        C = ws.post_P[d] + A @ (C - ws.pred_P[d + 1]) @ A.T
        if d < n_ut:
            xs[d], Cs[d] = x, C
            h = np.array([lay.cos[d], lay.sin[d], 0.0, 0.0, 0.0])
            r = hits.u[path[d]] - h @ (filt.ref.s[d] + x)
            chi2[d] = r * r / (hits.sigma[path[d]] ** 2 - h @ C @ h)
    return xs, Cs, chi2


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_smoother_equals_rts(seed):
    geometry = load_geometry("lhcb-like")
    _, lay = layout(geometry)
    n_fwd, n_ut = lay.layer.size, lay.n_ut
    filt, hits = _random_filter(lay, np.random.default_rng(seed))
    leaf = Leaf(np.full(n_fwd, -1, dtype=np.int64), np.zeros(5), np.zeros((5, 5)))
    n_hits, _ = fit_fixed(0, n_fwd, filt, hits, lay, 1e3, np.full(40, 1e300), leaf)
    assert n_hits == n_fwd
    sm = _smoother(n_ut)
    assert smooth_ut_chi2(filt, lay, hits, leaf.path, n_fwd, sm)
    xs, Cs, chi2 = _rts_ut(filt, lay, hits, leaf.path)
    scale = np.sqrt(np.einsum("dii->di", Cs))
    np.testing.assert_allclose(sm.x_ut / scale, xs / scale, rtol=0, atol=1e-6)
    np.testing.assert_allclose(
        sm.C_ut / (scale[:, :, None] * scale[:, None, :]),
        Cs / (scale[:, :, None] * scale[:, None, :]),
        rtol=0,
        atol=1e-5,
    )
    np.testing.assert_allclose(sm.chi2, chi2, rtol=1e-5)
    assert np.all(np.isfinite(chi2)) and np.all(chi2 >= 0.0)
