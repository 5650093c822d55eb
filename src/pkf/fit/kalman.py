"""The Kalman core: forward filter, backward filter, optimal states, χ², outliers (docs/physics.md#the-kalman-core).

One compiled core for every Kalman fitter; the extrapolator is passed in (a NamedTuple
context, see `pkf.fit.extrapolator`). Tracks come in batches as CSR arrays: the nodes
(measurements, sorted by z, at most one per layer) of track t are
``offsets[t]:offsets[t+1]``. Each node holds one or two scalar measurements
m_j = hx_j·x + hy_j·y + noise(σ_j) (pixel: x and y; strip: u = x·cos α + y·sin α).

Per iteration:

1. Forward filter (paper eqs. 1–8) from the seed at the first node: extrapolate
   (x_k|k−1 = f(x_k−1|k−1), P_k|k−1 = F·P·Fᵀ + Q) and update with each active node.
2. Backward filter, downstream → upstream, in information form (Y, y) starting from
   *no* information at the last node, so it is independent of the forward filter. It
   uses the same linearised model x_k = a_k + F_k·x_k−1 + w_k (a_k = f(r) − F_k·r at the
   forward linearisation point r), hence no second pass of extrapolations:
   update Y += h·hᵀ/σ², y += h·m/σ²; propagate Y ← Fᵀ(I + Y·Q)⁻¹·Y·F,
   y ← Fᵀ(I + Y·Q)⁻¹·(y − Y·a).
3. Optimal state at every node = weighted mean of the forward prediction and the
   backward filtered state (paper §3): C = (P⁻¹ + Y)⁻¹, x = C·(P⁻¹·x_p + y), with
   equilibrated Cholesky inverses. `SMOOTHER_RTS` computes the same states with the
   Rauch–Tung–Striebel smoother instead; a test checks they agree.
4. Track χ² = the sum of the forward filter's increments r_k|k−1ᵀ S_k⁻¹ r_k|k−1 (paper
   eq. 9), which for a linear Gaussian model equals the smoothed measurement residuals'
   χ² plus the χ² of the fitted scattering kinks and follows χ²(ndf), ndf = Σ
   measurement dimensions − 5. docs/physics.md#the-kalman-core wrote Σ r_kᵀ R_k⁻¹ r_k with the smoothed
   residuals and R = V − H·C·Hᵀ: that sum has mean Σ dimensions, not ndf (measured:
   χ²/ndf = 1.34 on telescope tracks), so it serves only as each node's standardised
   χ² for the outlier test.

The first iteration of a track linearises each step at the forward filtered state
(extended Kalman filter); later iterations, and refits after an outlier was removed,
linearise around the previous optimal states (a reference trajectory). Outlier removal: the active node whose
standardised χ² exceeds its cut by the largest factor is deactivated and the track
refitted, at most `max_outliers` times; the cut for 2-D (pixel) nodes is the one with
the same false-removal probability as `--outlier-chi2` for 1-D nodes (9 → 11.83). An outlier node gets no update (its filtered state is the
prediction) but still receives an optimal state.

Helpers every fitter shares (the GX2F and the GSF call them rather than copy them):
`scalar_update` (the measurement update), `node_chi2` and `find_outlier` (the outlier
statistic and the choice of the node to remove), `count_ndf`, `add_node_information` and
`transport_information` (measurements in information form and their transport upstream).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.fit.extrapolator import (
    STATUS_NOT_POSITIVE_DEFINITE,
    STATUS_OK,
    STATUS_TOO_FEW_HITS,
    extrapolate,
)
from pkf.physics.linalg import copy5, copy55, invert_spd, matmul55, sandwich, symmetrise

SMOOTHER_WEIGHTED_MEAN = 0
SMOOTHER_RTS = 1
SMOOTHER_NONE = 2  # forward filter only (filtered states as output): for timing studies


@nb.njit(cache=True, inline="always")
def _invert_general(a, out, lu, perm):
    """out = a⁻¹ for a general 5×5 matrix (LU with partial pivoting). False if singular."""
    for i in range(5):
        perm[i] = i
        for j in range(5):
            lu[i, j] = a[i, j]
    for c in range(5):
        pivot = c
        best = abs(lu[c, c])
        for r in range(c + 1, 5):
            if abs(lu[r, c]) > best:
                best = abs(lu[r, c])
                pivot = r
        if not best > 0.0 or not math.isfinite(best):
            return False
        if pivot != c:
            for j in range(5):
                t = lu[c, j]
                lu[c, j] = lu[pivot, j]
                lu[pivot, j] = t
            t2 = perm[c]
            perm[c] = perm[pivot]
            perm[pivot] = t2
        for r in range(c + 1, 5):
            f = lu[r, c] / lu[c, c]
            lu[r, c] = f
            for j in range(c + 1, 5):
                lu[r, j] -= f * lu[c, j]
    for col in range(5):
        # solve L·U·x = P·e_col
        for i in range(5):
            t = 1.0 if perm[i] == col else 0.0
            for k in range(i):
                t -= lu[i, k] * out[k, col]
            out[i, col] = t
        for i in range(4, -1, -1):
            t = out[i, col]
            for k in range(i + 1, 5):
                t -= lu[i, k] * out[k, col]
            out[i, col] = t / lu[i, i]
    return True


@nb.njit(cache=True, inline="always")
def scalar_update(x, p, hx, hy, m, var):
    """Kalman update of (x, P) in place with one scalar measurement m = hx·x + hy·y of
    variance var [mm²] (paper eqs. 4–8). Returns (r²/S, S): the χ² increment of the
    predicted residual r and its variance S = var + h·P·hᵀ; S ≤ 0 (nothing updated)
    if P is not positive definite along h. Every fitter's measurement update."""
    r = m - (hx * x[0] + hy * x[1])
    # P·h only involves the first two columns
    s = var
    ph0 = hx * p[0, 0] + hy * p[0, 1]
    ph1 = hx * p[1, 0] + hy * p[1, 1]
    s += hx * ph0 + hy * ph1
    if not s > 0.0:
        return 0.0, s
    ph = (ph0, ph1, hx * p[2, 0] + hy * p[2, 1], hx * p[3, 0] + hy * p[3, 1], hx * p[4, 0] + hy * p[4, 1])
    for i in range(5):
        x[i] += ph[i] * r / s
    for i in range(5):
        for j in range(i, 5):
            v = p[i, j] - ph[i] * ph[j] / s
            p[i, j] = v
            p[j, i] = v
    return r * r / s, s


