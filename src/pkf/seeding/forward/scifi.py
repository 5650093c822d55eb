"""Steps 2–3 of the forward extension: the q/p scan of the SciFi, its clusters, and the
combinatorial Kalman filter from the best of them.

`scifi_search` runs the stages in order: the trajectory at the q/p nodes
(`_node_states`), the Hough entries and clusters (`pkf.seeding.forward.hough`), the
straight-line ranking of every cluster (`_rank_clusters`), the stereo confirmation of the
best few (`_confirm_stereo`) and the follow of the best confirmed ones (`_follow_clusters`)
into the candidate list (`_insert_candidate`). Units: mm, 1/MeV.
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT
from pkf.params.ut_to_scifi import localize_ut_to_scifi
from pkf.seeding.forward.hough import find_clusters, hough_entries, node_interp, q_of_t, sort_entries, t_of_q
from pkf.seeding.forward.kalman import pvalue_ok, reference, velo_prior
from pkf.seeding.forward.lines import cluster_fit, line_fit, stereo_score
from pkf.seeding.forward.options import (
    I_BRANCH,
    I_MAX_CLUSTERS,
    I_MAX_NODES,
    I_MIN_X,
    I_SF_MIN,
    I_STEREO_CANDIDATES,
    I_STEREO_MIN,
    I_WINDOW_BINS,
    O_LINE_CHI2,
    O_LINE_MS,
    O_LINE_SIG,
    O_MISS,
    O_NODE_DW,
    O_NSIG,
    O_PM_FLOOR,
    O_SLOPE_MS,
    O_TAU0,
    O_TAU1,
    O_WEAK_QPRIOR,
)
from pkf.seeding.forward.records import MODE_FIXED, MODE_OFF, MODE_SEARCH, SearchRules
from pkf.seeding.forward.search import search
from pkf.seeding.forward_steps import TRANSPORT_FAILED, scan_states

_INLINE = dict(cache=True, inline="always", **NO_REFCOUNT)


@nb.njit(cache=True, **NO_REFCOUNT)
def _node_states(tr, lay, nodes, start, q_lo, q_hi, node_dw):
    """The start state given q/p transported to the SciFi layers at q/p nodes node_dw
    apart over [q_lo, q_hi] (nodes: `NodeStates`). Returns the number of nodes, 0 if the
    transport failed."""
    ext = tr.ext
    s0 = start.s0
    qn = nodes.q
    n_ut = lay.n_ut
    localize_ut_to_scifi(ext.uts_meta, ext.uts_cells, s0[0], s0[1], tr.poly, tr.table_ref)
    n_nodes = int(math.ceil((q_hi - q_lo) / node_dw)) + 1
    n_nodes = min(max(n_nodes, 2), qn.shape[0])
    for k in range(n_nodes):
        qn[k] = q_lo + (q_hi - q_lo) * k / (n_nodes - 1)
    st = scan_states(ext, tr.poly, tr.table_ref, tr.quadratic, lay.layer[n_ut - 1], lay.layer[n_ut:], s0,
                     start.ds0, qn[:n_nodes], nodes.x, nodes.dx, nodes.y, nodes.dy, tr.work)
    return 0 if st == TRANSPORT_FAILED else n_nodes


@nb.njit(**_INLINE)
def _line_errors(opt, pc, q_c):
    """σ² [mm²] of an x hit about a cluster's line at q/p = q_c, and the weight of the
    line's slope prior (1/σ²_β)."""
    sig2 = opt[O_LINE_SIG] ** 2 + (opt[O_LINE_MS] * q_c) ** 2
    w_beta = 1.0 / (pc[2] + (pc[8] + opt[O_SLOPE_MS] ** 2) * q_c * q_c)
    return sig2, w_beta


@nb.njit(**_INLINE)
def _line_at(kb, ke, q_c, lay, scan, n_nodes, hu, opt, pc):
    """The straight-line test (`lines.cluster_fit`) of entries kb … ke−1 about the
    trajectory at q/p = q_c. Returns (n_layers, χ², α, β, σ² of a hit)."""
    nodes = scan.nodes
    d_l = scan.line.d_l
    for li in range(lay.x_fwd.shape[0]):
        d_l[li], _ = node_interp(nodes.q, n_nodes, nodes.x, nodes.dx, lay.x_fwd[li] - lay.n_ut, q_c)
    sig2, w_beta = _line_errors(opt, pc, q_c)
    nl_, chi2l, alpha, beta = cluster_fit(kb, ke, scan.entries, hu, False, 0.0, scan.line, sig2, w_beta)
    return nl_, chi2l, alpha, beta, sig2


