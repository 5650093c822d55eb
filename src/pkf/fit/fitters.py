"""The fitters `pkf reconstruct --fitter` knows, each an extrapolator for the one Kalman core.

A `Fitter` says how to build its extrapolator for a geometry and which q/p its states
carry: the local momentum (reference fitter, which applies energy loss) or the
momentum at production (the parametrized fitter, paper §3), which decides the truth
its pulls are computed against.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from pkf.errors import InputError, NotBuiltYet
from pkf.fit.reference import reference_extrapolator
from pkf.geometry.detector import Geometry


@dataclass(frozen=True)
class Fitter:
    """A named Kalman fitter: `make_extrapolator(geometry, params)` and its q/p convention."""

    name: str
    make_extrapolator: Callable
    qop_at_production: bool
    iterations: int = 1


def _reference(geometry: Geometry, params=None):
    return reference_extrapolator(geometry)


def _parametrized(geometry: Geometry, params=None):
    from pkf.params.parameter_set import load_parameters

    return load_parameters(geometry, params).extrapolator(geometry)


FITTER_NAMES = ("parametrized", "reference", "gx2f", "gsf")
_NOT_BUILT = {"gx2f": 7, "gsf": 7}
_BUILT = {
    "parametrized": Fitter("parametrized", _parametrized, qop_at_production=True),
    "reference": Fitter("reference", _reference, qop_at_production=False),
}


def get_fitter(name: str) -> Fitter:
    """The fitter called `name`; NotBuiltYet for those still to come, InputError if unknown."""
    if name in _BUILT:
        return _BUILT[name]
    if name in _NOT_BUILT:
        raise NotBuiltYet(f"--fitter {name}: not built yet (issue #{_NOT_BUILT[name]}); "
                          "available now: " + ", ".join(_BUILT))
    raise InputError(f"--fitter: unknown fitter {name!r} (one of {', '.join(FITTER_NAMES)})")
