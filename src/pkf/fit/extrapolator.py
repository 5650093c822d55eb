"""The extrapolator interface of the Kalman core and its registry (docs/physics.md#the-kalman-core, docs/physics.md#the-parametrized-fitter).

An extrapolator is a typed NamedTuple of arrays and numbers (its "context") plus a
compiled step function registered for that NamedTuple class:

    step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work) -> status

which transports ``state_in`` (x, y, tx, ty, q/p) at z_from [mm] to z_to, writes the
transported state, the transport Jacobian F = ∂state_out/∂state_in (5×5) and the
process noise Q (5×5, added at z_to: C_out = F·C·Fᵀ + Q), and returns a status code
(`STATUS_OK` or a failure). ``work`` is (6, 5, 5) float64 scratch.

Material convention shared by every extrapolator: the state at a plane is the state
*downstream* of that plane's material, so a step between z1 < z2 (in either
direction) includes the material of exactly the planes with z1 < z_plane ≤ z2.

The core calls `extrapolate(ext, ...)`; numba resolves it at compile time to the step
registered for ``type(ext)`` and inlines it, so one compiled Kalman core serves every
extrapolator and is cached on disk per extrapolator type.
"""

from __future__ import annotations

import numba as nb
from numba.extending import overload

from pkf.params.transport import ParametrizedExtrapolator, parametrized_step
from pkf.fit.status import (  # noqa: F401  (the codes every extrapolator returns)
    STATUS_BELOW_P_MIN,
    STATUS_EXTRAPOLATION_FAILED,
    STATUS_NAMES,
    STATUS_NO_SEED,
    STATUS_NOT_POSITIVE_DEFINITE,
    STATUS_OK,
    STATUS_TOO_FEW_HITS,
)

_STEP_FUNCTIONS: dict[type, object] = {}


def register_extrapolator(context_class: type, step_function) -> None:
    """Make `step_function` (an njit function) the step of extrapolators of `context_class`."""
    _STEP_FUNCTIONS[context_class] = step_function


def extrapolate(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
    """Dispatch to the registered step of ``type(ext)`` (resolved at compile time inside
    numba code; this Python body serves NUMBA_DISABLE_JIT=1 debugging)."""
    step = _STEP_FUNCTIONS[type(ext)]
    return step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work)


# Inlined into its caller (the overload's implementation too, not only the step): a call
# boundary here passed the whole context by value, ~200 machine words per node, which cost
# ~40 ns per step (the telescope's parametrized step: 104 → 65 ns with the Kalman core's
# node loop around it).
@overload(extrapolate, inline="always")
def _extrapolate_overload(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
    if not isinstance(ext, nb.types.BaseNamedTuple):
        return None
    step = _STEP_FUNCTIONS.get(ext.instance_class)
    if step is None:
        return None

    def implementation(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
        return step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work)

    return implementation


# The parametrized extrapolator lives in `pkf.params.transport` (a lower floor, shared with the
# forward search); its step is registered here, so every user of the Kalman core has it.
register_extrapolator(ParametrizedExtrapolator, parametrized_step)