@nb.njit(cache=True, inline="always")
def node_chi2(state, cov, n_meas, hx, hy, m, sigma, active):
    """Standardised χ² r·R⁻¹·r of one node's smoothed residual r = m − H·x, with
    R = V − H·C·Hᵀ (active node) or V + H·C·Hᵀ (outlier) the residual's covariance;
    −1 if R is not positive definite. Used to find outliers (`find_outlier`)."""
    sign = -1.0 if active else 1.0
    r0 = m[0] - (hx[0] * state[0] + hy[0] * state[1])
    v0 = sigma[0] * sigma[0]
    c00 = hx[0] * (hx[0] * cov[0, 0] + hy[0] * cov[0, 1]) + hy[0] * (hx[0] * cov[1, 0] + hy[0] * cov[1, 1])
    r00 = v0 + sign * c00
    if n_meas == 1:
        if not r00 > 0.0:
            return -1.0
        return r0 * r0 / r00
    r1 = m[1] - (hx[1] * state[0] + hy[1] * state[1])
    v1 = sigma[1] * sigma[1]
    c11 = hx[1] * (hx[1] * cov[0, 0] + hy[1] * cov[0, 1]) + hy[1] * (hx[1] * cov[1, 0] + hy[1] * cov[1, 1])
    c01 = hx[0] * (hx[1] * cov[0, 0] + hy[1] * cov[0, 1]) + hy[0] * (hx[1] * cov[1, 0] + hy[1] * cov[1, 1])
    r11 = v1 + sign * c11
    r01 = sign * c01
    det = r00 * r11 - r01 * r01
    if not (r00 > 0.0 and det > 0.0):
        return -1.0
    return (r0 * r0 * r11 - 2.0 * r0 * r1 * r01 + r1 * r1 * r00) / det


