"""MC matching of tracks and pattern-recognition metrics (docs/physics.md#matching-and-metrics).

A track is matched to the MC particle that contributed ≥ 70% of its hits, else it is
a ghost; a second track matched to the same particle is a clone.
"""

from __future__ import annotations

import numpy as np

MATCH_FRACTION = 0.7


def match_tracks(track_of_hit: np.ndarray, particle_of_hit: np.ndarray, n_tracks: int):
    """Per track: (mc_particle_id or −1, fraction of hits from the best particle, is_ghost).

    track_of_hit: global track index of each candidate hit; particle_of_hit: the MC
    particle of that hit (0 for noise). Particle ids must be unique across events
    (combine event and particle id before calling).
    """
    best = np.full(n_tracks, -1, dtype=np.int64)
    fraction = np.zeros(n_tracks)
    if track_of_hit.size:
        track, particle, counts = _pair_counts(track_of_hit, particle_of_hit)
        counts = np.where(particle > 0, counts, 0)  # noise never wins
        order = np.lexsort((-counts, track))  # stable: of equal counts the smaller particle id wins
        track, particle, counts = track[order], particle[order], counts[order]
        first = np.ones(track.size, dtype=bool)
        first[1:] = track[1:] != track[:-1]
        n_hits = np.bincount(track_of_hit, minlength=n_tracks)
        tracks = track[first]
        best[tracks] = np.where(counts[first] > 0, particle[first], -1)
        fraction[tracks] = counts[first] / np.maximum(n_hits[tracks], 1)
    matched = fraction >= MATCH_FRACTION
    return np.where(matched, best, -1), fraction, ~matched


def _pair_counts(track_of_hit: np.ndarray, particle_of_hit: np.ndarray):
    """The distinct (track, particle) pairs sorted by track then particle, and their hit counts.

    What ``np.unique(np.column_stack(...), axis=0, return_counts=True)`` returns, from a lexsort
    of the two integer columns and their run lengths: ×5 faster (row-wise ``unique`` sorts
    16-byte records; 800k hits of 32k tracks: 0.74 → 0.15 s), identical output.
    """
    order = np.lexsort((particle_of_hit, track_of_hit))
    track, particle = track_of_hit[order], particle_of_hit[order]
    starts = np.ones(track.size, dtype=bool)
    starts[1:] = (track[1:] != track[:-1]) | (particle[1:] != particle[:-1])
    starts = np.flatnonzero(starts)
    return track[starts], particle[starts], np.diff(np.append(starts, track.size))


def pattern_metrics(matched_particle: np.ndarray, reconstructible: np.ndarray) -> dict:
    """Efficiency, ghost rate and clone rate (docs/physics.md#matching-and-metrics).

    matched_particle: per track, the global id of its matched particle or −1 (ghost).
    reconstructible: global ids of the reconstructible particles.
    """
    n_tracks = matched_particle.size
    real = matched_particle[matched_particle >= 0]
    unique_real = np.unique(real)
    found = np.isin(reconstructible, unique_real)
    return {
        "tracks": int(n_tracks),
        "reconstructible": int(reconstructible.size),
        "efficiency": float(found.mean()) if reconstructible.size else None,
        "ghost_rate": float((matched_particle < 0).mean()) if n_tracks else None,
        "clone_rate": float((real.size - unique_real.size) / real.size) if real.size else None,
    }


def reconstructible_particles(geometry, particle_key: np.ndarray, layer: np.ndarray) -> np.ndarray:
    """Keys of the particles that are reconstructible as long tracks (docs/physics.md#matching-and-metrics).

    Long: ≥ 3 VELO hits and, in each SciFi station, ≥ 1 hit on an x layer (stereo 0)
    and ≥ 1 on a stereo layer. A geometry without SciFi (e.g. the telescope): ≥ 3 hits.
    particle_key: per hit, the particle (0 for noise); layer: per hit.
    """
    from pkf.geometry.detector import SUBDETECTORS

    signal = particle_key > 0
    keys, inverse = np.unique(particle_key[signal], return_inverse=True)
    if keys.size == 0:
        return keys
    lay = layer[signal]
    sub = geometry.layer_subdetector[lay]
    scifi = SUBDETECTORS.index("scifi")
    velo_hits = np.bincount(inverse, weights=sub == SUBDETECTORS.index("velo"), minlength=keys.size)
    stations = np.unique(geometry.layer_station[geometry.layer_subdetector == scifi])
    if stations.size == 0:
        return keys[np.bincount(inverse, minlength=keys.size) >= 3]
    ok = velo_hits >= 3
    is_x = np.abs(geometry.layer_stereo[lay]) < 1e-9
    for station in stations:
        in_station = (sub == scifi) & (geometry.layer_station[lay] == station)
        ok &= np.bincount(inverse, weights=in_station & is_x, minlength=keys.size) >= 1
        ok &= np.bincount(inverse, weights=in_station & ~is_x, minlength=keys.size) >= 1
    return keys[ok]


def velo_reconstructible_particles(geometry, particle_key: np.ndarray, layer: np.ndarray) -> np.ndarray:
    """Keys of the particles with ≥ 3 VELO hits (VELO-track efficiency, docs/physics.md#matching-and-metrics)."""
    from pkf.geometry.detector import SUBDETECTORS

    signal = (particle_key > 0) & (geometry.layer_subdetector[layer] == SUBDETECTORS.index("velo"))
    keys, counts = np.unique(particle_key[signal], return_counts=True)
    return keys[counts >= 3]


def upstream_reconstructible_particles(geometry, particle_key: np.ndarray, layer: np.ndarray) -> np.ndarray:
    """Keys of the particles reconstructible as upstream tracks: ≥ 3 VELO hits and ≥ 3 UT hits
    (docs/physics.md#matching-and-metrics). Empty in a geometry without UT."""
    from pkf.geometry.detector import SUBDETECTORS

    signal = particle_key > 0
    keys, inverse = np.unique(particle_key[signal], return_inverse=True)
    sub = geometry.layer_subdetector[layer[signal]]
    velo_hits = np.bincount(inverse, weights=sub == SUBDETECTORS.index("velo"), minlength=keys.size)
    ut_hits = np.bincount(inverse, weights=sub == SUBDETECTORS.index("ut"), minlength=keys.size)
    return keys[(velo_hits >= 3) & (ut_hits >= 3)]
