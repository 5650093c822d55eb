"""The options of `pkf reconstruct` that decide its output: `ReconstructionConfig` (docs/cli.md).

Its own module so that the stage (`pkf.pipeline.reconstruct`) and the executors that run
its partitions (`pkf.pipeline.executor`, which rebuilds it from a dict in each worker) both
import it from below, without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass

from pkf.errors import InputError
from pkf.fit.fitters import Fitter, get_fitter

PATTERNS = ("triplet", "truth")


@dataclass(frozen=True)
class ReconstructionConfig:
    """Every option of `pkf reconstruct` that decides its output (docs/cli.md)."""

    fitters: tuple[str, ...] = ("parametrized",)
    pattern: str = "triplet"
    params: str | None = None
    outlier_chi2: float = 9.0
    max_outliers: int = 2
    iterations: int | None = None  # None: each fitter's own (Fitter.iterations)
    max_components: int = 12
    geometry: str | None = None  # --geometry NAME|FILE.toml; None: the one meta.json records
    track_states: bool = False  # --track-states: also write the per-node states of every stage

    def validate(self) -> list[Fitter]:
        if self.pattern not in PATTERNS:
            raise InputError(f"--pattern: unknown pattern {self.pattern!r} (one of {', '.join(PATTERNS)})")
        if not self.outlier_chi2 > 0:
            raise InputError(f"--outlier-chi2: must be > 0, not {self.outlier_chi2}")
        if self.max_outliers < 0:
            raise InputError(f"--max-outliers: must be >= 0, not {self.max_outliers}")
        if self.iterations is not None and self.iterations < 1:
            raise InputError(f"--iterations: must be >= 1, not {self.iterations}")
        if len(set(self.fitters)) != len(self.fitters):
            raise InputError("--fitter: a fitter is given twice")
        return [get_fitter(name) for name in self.fitters]
