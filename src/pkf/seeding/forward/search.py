"""The depth-first combinatorial Kalman filter of the forward extension (steps 1, 3 and 4).

`search` walks the forward layers j0 … j1−1 depth first: at each depth the state is
predicted from the parent branch (`_predict_depth`), the children are the compatible hits
in the window, best by Δχ² (`_children`), each child is filtered (`_take_child`), pruned
by χ² and station requirements, and a complete path is ranked against the best leaf and
the K best leaves (`_record_leaf`). The helpers are inlined: this loop is the hottest of
the pattern recognition.
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT
from pkf.seeding.forward.kalman import copy_leaf, first_at_least, load_start, maybe_crossed, predict, update
from pkf.seeding.forward.records import MODE_FIXED, MODE_OFF, MODE_SEARCH

_INLINE = dict(cache=True, inline="always", **NO_REFCOUNT)


@nb.njit(**_INLINE)
def _predict_depth(d, j, filt, rules):
    """Predict depth d (layer j) from its parent (the start for d = 0), apply the
    pseudo-measurement at rules.pm_depth (outside χ²), and store the predicted strip
    coordinate upred[d] and its variance sbase[d] without the hit's σ. Returns the
    parent's attach flag (1 once a search hit is on the branch)."""
    ref_s, ref_F, ref_Q = filt.ref
    ws = filt.ws
    pred_x, pred_P, post_P, pht = ws.pred_x, ws.pred_P, ws.post_P, ws.pht
    if d == 0:
        predict(ref_F, ref_Q, j, ws.x_init, ws.P_init, 0, pred_x, pred_P, d, ws.tmp)
        prev_att = 0
    else:
        predict(ref_F, ref_Q, j, ws.post_x, post_P, d - 1, pred_x, pred_P, d, ws.tmp)
        prev_att = ws.post_att[d - 1]
    if d == rules.pm_depth:
        pm_var = rules.pm_var
        for i in range(5):
            pht[i] = pred_P[d, i, 0]
        var = pred_P[d, 0, 0] + pm_var
        r = rules.pm_value - (ref_s[j, 0] + pred_x[d, 0])
        for i in range(5):
            kk = pht[i] / var
            pred_x[d, i] += kk * r
        for i in range(5):
            for m in range(5):
                post_P[d, i, m] = pred_P[d, i, m] - pht[i] * pht[m] / var
        for i in range(5):
            for m in range(5):
                pred_P[d, i, m] = post_P[d, i, m]
    return prev_att


@nb.njit(**_INLINE)
def _window_children(d, up, hw, sb, kmax, nsig, lo, hi, hits, ch_hit, ch_chi):
    """The hits of rows lo … hi−1 with |u − up| ≤ hw, Δχ² = r²/(sb + σ²) < nsig² and not
    used: the kmax best by Δχ² into ch_hit[d], ch_chi[d] (sorted). Returns their number."""
    _, hu, hsig, used = hits
    nc = 0
    h = first_at_least(hu, lo, hi, up - hw)
    while h < hi and hu[h] <= up + hw:
        if used[h]:
            h += 1
            continue
        r = hu[h] - up
        c2 = r * r / (sb + hsig[h] * hsig[h])
        if c2 < nsig * nsig:
            # insertion into the sorted top-kmax list
            if nc < kmax:
                pos = nc
                nc += 1
            elif c2 < ch_chi[d, nc - 1]:
                pos = nc - 1
            else:
                pos = -1
            if pos >= 0:
                while pos > 0 and ch_chi[d, pos - 1] > c2:
                    ch_chi[d, pos] = ch_chi[d, pos - 1]
                    ch_hit[d, pos] = ch_hit[d, pos - 1]
                    pos -= 1
                ch_chi[d, pos] = c2
                ch_hit[d, pos] = h
        h += 1
    return nc


