"""Compiled passes of a batch's work outside the pattern and fit kernels (issue 18.4).

MC matching, reconstructibility, truth and run-table rows of `pkf.pipeline.batch` were
numpy expressions that each made several passes over the hits or tracks of a batch (sorts,
unique, boolean masks, fancy indexing per column). Here each is one pass that writes into
arrays its caller allocates (`pkf.jit.NO_REFCOUNT`: no allocation inside), with the same
integer and float operations as the numpy expressions they replace, so the outputs are
bitwise identical (`benchmarks/table_hashes.py`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pkf.io.schemas import PARTICLE_KEY_BASE
from pkf.jit import NO_REFCOUNT

#: (row, column) of each of the 15 covariance columns c00 … c44 (`pkf.io.schemas.COV_COLUMNS`).
COV_ROW, COV_COL = (np.asarray(a, dtype=np.int64) for a in np.triu_indices(5))


@nb.njit(cache=True, **NO_REFCOUNT)
def hit_keys(event_id, particle_id, out):
    """out[i] = `pkf.io.schemas.particle_key` (event_id[i], particle_id[i]): zigzag(event)·2²⁴ +
    particle id where the particle id is > 0, else 0 (noise)."""
    for i in range(event_id.size):
        p = np.int64(particle_id[i])
        if p > 0:
            e = np.int64(event_id[i])
            z = 2 * e if e >= 0 else -2 * e - 1
            out[i] = z * PARTICLE_KEY_BASE + p
        else:
            out[i] = 0


@nb.njit(cache=True, **NO_REFCOUNT)
def equal(a, b) -> bool:
    """``np.array_equal`` of two 1-D arrays, stopping at the first difference (no temporary mask)."""
    if a.size != b.size:
        return False
    for i in range(a.size):
        if a[i] != b[i]:
            return False
    return True


@nb.njit(inline="always")
def _slot(key, mask):
    """Open-addressing slot of a particle key (Fibonacci hashing; int64 products wrap)."""
    h = (key ^ (key >> 29)) * -7046029254386353131
    return (h ^ (h >> 32)) & mask


@nb.njit(cache=True)
def particle_column_counts(key, layer, column_of_layer, n_columns):
    """Hits per particle and layer column: (keys, counts), the distinct keys > 0 of ``key`` in order
    of first appearance and counts (len(keys), n_columns) of their hits with
    ``column_of_layer[layer]`` = c. One pass through an open-addressing table of the keys
    (``np.unique(..., return_inverse=True)`` sorted all the hits' keys)."""
    size = 4
    while size < 2 * key.size:
        size *= 2
    mask = size - 1
    table = np.full(size, -1, np.int64)
    keys = np.empty(key.size, np.int64)
    index = np.full(key.size, -1, np.int64)
    n = 0
    for i in range(key.size):
        k = key[i]
        if k <= 0:
            continue
        h = _slot(k, mask)
        while table[h] >= 0 and keys[table[h]] != k:
            h = (h + 1) & mask
        if table[h] < 0:
            table[h] = n
            keys[n] = k
            n += 1
        index[i] = table[h]
    counts = np.zeros((n, n_columns), np.int64)
    for i in range(key.size):
        if index[i] >= 0:
            counts[index[i], column_of_layer[layer[i]]] += 1
    return keys[:n].copy(), counts


@nb.njit(inline="always")
def _insert(sorted_ids, m, p) -> None:
    """Insert p into the ascending sorted_ids[:m] (insertion sort: a track has tens of hits)."""
    j = m
    while j > 0 and sorted_ids[j - 1] > p:
        sorted_ids[j] = sorted_ids[j - 1]
        j -= 1
    sorted_ids[j] = p


@nb.njit(inline="always")
def _most_frequent(sorted_ids, m):
    """(id, count) of the most frequent of the ascending sorted_ids[:m], of equal counts the smaller
    id (as `pkf.pipeline.matching.match_tracks`); (−1, 0) if m = 0."""
    top, top_count, run = -1, 0, 0
    for j in range(m):
        run = run + 1 if j > 0 and sorted_ids[j] == sorted_ids[j - 1] else 1
        if (j + 1 == m or sorted_ids[j + 1] != sorted_ids[j]) and run > top_count:
            top, top_count = sorted_ids[j], run
    return top, top_count


@nb.njit(cache=True, **NO_REFCOUNT)
def match_grouped(track_of_hit, particle_of_hit, scratch, best, count, n_hits) -> bool:
    """Per track of hits grouped by track (``track_of_hit`` nondecreasing): its most frequent particle
    > 0 (``best``, of equal counts the smaller id; −1 if none), that particle's hits (``count``) and
    the track's hits (``n_hits``); ``best``/``count``/``n_hits`` come −1/0/0-filled. False, and
    nothing meaningful written, if the hits are not grouped. ``scratch``: as long as a track's hits."""
    n = track_of_hit.size
    a = 0
    while a < n:
        t = track_of_hit[a]
        b = a + 1
        while b < n and track_of_hit[b] == t:
            b += 1
        if b < n and track_of_hit[b] < t:
            return False
        m = 0
        for i in range(a, b):
            if particle_of_hit[i] > 0:
                _insert(scratch, m, particle_of_hit[i])
                m += 1
        best[t], count[t] = _most_frequent(scratch, m)
        n_hits[t] = b - a
        a = b
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def match_candidates(offsets, cand_row, hit_key, layer, layer_subdetector, velo, scifi, scratch, matches):
    """Both matchings of a batch's candidates (track t: hits ``cand_row[offsets[t]:offsets[t + 1]]``)
    in one pass: per track into ``matches`` (7, T), rows 0–2 the most frequent particle key > 0 of
    all its hits (−1 if none), its hits and the track's hits; rows 3–5 the same over its hits on
    subdetector ``velo``; row 6 1 where it has a hit on subdetector ``scifi``. As
    `pkf.pipeline.matching.match_tracks` of all hits and of the VELO hits, without gathering the
    hits' keys and subdetectors and selecting the VELO ones first. ``scratch`` (2, longest track)."""
    for t in range(offsets.size - 1):
        m = mv = n_velo = 0
        long = 0
        for i in range(offsets[t], offsets[t + 1]):
            r = cand_row[i]
            k = hit_key[r]
            s = layer_subdetector[layer[r]]
            if s == scifi:
                long = 1
            if s == velo:
                n_velo += 1
                if k > 0:
                    _insert(scratch[1], mv, k)
                    mv += 1
            if k > 0:
                _insert(scratch[0], m, k)
                m += 1
        matches[0, t], matches[1, t] = _most_frequent(scratch[0], m)
        matches[2, t] = offsets[t + 1] - offsets[t]
        matches[3, t], matches[4, t] = _most_frequent(scratch[1], mv)
        matches[5, t] = n_velo
        matches[6, t] = long


@nb.njit(cache=True, **NO_REFCOUNT)
def subdetector_counts(offsets, layer, layer_subdetector, active, out):
    """out[s, t] += 1 for each active node of track t (nodes ``offsets[t]:offsets[t + 1]``) on a
    layer of subdetector s (`pkf.geometry.detector.SUBDETECTORS`); ``out`` zeroed."""
    n_sub = out.shape[0]
    for t in range(offsets.size - 1):
        for node in range(offsets[t], offsets[t + 1]):
            s = layer_subdetector[layer[node]]
            if active[node] and 0 <= s < n_sub:
                out[s, t] += 1


@nb.njit(cache=True, **NO_REFCOUNT)
def state_columns(rows, z, state, cov, out):
    """The ``states`` columns of tracks ``rows``: out[0] = z, out[1:6] the five state parameters,
    out[6:21] the covariance's upper triangle row-major (`pkf.io.schemas.pack_covariance`)."""
    for k in range(rows.size):
        r = rows[k]
        out[0, k] = z[r]
        for i in range(5):
            out[1 + i, k] = state[r, i]
        c = 6
        for i in range(5):
            for j in range(i, 5):
                out[c, k] = cov[r, i, j]
                c += 1


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def pull_columns(rows, state, cov, truth, out):
    """The ``pulls`` columns of tracks ``rows`` against ``truth`` (len(rows), 5): out[0] = p_true =
    1/|q/p true|, out[1 + i] = res_i = state − truth, out[6 + i] = pull_i = res_i / σ_i with
    σ_i = √max(C_ii, 0) (NaN C_ii stays NaN, as numpy's maximum). IEEE division as numpy's
    (``error_model="numpy"``: σ = 0 gives ±inf or NaN, not ZeroDivisionError)."""
    for k in range(rows.size):
        r = rows[k]
        out[0, k] = 1.0 / np.abs(truth[k, 4])
        for i in range(5):
            res = state[r, i] - truth[k, i]
            c = cov[r, i, i]
            out[1 + i, k] = res
            out[6 + i, k] = res / np.sqrt(c if (c > 0.0 or c != c) else 0.0)