@nb.njit(cache=True, **NO_REFCOUNT)
def _rank_clusters(n_cl, t_lo, n_bins, n_nodes, lay, hu, cfg, scan, pc):
    """Straight-line test of every cluster at first order in q/p around its centre:
    scan.cl_key = χ² + nsig² per missing x layer (1e300: failed)."""
    opt, iopt = cfg.opt, cfg.iopt
    e = scan.entries
    qn, sdxs = scan.nodes.q, scan.nodes.dx
    cl_bin, cl_key, d_l = scan.cl_bin, scan.cl_key, scan.line.d_l
    x_fwd, n_ut = lay.x_fwd, lay.n_ut
    n_x = x_fwd.shape[0]
    n_win = iopt[I_WINDOW_BINS]
    nsig = opt[O_NSIG]
    for c_ in range(n_cl):
        b = cl_bin[c_]
        t_c = t_lo + b + 0.5 * n_win
        q_c = q_of_t(t_c, cfg.hough)
        tau_c = opt[O_TAU0] + opt[O_TAU1] * abs(q_c)
        k = 0
        while k < n_nodes - 2 and qn[k + 1] <= q_c:
            k += 1
        u = min(max((q_c - qn[k]) / (qn[k + 1] - qn[k]), 0.0), 1.0)
        for li in range(n_x):
            col = x_fwd[li] - n_ut
            d_l[li] = tau_c * (sdxs[k, col] + u * (sdxs[k + 1, col] - sdxs[k, col]))
        sig2, w_beta = _line_errors(opt, pc, q_c)
        nl_, chi2l, _, _ = cluster_fit(e.bin_start[b], e.bin_start[min(b + n_win, n_bins)], e, hu, True, t_c,
                                       scan.line, sig2, w_beta)
        if nl_ < iopt[I_MIN_X] or chi2l > opt[O_LINE_CHI2] * max(nl_ - 1, 1):
            cl_key[c_] = 1e300
        else:
            cl_key[c_] = chi2l + nsig * nsig * (n_x - nl_)


@nb.njit(cache=True, **NO_REFCOUNT)
def _confirm_stereo(n_cl, t_lo, n_bins, n_nodes, lay, hits, cfg, scan, pc, z_ut):
    """Stereo confirmation of the best clusters by line χ²: key += Σ stereo Δχ², or 1e300
    with a hit on fewer than stereo_min_layers stereo layers; clusters not checked get
    1e300 (not followed)."""
    opt, iopt = cfg.opt, cfg.iopt
    e = scan.entries
    cl_bin, cl_npop, cl_key = scan.cl_bin, scan.cl_npop, scan.cl_key
    n_win = iopt[I_WINDOW_BINS]
    n_conf = 0
    while n_conf < iopt[I_STEREO_CANDIDATES]:
        best = -1
        for c_ in range(n_cl):
            if cl_key[c_] < 1e299 and cl_npop[c_] >= 0 and (best < 0 or cl_key[c_] < cl_key[best]):
                best = c_
        if best < 0:
            break
        n_conf += 1
        cl_npop[best] = -cl_npop[best] - 1  # mark as confirmed
        b = cl_bin[best]
        q_c = q_of_t(t_lo + b + 0.5 * n_win, cfg.hough)
        _, _, alpha, beta, sig2 = _line_at(e.bin_start[b], e.bin_start[min(b + n_win, n_bins)], q_c, lay, scan,
                                           n_nodes, hits.u, opt, pc)
        sscore, n_stereo = stereo_score(hits, lay, scan, n_nodes, q_c, alpha, beta, sig2, pc, z_ut, opt[O_NSIG])
        cl_key[best] = cl_key[best] + sscore if n_stereo >= iopt[I_STEREO_MIN] else 1e300
    for c_ in range(n_cl):
        if cl_npop[c_] >= 0:
            cl_key[c_] = 1e300  # not confirmed: not followed