@nb.njit(**_INLINE)
def _children(d, j, prev_att, filt, hits, lay, rules):
    """The children of depth d (layer j) into ch_hit[d] (sorted-hit index, −1 no hit, −2 a
    skip) and ch_chi[d] by the layer's mode. Returns their number."""
    ref_s = filt.ref.s
    ws = filt.ws
    pred_x, pred_P, ch_hit, ch_chi = ws.pred_x, ws.pred_P, ws.ch_hit, ws.ch_chi
    nsig = rules.nsig
    c = lay.cos[j]
    s = lay.sin[j]
    up = c * (ref_s[j, 0] + pred_x[d, 0]) + s * (ref_s[j, 1] + pred_x[d, 1])
    sb = c * c * pred_P[d, 0, 0] + 2.0 * c * s * pred_P[d, 0, 1] + s * s * pred_P[d, 1, 1]
    ws.upred[d] = up
    ws.sbase[d] = sb
    nc = 0
    md = filt.mode[j]
    if md != MODE_OFF and not maybe_crossed(ref_s[j, 0] + pred_x[d, 0], ref_s[j, 1] + pred_x[d, 1],
                                            pred_P[d, 0, 0], pred_P[d, 1, 1], lay.acceptance, j):
        md = MODE_OFF  # certainly outside the active area: no hit, not a missing one
    if md == MODE_FIXED:
        h = filt.fixed[j]
        if h >= 0:
            r = hits.u[h] - up
            c2 = r * r / (sb + hits.sigma[h] * hits.sigma[h])
            if c2 < nsig * nsig:
                ch_hit[d, 0] = h
                ch_chi[d, 0] = c2
                nc = 1
        if nc == 0:
            ch_hit[d, 0] = -1
            ch_chi[d, 0] = 0.0
            nc = 1
    elif md == MODE_SEARCH:
        kmax = rules.first_branches if prev_att == 0 else rules.max_branch
        f_sig = lay.sigma[j]
        hw = nsig * math.sqrt(sb + f_sig * f_sig)
        nc = _window_children(d, up, hw, sb, kmax, nsig, hits.offsets[j], hits.offsets[j + 1], hits, ch_hit,
                              ch_chi)
        skips_so_far = 0 if d == 0 else ws.post_skip[d - 1]
        if (nc == 0 or (rules.skip_first and prev_att == 0)) and skips_so_far < rules.max_skip:
            ch_hit[d, nc] = -2  # skip
            ch_chi[d, nc] = 0.0
            nc += 1
    else:
        ch_hit[d, 0] = -1
        ch_chi[d, 0] = 0.0
        nc = 1
    return nc


@nb.njit(**_INLINE)
def _take_child(d, j, h, filt, hits, lay):
    """Depth d (layer j) takes child h: the filtered state with hit h (h ≥ 0) or the
    prediction, and the branch's χ², hit counts, requirement mask, attach flag, skips."""
    ws = filt.ws
    post_chi, post_n, post_nf, post_skip, post_mask, post_att = (ws.post_chi, ws.post_n, ws.post_nf,
                                                                 ws.post_skip, ws.post_mask, ws.post_att)
    if d == 0:
        prev_chi = 0.0
        prev_n = 0
        prev_nf = 0
        prev_skip = 0
        prev_mask = 0
        prev_att = 0
    else:
        prev_chi = post_chi[d - 1]
        prev_n = post_n[d - 1]
        prev_nf = post_nf[d - 1]
        prev_skip = post_skip[d - 1]
        prev_mask = post_mask[d - 1]
        prev_att = post_att[d - 1]
    if h >= 0:
        c = lay.cos[j]
        s = lay.sin[j]
        var = ws.sbase[d] + hits.sigma[h] * hits.sigma[h]
        r = hits.u[h] - ws.upred[d]
        update(ws.pred_x, ws.pred_P, d, c, s, r, var, ws.post_x, ws.post_P, ws.pht)
        post_chi[d] = prev_chi + r * r / var
        if filt.mode[j] == MODE_SEARCH:
            post_n[d] = prev_n + 1
            post_nf[d] = prev_nf
            post_mask[d] = prev_mask | lay.bit[j]
            post_att[d] = 1
        else:
            post_n[d] = prev_n
            post_nf[d] = prev_nf + 1
            post_mask[d] = prev_mask | lay.bit[j]
            post_att[d] = prev_att
        post_skip[d] = prev_skip
    else:
        for i in range(5):
            ws.post_x[d, i] = ws.pred_x[d, i]
            for m in range(5):
                ws.post_P[d, i, m] = ws.pred_P[d, i, m]
        post_chi[d] = prev_chi
        post_n[d] = prev_n
        post_nf[d] = prev_nf
        post_mask[d] = prev_mask
        post_att[d] = prev_att
        post_skip[d] = prev_skip + (1 if h == -2 else 0)
    ws.path[d] = h if h >= 0 else -1