@nb.njit(cache=True, inline="always")
def count_ndf(n_meas, active):
    """ndf = Σ measurement dimensions of the active nodes − 5 (docs/physics.md#the-kalman-core)."""
    ndf = -5
    for k in range(n_meas.size):
        if active[k]:
            ndf += n_meas[k]
    return ndf


@nb.njit(cache=True, inline="always")
def add_node_information(info, info_vec, n_meas, hx, hy, m, sigma, state):
    """Add one node's measurements in information form: Y += Σ_j h_jᵀh_j/σ_j²,
    y += Σ_j h_jᵀ(m_j − h_j·state)/σ_j² (state = 0: the measured values themselves; the
    current trajectory: its residuals). Y 5×5, y 5-vector, h_j = (hx_j, hy_j, 0, 0, 0)."""
    for j in range(n_meas):
        w = 1.0 / (sigma[j] * sigma[j])
        h0 = hx[j]
        h1 = hy[j]
        r = m[j] - (h0 * state[0] + h1 * state[1])
        info[0, 0] += h0 * h0 * w
        info[0, 1] += h0 * h1 * w
        info[1, 0] += h0 * h1 * w
        info[1, 1] += h1 * h1 * w
        info_vec[0] += h0 * r * w
        info_vec[1] += h1 * r * w


@nb.njit(cache=True, inline="always")
def transport_information(f, a, vec, out, tmp, tmp_vec):
    """Information of the state downstream of a step x′ = F·x, carried to upstream of it:
    out = Fᵀ·a·F (5×5, symmetrised; out may be a) and vec ← Fᵀ·vec. tmp (5×5) and
    tmp_vec (5) are scratch."""
    for i in range(5):
        for j in range(5):
            s = 0.0
            for l in range(5):
                s += a[i, l] * f[l, j]
            tmp[i, j] = s
    for i in range(5):
        for j in range(5):
            s = 0.0
            for l in range(5):
                s += f[l, i] * tmp[l, j]
            out[i, j] = s
    symmetrise(out)
    for i in range(5):
        s = 0.0
        for l in range(5):
            s += f[l, i] * vec[l]
        tmp_vec[i] = s
    copy5(tmp_vec, vec)


@nb.njit(cache=True)
def find_outlier(state, cov, n_meas, hx, hy, m, sigma, active, outlier_cuts, out_node_chi2,
                 measurement_only_fallback):
    """Every node's standardised χ² (`node_chi2` of its output state and covariance) into
    out_node_chi2, and the outlier candidate: the active node whose χ² exceeds its cut
    (outlier_cuts[dimensions − 1]) by the largest factor.

    Returns (status, candidate index, −1 if no active node exceeds its cut). A residual
    covariance that is not positive definite gives STATUS_NOT_POSITIVE_DEFINITE, or, with
    `measurement_only_fallback` (mixture outputs, whose covariance can exceed the
    measurement variance), the χ² standardised by the measurement variance alone.
    Shared by every fitter's outlier removal (docs/physics.md#the-kalman-core): the caller deactivates the
    candidate and refits, at most `--max-outliers` times.
    """
    status = STATUS_OK
    worst = -1
    worst_excess = 1.0
    for k in range(n_meas.size):
        c_node = node_chi2(state[k], cov[k], n_meas[k], hx[k], hy[k], m[k], sigma[k], active[k])
        if c_node < 0.0:
            if measurement_only_fallback:
                c_node = node_chi2(state[k], np.zeros((5, 5)), n_meas[k], hx[k], hy[k], m[k], sigma[k], active[k])
            else:
                status = STATUS_NOT_POSITIVE_DEFINITE
        out_node_chi2[k] = c_node
        if active[k]:
            excess = c_node / outlier_cuts[n_meas[k] - 1]
            if excess > worst_excess:
                worst_excess = excess
                worst = k
    return status, worst


