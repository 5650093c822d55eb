"""The triplet pattern recognition (`--pattern triplet`, docs/physics.md#pattern-recognition) as one step of a chunk.

VELO tracks from hit triplets (`pkf.seeding.velo_search`), extended through the UT and
the magnet into the SciFi with the parametrized extrapolations
(`pkf.seeding.forward`). Every VELO track becomes a candidate: with its UT and SciFi
hits when the extension found them (a long track), with its UT hits when only those were
found (an upstream track: no SciFi extension, ≥ 4 UT hits that pass the UT outlier check,
q/p from the VELO→UT kink), else as a VELO track.

Occupancy and interrupts. Both searches open windows of fixed size around every seed,
so their cost per hit grows with the hit density (lhcb-like minimum bias, CPU of one
core: 2.9 µs per hit at ν = 7.6 (`benchmarks/pattern_recognition.py`, 50 events; 3.2 µs
before the UT outlier check's smoother lost its inverses), 15 µs in events of 26–33k hits
at ν = 30, 23 µs in one of 51k hits, the forward extension's full-range scans most of it;
a ν = 1000 event of 1.07 M hits ran for minutes and took 60 s to answer a Ctrl-C). An
event with more than `MAX_EVENT_HITS` hits (50,000: 2.3× the largest of 120 events at
ν = 7.6, about ν = 40, where a hit costs ≈ 7× as much as at ν = 7.6) is therefore not searched: it gets no
candidates and is counted (`crowded_events`; `pkf reconstruct` reports it in run.json
``counts.events_over_hit_limit`` and on stderr). The other events are searched in groups
of at most `GROUP_HITS` hits, whole events each (the result of an event depends only on
its own hits, so the candidates are the same; 120 events at ν = 7.6: identical
candidates table, CPU +1 %): the compiled kernels cannot be interrupted, and between
groups Python sees a Ctrl-C (a group is ≲ 0.2 s at ν = 7.6, ≲ 1.2 s at the limit).
"""

from __future__ import annotations

import numpy as np

from pkf.fit.candidates import Candidates
from pkf.geometry.detector import Geometry
from pkf.io.row_order import group_sort_order
from pkf.seeding.forward import extend_velo_tracks
from pkf.seeding.velo_search import find_velo_tracks

#: Events with more hits than this are not searched (module docstring).
MAX_EVENT_HITS = 50_000
#: Whole events are searched in groups of at most this many hits (one event may exceed it).
GROUP_HITS = 50_000


def crowded_events(event_id: np.ndarray, max_event_hits: int | None = None) -> np.ndarray:
    """Event ids (sorted) of the events with more than `max_event_hits` (default
    `MAX_EVENT_HITS`) hits; event_id: per hit."""
    max_event_hits = MAX_EVENT_HITS if max_event_hits is None else max_event_hits
    events, counts = np.unique(event_id, return_counts=True)
    return events[counts > max_event_hits]


def _event_groups(event_id: np.ndarray, group_hits: int) -> list[tuple[int, int]]:
    """Row ranges [lo, hi) of whole events (rows sorted by event), each of at most
    `group_hits` rows unless one event alone has more."""
    starts = np.flatnonzero(np.r_[True, event_id[1:] != event_id[:-1]])
    ends = np.r_[starts[1:], event_id.size]
    groups = []
    lo = 0
    for start, end in zip(starts.tolist(), ends.tolist()):
        if end - lo > group_hits and start > lo:
            groups.append((lo, start))
            lo = start
    if event_id.size:
        groups.append((lo, event_id.size))
    return groups


