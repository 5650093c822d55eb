"""The fitters `pkf reconstruct --fitter` knows: an extrapolator context and a fit function.

A `Fitter` says how to build its extrapolator for a geometry, which q/p its states
carry: the local momentum (reference fitter, which applies energy loss) or the
momentum at production (the parametrized fitter, paper §3), which decides the truth
its pulls are computed against, and which fit function runs it: the one Kalman core
(`fit_batch`) for the Kalman fitters, `fit_batch_gx2f` for the global χ² fitter (on the
reference extrapolator) and `fit_batch_gsf` for the Gaussian-sum filter (electron
hypothesis, docs/physics.md#the-global-χ²-fitter-gx2f). Every fit function has the signature
``fit(extrapolator, batch, options, seeds, seed_covs, beamline_extrapolator, track_states=False)
-> FitResult``; with ``track_states=True`` the result's ``track_states`` holds every node's
predicted, filtered and smoothed states (`pkf.fit.tracks.TrackStates`; the GX2F: smoothed only).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from pkf.errors import InputError, NotBuiltYet
from pkf.fit.gsf import fit_batch_gsf, gsf_extrapolator
from pkf.fit.gx2f import fit_batch_gx2f
from pkf.fit.hypothesis import with_hypothesis
from pkf.fit.reference import reference_extrapolator
from pkf.fit.tracks import fit_batch
from pkf.geometry.detector import Geometry


@dataclass(frozen=True)
class Fitter:
    """A named fitter: `make_extrapolator(geometry, params)`, its q/p convention, its fit
    function (default: the Kalman core's `fit_batch`) and `iterations`, the number of
    Kalman passes it needs when `--iterations` is not given (see `REFERENCE_ITERATIONS`)."""

    name: str
    make_extrapolator: Callable
    qop_at_production: bool
    iterations: int = 1
    fit: Callable = fit_batch

    def extrapolator(self, geometry: Geometry, params=None, hypothesis: str = "pion"):
        """`make_extrapolator(geometry, params)` under the Kalman fitters' particle
        `hypothesis` (`KalmanOptions.hypothesis`, `pkf.fit.hypothesis.with_hypothesis`); the
        GX2F (pion) and the GSF (electron, with the full Bethe–Heitler mixture) keep their own."""
        extrapolator = self.make_extrapolator(geometry, params)
        if self.fit is fit_batch:
            extrapolator = with_hypothesis(extrapolator, geometry, hypothesis)
        return extrapolator


#: Passes of the reference Kalman fitter by default. One pass linearises the RK4 transport
#: through the magnet at the seed's q/p; for 2–5 GeV tracks whose seed is 5–15 % off that
#: is not the χ² minimum. Measured on lhcb-like π gun long tracks, 2–5 GeV (three samples
#: of 940–1400; `python benchmarks/gsf_components.py`, section 3): with 2 passes the
#: first-hit q/p moves from 1.0–1.06σ RMS (max 15–21σ) to 0.02–0.05σ RMS from the GX2F's
#: χ² minimum, the δp/p core at 2–2.5 GeV narrows from 0.27 % to 0.17–0.18 %, and the q/p
#: pull core from 1.15–1.17 to 1.01–1.05; a third pass changes nothing (≤ 0.03σ). Cost:
#: ×1.7–2.1 the reference fit's time (½ of the GX2F's).
REFERENCE_ITERATIONS = 2

#: Passes of the parametrized fitter by default, for the same reason. With one pass its q/p
#: pulls were too wide wherever the seed's q/p is far from the fit's: measured on 15 minimum-
#: bias events at ν = 7.6 (triplet pattern, 3,208 real long tracks, `benchmarks/fit_quality.py`),
#: first-hit q/p pull core 1 → 2 passes: 1.33 → 1.01 at 1.5–3 GeV, 1.10 → 1.04 at 3–5, 1.04 →
#: 1.03 at 5–10, 1.01 → 1.00 at 10–100 GeV; δp/p core 0.283 → 0.203 % at 1.5–3 GeV (reference
#: 0.191 %), 0.237 → 0.217 % at 3–5 GeV (reference 0.219 %). On a 1.5–2.6 GeV π gun (341 long
#: tracks): q/p pull 1.63 → 1.02, δp/p 0.295 → 0.207 % (reference 0.176 %). Cost: ×1.5–1.7 the
#: parametrized fit's time. Seeding from the pattern's q/p (`pkf.fit.seed.pattern_seed`, 0.21 %
#: median error instead of the least-squares 0.65 %) does not make one pass enough: 60 events at
#: ν = 7.6 (seed 31, 12,765 real long tracks), q/p pull core 1 → 2 passes 1.14 → 1.07 at 1.5–3 GeV,
#: 1.11 → 1.07 at 3–5, 1.06 → 1.06 at 5–10, 0.99 → 0.99 at 10–100; δp/p core 0.235 → 0.221 %,
#: 0.238 → 0.232 %; the first-hit q/p of one pass is 0.81σ RMS from two passes' at 1.5–3 GeV
#: (0.24σ at 3–5). With the seed's q/p this close, what the second pass still corrects is the
#: first pass's linearisation at the forward *filtered* states (not measured further).
PARAMETRIZED_ITERATIONS = 2


def _reference(geometry: Geometry, params=None):
    return reference_extrapolator(geometry)


def _parametrized(geometry: Geometry, params=None):
    from pkf.params.parameter_set import load_parameters

    return load_parameters(geometry, params).extrapolator(geometry)


def _gsf(geometry: Geometry, params=None):
    return gsf_extrapolator(geometry)


FITTER_NAMES = ("parametrized", "reference", "gx2f", "gsf")
_NOT_BUILT: dict[str, int] = {}
_BUILT = {
    "parametrized": Fitter("parametrized", _parametrized, qop_at_production=True, iterations=PARAMETRIZED_ITERATIONS),
    "reference": Fitter("reference", _reference, qop_at_production=False, iterations=REFERENCE_ITERATIONS),
    "gx2f": Fitter("gx2f", _reference, qop_at_production=False, fit=fit_batch_gx2f),
    "gsf": Fitter("gsf", _gsf, qop_at_production=False, fit=fit_batch_gsf),
}


def get_fitter(name: str) -> Fitter:
    """The fitter called `name`; NotBuiltYet for those still to come, InputError if unknown."""
    if name in _BUILT:
        return _BUILT[name]
    if name in _NOT_BUILT:
        raise NotBuiltYet(f"--fitter {name}: not built yet (issue #{_NOT_BUILT[name]}); "
                          "available now: " + ", ".join(_BUILT))
    raise InputError(f"--fitter: unknown fitter {name!r} (one of {', '.join(FITTER_NAMES)})")
