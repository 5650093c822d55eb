"""The UT outlier check of the final fit (step 4): every UT hit against the rest of the track.

The UT hits of an extension are chosen before the SciFi hits constrain the track: the UT
search and the UT confirmation run from the VELO with (at best) the SciFi q/p as a prior,
so their windows are set by the VELO state's extrapolation error at that momentum
(≈ 1.7 mm at 3 GeV). A hit of another particle inside such a window but far from the
VELO + SciFi trajectory survives the final fit's per-hit gate and widens the fitted
track's pulls (issue 15: 23 % of the real long candidates of minimum bias at ν = 7.6
carried one).

After the final fit through the UT and SciFi hits (`kalman.fit_fixed`, a forward Kalman
filter around the reference trajectory), a smoother runs back from the last SciFi layer to
the first UT layer (`smooth_ut_chi2`, the modified Bryson–Frazier form: no matrix inverse
per layer): its state at UT layer j uses every measurement. The χ² of the hit m on layer j
against the track *without* it is

    χ²_j = r_s² / (σ² − H·C_s·Hᵀ),   r_s = m − H·x_s,

(x_s, C_s the smoothed state and covariance; Frühwirth's unbiased residual, equal to the
fit's χ² minus the χ² of the fit without the hit). The prediction without the hit, u =
m − r_s·σ²/(σ² − H·C_s·Hᵀ) with variance H·C_s·Hᵀ·σ²/(σ² − H·C_s·Hᵀ), carries the
measurement error, the scattering and the q/p uncertainty of the whole track.

`clean_ut_hits` changes one hit at a time, refits and checks again (a layer's hit is
replaced at most once; a drop is final), in this order (`_next_change`):

1. the worst hit with χ² > ``ut_outlier_chi2`` is replaced by the hit of its layer with
   the lowest χ² against that prediction if it is below the cut (and not taken by a good
   extension), else dropped;
2. a hit is replaced by another of its layer whose χ² is lower by > ``ut_swap_margin``;
3. a hit (also one put in by 1 or 2) is dropped if another hit of its layer, taken or not,
   has χ² < ``ut_ambiguous_chi2``.

Why 3: the UT strips measure u only, and in the dense core of minimum bias two particles
often cross a UT layer a strip pitch apart. Measured on 20 events at ν = 7.6 with truth
VELO seeds (`ForwardOptions` defaults otherwise): the true UT hits of correct extensions
have χ² distributed as χ²(1) (quantiles 50/90/99 %: 0.44/2.69/6.6), the foreign ones
0.59/5.36/14.8 — a χ² cut alone removes few (cut 9: 4 % of the foreign, 0.2 % of the true
hits). 95 % of the foreign hits sit next to the particle's own hit (median |Δu| 0.09 mm);
in 56 % the other particle's extension holds our hit (the two tracks swapped hits, the
first one found taking the wrong one), and a fit through such a hit has a q/p pull width
of 1.1–1.4. Dropping hits with a neighbour at χ² < 4: correct extensions with a foreign UT
hit 24 % → 4.5 %, UT hits per correct extension 3.55 → 2.93, efficiency −0.3 points at
2–5 GeV (3 of 1100 tracks), unchanged above, ghost rate 0.25 → 0.15 % (with χ² < 9: 2.0 %,
2.61 UT hits, −0.5 points at 2–5 GeV). The cut is 9 since issue 15: through the whole triplet
pattern (600 events, ν = 7.6) the real long candidates with a foreign UT hit fell from 6,132
to 2,567 of 142k, whose q/p pulls are ≈ 2 wide, and the reference fit's first-hit q/p pull core
at 1.5–3 GeV from 1.053 to 1.042, for −0.13 / −0.09 points of long efficiency at 2–5 / > 5 GeV
and δp/p core 0.204 → 0.207 % (`ForwardOptions`). Units: mm, 1/MeV.
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT
from pkf.seeding.forward.kalman import first_at_least, fit_fixed
from pkf.seeding.forward.options import O_UT_OUTLIER, O_UT_SWAP


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _fold_measurement(ws, ref_s, lay, hits, path, d, sm):
    """Fold the hit of depth d (if any) into the adjoint variables of the modified
    Bryson–Frazier smoother (Bierman 1973): from λ̂_d, Λ̂_d (sm.lam, sm.Lam: the information
    of the measurements after d) to λ̃_d = C_dᵀ·λ̂_d − Hᵀ·y_d/S_d and Λ̃_d = C_dᵀ·Λ̂_d·C_d +
    Hᵀ·H/S_d, with C_d = I − K_d·H, K_d = P⁻_d·Hᵀ/S_d, y_d and S_d the innovation and its
    variance of the last fit at d (H = [cos α, sin α, 0, 0, 0]: only rows and columns 0, 1
    of Λ change)."""
    h = path[d]
    if h < 0:
        return
    pred_x, pred_P = ws.pred_x, ws.pred_P
    lam, Lam, v, k = sm.lam, sm.Lam, sm.v, sm.k
    c = lay.cos[d]
    s = lay.sin[d]
    up = c * (ref_s[d, 0] + pred_x[d, 0]) + s * (ref_s[d, 1] + pred_x[d, 1])
    sb = c * c * pred_P[d, 0, 0] + 2.0 * c * s * pred_P[d, 0, 1] + s * s * pred_P[d, 1, 1]
    var = sb + hits.sigma[h] * hits.sigma[h]
    y = hits.u[h] - up
    for i in range(5):
        k[i] = (c * pred_P[d, i, 0] + s * pred_P[d, i, 1]) / var
    k_lam = 0.0
    for i in range(5):
        k_lam += k[i] * lam[i]
        acc = 0.0
        for m in range(5):
            acc += Lam[i, m] * k[m]
        v[i] = acc
    alpha = 1.0 / var
    for i in range(5):
        alpha += k[i] * v[i]
    g = k_lam + y / var
    lam[0] -= c * g
    lam[1] -= s * g
    # Λ̃_im = Λ_im − h_i·v_m − v_i·h_m + h_i·h_m·(Kᵀ·Λ·K + 1/S)
    for m in range(5):
        Lam[0, m] -= c * v[m]
        Lam[1, m] -= s * v[m]
    for i in range(5):
        Lam[i, 0] -= v[i] * c
        Lam[i, 1] -= v[i] * s
    Lam[0, 0] += c * c * alpha
    Lam[0, 1] += c * s * alpha
    Lam[1, 0] += s * c * alpha
    Lam[1, 1] += s * s * alpha


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _adjoint_back(F, d, sm):
    """λ̂_{d−1} = F_dᵀ·λ̃_d, Λ̂_{d−1} = F_dᵀ·Λ̃_d·F_d (F_d: the step onto depth d; its row 4
    is e₄: q/p is transported unchanged)."""
    lam, Lam, M, v = sm.lam, sm.Lam, sm.M, sm.v
    for i in range(5):  # M = Λ̃·F
        for k in range(5):
            acc = Lam[i, 4] if k == 4 else 0.0
            for m in range(4):
                acc += Lam[i, m] * F[d, m, k]
            M[i, k] = acc
    for k in range(5):
        acc = lam[4] if k == 4 else 0.0
        for m in range(4):
            acc += F[d, m, k] * lam[m]
        v[k] = acc
    for k in range(5):
        lam[k] = v[k]
    for i in range(5):  # Λ̂ = Fᵀ·M, symmetric
        for k in range(i, 5):
            acc = M[4, k] if i == 4 else 0.0
            for m in range(4):
                acc += F[d, m, i] * M[m, k]
            Lam[i, k] = acc
            Lam[k, i] = acc


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _smoothed_state(ws, d, sm):
    """The smoothed state at depth d from the filtered one and the adjoint variables
    after d: x_s = x⁺_d − P⁺_d·λ̂_d, C_s = P⁺_d − P⁺_d·Λ̂_d·P⁺_d (into sm.x, sm.C)."""
    post_x, post_P = ws.post_x, ws.post_P
    lam, Lam, M, x, C = sm.lam, sm.Lam, sm.M, sm.x, sm.C
    for i in range(5):
        acc = post_x[d, i]
        for m in range(5):
            acc -= post_P[d, i, m] * lam[m]
        x[i] = acc
    for i in range(5):  # M = Λ̂·P⁺
        for k in range(5):
            acc = 0.0
            for m in range(5):
                acc += Lam[i, m] * post_P[d, m, k]
            M[i, k] = acc
    for i in range(5):
        for k in range(i, 5):
            acc = post_P[d, i, k]
            for m in range(5):
                acc -= post_P[d, i, m] * M[m, k]
            C[i, k] = acc
            C[k, i] = acc


@nb.njit(cache=True, **NO_REFCOUNT)
def _hit_chi2(ref_s, lay, hits, x, C, j, h):
    """(χ², r_s, H·C_s·Hᵀ) of hit h on UT layer j against the smoothed state x, C (deviation
    from ref_s) without the hit (module docstring); χ² = inf if σ² − H·C_s·Hᵀ ≤ 0 (rounding)."""
    c = lay.cos[j]
    s = lay.sin[j]
    u_s = c * (ref_s[j, 0] + x[0]) + s * (ref_s[j, 1] + x[1])
    hch = c * c * C[0, 0] + 2.0 * c * s * C[0, 1] + s * s * C[1, 1]
    r = hits.u[h] - u_s
    den = hits.sigma[h] * hits.sigma[h] - hch
    return (r * r / den if den > 0.0 else math.inf), r, hch


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _store_ut_layer(sm, filt, lay, hits, path, d):
    """Keep the smoothed state of UT layer d (sm.x_ut, sm.C_ut) and the χ² of its hit, if
    any, against the rest of the track (sm.chi2)."""
    for i in range(5):
        sm.x_ut[d, i] = sm.x[i]
        for k in range(5):
            sm.C_ut[d, i, k] = sm.C[i, k]
    if path[d] >= 0:
        sm.chi2[d], _, _ = _hit_chi2(filt.ref.s, lay, hits, sm.x, sm.C, d, path[d])


@nb.njit(cache=True, **NO_REFCOUNT)
def smooth_ut_chi2(filt, lay, hits, path, n_fwd, sm):
    """Smooth the last `fit_fixed` over layers 0 … n_fwd−1 back to the UT layers (states
    kept in sm.x_ut, sm.C_ut) and put the χ² of each UT hit path[j] against the rest of the
    track into sm.chi2[j] (NaN: no hit). The smoother is the modified Bryson–Frazier form
    (Bierman 1973; `_fold_measurement`, `_adjoint_back`, `_smoothed_state`): it carries
    the information of the later measurements back as adjoint variables, with no matrix
    inverse per layer, and equals the Rauch–Tung–Striebel smoother it replaced to rounding
    (ut_chi2 of 50 minbias events at ν = 1 and 7.6: largest relative difference 3e-8 and
    9e-7, the same hits and q/p on every track). The RTS steps, each with a 5×5 inverse,
    were 15 % of the forward extension's CPU samples; without them the extension takes
    11 % less CPU (ν = 7.6: 23.1 → 20.5 ms/event, ν = 1: 2.65 → 2.30; 50 events, three
    interleaved rounds). Returns True."""
    ws = filt.ws
    ref_s = filt.ref.s
    n_ut = lay.n_ut
    for j in range(n_ut):
        sm.chi2[j] = math.nan
    for i in range(5):
        sm.lam[i] = 0.0
        for k in range(5):
            sm.Lam[i, k] = 0.0
    for d in range(n_fwd - 1, -1, -1):
        if d < n_ut:
            _smoothed_state(ws, d, sm)
            _store_ut_layer(sm, filt, lay, hits, path, d)
        if d > 0:
            _fold_measurement(ws, ref_s, lay, hits, path, d, sm)
            _adjoint_back(filt.ref.F, d, sm)
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def _replacement(filt, lay, hits, sm, j, h, below, skip_used):
    """(hit, χ²): the hit of UT layer j (not h, not taken by a good extension if
    skip_used) with the lowest χ² < below against the track without h (the smoothed state
    at j, sm.x_ut[j], sm.C_ut[j]); hit −1 if none."""
    _, r_s, hch = _hit_chi2(filt.ref.s, lay, hits, sm.x_ut[j], sm.C_ut[j], j, h)
    v = hits.sigma[h] * hits.sigma[h]
    den = v - hch
    if not den > 0.0:
        return -1, below
    u_pred = hits.u[h] - r_s * v / den  # the prediction without h
    var_pred = hch * v / den
    f_sig = lay.sigma[j]
    half = math.sqrt(below * (var_pred + f_sig * f_sig))
    lo = hits.offsets[j]
    hi = hits.offsets[j + 1]
    best = -1
    best_chi = below
    k = first_at_least(hits.u, lo, hi, u_pred - half)
    while k < hi and hits.u[k] <= u_pred + half:
        if k != h and not (skip_used and hits.used[k]):
            r = hits.u[k] - u_pred
            c2 = r * r / (var_pred + hits.sigma[k] * hits.sigma[k])
            if c2 < best_chi:
                best_chi = c2
                best = k
        k += 1
    return best, best_chi


@nb.njit(cache=True, **NO_REFCOUNT)
def _next_change(filt, lay, hits, sm, path, changed, cut, margin, ambiguous):
    """The next change of the UT hits (layer, new hit −1: drop; layer −1: none): the worst
    hit above cut, replaced by the best hit of its layer below the cut or dropped; else
    the hit with the largest χ² gain (> margin) from the best other hit of its layer;
    else a hit with another hit of its layer (taken or not) at χ² < ambiguous, dropped
    (the lowest such χ² first). A layer already changed (bit j of changed) is not
    replaced again, but it may still be dropped."""
    n_ut = lay.n_ut
    worst_j = -1
    worst_chi = cut
    for j in range(n_ut):
        if (changed >> j) & 1 == 0 and sm.chi2[j] > worst_chi:  # NaN (no hit) compares False
            worst_chi = sm.chi2[j]
            worst_j = j
    if worst_j >= 0:
        h_new, _ = _replacement(filt, lay, hits, sm, worst_j, path[worst_j], cut, True)
        return worst_j, h_new
    best_j = -1
    best_h = -1
    best_gain = margin
    for j in range(n_ut):
        if (changed >> j) & 1 == 0 and path[j] >= 0 and sm.chi2[j] > margin:
            h_alt, chi_alt = _replacement(filt, lay, hits, sm, j, path[j], sm.chi2[j] - margin, True)
            if h_alt >= 0 and sm.chi2[j] - chi_alt > best_gain:
                best_gain = sm.chi2[j] - chi_alt
                best_j = j
                best_h = h_alt
    if best_j >= 0:
        return best_j, best_h
    best_amb = ambiguous
    for j in range(n_ut):
        if path[j] >= 0:
            h_alt, chi_alt = _replacement(filt, lay, hits, sm, j, path[j], best_amb, False)
            if h_alt >= 0:
                best_amb = chi_alt
                best_j = j
    return best_j, -1


@nb.njit(cache=True, **NO_REFCOUNT)
def clean_ut_hits(lay, hits, cfg, filt, best, sm, n_fwd, nsig, prune, n_fit, chi_f, ambiguous):
    """Check the UT hits of the fit just made (`fit_fixed(0, n_fwd, filt, hits, lay, nsig,
    prune, best)`, n_fit ≥ 1 hits with χ² chi_f, its hits in best.path) against the rest
    of the track (module docstring, `_next_change`; ambiguous: the neighbour cut of rule 3),
    refit after each change, until nothing changes. sm.chi2: the χ² per UT
    layer of the final fit. Returns (hits, χ²) of the final fit (−1 hits if a refit
    failed its cuts)."""
    cut = cfg.opt[O_UT_OUTLIER]
    margin = cfg.opt[O_UT_SWAP]
    n_ut = lay.n_ut
    path = best.path
    n_u = 0
    for j in range(n_ut):
        if path[j] >= 0:
            n_u += 1
    if n_u == 0:
        return n_fit, chi_f  # nothing to check (sm.chi2 stays NaN)
    changed = 0
    for _ in range(2 * n_ut + 1):  # a layer is replaced at most once, a drop is final
        if not smooth_ut_chi2(filt, lay, hits, path, n_fwd, sm):
            break
        j_change, h_new = _next_change(filt, lay, hits, sm, path, changed, cut, margin, ambiguous)
        if j_change < 0:
            break
        for j in range(n_fwd):
            filt.fixed[j] = path[j]
        filt.fixed[j_change] = h_new
        changed |= 1 << j_change
        n_fit, chi_f = fit_fixed(0, n_fwd, filt, hits, lay, nsig, prune, best)
        if n_fit < 1:
            for j in range(n_ut):
                sm.chi2[j] = math.nan
            break
    return n_fit, chi_f
