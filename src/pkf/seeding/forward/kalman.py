"""Kalman-filter pieces of the forward extension: a deviation δ from a reference trajectory.

The state is (x, y, tx, ty, q/p) [mm, 1/MeV]; the filter runs on its deviation from a
reference trajectory (`reference`), whose Jacobians and noise come from the parametrized
steps (`pkf.seeding.forward_steps`). A strip measures u = x·cos α + y·sin α: H = [cos α,
sin α, 0, 0, 0]. `fit_fixed` is the filter through given hits; the combinatorial search
is `pkf.seeding.forward.search`.
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT
from pkf.seeding.forward.options import O_VMSTX, O_VMSX, O_VSTX, O_VSX
from pkf.seeding.forward_steps import reference_trajectory


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def predict(F3, Q3, j, X, P3, a, X_out, P3_out, b, tmp):
    """X_out[b] = F·X[a], P3_out[b] = F·P3[a]·Fᵀ + Q with F = F3[j], Q = Q3[j], for the
    parametrized steps: q/p is transported unchanged (F row 4 = e₄) and has no noise
    (Q row/column 4 = 0). Indexed rather than sliced: a slice is an array view, and the
    views' reference counting cost more than the arithmetic in this loop."""
    for i in range(4):
        acc = 0.0
        for k in range(5):
            acc += F3[j, i, k] * X[a, k]
        X_out[b, i] = acc
    X_out[b, 4] = X[a, 4]
    for i in range(4):
        for k in range(5):
            acc = 0.0
            for m in range(5):
                acc += F3[j, i, m] * P3[a, m, k]
            tmp[i, k] = acc
    for k in range(5):
        tmp[4, k] = P3[a, 4, k]
    for i in range(4):
        for k in range(i, 4):
            acc = Q3[j, i, k]
            for m in range(5):
                acc += tmp[i, m] * F3[j, k, m]
            P3_out[b, i, k] = acc
            P3_out[b, k, i] = acc
        acc = tmp[i, 4]  # (F·P)[i, 4] · F[4, 4] = 1
        P3_out[b, i, 4] = acc
        P3_out[b, 4, i] = acc
    P3_out[b, 4, 4] = P3[a, 4, 4]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def update(X, P3, d, c, s, r, var, X_out, P3_out, pht):
    """Strip update of state d with residual r and residual variance var = H·P·Hᵀ + σ²."""
    for i in range(5):
        pht[i] = c * P3[d, i, 0] + s * P3[d, i, 1]
    for i in range(5):
        k = pht[i] / var
        X_out[d, i] = X[d, i] + k * r
        for m in range(5):
            P3_out[d, i, m] = P3[d, i, m] - k * pht[m]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def velo_prior(opt, q_noise, sigma_q, P):
    for i in range(5):
        for k in range(5):
            P[i, k] = 0.0
    vx = opt[O_VSX] ** 2 + (opt[O_VMSX] * q_noise) ** 2
    vt = opt[O_VSTX] ** 2 + (opt[O_VMSTX] * q_noise) ** 2
    P[0, 0] = vx
    P[1, 1] = vx
    P[2, 2] = vt
    P[3, 3] = vt
    P[4, 4] = sigma_q * sigma_q


@nb.njit(cache=True, **NO_REFCOUNT)
def reference(tr, lay, ref, a, j_end, s_v, q, q_noise):
    """Reference trajectory from VELO layer a through forward layers 0 … j_end−1 at
    q/p = q; noise at |q/p| = q_noise (tr: `Transport`, lay: `Layout`, ref: `Reference`
    filled). Returns the worst transport status."""
    work = tr.work
    n_ut = lay.n_ut
    ref_Q = ref.Q
    s_in = work[0, 0]
    for i in range(4):
        s_in[i] = s_v[i]
    s_in[4] = q
    st = reference_trajectory(tr.ext, tr.poly, tr.table_ref, tr.quadratic, a, lay.layer, n_ut, j_end, s_in,
                              q_noise, ref.s, ref.F, ref_Q, work[0, 1])
    # model error of the SciFi layer steps at low momentum (see ForwardOptions.scifi_model_noise)
    f = 1.0 + (tr.model_noise * q_noise) ** 2
    for j in range(n_ut + 1, j_end):
        for i in range(5):
            for k in range(5):
                ref_Q[j, i, k] *= f
    return st

