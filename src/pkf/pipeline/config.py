"""The options of `pkf reconstruct` that decide its output: `ReconstructionConfig` (docs/cli.md).

Its own module so that the stage (`pkf.pipeline.reconstruct`) and the executors that run
its partitions (`pkf.pipeline.executor`, which rebuilds it from a dict in each worker) both
import it from below, without importing each other.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

from pkf.errors import InputError
from pkf.fit.fitters import Fitter, get_fitter
from pkf.fit.options import FitOptions, GSFOptions, GX2FOptions, KalmanOptions

PATTERNS = ("triplet", "truth")
#: The per-fitter option objects a config holds, by field name.
_FITTER_OPTIONS = {"kalman": KalmanOptions, "gx2f": GX2FOptions, "gsf": GSFOptions}


@dataclass(frozen=True)
class ReconstructionConfig:
    """Every option of `pkf reconstruct` that decides its output (docs/cli.md): the fitters,
    the pattern recognition, the parameter file and geometry, the outlier rejection every
    fitter shares, and each fitter family's own options (`pkf.fit.options`).

    One serialisation: `to_dict` (JSON types, the ``config`` of run.json and what the
    workers receive) and `from_dict` (its inverse)."""

    fitters: tuple[str, ...] = ("parametrized",)
    pattern: str = "triplet"
    params: str | None = None
    outlier_chi2: float = 9.0
    max_outliers: int = 2
    geometry: str | None = None  # --geometry NAME|FILE.toml; None: the one meta.json records
    kalman: KalmanOptions = field(default_factory=KalmanOptions)  # iterations None: each fitter's own
    gx2f: GX2FOptions = field(default_factory=GX2FOptions)
    gsf: GSFOptions = field(default_factory=GSFOptions)
    track_states: bool = False  # --track-states: also write the per-node states of every stage

    def validate(self) -> list[Fitter]:
        if self.pattern not in PATTERNS:
            raise InputError(f"--pattern: unknown pattern {self.pattern!r} (one of {', '.join(PATTERNS)})")
        if not self.outlier_chi2 > 0:
            raise InputError(f"--outlier-chi2: must be > 0, not {self.outlier_chi2}")
        if self.max_outliers < 0:
            raise InputError(f"--max-outliers: must be >= 0, not {self.max_outliers}")
        if len(set(self.fitters)) != len(self.fitters):
            raise InputError("--fitter: a fitter is given twice")
        return [get_fitter(name) for name in self.fitters]

    def fit_options(self, fitter: Fitter) -> FitOptions:
        """The options `fitter` runs with: this config's, with the Kalman passes resolved
        to the fitter's own default (`Fitter.iterations`) when none are given."""
        kalman = replace(self.kalman, iterations=self.kalman.iterations or fitter.iterations)
        return FitOptions(self.outlier_chi2, self.max_outliers, kalman, self.gx2f, self.gsf)

    def to_dict(self) -> dict:
        """Plain JSON types (lists for tuples, a dict per option object)."""
        out = asdict(self)
        out["fitters"] = list(self.fitters)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> ReconstructionConfig:
        """The config `to_dict` gave (extra keys of run.json's ``config`` are ignored)."""
        known = {f.name for f in fields(cls)}
        values = {k: v for k, v in data.items() if k in known}
        values["fitters"] = tuple(values.get("fitters", cls.fitters))
        for name, kind in _FITTER_OPTIONS.items():
            if isinstance(values.get(name), dict):
                values[name] = kind(**values[name])
        return cls(**values)