@nb.njit(cache=True)
def _fit_once(ext, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, use_reference, ref,
              pred, pred_cov, filt, filt_cov, jac, noise, offset, smoother, out_state, out_cov,
              work, mats, vec5, perm):
    """One forward + backward + combination pass over the n nodes of one track.

    Arrays pred…noise/ref are per-node scratch (first n rows used); out_state/out_cov
    receive the optimal states. Returns (status code, track χ²).
    """
    n = z.size
    lin = vec5[:5]
    chi2 = 0.0
    tmp = mats[0]
    # ---- forward filter
    # The seed prior: at the pattern estimate, or, once a previous fit exists, at its
    # optimal first state, so that the prior biases nothing at convergence.
    copy5(ref[0] if use_reference else seed, pred[0])
    copy55(seed_cov, pred_cov[0])
    for k in range(n):
        if k > 0:
            if use_reference:
                copy5(ref[k - 1], lin)
            else:
                copy5(filt[k - 1], lin)
            status = extrapolate(ext, lin, z[k - 1], z[k], pred[k], jac[k], noise[k], work)
            if status != STATUS_OK:
                return status, chi2
            # offset a_k = f(r) − F·r so that x_k = a_k + F·x_k−1 (linearised model)
            for i in range(5):
                s = 0.0
                for j in range(5):
                    s += jac[k, i, j] * lin[j]
                offset[k, i] = pred[k, i] - s
            if use_reference:
                for i in range(5):
                    s = 0.0
                    for j in range(5):
                        s += jac[k, i, j] * (filt[k - 1, j] - lin[j])
                    pred[k, i] += s
            sandwich(jac[k], filt_cov[k - 1], tmp, pred_cov[k])
            for i in range(5):
                for j in range(5):
                    pred_cov[k, i, j] += noise[k, i, j]
        copy5(pred[k], filt[k])
        copy55(pred_cov[k], filt_cov[k])
        if active[k]:
            for j in range(n_meas[k]):
                increment, s = scalar_update(filt[k], filt_cov[k], hx[k, j], hy[k, j], m[k, j], sigma[k, j] ** 2)
                if not s > 0.0:
                    return STATUS_NOT_POSITIVE_DEFINITE, chi2
                chi2 += increment
    if smoother == SMOOTHER_NONE:
        for k in range(n):
            copy5(filt[k], out_state[k])
            copy55(filt_cov[k], out_cov[k])
        return STATUS_OK, chi2
    if smoother == SMOOTHER_RTS:
        status = _rts_smoother(n, pred, pred_cov, filt, filt_cov, jac, out_state, out_cov, mats, vec5, perm)
    else:
        status = _backward_information_filter(n, n_meas, hx, hy, m, sigma, active, pred, pred_cov, jac,
                                               noise, offset, out_state, out_cov, mats, vec5, perm)
    return status, chi2