def _group_candidates(geometry, forward_extrapolator, event_id, layer, u, v, z, sigma_u, sigma_v):
    """`triplet_candidates` of one group of whole events (rows index the group's arrays):
    per hit (event, track id, row) and per track, in the same order, the pattern's state
    (T, 5) at state_z (T) and its q/p variance (T) (`_pattern_estimate`)."""
    velo = find_velo_tracks(event_id, layer, u, v, z, np.column_stack([sigma_u, sigma_v]), geometry)
    n_tracks = velo.event_id.size
    if n_tracks == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty, np.zeros((0, 5)), np.zeros(0), np.zeros(0)
    state = np.column_stack([velo.x, velo.y, velo.tx, velo.ty])
    forward = extend_velo_tracks(
        velo.event_id, state, velo.z, event_id, layer, u, sigma_u, geometry, forward_extrapolator
    )
    velo_track = np.repeat(np.arange(n_tracks), np.diff(velo.offsets))
    fwd_track = forward.track_of_hit
    keep = (forward.found | forward.upstream)[fwd_track]
    track = np.concatenate([velo_track, fwd_track[keep]])
    rows = np.concatenate([velo.hit_rows, forward.hit_rows[keep]])
    order, _ = group_sort_order(track, rows, n_tracks)  # = np.lexsort((rows, track))
    track, rows = track[order], rows[order]
    track_event = velo.event_id[track]
    # track ids from 0 within each event (VELO tracks come sorted by event)
    first_of_event = np.searchsorted(velo.event_id, velo.event_id, side="left")
    track_id = track - first_of_event[track]
    return (
        track_event.astype(np.int64),
        track_id.astype(np.int64),
        rows.astype(np.int64),
        *_pattern_estimate(velo, forward),
    )


def _pattern_estimate(velo, forward):
    """The state the pattern hands to the fit, per VELO track (every VELO track is a
    candidate, in this order): (x, y, tx, ty) of the VELO straight-line fit at its first
    hit (z) and, where the forward extension carried it into the SciFi, the extension's
    q/p (at production) and variance, for upstream tracks the q/p of the VELO→UT kink and
    its variance; NaN q/p for VELO tracks (the hits of an extension that was not accepted
    are not in the candidate)."""
    found = forward.found | forward.upstream
    qop = np.where(found, forward.qop, np.nan)
    qop_var = np.where(found, forward.qop_var, np.nan)
    state = np.column_stack([velo.x, velo.y, velo.tx, velo.ty, qop])
    return state, np.asarray(velo.z, dtype=np.float64), qop_var


def triplet_candidates(
    geometry: Geometry,
    forward_extrapolator,
    event_id: np.ndarray,
    layer: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    z: np.ndarray,
    sigma_u: np.ndarray,
    sigma_v: np.ndarray,
    max_event_hits: int | None = None,
    group_hits: int | None = None,
):
    """Candidates of the hits of a chunk of events (per-hit arrays, sorted by event).

    Returns the `Candidates` (as `truth_candidates`, with the pattern's state estimate,
    `_pattern_estimate`), track ids from 0 within each event. Events with more than
    `max_event_hits` (`MAX_EVENT_HITS`) hits get none (`crowded_events`); the others are
    searched in groups of whole events of at most `group_hits` (`GROUP_HITS`) hits
    (module docstring).
    """
    group_hits = GROUP_HITS if group_hits is None else group_hits
    event_id = np.asarray(event_id)
    searched = ~np.isin(event_id, crowded_events(event_id, max_event_hits))
    rows_searched = np.flatnonzero(searched) if not searched.all() else None
    columns = [np.asarray(c) for c in (event_id, layer, u, v, z, sigma_u, sigma_v)]
    if rows_searched is not None:
        columns = [c[rows_searched] for c in columns]
    parts = []
    for lo, hi in _event_groups(columns[0], group_hits):
        ev, tr, rows, state, state_z, qop_var = _group_candidates(
            geometry, forward_extrapolator, *(c[lo:hi] for c in columns)
        )
        parts.append((ev, tr, rows + lo, state, state_z, qop_var))
    if not parts:
        return Candidates.empty()
    cand_event, cand_track, rows, state, state_z, qop_var = (np.concatenate(p) for p in zip(*parts))
    if rows_searched is not None:
        rows = rows_searched[rows]
    return Candidates.from_hit_lists(cand_event, cand_track, rows, state, state_z, qop_var)
