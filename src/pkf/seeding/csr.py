"""Track candidates in CSR form: what `VeloTracks` and `ForwardTracks` share."""

from __future__ import annotations

import numpy as np


class CsrTracks:
    """Mixin of a result whose track t has the hits hit_rows[offsets[t]:offsets[t+1]]."""

    offsets: np.ndarray

    @property
    def n_tracks(self) -> int:
        return int(self.offsets.size - 1)

    @property
    def n_hits(self) -> np.ndarray:
        """Number of hits per track."""
        return np.diff(self.offsets)

    @property
    def track_of_hit(self) -> np.ndarray:
        """Track index of each entry of ``hit_rows``."""
        return np.repeat(np.arange(self.n_tracks, dtype=np.int64), self.n_hits)