@nb.njit(cache=True, **NO_REFCOUNT)
def _insert_candidate(cand, path, n_sf, chi_c, q, var, n_ut, miss):
    """Insert a SciFi candidate into cand (`Ranked`, best first by χ² − miss·hits) unless
    its SciFi path is already there or it ranks beyond the list. Returns True if inserted."""
    c_paths, c_n, c_chi, c_q, c_var, c_count = cand
    n_fwd = path.shape[0]
    key = chi_c - miss * n_sf
    for c2 in range(c_count[0]):
        same = True
        for j in range(n_ut, n_fwd):
            if c_paths[c2, j] != path[j]:
                same = False
                break
        if same:
            return False
    nc = c_count[0]
    pos = nc
    while pos > 0 and key < c_chi[pos - 1] - miss * c_n[pos - 1]:
        pos -= 1
    if pos >= c_n.shape[0]:
        return False
    for q_ in range(min(nc, c_n.shape[0] - 1), pos, -1):
        c_n[q_] = c_n[q_ - 1]
        c_chi[q_] = c_chi[q_ - 1]
        c_q[q_] = c_q[q_ - 1]
        c_var[q_] = c_var[q_ - 1]
        for j in range(n_fwd):
            c_paths[q_, j] = c_paths[q_ - 1, j]
    c_n[pos] = n_sf
    c_chi[pos] = chi_c
    c_q[pos] = q
    c_var[pos] = var
    for j in range(n_fwd):
        c_paths[pos, j] = path[j]
    if nc < c_n.shape[0]:
        c_count[0] = nc + 1
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def _follow_clusters(n_cl, t_lo, n_bins, n_nodes, tr, lay, hits, cfg, w, track, ut_hits, pc):
    """Follow the best confirmed clusters with the combinatorial KF: a reference
    trajectory at the cluster's q/p, the VELO prior, the UT hits ut_hits fixed, a
    pseudo-measurement of x at the first SciFi x layer from the cluster's line, then the
    SciFi layers searched (pc: the start's conditional covariance, `Start`). Stops at a good, (nearly) complete candidate."""
    opt, iopt = cfg.opt, cfg.iopt
    scan = w.scan
    filt = w.filt
    ref_s = filt.ref.s
    e = scan.entries
    nodes = scan.nodes
    line = scan.line
    cl_bin, cl_key = scan.cl_bin, scan.cl_key
    x_fwd, n_ut = lay.x_fwd, lay.n_ut
    n_fwd = lay.layer.shape[0]
    n_x = x_fwd.shape[0]
    n_win = iopt[I_WINDOW_BINS]
    bx, bP = w.leaf_b.x, w.leaf_b.P
    n_follow = 0
    while n_follow < iopt[I_MAX_CLUSTERS]:
        best = -1
        for c_ in range(n_cl):
            if cl_key[c_] < 1e299 and (best < 0 or cl_key[c_] < cl_key[best]):
                best = c_
        if best < 0:
            break
        cl_key[best] = 1e300
        n_follow += 1
        b = cl_bin[best]
        q_c = q_of_t(t_lo + b + 0.5 * n_win, cfg.hough)
        nl_, _, _, _, sig2 = _line_at(e.bin_start[b], e.bin_start[min(b + n_win, n_bins)], q_c, lay, scan,
                                      n_nodes, hits.u, opt, pc)
        # refined q/p: mean Hough coordinate of the chosen entries
        ts = 0.0
        for li in range(n_x):
            if line.chosen[li] >= 0:
                ts += e.t[line.chosen[li]]
        q_c = q_of_t(ts / nl_, cfg.hough)
        # pseudo-measurement at the first x layer: the cluster's straight line there, fitted
        # without the slope prior (which may pull it by more than the hit spacing)
        _, _, alpha, _ = line_fit(n_x, line.chosen, line.rx, line.x_z, sig2, 0.0)
        x_first, _ = node_interp(nodes.q, n_nodes, nodes.x, nodes.dx, x_fwd[0] - n_ut, q_c)
        if reference(tr, lay, filt.ref, track.a, n_fwd, track.s_v, q_c, abs(q_c)) == TRANSPORT_FAILED:
            continue
        for j in range(n_fwd):
            if j < n_ut:
                filt.mode[j] = MODE_FIXED if ut_hits[j] >= 0 else MODE_OFF
                filt.fixed[j] = ut_hits[j]
            else:
                filt.mode[j] = MODE_SEARCH
        for i in range(4):
            filt.x0[i] = 0.0
        filt.x0[4] = -q_c
        velo_prior(opt, abs(q_c), opt[O_WEAK_QPRIOR], filt.P0)
        rules = SearchRules(opt[O_NSIG], iopt[I_BRANCH], iopt[I_BRANCH], n_fwd - n_ut - iopt[I_SF_MIN],
                            iopt[I_SF_MIN], False, lay.scifi_need, cfg.cuts.sf_prune, iopt[I_MAX_NODES],
                            opt[O_MISS], x_fwd[0], x_first + alpha, sig2 + opt[O_PM_FLOOR] ** 2)
        n_sf, _, chi_c = search(0, n_fwd, filt, hits, lay, rules, w.leaf_b, w.top_none)
        if n_sf < 0:
            continue
        if _insert_candidate(w.cand, w.leaf_b.path, n_sf, chi_c, ref_s[n_fwd - 1, 4] + bx[4], bP[4, 4], n_ut,
                             opt[O_MISS]) \
                and n_sf >= n_fwd - n_ut - 1 and pvalue_ok(chi_c, n_sf, cfg.cuts.good):
            break  # a good, (nearly) complete candidate: the next clusters are worse
    return w.cand.count[0]


