"""Track candidates as the pattern recognition hands them to the fitters: one CSR container.

Both pattern recognitions (`pkf.pipeline.triplet_pattern`, `pkf.pipeline.truth_pattern`)
return a `Candidates`; `pkf.fit.tracks.TrackBatch.from_candidates` turns it into the
fitters' node arrays, and the run's ``candidates`` table and the MC matching read it as it
is, without regrouping hits into tracks again.

A pattern recognition that estimates the track's state hands it over with the hits
(`Candidates.state`, `state_z`, `qop_var`): the triplet pattern gives the straight-line
state of the VELO fit at the first hit and, for the tracks its forward extension carried
into the SciFi, the extension's q/p (at production) and its variance; the fit seeds from
them (`pkf.fit.seed.pattern_seed`). NaN where the pattern has no estimate (the q/p of
VELO-only tracks); the truth pattern has none (None): it only groups hits, and a state
from the truth would be a seed no real pattern recognition could give.
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

    The pattern's estimate, per track, or None if the pattern gives none (module
    docstring): state (T, 5) = (x, y [mm], tx, ty, q/p [1/MeV]) at z = state_z (T) [mm],
    q/p at production (the parametrized convention, docs/physics.md#the-parametrized-fitter),
    and qop_var (T) [1/MeV²] its variance; NaN entries where the pattern has no estimate
    of that parameter (e.g. the q/p of a VELO-only track).
    """

    event_id: np.ndarray
    track_id: np.ndarray
    offsets: np.ndarray
    hit_row: np.ndarray
    state: np.ndarray | None = None
    state_z: np.ndarray | None = None
    qop_var: np.ndarray | None = None

    def __post_init__(self):
        given = [a is not None for a in (self.state, self.state_z, self.qop_var)]
        if any(given) and not all(given):
            raise ValueError("Candidates: state, state_z and qop_var come together")
        if all(given) and (self.state.shape != (self.n_tracks, 5) or self.state_z.shape != (self.n_tracks,)
                           or self.qop_var.shape != (self.n_tracks,)):
            raise ValueError("Candidates: state (T, 5), state_z (T) and qop_var (T) for T tracks")

    @classmethod
    def from_hit_lists(cls, hit_event: np.ndarray, hit_track: np.ndarray, hit_row: np.ndarray,
                       state: np.ndarray | None = None, state_z: np.ndarray | None = None,
                       qop_var: np.ndarray | None = None) -> Candidates:
        """From one entry per candidate hit: its (event, track) and row, the hits of a track
        consecutive and tracks ordered by (event, track); the pattern's estimate (state,
        state_z, qop_var: one entry per track in the same order, or None) as the fields."""
        hit_event = np.asarray(hit_event, dtype=np.int64)
        hit_track = np.asarray(hit_track, dtype=np.int64)
        first = np.ones(hit_event.size, dtype=bool)
        first[1:] = (hit_event[1:] != hit_event[:-1]) | (hit_track[1:] != hit_track[:-1])
        starts = np.flatnonzero(first)
        offsets = np.append(starts, hit_event.size).astype(np.int64)
        if state is not None:
            state = np.asarray(state, dtype=np.float64)
            state_z = np.asarray(state_z, dtype=np.float64)
            qop_var = np.asarray(qop_var, dtype=np.float64)
        return cls(hit_event[starts], hit_track[starts], offsets, np.asarray(hit_row, dtype=np.int64),
                   state, state_z, qop_var)

    @property
    def has_estimate(self) -> bool:
        """Whether the pattern handed over its state estimate (it may still be NaN per track)."""
        return self.state is not None

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
