"""The compiled driver of the forward extension: two passes over the VELO tracks (step 6).

The first pass extends every track from its UT candidates (`ut`, `scifi`); a good
extension takes its hits. The second pass scans the full q/p range for the tracks still
without an extension, on the hits left. `new_work` allocates the scratch every track
reuses, `new_pass_work` the per-track scratch of the passes.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT
from pkf.seeding.forward.hough import x_layer_counts
from pkf.seeding.forward.kalman import pvalue_ok
from pkf.seeding.forward.options import (
    I_FALLBACK,
    I_MAX_CLUSTERS,
    I_STATION_X,
    I_TAKE_HITS,
    O_NODE_DW,
    O_QMAX,
    STATUS_INVALID,
    STATUS_NOT_FOUND,
)
from pkf.seeding.forward.records import (
    MAX_CHILDREN,
    MAX_PER_LAYER,
    Entries,
    Filter,
    Hits,
    Kept,
    KFWork,
    Leaf,
    PassWork,
    LineWork,
    NodeStates,
    Ranked,
    Reference,
    Scan,
    Smoother,
    Start,
    Track,
    UtCandidates,
    Work,
)
from pkf.seeding.forward.scifi import scifi_search
from pkf.seeding.forward.ut import finalize, ut_candidates, ut_start


def _ranked(k: int, n_fwd: int, fill: int = 0) -> Ranked:
    return Ranked(
        np.full((k, n_fwd), fill, dtype=np.int64),
        np.zeros(k, dtype=np.int64),
        np.zeros(k),
        np.zeros(k),
        np.zeros(k),
        np.zeros(1, dtype=np.int64),
    )


def _kf_work(n_fwd: int) -> KFWork:
    def ints():
        return np.zeros(n_fwd, dtype=np.int64)

    return KFWork(
        pred_x=np.zeros((n_fwd, 5)),
        post_x=np.zeros((n_fwd, 5)),
        pred_P=np.zeros((n_fwd, 5, 5)),
        post_P=np.zeros((n_fwd, 5, 5)),
        tmp=np.zeros((5, 5)),
        pht=np.zeros(5),
        upred=np.zeros(n_fwd),
        sbase=np.zeros(n_fwd),
        post_chi=np.zeros(n_fwd),
        ch_chi=np.zeros((n_fwd, MAX_CHILDREN)),
        n_ch=ints(),
        it=ints(),
        post_n=ints(),
        post_nf=ints(),
        post_skip=ints(),
        post_mask=ints(),
        post_att=ints(),
        path=ints(),
        ch_hit=np.zeros((n_fwd, MAX_CHILDREN), dtype=np.int64),
        x_init=np.zeros((1, 5)),
        P_init=np.zeros((1, 5, 5)),
        search_left=ints(),
    )


def _scan(n_fwd: int, n_sf: int, n_x: int, max_nodes_q: int, max_entries: int, max_bins: int, n_hits: int) -> Scan:
    n_sf_nodes = (max_nodes_q, n_sf)
    entries = Entries(
        t=np.zeros(max_entries),
        bin=np.zeros(max_entries, dtype=np.int64),
        layer=np.zeros(max_entries, dtype=np.int64),
        hit=np.zeros(max_entries, dtype=np.int64),
        order=np.zeros(max_entries, dtype=np.int64),
        bin_count=np.zeros(max_bins + 1, dtype=np.int64),
        bin_start=np.zeros(max_bins + 2, dtype=np.int64),
    )
    line = LineWork(
        chosen=np.full(n_x, -1, dtype=np.int64),
        rx=np.zeros(n_x),
        x_z=np.zeros(n_x),
        d_l=np.zeros(n_x),
        cand_e=np.zeros((n_x, MAX_PER_LAYER), dtype=np.int64),
        cand_r=np.zeros((n_x, MAX_PER_LAYER)),
        cand_n=np.zeros(n_x, dtype=np.int64),
    )
    return Scan(
        nodes=NodeStates(np.zeros(max_nodes_q), *(np.zeros(n_sf_nodes) for _ in range(4))),
        inv_x=np.zeros((n_x, max_nodes_q)),
        inv_q=np.zeros((n_x, max_nodes_q)),
        inv_dq=np.zeros((n_x, max_nodes_q)),
        entries=entries,
        cl_bin=np.zeros(max_entries + 1, dtype=np.int64),
        cl_npop=np.zeros(max_entries + 1, dtype=np.int64),
        cl_key=np.zeros(max_entries + 1),
        line=line,
        f_z=np.zeros(n_fwd),
        mask_pop=np.zeros(1 << n_x, dtype=np.int64),
        free_next=np.arange(n_hits + 1, dtype=np.int64),
    )


def _smoother(n_ut: int) -> Smoother:
    return Smoother(
        lam=np.zeros(5),
        Lam=np.zeros((5, 5)),
        M=np.zeros((5, 5)),
        v=np.zeros(5),
        k=np.zeros(5),
        x=np.zeros(5),
        C=np.zeros((5, 5)),
        x_ut=np.zeros((n_ut, 5)),
        C_ut=np.zeros((n_ut, 5, 5)),
        chi2=np.full(n_ut, np.nan),
    )


def new_work(lay, cfg, max_entries: int, max_bins: int, n_hits: int) -> Work:
    """Scratch of one kernel call (reused by every track); n_hits: the sorted hits."""
    n_fwd = lay.layer.size
    n_sf = n_fwd - lay.n_ut
    opt, iopt = cfg.opt, cfg.iopt
    max_nodes_q = int(math.ceil(2.0 * opt[O_QMAX] / opt[O_NODE_DW])) + 2
    path = np.full(n_fwd, -1, dtype=np.int64)
    scan = _scan(n_fwd, n_sf, lay.x_layers.size, max_nodes_q, max_entries, max_bins, n_hits)
    x_layer_counts(lay, bool(iopt[I_STATION_X] != 0), scan.mask_pop)
    filt = Filter(
        ref=Reference(np.zeros((n_fwd, 5)), np.zeros((n_fwd, 5, 5)), np.zeros((n_fwd, 5, 5))),
        ws=_kf_work(n_fwd),
        mode=np.zeros(n_fwd, dtype=np.int64),
        fixed=np.full(n_fwd, -1, dtype=np.int64),
        x0=np.zeros(5),
        P0=np.zeros((5, 5)),
    )
    return Work(
        filt=filt,
        leaf_b=Leaf(path, np.zeros(5), np.zeros((5, 5))),
        leaf_c=Leaf(path, np.zeros(5), np.zeros((5, 5))),
        scan=scan,
        top_none=_ranked(0, n_fwd),
        cand=_ranked(int(iopt[I_MAX_CLUSTERS]), n_fwd, -1),
        best_key=np.zeros(1),
        smooth=_smoother(lay.n_ut),
    )


def new_pass_work(n_fwd: int, n_ut: int, n_ut_candidates: int, n_tracks: int, n_hits: int) -> PassWork:
    """Per-track scratch of the two passes (`PassWork`)."""
    k = n_ut_candidates
    utc = UtCandidates(
        np.zeros(k),
        np.zeros(k),
        np.zeros(k),
        np.zeros(k),
        np.zeros(k),
        np.zeros(k, dtype=np.int64),
        np.zeros(k, dtype=np.int64),
        np.zeros((k, 12)),
        np.zeros((k, 5)),
        np.zeros((k, 5)),
    )
    kept = Kept(
        np.zeros(n_tracks, dtype=np.bool_),
        np.zeros((n_tracks, 5)),
        np.zeros((n_tracks, 5)),
        np.zeros((n_tracks, 12)),
        np.zeros((n_tracks, n_ut), dtype=np.int64),
        np.zeros((n_tracks, 4)),
        np.zeros(n_tracks, dtype=np.int64),
    )
    return PassWork(
        top_ut=_ranked(k, n_fwd),
        utc=utc,
        start=Start(np.zeros(5), np.zeros(5), np.zeros(12)),
        s_v=np.zeros(5),
        ut_best=np.full(n_fwd, -1, dtype=np.int64),
        ut_hits=np.full(n_fwd, -1, dtype=np.int64),
        kept=kept,
        used=np.zeros(n_hits, dtype=np.bool_),
    )


@nb.njit(cache=True, **NO_REFCOUNT)
def _keep(kept, t, start, ut_best, utc, n_utc):
    """Keep what the second pass needs of track t (`Kept`)."""
    kept.need_scan[t] = True
    for i in range(5):
        kept.s0[t, i] = start.s0[i]
        kept.ds0[t, i] = start.ds0[i]
    for i in range(12):
        kept.pc[t, i] = start.pc[i]
    for j in range(kept.ut.shape[1]):
        kept.ut[t, j] = ut_best[j]
    kept.n_utc[t] = n_utc
    kept.u[t, 0] = utc.q[0]
    kept.u[t, 1] = utc.var[0]
    kept.u[t, 2] = utc.chi2[0]
    kept.u[t, 3] = utc.n[0]


@nb.njit(cache=True, **NO_REFCOUNT)
def _restore(kept, t, start, ut_best, utc):
    """The inverse of `_keep`: returns the number of UT candidates (only the best's q/p,
    variance, χ² and hits are restored)."""
    for i in range(5):
        start.s0[i] = kept.s0[t, i]
        start.ds0[i] = kept.ds0[t, i]
    for i in range(12):
        start.pc[i] = kept.pc[t, i]
    for j in range(kept.ut.shape[1]):
        ut_best[j] = kept.ut[t, j]
    utc.q[0] = kept.u[t, 0]
    utc.var[0] = kept.u[t, 1]
    utc.chi2[0] = kept.u[t, 2]
    utc.n[0] = int(kept.u[t, 3])
    return kept.n_utc[t]


@nb.njit(cache=True, **NO_REFCOUNT)
def _extend(tr, lay, hits, cfg, w, pw, track, n_utc, second_pass, out):
    """Steps 2–4 from each UT candidate (its fitted state, its q/p range, its hits in the
    KF), best first; in the second pass from the VELO prior alone over the whole q/p
    range. Returns (accepted, done: a good, (nearly) complete extension ended the search)."""
    opt, iopt = cfg.opt, cfg.iopt
    top_ut, utc, start, _, ut_best, ut_hits, _, _ = pw
    n_ut = lay.n_ut
    n_fwd = lay.layer.shape[0]
    t = track.t
    qmax = opt[O_QMAX]
    w.best_key[0] = 1e300
    final_ok = False
    done = False
    for attempt in range(n_utc, n_utc + 1) if second_pass else range(n_utc):
        if done:
            break
        if attempt < n_utc:
            q_lo = utc.lo[attempt]
            q_hi = utc.hi[attempt]
            for j in range(n_fwd):
                ut_hits[j] = top_ut.paths[utc.leaf[attempt], j] if j < n_ut else -1
            from_start = Start(utc.s0[attempt], utc.ds0[attempt], utc.pc[attempt])
        else:
            if iopt[I_FALLBACK] == 0:
                break
            q_lo = -qmax
            q_hi = qmax
            for j in range(n_fwd):
                ut_hits[j] = -1
            from_start = start
        n_c = scifi_search(tr, lay, hits, cfg, w, track, from_start, q_lo, q_hi, ut_hits)
        for c in range(n_c):
            ok_c = finalize(tr, lay, hits, cfg, w, track, c, ut_best, n_utc > 0, out)
            final_ok = final_ok or ok_c
            if (
                final_ok
                and pvalue_ok(out.chi2[t], out.ndf[t] + 1, cfg.cuts.good)
                and out.n_scifi[t] >= n_fwd - n_ut - 1
            ):
                done = True  # a good, (nearly) complete extension: no need to look further
                break
    return final_ok, done


@nb.njit(cache=True, **NO_REFCOUNT)
def _valid_state(a, s_v):
    if a < 0:
        return False
    for i in range(4):
        if not np.isfinite(s_v[i]):
            return False
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def extend_kernel(tr, lay, cfg, w, pw, inp, out):
    """Extend every track of inp (`Inputs`) in two passes (module docstring of
    `pkf.seeding.forward`, step 6): the UT starts of every track, then the full-range scan
    for the tracks without an extension, on the SciFi hits no good extension took.
    Writes out (`Output`); all scratch is in w (`Work`) and pw (`PassWork`)."""
    t_ev, t_state, t_layer, lay_off, hu, hsig = inp
    top_ut, utc, start, s_v, ut_best, _, kept, used = pw
    n_fwd = lay.layer.shape[0]
    n_tracks = t_ev.shape[0]
    for step in range(2 * n_tracks):
        second_pass = step >= n_tracks
        t = step - n_tracks if second_pass else step
        if second_pass and not kept.need_scan[t]:
            continue
        hits = Hits(lay_off[t_ev[t]], hu, hsig, used)
        for i in range(4):
            s_v[i] = t_state[t, i]
        s_v[4] = 0.0
        track = Track(t, t_layer[t], s_v)
        if second_pass:
            n_utc = _restore(kept, t, start, ut_best, utc)
        else:
            out.status[t] = STATUS_NOT_FOUND
            for j in range(n_fwd):
                out.hits[t, j] = -1
            if not _valid_state(track.a, s_v) or not ut_start(tr, lay, hits, cfg, w, track, start):
                out.status[t] = STATUS_INVALID
                continue
            n_utc = ut_candidates(tr, lay, hits, cfg, w, track, top_ut, utc, ut_best)
        final_ok, done = _extend(tr, lay, hits, cfg, w, pw, track, n_utc, second_pass, out)
        if not second_pass:
            if final_ok and done and cfg.iopt[I_TAKE_HITS] != 0:
                for j in range(n_fwd):  # a good extension takes its UT and SciFi hits
                    if out.hits[t, j] >= 0:
                        used[out.hits[t, j]] = True
                        w.scan.free_next[out.hits[t, j]] = out.hits[t, j] + 1
            elif not final_ok:
                _keep(kept, t, start, ut_best, utc, n_utc)
            continue
        out.from_scan[t] = final_ok