@nb.njit(**_INLINE)
def _record_leaf(d, j0, nd, ws, miss_penalty, best, top, best_n, best_nf, best_chi):
    """A complete path at depth d = nd − 1: keep it in best (`Leaf`) if it ranks before
    the best so far (best_n, best_nf, best_chi) and insert it into top (`Ranked`, K = 0:
    none). Returns the new best (n, nf, χ²)."""
    post_x, post_P, post_chi, post_n, path = ws.post_x, ws.post_P, ws.post_chi, ws.post_n, ws.path
    top_paths, top_n, top_chi, top_dq, top_var, top_count = top
    key = post_chi[d] - miss_penalty * post_n[d]
    if best_n < 0 or key < best_chi - miss_penalty * best_n:
        best_n = post_n[d]
        best_nf = ws.post_nf[d]
        best_chi = post_chi[d]
        for k in range(nd):
            best.path[j0 + k] = path[k]
        copy_leaf(post_x, post_P, d, best)
    n_top_max = top_n.shape[0]
    if n_top_max > 0:
        nt = top_count[0]
        pos = nt
        while pos > 0 and key < top_chi[pos - 1] - miss_penalty * top_n[pos - 1]:
            pos -= 1
        if pos < n_top_max:
            last = min(nt, n_top_max - 1)
            for q_ in range(last, pos, -1):
                top_n[q_] = top_n[q_ - 1]
                top_chi[q_] = top_chi[q_ - 1]
                top_dq[q_] = top_dq[q_ - 1]
                top_var[q_] = top_var[q_ - 1]
                for k in range(nd):
                    top_paths[q_, j0 + k] = top_paths[q_ - 1, j0 + k]
            top_n[pos] = post_n[d]
            top_chi[pos] = post_chi[d]
            top_dq[pos] = post_x[d, 4]
            top_var[pos] = post_P[d, 4, 4]
            for k in range(nd):
                top_paths[pos, j0 + k] = path[k]
            if nt < n_top_max:
                top_count[0] = nt + 1
    return best_n, best_nf, best_chi


