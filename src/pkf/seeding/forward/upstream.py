"""Upstream tracks (VELO + UT, no SciFi extension): the third pass of the forward extension (step 5).

A VELO track without a SciFi extension keeps the UT hits of its best UT candidate if they
pass the UT outlier check against its VELO + UT fit (`ut.clean_upstream`). The UT search
of the first pass runs before most long tracks of the event are found, so its best
candidate is often the UT hits of *another* particle's long track: on 60 minimum-bias
events at ν = 7.6 (issue 15), of the 1,383 real upstream tracks 95 held four foreign UT
hits (78 of them the UT hits of a long track, 84 while the particle's own four UT hits
were in the event), mostly below 1.5 GeV, and the fitters' χ²/ndf of those was ≈ 11 (the
VELO→UT kink of another particle). Hence this pass runs after both passes, when every
long track is known: the UT hits of every accepted long track (status ok) are taken, the
UT search (step 1) runs again on the hits left for each track without an extension, and
its best candidate goes through the UT outlier check (neighbour cut
``upstream_ambiguous_chi2``) and must keep `UPSTREAM_MIN_UT_HITS` UT hits and a p-value ≥
``upstream_pvalue`` of its VELO + UT fit, else the track stays a VELO track
(STATUS_NO_SCIFI, n_ut = 0). Units: mm, 1/MeV.
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT
from pkf.seeding.forward.options import I_TAKE_HITS, I_UT_MIN, STATUS_INVALID, STATUS_NO_SCIFI, STATUS_NOT_FOUND, STATUS_OK
from pkf.seeding.forward.records import Hits, Track
from pkf.seeding.forward.ut import clean_upstream, ut_candidates, ut_start

UPSTREAM_MIN_UT_HITS = 4
"""UT hits an upstream track needs after the UT outlier check (`_upstream`). Measured on 60
minimum-bias events at ν = 7.6 (issue 15): after the check, upstream candidates with 3 UT
hits carry a UT hit of another particle in 39 % of cases, those with 4 in 10.5 %."""


@nb.njit(cache=True, **NO_REFCOUNT)
def _upstream(tr, lay, hits, cfg, w, track, out, utc, ut_best):
    """Track t as an upstream track: the best UT candidate's hits after the UT outlier check
    (`ut.clean_upstream`), q/p from the VELO→UT kink; with fewer than ``ut_min_hits`` or
    `UPSTREAM_MIN_UT_HITS` UT hits left, or a χ² above the ``upstream_pvalue`` cut (ndf =
    hits − 1), it stays a VELO track (STATUS_NO_SCIFI, no UT hits, n_ut = 0)."""
    n_ut = lay.n_ut
    t = track.t
    out.status[t] = STATUS_NO_SCIFI
    n_h, chi_c, q_c, v_c = clean_upstream(tr, lay, hits, cfg, w, track, utc.q[0], utc.var[0], ut_best)
    if n_h < max(cfg.iopt[I_UT_MIN], UPSTREAM_MIN_UT_HITS) or chi_c > cfg.cuts.upstream[n_h]:
        return
    path = w.leaf_c.path
    out.q[t] = q_c
    out.qvar[t] = v_c
    out.chi2[t] = chi_c
    out.ndf[t] = n_h - 1
    for j in range(n_ut):
        out.hits[t, j] = path[j]
        out.ut_chi2[t, j] = w.smooth.chi2[j]
    out.n_ut[t] = n_h


@nb.njit(cache=True, **NO_REFCOUNT)
def _take_long_ut_hits(lay, out, used):
    """Mark the UT hits of every long track with UT hits (status ok) as taken."""
    for t in range(out.status.shape[0]):
        if out.status[t] == STATUS_OK:
            for j in range(lay.n_ut):
                if out.hits[t, j] >= 0:
                    used[out.hits[t, j]] = True


@nb.njit(cache=True, **NO_REFCOUNT)
def _search_upstream(tr, lay, cfg, w, pw, inp, out, t):
    """The UT search (step 1) for track t on the hits not taken and, with a UT candidate,
    `_upstream`."""
    t_ev, t_state, t_layer, lay_off, hu, hsig = inp
    top_ut, utc, start, s_v, ut_best, _, _, used = pw
    hits = Hits(lay_off[t_ev[t]], hu, hsig, used)
    for i in range(4):
        s_v[i] = t_state[t, i]
    s_v[4] = 0.0
    track = Track(t, t_layer[t], s_v)
    if not ut_start(tr, lay, hits, cfg, w, track, start):
        out.status[t] = STATUS_INVALID
        return
    if ut_candidates(tr, lay, hits, cfg, w, track, top_ut, utc, ut_best) > 0:
        _upstream(tr, lay, hits, cfg, w, track, out, utc, ut_best)


@nb.njit(cache=True, **NO_REFCOUNT)
def _clear(out, t, n_ut):
    """Track t back to a VELO track without a UT candidate (status not found)."""
    out.status[t] = STATUS_NOT_FOUND
    out.q[t] = math.nan
    out.qvar[t] = math.nan
    out.chi2[t] = math.nan
    out.ndf[t] = 0
    out.n_ut[t] = 0
    for j in range(n_ut):
        out.hits[t, j] = -1
        out.ut_chi2[t, j] = math.nan


@nb.njit(cache=True, **NO_REFCOUNT)
def _claim(lay, out, owner):
    """owner[h]: the upstream track with the lowest χ² among those holding UT hit h."""
    for t in range(out.status.shape[0]):
        if out.n_ut[t] > 0 and out.status[t] == STATUS_NO_SCIFI:
            for j in range(lay.n_ut):
                h = out.hits[t, j]
                if h >= 0 and (owner[h] < 0 or out.chi2[t] < out.chi2[owner[h]]):
                    owner[h] = t


@nb.njit(cache=True, **NO_REFCOUNT)
def _owns_all(lay, out, owner, t):
    for j in range(lay.n_ut):
        h = out.hits[t, j]
        if h >= 0 and owner[h] != t:
            return False
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def upstream_pass(tr, lay, cfg, w, pw, inp, out, owner):
    """The third pass (module docstring), after `kernel.extend_kernel`: the long tracks take
    their UT hits; every track without an extension (status not found) gets the UT search on
    the hits left and, with a UT candidate, becomes an upstream track (`_upstream`). A UT
    hit held by two upstream tracks belongs to the one with the lower χ² (owner (hits),
    −1 on entry): the tracks that own all their hits take them, the others search again
    on the hits left. Without take_hits nothing is taken (each track on its own)."""
    used = pw.used
    n_ut = lay.n_ut
    n_tracks = out.status.shape[0]
    take = cfg.iopt[I_TAKE_HITS] != 0
    if take:
        _take_long_ut_hits(lay, out, used)
    for t in range(n_tracks):
        if out.status[t] == STATUS_NOT_FOUND:
            _search_upstream(tr, lay, cfg, w, pw, inp, out, t)
    if not take:
        return
    _claim(lay, out, owner)
    for t in range(n_tracks):
        if out.n_ut[t] > 0 and out.status[t] == STATUS_NO_SCIFI and _owns_all(lay, out, owner, t):
            for j in range(n_ut):
                if out.hits[t, j] >= 0:
                    used[out.hits[t, j]] = True
    for t in range(n_tracks):
        if out.n_ut[t] > 0 and out.status[t] == STATUS_NO_SCIFI and not _owns_all(lay, out, owner, t):
            _clear(out, t, n_ut)
            _search_upstream(tr, lay, cfg, w, pw, inp, out, t)