@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def maybe_crossed(x, y, vx, vy, acc, j):
    """False if (x, y) with variances (vx, vy) is outside the active area acc[j] (half_x,
    half_y, hole radius, hole half_x, hole half_y) by more than 3σ."""
    sx = 3.0 * math.sqrt(max(vx, 0.0))
    sy = 3.0 * math.sqrt(max(vy, 0.0))
    if abs(x) - sx > acc[j, 0] or abs(y) - sy > acc[j, 1]:
        return False
    if acc[j, 2] > 0.0:
        r = math.sqrt(x * x + y * y)
        if r + math.sqrt(sx * sx + sy * sy) < acc[j, 2]:
            return False
    if acc[j, 3] > 0.0 and abs(x) + sx < acc[j, 3] and abs(y) + sy < acc[j, 4]:
        return False
    return True


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def first_at_least(hu, lo, hi, x):
    """The first row h in lo … hi−1 with hu[h] ≥ x (hu sorted; hi if none), by bisection
    without branches on the data (the step is a conditional move: a hit layer of an event
    at ν = 7.6 takes ~10 halvings, each a mispredicted branch in the textbook form; the
    same row)."""
    base = lo
    n = hi - lo
    while n > 1:
        half = n >> 1
        base = base + half if hu[base + half - 1] < x else base
        n -= half
    if n == 1 and hu[base] < x:
        base += 1
    return base


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def pvalue_ok(chi2, n_meas, cut):
    return chi2 <= cut[min(n_meas, cut.shape[0] - 1)]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def conditional(P, pc, k):
    """Covariance of (x, tx) and (y, ty) given q/p: pc[k … k+5] = xx, x·tx, tx·tx, yy, y·ty, ty·ty."""
    pc[k] = P[0, 0] - P[0, 4] ** 2 / P[4, 4]
    pc[k + 1] = P[0, 2] - P[0, 4] * P[2, 4] / P[4, 4]
    pc[k + 2] = P[2, 2] - P[2, 4] ** 2 / P[4, 4]
    pc[k + 3] = P[1, 1] - P[1, 4] ** 2 / P[4, 4]
    pc[k + 4] = P[1, 3] - P[1, 4] * P[3, 4] / P[4, 4]
    pc[k + 5] = P[3, 3] - P[3, 4] ** 2 / P[4, 4]



@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def load_start(filt):
    """Copy the start deviation and covariance (filt.x0, filt.P0) to depth −1 of the scratch."""
    x_init = filt.ws.x_init
    P_init = filt.ws.P_init
    for i in range(5):
        x_init[0, i] = filt.x0[i]
        for k in range(5):
            P_init[0, i, k] = filt.P0[i, k]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def copy_leaf(post_x, post_P, d, best):
    """best.x, best.P = the filtered state and covariance at depth d."""
    for i in range(5):
        best.x[i] = post_x[d, i]
        for m in range(5):
            best.P[i, m] = post_P[d, i, m]


@nb.njit(cache=True, **NO_REFCOUNT)
def fit_fixed(j0, j1, filt, hits, lay, nsig, chi2_prune, best):
    """The Kalman filter through layers j0 … j1−1 with the hits filt.fixed[j] (sorted-hit
    index, −1: none): `search.search` with every layer MODE_FIXED (a hit beyond nsig σ or
    certainly outside the active area is not attached), as one straight loop — the
    refits, fits and transports of the extension call it ~5 times per track, and the
    combinatorial search's set-up costs more than such a fit. Returns (hits attached,
    χ²), −1 hits if the χ² or a station requirement fails (the same pruning as the
    search); best.path[j] (hit or −1) and the deviation state/covariance at layer j1−1 in
    best.x/best.P (best: `Leaf`)."""
    fixed = filt.fixed
    ref_s, ref_F, ref_Q = filt.ref
    ws = filt.ws
    pred_x, post_x, pred_P, post_P, tmp, pht = ws.pred_x, ws.post_x, ws.pred_P, ws.post_P, ws.tmp, ws.pht
    _, hu, hsig, _ = hits
    f_cos, f_sin, f_acc, f_bit, f_group_end, f_need_end = (lay.cos, lay.sin, lay.acceptance, lay.bit,
                                                           lay.group_end, lay.need_end)
    best_path = best.path
    load_start(filt)
    chi2 = 0.0
    n_hits = 0
    mask = 0
    for d in range(j1 - j0):
        j = j0 + d
        if d == 0:
            predict(ref_F, ref_Q, j, ws.x_init, ws.P_init, 0, pred_x, pred_P, d, tmp)
        else:
            predict(ref_F, ref_Q, j, post_x, post_P, d - 1, pred_x, pred_P, d, tmp)
        c = f_cos[j]
        s = f_sin[j]
        h = fixed[j]
        if h >= 0 and not maybe_crossed(ref_s[j, 0] + pred_x[d, 0], ref_s[j, 1] + pred_x[d, 1],
                                        pred_P[d, 0, 0], pred_P[d, 1, 1], f_acc, j):
            h = -1
        if h >= 0:
            up = c * (ref_s[j, 0] + pred_x[d, 0]) + s * (ref_s[j, 1] + pred_x[d, 1])
            sb = c * c * pred_P[d, 0, 0] + 2.0 * c * s * pred_P[d, 0, 1] + s * s * pred_P[d, 1, 1]
            var = sb + hsig[h] * hsig[h]
            r = hu[h] - up
            if r * r / var >= nsig * nsig:
                h = -1
        if h >= 0:
            update(pred_x, pred_P, d, c, s, r, var, post_x, post_P, pht)
            chi2 += r * r / var
            n_hits += 1
            mask |= f_bit[j]
        else:
            for i in range(5):
                post_x[d, i] = pred_x[d, i]
                for m in range(5):
                    post_P[d, i, m] = pred_P[d, i, m]
        best_path[j] = h
        if chi2 > chi2_prune[min(n_hits, chi2_prune.shape[0] - 1)]:
            return -1, chi2
        if f_group_end[j] and (mask & f_need_end[j]) != f_need_end[j]:
            return -1, chi2
    copy_leaf(post_x, post_P, j1 - j0 - 1, best)
    return n_hits, chi2
