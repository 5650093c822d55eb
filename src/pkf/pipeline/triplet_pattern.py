"""The triplet pattern recognition (`--pattern triplet`, DESIGN §7) as one step of a chunk.

VELO tracks from hit triplets (`pkf.seeding.velo_search`), extended through the UT and
the magnet into the SciFi with the parametrized extrapolations
(`pkf.seeding.forward`). Every VELO track becomes a candidate: with its UT and SciFi
hits when the extension found them (a long track), else as a VELO track.
"""

from __future__ import annotations

import numpy as np

from pkf.geometry.detector import Geometry
from pkf.seeding.forward import extend_velo_tracks
from pkf.seeding.velo_search import find_velo_tracks


def triplet_candidates(geometry: Geometry, forward_extrapolator, event_id: np.ndarray, layer: np.ndarray,
                       u: np.ndarray, v: np.ndarray, z: np.ndarray, sigma_u: np.ndarray,
                       sigma_v: np.ndarray):
    """Candidates of the hits of a chunk of events (per-hit arrays, sorted by event).

    Returns (cand_event, cand_track, hit_row) like `truth_candidates`: one entry per
    candidate hit, track ids from 0 within each event.
    """
    velo = find_velo_tracks(event_id, layer, u, v, z, np.column_stack([sigma_u, sigma_v]), geometry)
    n_tracks = velo.event_id.size
    if n_tracks == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty
    state = np.column_stack([velo.x, velo.y, velo.tx, velo.ty])
    forward = extend_velo_tracks(velo.event_id, state, velo.z, event_id, layer, u, sigma_u, geometry,
                                 forward_extrapolator)
    velo_track = np.repeat(np.arange(n_tracks), np.diff(velo.offsets))
    found = forward.found
    fwd_track = forward.track_of_hit
    keep = found[fwd_track]
    track = np.concatenate([velo_track, fwd_track[keep]])
    rows = np.concatenate([velo.hit_rows, forward.hit_rows[keep]])
    order = np.lexsort((rows, track))
    track, rows = track[order], rows[order]
    track_event = velo.event_id[track]
    # track ids from 0 within each event (VELO tracks come sorted by event)
    first_of_event = np.searchsorted(velo.event_id, velo.event_id, side="left")
    track_id = track - first_of_event[track]
    return track_event.astype(np.int64), track_id.astype(np.int64), rows.astype(np.int64)
