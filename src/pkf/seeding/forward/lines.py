"""Straight-line test and stereo confirmation of a q/p cluster (step 3).

Given q/p the VELO state predicts the direction in the SciFi; random coincidences of
implied q/p have random directions and do not line up. `cluster_fit` finds the line
through the cluster's x-layer entries that best collects them, `stereo_score` checks the
stereo layers along it. Units: mm, 1/MeV.
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT
from pkf.seeding.forward.hough import node_interp
from pkf.seeding.forward.kalman import first_at_least
from pkf.seeding.forward.records import MAX_PER_LAYER


@nb.njit(cache=True, **NO_REFCOUNT)
def stereo_score(hits, lay, scan, n_nodes, q_c, alpha, beta, sig2, pc, z_ut, nsig):
    """Stereo confirmation of a q/p cluster: on every SciFi stereo layer the nearest hit
    to u = x·cos α + y·sin α, with x from the cluster's line and y from the VELO prior
    given q/p (σ_y: the conditional covariance pc carried by a straight line). Returns
    (Σ min(Δχ², nsig²) over the stereo layers, number of layers with a hit within nsig σ).
    The line is α + β·(z − z₀) about the trajectory at q_c, z₀ the first x layer's z;
    sig2 its σ² [mm²] (hits: `Hits`, lay: `Layout`, scan: `Scan` with the node states)."""
    loe, hu, _, used = hits
    n_ut = lay.n_ut
    n_fwd = lay.layer.shape[0]
    f_cos, f_sin, f_sig = lay.cos, lay.sin, lay.sigma
    f_z = scan.f_z
    z0 = scan.line.x_z[0]
    qn, sxs, sdxs, sys_, sdys = scan.nodes
    score = 0.0
    n_found = 0
    q2 = q_c * q_c
    for j in range(n_ut, n_fwd):
        c = f_cos[j]
        s = f_sin[j]
        if abs(s) < 1e-6:
            continue
        col = j - n_ut
        x_ref, _ = node_interp(qn, n_nodes, sxs, sdxs, col, q_c)
        y_ref, _ = node_interp(qn, n_nodes, sys_, sdys, col, q_c)
        x = x_ref + alpha + beta * (f_z[j] - z0)
        dz = f_z[j] - z_ut
        vy = (pc[3] + pc[9] * q2) + 2.0 * dz * (pc[4] + pc[10] * q2) + dz * dz * (pc[5] + pc[11] * q2)
        var = s * s * max(vy, 0.0) + c * c * sig2 + f_sig[j] * f_sig[j]
        up = c * x + s * y_ref
        hw = nsig * math.sqrt(var)
        # the smallest r² first, one division (x ↦ x/var is monotonic: the same Δχ² bit for bit)
        best_r2 = math.inf
        h = first_at_least(hu, loe[j], loe[j + 1], up - hw)
        while h < loe[j + 1] and hu[h] <= up + hw:
            if not used[h]:
                best_r2 = min(best_r2, (hu[h] - up) ** 2)
            h += 1
        best = min(nsig * nsig, best_r2 / var)
        if best < nsig * nsig:
            n_found += 1
        score += best
    return score, n_found


@nb.njit(cache=True, **NO_REFCOUNT)
def line_fit(n_x, chosen, rx, x_z, sig2, w_beta):
    """Least-squares line rx = α + β·(z − z_0) through the chosen layers with the prior
    β ~ N(0, 1/w_beta). Returns (n, χ², α, β)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    r0 = 0.0
    r1 = 0.0
    n = 0
    for li in range(n_x):
        if chosen[li] < 0:
            continue
        dz = x_z[li] - x_z[0]
        s0 += 1.0
        s1 += dz
        s2 += dz * dz
        r0 += rx[li]
        r1 += rx[li] * dz
        n += 1
    if n == 0:
        return 0, 0.0, 0.0, 0.0
    s2 += w_beta * sig2
    det = s0 * s2 - s1 * s1
    if det <= 0.0:
        return n, 0.0, r0 / s0, 0.0
    alpha = (s2 * r0 - s1 * r1) / det
    beta = (s0 * r1 - s1 * r0) / det
    chi2 = beta * beta * w_beta
    for li in range(n_x):
        if chosen[li] >= 0:
            res = rx[li] - alpha - beta * (x_z[li] - x_z[0])
            chi2 += res * res / sig2
    return n, chi2, alpha, beta


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _collect_nearest(kb, ke, entries, hu, lin, t_c, line):
    """Per x layer the MAX_PER_LAYER entries of kb … ke−1 nearest to the trajectory (see
    `cluster_fit`), sorted by |residual|: line.cand_e, cand_r, cand_n."""
    e_hit, e_t, e_li, e_order = entries.hit, entries.t, entries.layer, entries.order
    _, _, x_z, x_c, cand_e, cand_r, cand_n = line
    for li in range(x_z.shape[0]):
        cand_n[li] = 0
    for kk in range(kb, ke):
        ent = e_order[kk]
        li = e_li[ent]
        r = (e_t[ent] - t_c) * x_c[li] if lin else hu[e_hit[ent]] - x_c[li]
        m = cand_n[li]
        if m < MAX_PER_LAYER:
            cand_n[li] = m + 1
        elif abs(r) < abs(cand_r[li, m - 1]):
            m = m - 1
        else:
            continue
        while m > 0 and abs(cand_r[li, m - 1]) > abs(r):  # keep sorted by |r|
            cand_r[li, m] = cand_r[li, m - 1]
            cand_e[li, m] = cand_e[li, m - 1]
            m -= 1
        cand_r[li, m] = r
        cand_e[li, m] = ent


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _nearest(cand_r, cand_n, li, pred):
    """(|distance|, index) of the entry of x layer li nearest to the residual pred (1e300, −1: none)."""
    bd = 1e300
    best = -1
    for m in range(cand_n[li]):
        dd = abs(cand_r[li, m] - pred)
        if dd < bd:
            bd = dd
            best = m
    return bd, best


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _best_line(lf, ll, line, sig2, w_beta):
    """Of the lines through one entry of x layer lf and one of ll, the one whose nearest
    entries on every layer give the lowest χ² (slope prior w_beta). Returns (α, β)."""
    _, _, x_z, _, _, cand_r, cand_n = line
    best_chi = 1e300
    best_a = 0.0
    best_b = 0.0
    for i1 in range(cand_n[lf]):
        for i2 in range(cand_n[ll] if ll != lf else 1):
            r1 = cand_r[lf, i1]
            if ll != lf:
                b_ = (cand_r[ll, i2] - r1) / (x_z[ll] - x_z[lf])
            else:
                b_ = 0.0
            a_ = r1 - b_ * (x_z[lf] - x_z[0])
            chi = b_ * b_ * w_beta
            for li in range(x_z.shape[0]):
                if cand_n[li] == 0:
                    continue
                bd, _ = _nearest(cand_r, cand_n, li, a_ + b_ * (x_z[li] - x_z[0]))
                chi += bd * bd / sig2
            if chi < best_chi:
                best_chi = chi
                best_a = a_
                best_b = b_
    return best_a, best_b


