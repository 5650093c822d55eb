"""Track candidates as the pattern recognition hands them to the fitters: one CSR container.

Both pattern recognitions (`pkf.pipeline.triplet_pattern`, `pkf.pipeline.truth_pattern`)
return a `Candidates`; `pkf.fit.tracks.TrackBatch.from_candidates` turns it into the
fitters' node arrays, and the run's ``candidates`` table and the MC matching read it as it
is, without regrouping hits into tracks again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Candidates:
    """Track candidates of a chunk of events (CSR).

    event_id, track_id (T, int64): each track's key, tracks ordered by (event, track),
    track ids counting from 0 within an event; offsets (T+1): the hits of track t are
    ``hit_row[offsets[t]:offsets[t+1]]``, rows of the chunk's hit table in the order the
    pattern recognition gave them (the fitters sort them by z).
    """

    event_id: np.ndarray
    track_id: np.ndarray
    offsets: np.ndarray
    hit_row: np.ndarray

    @classmethod
    def from_hit_lists(cls, hit_event: np.ndarray, hit_track: np.ndarray, hit_row: np.ndarray) -> Candidates:
        """From one entry per candidate hit: its (event, track) and row, the hits of a track
        consecutive and tracks ordered by (event, track)."""
        hit_event = np.asarray(hit_event, dtype=np.int64)
        hit_track = np.asarray(hit_track, dtype=np.int64)
        first = np.ones(hit_event.size, dtype=bool)
        first[1:] = (hit_event[1:] != hit_event[:-1]) | (hit_track[1:] != hit_track[:-1])
        starts = np.flatnonzero(first)
        offsets = np.append(starts, hit_event.size).astype(np.int64)
        return cls(hit_event[starts], hit_track[starts], offsets, np.asarray(hit_row, dtype=np.int64))

    @classmethod
    def empty(cls) -> Candidates:
        none = np.zeros(0, dtype=np.int64)
        return cls(none, none, np.zeros(1, dtype=np.int64), none)

    @property
    def n_tracks(self) -> int:
        return self.event_id.size

    @property
    def n_hits(self) -> np.ndarray:
        """Hits per track (T)."""
        return np.diff(self.offsets)

    @property
    def track_of_hit(self) -> np.ndarray:
        """Index (0..T−1) of the track of each candidate hit."""
        return np.repeat(np.arange(self.n_tracks), self.n_hits)

    @property
    def hit_event(self) -> np.ndarray:
        """Event of each candidate hit."""
        return np.repeat(self.event_id, self.n_hits)

    @property
    def hit_track(self) -> np.ndarray:
        """Track id (within its event) of each candidate hit."""
        return np.repeat(self.track_id, self.n_hits)
