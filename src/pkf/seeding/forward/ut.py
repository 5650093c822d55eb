"""The UT side of the forward extension: the start state, the UT search (step 1) and the
UT confirmation with the final fit (step 4).

`ut_start` carries the VELO prior through the UT without hits (the state at the last UT
layer given q/p), `ut_candidates` runs the UT search around q/p = 0 and re-fits its best
leaves around their own q/p, and `finalize` re-collects the UT hits with a SciFi
candidate's q/p and fits the whole extension. Units: mm, 1/MeV.
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT
from pkf.seeding.forward.kalman import conditional, fit_fixed, reference, velo_prior
from pkf.seeding.forward.options import (
    I_BRANCH,
    I_CONFIRM_MIN,
    I_MAX_NODES,
    I_NOUT_MIN,
    I_SF_MIN,
    I_UT_BRANCH,
    I_UT_FIRST,
    I_UT_MIN,
    I_UT_REFITS,
    O_CONFIRM_NSIG,
    O_HOUGH_NSIG,
    O_MISS,
    O_NSIG,
    O_QMAX,
    O_UT_NSIG,
    O_UPSTREAM_AMBIGUOUS,
    O_UT_AMBIGUOUS,
    O_UT_QPRIOR,
    O_WEAK_QPRIOR,
    STATUS_NO_UT,
    STATUS_OK,
)
from pkf.seeding.forward.outliers import clean_ut_hits
from pkf.seeding.forward.records import MODE_OFF, MODE_SEARCH, SearchRules
from pkf.seeding.forward.search import search
from pkf.seeding.forward_steps import TRANSPORT_FAILED


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _zero_start(filt, q):
    """Start deviation 0 in position and slope, −q in q/p (the reference is at q)."""
    for i in range(4):
        filt.x0[i] = 0.0
    filt.x0[4] = -q


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _search_ut(filt, lay):
    """MODE_SEARCH on the UT layers, the others off."""
    for j in range(lay.layer.shape[0]):
        filt.mode[j] = MODE_SEARCH if j < lay.n_ut else MODE_OFF


@nb.njit(cache=True, **NO_REFCOUNT)
def ut_start(tr, lay, hits, cfg, w, track, start):
    """The VELO prior carried through the UT without hits, at |q/p| = 0 and at the noise
    of 1/p_min: start (`Start`) = the state at the last UT layer given q/p, its derivative
    and its conditional covariance. Returns False if the transport failed."""
    opt = cfg.opt
    filt = w.filt
    ref_s = filt.ref.s
    cx, cP = w.leaf_c.x, w.leaf_c.P
    s0, ds0, pc = start
    n_ut = lay.n_ut
    qmax = opt[O_QMAX]
    ut_prune = cfg.cuts.ut_prune
    if reference(tr, lay, filt.ref, track.a, n_ut, track.s_v, 0.0, 0.0) == TRANSPORT_FAILED:
        return False
    for j in range(n_ut):
        filt.fixed[j] = -1
    for i in range(5):
        filt.x0[i] = 0.0
    velo_prior(opt, 0.0, opt[O_WEAK_QPRIOR], filt.P0)
    fit_fixed(0, n_ut, filt, hits, lay, 1.0, ut_prune, w.leaf_c)
    for i in range(5):
        s0[i] = ref_s[n_ut - 1, i] + cx[i]
        ds0[i] = cP[i, 4] / cP[4, 4]
    conditional(cP, pc, 0)
    reference(tr, lay, filt.ref, track.a, n_ut, track.s_v, 0.0, qmax)
    velo_prior(opt, qmax, opt[O_WEAK_QPRIOR], filt.P0)
    fit_fixed(0, n_ut, filt, hits, lay, 1.0, ut_prune, w.leaf_c)
    conditional(cP, pc, 6)
    for i in range(6):
        pc[6 + i] = (pc[6 + i] - pc[i]) / (qmax * qmax)
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def _refit_leaf(tr, lay, hits, cfg, w, track, top_ut, c, q_c, v_c):
    """Re-fit UT leaf c of top_ut around its own q/p (start q_c, variance v_c) with the
    noise at that q/p, ut_refits times. Returns (hits, χ², q/p, variance); 0 hits if the
    transport failed."""
    opt, iopt = cfg.opt, cfg.iopt
    filt = w.filt
    n_ut = lay.n_ut
    chi_c = 1e300
    n_c = 0
    for _ in range(iopt[I_UT_REFITS]):
        q_noise = min(math.sqrt(q_c * q_c + v_c), opt[O_QMAX])
        if reference(tr, lay, filt.ref, track.a, n_ut, track.s_v, q_c, q_noise) == TRANSPORT_FAILED:
            n_c = 0
            break
        for j in range(n_ut):
            filt.fixed[j] = top_ut.paths[c, j]
        _zero_start(filt, q_c)
        velo_prior(opt, q_noise, opt[O_WEAK_QPRIOR], filt.P0)
        n_c, chi_c = fit_fixed(0, n_ut, filt, hits, lay, opt[O_UT_NSIG], cfg.cuts.ut_prune, w.leaf_c)
        if n_c < iopt[I_UT_MIN]:
            break
        q_c = filt.ref.s[n_ut - 1, 4] + w.leaf_c.x[4]
        v_c = w.leaf_c.P[4, 4]
    return n_c, chi_c, q_c, v_c


@nb.njit(cache=True, **NO_REFCOUNT)
def _insert_ut_candidate(utc, n_utc, c, n_c, chi_c, q_c, v_c, cfg, w, n_ut):
    """Insert the re-fitted leaf c into the UT candidates utc (`UtCandidates`, by hits then
    χ²) with its q/p range ± hough_sigmas·σ and its fitted state at the last UT layer
    given q/p (the fit in w.leaf_c, around w.filt.ref)."""
    opt = cfg.opt
    qmax = opt[O_QMAX]
    r_lo, r_hi, u_q, u_var, u_chi, u_n, u_leaf, u_pc, u_s0, u_ds0 = utc
    ref_s = w.filt.ref.s
    cx, cP = w.leaf_c.x, w.leaf_c.P
    w_ = opt[O_HOUGH_NSIG] * math.sqrt(v_c)
    pos = n_utc
    while pos > 0 and (n_c > u_n[pos - 1] or (n_c == u_n[pos - 1] and chi_c < u_chi[pos - 1])):
        pos -= 1
    for k in range(n_utc, pos, -1):
        r_lo[k] = r_lo[k - 1]
        r_hi[k] = r_hi[k - 1]
        u_q[k] = u_q[k - 1]
        u_var[k] = u_var[k - 1]
        u_chi[k] = u_chi[k - 1]
        u_n[k] = u_n[k - 1]
        u_leaf[k] = u_leaf[k - 1]
        for i in range(12):
            u_pc[k, i] = u_pc[k - 1, i]
        for i in range(5):
            u_s0[k, i] = u_s0[k - 1, i]
            u_ds0[k, i] = u_ds0[k - 1, i]
    r_lo[pos] = max(q_c - w_, -qmax)
    r_hi[pos] = min(q_c + w_, qmax)
    u_q[pos] = q_c
    u_var[pos] = v_c
    u_chi[pos] = chi_c
    u_n[pos] = n_c
    u_leaf[pos] = c
    conditional(cP, u_pc[pos], 0)
    for i in range(6, 12):
        u_pc[pos, i] = 0.0
    for i in range(5):
        u_s0[pos, i] = ref_s[n_ut - 1, i] + cx[i]
        u_ds0[pos, i] = cP[i, 4] / cP[4, 4]


@nb.njit(cache=True, **NO_REFCOUNT)
def ut_search(lay, hits, cfg, w, top_ut):
    """The UT search of step 1: the combinatorial KF over the UT layers around q/p = 0 with
    the q/p prior ut_q_prior/p_min, its best leaves into top_ut (`Ranked`, most hits first).
    Returns their number. Expects w.filt.ref at q/p = 0 and w.filt.x0 = 0 (`ut_start`)."""
    opt, iopt = cfg.opt, cfg.iopt
    filt = w.filt
    n_ut = lay.n_ut
    _search_ut(filt, lay)
    velo_prior(opt, opt[O_QMAX], opt[O_UT_QPRIOR], filt.P0)
    rules = SearchRules(opt[O_UT_NSIG], iopt[I_UT_FIRST], iopt[I_UT_BRANCH], n_ut - iopt[I_UT_MIN],
                        iopt[I_UT_MIN], True, 0, cfg.cuts.ut_prune, iopt[I_MAX_NODES], 1e6, -1, 0.0, 1.0)
    search(0, n_ut, filt, hits, lay, rules, w.leaf_b, top_ut)
    return top_ut.count[0]


@nb.njit(cache=True, **NO_REFCOUNT)
def ut_candidates(tr, lay, hits, cfg, w, track, top_ut, utc, ut_best):
    """Step 1: the UT search around q/p = 0 (noise of 1/p_min, `ut_search`) into top_ut
    (`Ranked`), each leaf re-fitted around its own q/p; those passing the UT χ² cut are the UT
    candidates utc, best first. ut_best: the UT hits of the best (−1 none). Returns the
    number of candidates. Expects w.filt.ref at q/p = 0 and w.filt.x0 = 0 (`ut_start`)."""
    iopt = cfg.iopt
    filt = w.filt
    n_ut = lay.n_ut
    n_fwd = lay.layer.shape[0]
    ut_cut = cfg.cuts.ut
    n_leaves = ut_search(lay, hits, cfg, w, top_ut)
    q0_ref = filt.ref.s[n_ut - 1, 4]
    for j in range(n_fwd):
        ut_best[j] = top_ut.paths[0, j] if (n_leaves > 0 and j < n_ut) else -1
    n_utc = 0
    for c in range(n_leaves):
        n_c, chi_c, q_c, v_c = _refit_leaf(tr, lay, hits, cfg, w, track, top_ut, c, q0_ref + top_ut.q[c],
                                           top_ut.var[c])
        if n_c < iopt[I_UT_MIN] or chi_c > ut_cut[min(n_c, ut_cut.shape[0] - 1)]:
            continue
        _insert_ut_candidate(utc, n_utc, c, n_c, chi_c, q_c, v_c, cfg, w, n_ut)
        n_utc += 1
    if n_utc > 0:
        for j in range(n_ut):
            ut_best[j] = top_ut.paths[utc.leaf[0], j]
    return n_utc


@nb.njit(cache=True, **NO_REFCOUNT)
def _confirm_ut(lay, hits, cfg, w, q_best, var_best, ut_hits, use_ut_hits):
    """UT hits for the final fit into w.filt.fixed[:n_ut]: searched again with the SciFi
    q/p (± its σ) as prior in windows of confirm_window_sigmas (≥ ut_confirm_min_hits),
    or, with ut_confirm_min_hits = 0, the start's (ut_hits if use_ut_hits). Returns
    their number."""
    opt, iopt = cfg.opt, cfg.iopt
    filt = w.filt
    n_ut = lay.n_ut
    confirm_min = iopt[I_CONFIRM_MIN]
    n_conf = 0
    if confirm_min > 0:
        _search_ut(filt, lay)
        for i in range(5):
            filt.x0[i] = 0.0
        velo_prior(opt, abs(q_best), 0.0, filt.P0)
        filt.P0[4, 4] = var_best
        rules = SearchRules(opt[O_CONFIRM_NSIG], iopt[I_BRANCH], iopt[I_BRANCH], n_ut - confirm_min, confirm_min,
                            True, 0, cfg.cuts.ut_prune, iopt[I_MAX_NODES], 1e6, -1, 0.0, 1.0)
        nb_c, _, _ = search(0, n_ut, filt, hits, lay, rules, w.leaf_c, w.top_none)
        for j in range(n_ut):
            filt.fixed[j] = w.leaf_c.path[j] if nb_c >= confirm_min else -1
            if filt.fixed[j] >= 0:
                n_conf += 1
    else:
        for j in range(n_ut):
            filt.fixed[j] = ut_hits[j] if use_ut_hits else -1
            if filt.fixed[j] >= 0:
                n_conf += 1
    return n_conf


@nb.njit(cache=True, **NO_REFCOUNT)
def _accept(lay, cfg, w, t, chi_f, out):
    """Cuts on the final fit of track t (path in w.leaf_b) and, if it ranks before the
    best so far (w.best_key), its output. Returns True if it passes the cuts."""
    opt, iopt = cfg.opt, cfg.iopt
    cuts = cfg.cuts
    path = w.leaf_b.path
    n_ut = lay.n_ut
    n_fwd = lay.layer.shape[0]
    n_u = 0
    n_s = 0
    for j in range(n_fwd):
        if path[j] >= 0:
            if j < n_ut:
                n_u += 1
            else:
                n_s += 1
    if n_s < iopt[I_SF_MIN] or chi_f > cuts.final[min(n_u + n_s, cuts.final.shape[0] - 1)]:
        return False
    if n_u == 0 and (n_s < iopt[I_NOUT_MIN] or chi_f > cuts.no_ut[min(n_s, cuts.no_ut.shape[0] - 1)]):
        return False  # without UT hits the VELO–SciFi match alone must be convincing
    key = chi_f - opt[O_MISS] * (n_u + n_s)
    if key >= w.best_key[0]:
        return True
    w.best_key[0] = key
    for j in range(n_fwd):
        out.hits[t, j] = path[j]
    out.q[t] = w.filt.ref.s[n_fwd - 1, 4] + w.leaf_b.x[4]
    out.qvar[t] = w.leaf_b.P[4, 4]
    out.chi2[t] = chi_f
    out.ndf[t] = n_u + n_s - 1
    out.n_ut[t] = n_u
    out.n_scifi[t] = n_s
    out.status[t] = STATUS_OK if n_u > 0 else STATUS_NO_UT
    for j in range(n_ut):
        out.ut_chi2[t, j] = w.smooth.chi2[j]
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def finalize(tr, lay, hits, cfg, w, track, c, ut_hits, use_ut_hits, out):
    """Step 4 for SciFi candidate c of w.cand: UT confirmation with its q/p as prior, then
    the final fit over the UT and SciFi hits at that q/p with the UT outlier check
    (`outliers.clean_ut_hits`); if it fails its cuts, once more without UT hits. Returns
    True if accepted (the output of track.t is written if it ranks before the best so far)."""
    opt = cfg.opt
    filt = w.filt
    n_ut = lay.n_ut
    n_fwd = lay.layer.shape[0]
    q_best = w.cand.q[c]
    sf_path = w.cand.paths[c]
    if reference(tr, lay, filt.ref, track.a, n_fwd, track.s_v, q_best, abs(q_best)) == TRANSPORT_FAILED:
        return False
    for attempt in range(2):
        if attempt == 0:
            if _confirm_ut(lay, hits, cfg, w, q_best, w.cand.var[c], ut_hits, use_ut_hits) == 0:
                continue  # identical to attempt 1
        else:
            for j in range(n_ut):
                filt.fixed[j] = -1
        for j in range(n_ut, n_fwd):
            filt.fixed[j] = sf_path[j]
        _zero_start(filt, q_best)
        velo_prior(opt, abs(q_best), opt[O_WEAK_QPRIOR], filt.P0)
        n_fit, chi_f = fit_fixed(0, n_fwd, filt, hits, lay, opt[O_NSIG], cfg.cuts.sf_prune, w.leaf_b)
        for j in range(n_ut):
            w.smooth.chi2[j] = math.nan
        if attempt == 0 and n_fit >= 1:
            n_fit, chi_f = clean_ut_hits(lay, hits, cfg, filt, w.leaf_b, w.smooth, n_fwd, opt[O_NSIG],
                                         cfg.cuts.sf_prune, n_fit, chi_f, opt[O_UT_AMBIGUOUS])
        if n_fit >= 1 and _accept(lay, cfg, w, track.t, chi_f, out):
            return True
    return False


@nb.njit(cache=True, **NO_REFCOUNT)
def clean_upstream(tr, lay, hits, cfg, w, track, q_c, v_c, ut_hits):
    """The UT outlier check (`outliers.clean_ut_hits`) for an upstream track (no SciFi
    extension): the VELO prior + the UT hits ut_hits fitted around q_c (variance v_c, 1/MeV)
    as in `_refit_leaf`, then each UT hit against the rest of the track, the ambiguous
    neighbour rule included (a UT hit with another hit of its layer at χ² <
    ``upstream_ambiguous_chi2`` is dropped). Issue 15: 39 % of the upstream candidates of minimum
    bias at ν = 7.6 carried a UT hit of another particle, nearly always next to the
    particle's own hit. Returns (UT hits, χ², q/p, variance) of the final fit, its hits in
    w.leaf_c.path; 0 hits if the transport or a refit failed."""
    opt = cfg.opt
    filt = w.filt
    n_ut = lay.n_ut
    q_noise = min(math.sqrt(q_c * q_c + v_c), opt[O_QMAX])
    if reference(tr, lay, filt.ref, track.a, n_ut, track.s_v, q_c, q_noise) == TRANSPORT_FAILED:
        return 0, math.inf, q_c, v_c
    for j in range(n_ut):
        filt.fixed[j] = ut_hits[j]
    _zero_start(filt, q_c)
    velo_prior(opt, q_noise, opt[O_WEAK_QPRIOR], filt.P0)
    n_c, chi_c = fit_fixed(0, n_ut, filt, hits, lay, opt[O_UT_NSIG], cfg.cuts.ut_prune, w.leaf_c)
    if n_c < 1:
        return 0, math.inf, q_c, v_c
    n_c, chi_c = clean_ut_hits(lay, hits, cfg, filt, w.leaf_c, w.smooth, n_ut, opt[O_UT_NSIG],
                               cfg.cuts.ut_prune, n_c, chi_c, opt[O_UPSTREAM_AMBIGUOUS])
    if n_c < 1:
        return 0, math.inf, q_c, v_c
    return n_c, chi_c, filt.ref.s[n_ut - 1, 4] + w.leaf_c.x[4], w.leaf_c.P[4, 4]