@nb.njit(cache=True, **NO_REFCOUNT)
def cluster_fit(kb, ke, entries, hu, lin, t_c, line, sig2, w_beta):
    """Straight-line test of a q/p cluster in the SciFi x layers.

    The entries kb … ke−1 (in entries.order, `Entries`) are hits on x layer
    entries.layer; their x residual to the trajectory at the cluster's q/p is
    r = u − x_c[layer] (lin=False, x_c = line.d_l: the interpolated trajectory) or, to
    first order, (t − t_c)·x_c[layer] (lin=True, x_c: τ(q_c)·dx/dq; cheaper, for
    ranking). Lines through one entry of the first and one of the last layer (the
    MAX_PER_LAYER nearest to the trajectory on each) pick the nearest entry on every
    other layer; the best line by χ² is refitted with β ~ N(0, 1/w_beta): given q/p the
    VELO state predicts the direction in the SciFi, random coincidences of implied q/p
    have random directions and do not line up. Returns (n_layers, χ², α, β);
    line.chosen[li] (entry or −1) and line.rx[li] its residual (`LineWork`).
    """
    chosen, rx, x_z, _, cand_e, cand_r, cand_n = line
    n_x = x_z.shape[0]
    _collect_nearest(kb, ke, entries, hu, lin, t_c, line)
    lf = -1
    ll = -1
    for li in range(n_x):
        if cand_n[li] > 0:
            if lf < 0:
                lf = li
            ll = li
    if lf < 0:
        for li in range(n_x):
            chosen[li] = -1
        return 0, 0.0, 0.0, 0.0
    best_a, best_b = _best_line(lf, ll, line, sig2, w_beta)
    for li in range(n_x):
        chosen[li] = -1
        if cand_n[li] == 0:
            continue
        _, m = _nearest(cand_r, cand_n, li, best_a + best_b * (x_z[li] - x_z[0]))
        if m >= 0:
            chosen[li] = cand_e[li, m]
            rx[li] = cand_r[li, m]
    return line_fit(n_x, chosen, rx, x_z, sig2, w_beta)