@nb.njit(cache=True)
def _backward_information_filter(n, n_meas, hx, hy, m, sigma, active, pred, pred_cov, jac, noise,
                                 offset, out_state, out_cov, mats, vec5, perm):
    """Backward information filter and weighted-mean combination (see module docstring)."""
    info = mats[2]  # Y
    info_vec = vec5[5:10]  # y
    spd_vec = vec5[10:20]
    origin = vec5[20:25]  # zeros: the measurements enter as measured values
    vec5 = vec5[:5]
    for i in range(5):
        info_vec[i] = 0.0
    a = mats[3]
    inv = mats[4]
    tmp = mats[0]
    tmp2 = mats[1]
    lu = mats[5]
    for i in range(5):
        origin[i] = 0.0
        for j in range(5):
            info[i, j] = 0.0
    for k in range(n - 1, -1, -1):
        if active[k]:
            add_node_information(info, info_vec, n_meas[k], hx[k], hy[k], m[k], sigma[k], origin)
        # combination in information form: C = (P⁻¹ + Y)⁻¹, x = C·(P⁻¹·x_p + y)
        if not invert_spd(pred_cov[k], inv, lu, spd_vec):
            return STATUS_NOT_POSITIVE_DEFINITE
        for i in range(5):
            s = info_vec[i]
            for j in range(5):
                s += inv[i, j] * pred[k, j]
            vec5[i] = s
        for i in range(5):
            for j in range(5):
                a[i, j] = inv[i, j] + info[i, j]
        if not invert_spd(a, out_cov[k], lu, spd_vec):
            return STATUS_NOT_POSITIVE_DEFINITE
        for i in range(5):
            s = 0.0
            for j in range(5):
                s += out_cov[k, i, j] * vec5[j]
            out_state[k, i] = s
        for i in range(5):
            if not out_cov[k, i, i] > 0.0:
                return STATUS_NOT_POSITIVE_DEFINITE
        if k == 0:
            break
        # propagate to node k−1: M = (I + Y·Q)⁻¹; Y ← Fᵀ·M·Y·F; y ← Fᵀ·M·(y − Y·a)
        matmul55(info, noise[k], a)
        for i in range(5):
            a[i, i] += 1.0
        if not _invert_general(a, inv, lu, perm):
            return STATUS_NOT_POSITIVE_DEFINITE
        for i in range(5):
            s = info_vec[i]
            for j in range(5):
                s -= info[i, j] * offset[k, j]
            vec5[i] = s
        matmul55(inv, info, tmp)  # M·Y
        for i in range(5):
            s = 0.0
            for j in range(5):
                s += inv[i, j] * vec5[j]
            info_vec[i] = s  # M·(y − Y·a)
        # Y ← Fᵀ·(M·Y)·F, y ← Fᵀ·M·(y − Y·a)
        transport_information(jac[k], tmp, info_vec, info, tmp2, vec5)
    return STATUS_OK


@nb.njit(cache=True)
def _rts_smoother(n, pred, pred_cov, filt, filt_cov, jac, out_state, out_cov, mats, vec, perm):
    """Rauch–Tung–Striebel smoother over the forward pass (the alternative combination)."""
    vec5 = vec[:5]
    spd_vec = vec[10:20]
    gain = mats[2]
    inv = mats[3]
    tmp = mats[0]
    tmp2 = mats[1]
    lu = mats[5]
    copy5(filt[n - 1], out_state[n - 1])
    copy55(filt_cov[n - 1], out_cov[n - 1])
    for k in range(n - 2, -1, -1):
        # A = P_k|k · F_k+1ᵀ · P_k+1|k⁻¹
        if not invert_spd(pred_cov[k + 1], inv, lu, spd_vec):
            return STATUS_NOT_POSITIVE_DEFINITE
        for i in range(5):
            for j in range(5):
                s = 0.0
                for l in range(5):
                    s += filt_cov[k, i, l] * jac[k + 1, j, l]
                tmp[i, j] = s
        matmul55(tmp, inv, gain)
        for i in range(5):
            vec5[i] = out_state[k + 1, i] - pred[k + 1, i]
        for i in range(5):
            s = filt[k, i]
            for j in range(5):
                s += gain[i, j] * vec5[j]
            out_state[k, i] = s
        for i in range(5):
            for j in range(5):
                tmp2[i, j] = out_cov[k + 1, i, j] - pred_cov[k + 1, i, j]
        sandwich(gain, tmp2, tmp, out_cov[k])
        for i in range(5):
            for j in range(5):
                out_cov[k, i, j] += filt_cov[k, i, j]
        symmetrise(out_cov[k])
        for i in range(5):
            if not out_cov[k, i, i] > 0.0:
                return STATUS_NOT_POSITIVE_DEFINITE
    return STATUS_OK