@nb.njit(cache=True, **NO_REFCOUNT)
def scifi_search(tr, lay, hits, cfg, w, track, start, q_lo, q_hi, ut_hits):
    """Steps 2–3: q/p scan of the SciFi x layers over [q_lo, q_hi], then the combinatorial
    KF from the best clusters (through the UT hits ut_hits, −1: none, then the SciFi
    layers). start (`Start`): the state at the last UT layer given q/p and its
    conditional covariance. Fills w.cand (`Ranked`: paths, SciFi hits, χ², q/p, its
    variance), best first (χ² − miss_penalty·hits); returns their number.
    """
    opt, iopt = cfg.opt, cfg.iopt
    scan = w.scan
    e = scan.entries
    w.cand.count[0] = 0
    if not q_hi > q_lo:
        return 0
    n_nodes = _node_states(tr, lay, scan.nodes, start, q_lo, q_hi, opt[O_NODE_DW])
    if n_nodes == 0:
        return 0
    # Hough coordinate t of every x-layer hit in the covered range, sorted into bins
    t_lo = t_of_q(q_lo, cfg.hough)
    n_bins = min(int(t_of_q(q_hi, cfg.hough) - t_lo) + 1, e.bin_count.shape[0] - 1)
    layer_z = tr.ext.layer_z
    z_ut = layer_z[lay.layer[lay.n_ut - 1]]
    for j in range(lay.layer.shape[0]):
        scan.f_z[j] = layer_z[lay.layer[j]]
    for li in range(lay.x_layers.shape[0]):
        scan.line.x_z[li] = layer_z[lay.x_layers[li]]
    n_e = hough_entries(lay, hits, cfg.hough, scan, n_nodes, start.pc, max(abs(q_lo), abs(q_hi)), z_ut,
                        opt[O_NSIG], t_lo, n_bins)
    sort_entries(n_e, n_bins, e)
    n_cl = find_clusters(n_e, n_bins, iopt[I_WINDOW_BINS], iopt[I_MIN_X], scan)
    # straight-line test of every cluster, then the stereo confirmation of the best few
    _rank_clusters(n_cl, t_lo, n_bins, n_nodes, lay, hits.u, cfg, scan, start.pc)
    _confirm_stereo(n_cl, t_lo, n_bins, n_nodes, lay, hits, cfg, scan, start.pc, z_ut)
    for k in range(n_e):
        e.bin_count[e.bin[k]] = 0
    return _follow_clusters(n_cl, t_lo, n_bins, n_nodes, tr, lay, hits, cfg, w, track, ut_hits, start.pc)
