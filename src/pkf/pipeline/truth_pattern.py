"""Ideal pattern recognition (`--pattern truth`): the hits of each MC particle form a track.

For fit studies: every particle with hits on at least three layers becomes a candidate,
with at most one hit per layer (the first by hit_id). Noise hits belong to no candidate.
Only the grouping uses MC truth; the fit's seed comes from the hits alone.
"""

from __future__ import annotations

import numpy as np

from pkf.fit.candidates import Candidates

MIN_HITS = 3


def truth_candidates(event_id: np.ndarray, layer: np.ndarray, particle_id: np.ndarray):
    """Group hit rows by (event, particle).

    Arguments are per hit (hits and their MC particle, aligned). Returns the
    `Candidates`, track ids counting from 0 within each event in order of particle id.
    """
    rows = np.flatnonzero(particle_id > 0)
    order = np.lexsort((rows, layer[rows], particle_id[rows], event_id[rows]))
    rows = rows[order]
    ev, pid, lay = event_id[rows], particle_id[rows], layer[rows]
    first_on_layer = np.ones(rows.size, dtype=bool)
    first_on_layer[1:] = (ev[1:] != ev[:-1]) | (pid[1:] != pid[:-1]) | (lay[1:] != lay[:-1])
    rows, ev, pid = rows[first_on_layer], ev[first_on_layer], pid[first_on_layer]
    new_group = np.ones(rows.size, dtype=bool)
    new_group[1:] = (ev[1:] != ev[:-1]) | (pid[1:] != pid[:-1])
    group = np.cumsum(new_group) - 1
    size = np.bincount(group)
    keep = size[group] >= MIN_HITS
    rows, ev, group = rows[keep], ev[keep], group[keep]
    # renumber groups per event: 0, 1, 2, ...
    new_group = np.ones(rows.size, dtype=bool)
    new_group[1:] = group[1:] != group[:-1]
    new_event = np.ones(rows.size, dtype=bool)
    new_event[1:] = ev[1:] != ev[:-1]
    global_index = np.cumsum(new_group) - 1
    event_start_index = np.maximum.accumulate(np.where(new_event, global_index, 0))
    return Candidates.from_hit_lists(ev, global_index - event_start_index, rows)
