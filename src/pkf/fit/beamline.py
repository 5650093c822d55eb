"""The beamline state: straight line to the point of closest approach to the z axis (docs/physics.md#the-kalman-core).

The same code for every fitter, as in the paper: from the optimal state at the first
hit, a straight-line extrapolation to z_pca = z − (x·tx + y·ty)/(tx² + ty²), adding the
Highland noise of every material plane crossed on the way (in the plane's active
area), with no energy loss. The straight line is the reference extrapolator in a field
of zero (Runge–Kutta is exact for it), so the material handling is the reference's: the
propagator of `pkf.fit.propagate` with the Kalman material actor, whose RK4 segment is
replaced by `_straight_transport`, the same arithmetic with the field's terms (zeros)
left out: bitwise the reference's states, Jacobians and noise (a test compares them), at
a tenth of the cost (the RK4 segment evaluated the field map four times per plane).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.fit.propagate import KalmanMaterial, in_envelope, propagator, kalman_interact
from pkf.fit.reference import ReferenceExtrapolator, reference_extrapolator
from pkf.fit.status import STATUS_EXTRAPOLATION_FAILED, STATUS_OK
from pkf.geometry.detector import Geometry
from pkf.geometry.field import uniform_field
from pkf.jit import NO_REFCOUNT, fma
from pkf.physics.constants import MASS_PION
from pkf.physics.linalg import copy5, sandwich, set_identity, zero55

#: RK4 step of the straight line: any length is exact in zero field.
STRAIGHT_LINE_STEP = 1e6


def straight_line_extrapolator(geometry: Geometry, mass: float = MASS_PION) -> ReferenceExtrapolator:
    """The beamline extrapolator of `geometry`: straight lines through its material planes."""
    return reference_extrapolator(geometry, mass=mass, max_step=STRAIGHT_LINE_STEP, energy_loss=False,
                                  field=uniform_field(0.0, 0.0, 0.0))


@nb.njit(cache=True, inline="always")
def _straight_transport(actor, ext, z_from, z_to, crossed):
    """The Kalman actor's segment (`pkf.fit.propagate`) in zero field: RK4 of a straight
    line, whose stages all have the slopes of the start, x += h/6·(tx + 2tx + 2tx + tx)
    per RK step h (the RK4 sum, so that the result is the reference's to the bit), and the
    segment's Jacobian S = 1 + a·(E₀₂ + E₁₃), a = Σ h/6·6; then jac ← S·jac and
    noise ← S·noise·Sᵀ (symmetrised from the upper triangle, as `sandwich`) with the
    zeros of S left out. The steps are those of the reference (⌈|Δz|/max_step⌉)."""
    if z_to == z_from:
        return STATUS_OK
    state = actor.state
    dz = z_to - z_from
    nsteps = max(1, int(math.ceil(abs(dz) / ext.max_step)))
    h = dz / nsteps
    x = state[0]
    y = state[1]
    tx = state[2]
    ty = state[3]
    a = 0.0
    for _ in range(nsteps):
        x = x + h / 6.0 * (tx + 2.0 * tx + 2.0 * tx + tx)
        y = y + h / 6.0 * (ty + 2.0 * ty + 2.0 * ty + ty)
        a += h / 6.0 * 6.0
    state[0] = x
    state[1] = y
    if not in_envelope(state):
        return STATUS_EXTRAPOLATION_FAILED
    jac = actor.jac
    for j in range(5):
        jac[0, j] = fma(a, jac[2, j], jac[0, j])
        jac[1, j] = fma(a, jac[3, j], jac[1, j])
    c = actor.noise
    tmp = actor.work[1]
    for j in range(5):  # tmp = S·c
        tmp[0, j] = fma(a, c[2, j], c[0, j])
        tmp[1, j] = fma(a, c[3, j], c[1, j])
        for i in range(2, 5):
            tmp[i, j] = c[i, j]
    for i in range(5):  # c = tmp·Sᵀ, upper triangle mirrored
        for j in range(i, 5):
            if j == 0:
                v = fma(a, tmp[i, 2], tmp[i, 0])
            elif j == 1:
                v = fma(a, tmp[i, 3], tmp[i, 1])
            else:
                v = tmp[i, j]
            c[i, j] = v
            c[j, i] = v
    return STATUS_OK


_propagate_straight = propagator(_straight_transport, kalman_interact)


@nb.njit(cache=True, inline="always")
def straight_line_step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
    """`pkf.fit.reference.reference_step` of the straight-line context `ext`
    (`straight_line_extrapolator`; its field is not read) through `_straight_transport`."""
    copy5(state_in, state_out)
    set_identity(jac_out)
    zero55(noise_out)
    if z_to == z_from:
        return STATUS_OK
    status = _propagate_straight(ext, KalmanMaterial(state_out, jac_out, noise_out, work), z_from, z_to)
    if status != STATUS_OK:
        return status
    if not math.isfinite(state_out[4]):
        return STATUS_EXTRAPOLATION_FAILED
    return STATUS_OK


@nb.njit(cache=True)
def beamline_states(ext, z_first, first_states, first_covs, out_z, out_states, out_covs):
    """Beamline state of each track from its optimal state at the first hit (z_first [mm])."""
    _beamline_loop(ext, z_first, first_states, first_covs, out_z, out_states, out_covs, np.empty((5, 5)),
                   np.empty((5, 5)), np.empty((6, 5, 5)))


@nb.njit(cache=True, **NO_REFCOUNT)
def _beamline_loop(ext, z_first, first_states, first_covs, out_z, out_states, out_covs, jac, noise, work):
    """`beamline_states` with the caller's scratch (jac, noise 5×5, work (6, 5, 5)): no
    allocation, so compiled without reference counting (`pkf.jit.NO_REFCOUNT`). `ext` is
    the straight-line context (`straight_line_extrapolator`)."""
    for t in range(z_first.size):
        s = first_states[t]
        t2 = s[2] * s[2] + s[3] * s[3]
        z_pca = z_first[t]
        if t2 > 0.0:
            z_pca = z_first[t] - (s[0] * s[2] + s[1] * s[3]) / t2
        out_z[t] = z_pca
        straight_line_step(ext, s, z_first[t], z_pca, out_states[t], jac, noise, work)
        sandwich(jac, first_covs[t], work[0], out_covs[t])
        for i in range(5):
            for j in range(5):
                out_covs[t, i, j] += noise[i, j]