@nb.njit(cache=True, **NO_REFCOUNT)
def search(j0, j1, filt, hits, lay, rules, best, top):
    """Depth-first combinatorial Kalman filter over forward layers j0 … j1−1.

    filt (`Filter`): the reference trajectory, the start (x0, P0) and per layer the mode:
    MODE_SEARCH (hits in the window that are not hits.used — taken by a good extension,
    step 6 — up to rules.first_branches / max_branch by Δχ²), MODE_FIXED (the hit
    filt.fixed[j] if Δχ² < nsig², sorted-hit index, −1 none), MODE_OFF (transport only).
    Search layers without an accepted hit are skips (at most rules.max_skip); before the
    first search hit is attached the skip branch is always tried if rules.skip_first. The
    pseudo-measurement of rules (`SearchRules`) is applied before the hits, outside χ².
    lay.bit[j]: requirement bit of layer j (0: none); at lay.group_end[j] the bits
    lay.need_end[j] must be present; rules.need: bits required at the end.

    Returns (n_search_hits, n_fixed_hits, chi2) of the best leaf (most search hits, then
    lowest χ²) with best.path[j] (sorted-hit index or −1) and the deviation
    state/covariance at layer j1−1 in best.x/best.P (`Leaf`); n = −1 if none. top
    (`Ranked`, its q holding the q/p deviation): the K best leaves (K = 0: not
    collected), ranked like the best: χ² − miss_penalty·(search hits), lowest first (a
    large penalty: most hits first, then χ²).

    Branch and bound: χ² only grows along a branch and each search layer below depth d adds
    at most one hit, so no leaf below d has a key lower than post_chi[d] −
    miss_penalty·(post_n[d] + search layers below d); a branch whose bound is not below the
    best leaf's key (K = 0) or, with K leaves collected, the K-th one's, is not followed.
    The results are the same bit for bit (rounding is monotonic, and a leaf must rank
    strictly before to be kept); only the node count, and so the ``max_nodes`` cap, sees
    the difference. Measured on the SciFi follows (ν = 7.6, 20 events): 27.6 → 19.5 nodes
    per follow in the first pass, 18.9 → 17.0 in the second.
    """
    nd = j1 - j0
    ws = filt.ws
    post_chi, post_n, post_nf, post_mask = ws.post_chi, ws.post_n, ws.post_nf, ws.post_mask
    n_ch, it, ch_hit = ws.n_ch, ws.it, ws.ch_hit
    f_group_end, f_need_end = lay.group_end, lay.need_end
    chi2_prune = rules.prune
    n_prune = chi2_prune.shape[0]
    need = rules.need
    top.count[0] = 0
    load_start(filt)
    search_left = ws.search_left
    left = 0
    for dd in range(nd - 1, -1, -1):
        search_left[dd] = left
        if filt.mode[j0 + dd] == MODE_SEARCH:
            left += 1
    miss = rules.miss_penalty
    top_n, top_chi, top_count = top.n, top.chi2, top.count
    k_top = top_n.shape[0]
    best_n = -1
    best_nf = 0
    best_chi = 1e300
    nodes = 0
    d = 0
    expand = True
    while d >= 0:
        if expand:
            expand = False
            j = j0 + d
            prev_att = _predict_depth(d, j, filt, rules)
            nodes += 1
            n_ch[d] = _children(d, j, prev_att, filt, hits, lay, rules)
            it[d] = 0
            if nodes > rules.max_nodes:
                break
        if it[d] >= n_ch[d]:
            d -= 1
            continue
        ci = it[d]
        it[d] += 1
        j = j0 + d
        _take_child(d, j, ch_hit[d, ci], filt, hits, lay)
        # pruning
        ntot = post_n[d] + post_nf[d]
        if post_chi[d] > chi2_prune[min(ntot, n_prune - 1)]:
            continue
        if f_group_end[j] and (post_mask[d] & f_need_end[j]) != f_need_end[j]:
            continue
        # branch and bound: a leaf below has χ² ≥ post_chi[d] and at most search_left[d]
        # more search hits; if even that key cannot rank, neither can the leaf
        bound = post_chi[d] - miss * (post_n[d] + search_left[d])
        if k_top == 0:
            if best_n >= 0 and bound >= best_chi - miss * best_n:
                continue
        elif top_count[0] == k_top and bound >= top_chi[k_top - 1] - miss * top_n[k_top - 1]:
            continue
        if d == nd - 1:
            if post_n[d] >= rules.min_hits and (post_mask[d] & need) == need:
                best_n, best_nf, best_chi = _record_leaf(d, j0, nd, ws, rules.miss_penalty, best, top,
                                                         best_n, best_nf, best_chi)
            continue
        d += 1
        expand = True
    return best_n, best_nf, best_chi