@nb.njit(cache=True)
def fit_tracks(ext, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma,
               seeds, seed_covs, outlier_chi2, max_outliers, n_iterations, smoother,
               out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2, out_ndf,
               out_n_outliers):
    """Fit a batch of tracks (CSR nodes) with extrapolator `ext`.

    Node arrays: node_z [mm] (n), node_n_meas (1 or 2), node_hx/node_hy (n, 2) the
    measurement directions, node_m (n, 2) measured values [mm], node_sigma (n, 2) [mm].
    seeds (T, 5) at the first node's z, seed_covs (T, 5, 5). outlier_chi2 (2): the cut on a
    node's standardised χ² for 1- and 2-dimensional nodes. Outputs: optimal states and
    covariances per node, each node's χ² contribution and whether it is active (not an
    outlier), and per track status, χ², ndf and number of removed outliers.
    """
    n_tracks = offsets.size - 1
    max_nodes = 1
    for t in range(n_tracks):
        max_nodes = max(max_nodes, offsets[t + 1] - offsets[t])
    pred = np.empty((max_nodes, 5))
    pred_cov = np.empty((max_nodes, 5, 5))
    filt = np.empty((max_nodes, 5))
    filt_cov = np.empty((max_nodes, 5, 5))
    jac = np.empty((max_nodes, 5, 5))
    noise = np.empty((max_nodes, 5, 5))
    offset = np.empty((max_nodes, 5))
    ref = np.empty((max_nodes, 5))
    work = np.empty((6, 5, 5))
    mats = np.empty((6, 5, 5))
    vec5 = np.empty(25)
    perm = np.empty(5, dtype=np.int64)
    for t in range(n_tracks):
        lo = offsets[t]
        hi = offsets[t + 1]
        n = hi - lo
        active = out_active[lo:hi]
        active[:] = True
        n_out = 0
        status = STATUS_OK
        chi2 = 0.0
        ndf = 0
        have_reference = False
        while True:
            ndf = count_ndf(node_n_meas[lo:hi], active)
            if ndf <= 0:
                status = STATUS_TOO_FEW_HITS
                break
            for it in range(max(1, n_iterations)):
                status, chi2 = _fit_once(
                    ext, node_z[lo:hi], node_n_meas[lo:hi], node_hx[lo:hi], node_hy[lo:hi],
                    node_m[lo:hi], node_sigma[lo:hi], active, seeds[t], seed_covs[t], have_reference,
                    ref, pred, pred_cov, filt, filt_cov, jac, noise, offset, smoother,
                    out_state[lo:hi], out_cov[lo:hi], work, mats, vec5, perm,
                )
                if status != STATUS_OK:
                    break
                for k in range(n):
                    copy5(out_state[lo + k], ref[k])
                have_reference = True
            if status != STATUS_OK:
                break
            status, worst = find_outlier(out_state[lo:hi], out_cov[lo:hi], node_n_meas[lo:hi], node_hx[lo:hi],
                                         node_hy[lo:hi], node_m[lo:hi], node_sigma[lo:hi], active, outlier_chi2,
                                         out_node_chi2[lo:hi], False)
            if status != STATUS_OK:
                break
            if n_out < max_outliers and worst >= 0:
                active[worst] = False
                n_out += 1
                continue
            break
        out_status[t] = status
        out_chi2[t] = chi2 if status == STATUS_OK else np.nan
        out_ndf[t] = ndf
        out_n_outliers[t] = n_out
