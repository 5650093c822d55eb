"""The propagator of the fitters on the field map: plane navigation, RK4 stepper, material actors.

Modelled on ACTS's Propagator (stepper + navigator + actor list, material applied by
its MaterialInteractor), with pkf's compile-time dispatch instead of templates:

- Navigator, `propagate(ext, actor, z_from, z_to)`: visits the material planes with
  z_from < z_plane ≤ z_to (downstream) or z_to < z_plane ≤ z_from (upstream), in
  flight order, so that a state at a plane is the state downstream of its material
  (the convention of `pkf.fit.extrapolator`). Between planes it asks the actor to
  transport, at each plane to interact; a status other than `STATUS_OK` stops it.
- Actor: a NamedTuple of arrays (the states it carries, its scratch) whose class is
  registered with `register_actor(cls, transport, interact)`:

      transport(actor, ext, z_from, z_to, crossed) -> status
      interact(actor, ext, k, direction) -> status

  ``crossed`` is the number of planes crossed so far in this propagation, k the plane
  index, direction +1.0 downstream and −1.0 upstream. numba resolves the calls to the
  registered functions when it compiles the caller (`pkf.fit.dispatch`). The actors:
  `KalmanMaterial` here (one state, its Jacobian and process noise: the reference
  extrapolator, and each component of the GSF), the scattering-angle actor of the
  GX2F (`pkf.fit.gx2f`) and the mixture actor of the GSF (`pkf.fit.gsf`).
- Stepper, `rk4_segment`: RK4 with its Jacobian through the field map for one state.
- Material, `plane_path_x0`: the path [X0] through a plane where the track crosses its
  active area (as in the simulation), from which every actor takes its Highland width
  and Bethe mean loss (`mean_energy_loss`).

``ext`` is the reference extrapolator's context (`pkf.fit.reference.ReferenceExtrapolator`):
field, RK4 step limit, the planes sorted by z [mm], mass hypothesis [MeV], energy loss on/off.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.dispatch import dispatched
from pkf.physics.linalg import copy55, matmul55, sandwich, search_sorted
from pkf.fit.status import STATUS_EXTRAPOLATION_FAILED, STATUS_OK
from pkf.geometry.acceptance import in_active_area
from pkf.physics.materials import (
    SI_X0_MM,
    apply_energy_loss_to_qop,
    bethe_mean_loss,
    energy_loss_qop_derivative,
    highland_theta0,
    path_length_x0,
    scattering_noise,
)
from pkf.physics.transport import rk4_transport_jacobian

#: Largest |tx|, |ty| a transported state may reach (the simulation envelope, docs/physics.md#simulation).
MAX_SLOPE = 10.0

transport = dispatched("transport", "actor, ext, z_from, z_to, crossed",
                       "Move the actor's state(s) from z_from to z_to [mm]; returns a status code.")
interact = dispatched("interact", "actor, ext, k, direction",
                      "Material of plane k crossed in `direction` (±1.0); returns a status code.")


def register_actor(actor_class: type, transport_function, interact_function) -> None:
    """Make the njit functions the transport and interaction of actors of `actor_class`."""
    transport.register(actor_class, transport_function)
    interact.register(actor_class, interact_function)


# ----------------------------------------------------------------------------------
# Navigator
# ----------------------------------------------------------------------------------


def propagator(transport_function, interact_function):
    """The navigator (`propagate`) with the actor's transport and interaction called
    directly: inlined into the fitter's kernel, with no call per plane through the
    dispatch of `transport`/`interact` (measured in one process against the pre-actor
    kernels, CPU time: GX2F +15 % → +4…7 %, reference +9 % → +4…6 %). `propagate` is this
    navigator with the dispatched functions."""

    @nb.njit(cache=True, inline="always")
    def navigate(ext, actor, z_from, z_to):
        """Transport `actor` from z_from to z_to [mm] through the material planes in between
        (see the module docstring). Returns the first status other than STATUS_OK, or the
        last segment's status."""
        plane_z = ext.plane_z
        z = z_from
        crossed = 0
        if z_to > z_from:  # one loop per direction (no direction flag in the loop)
            k = search_sorted(plane_z, z_from, True)  # first plane with z > z_from
            while k < plane_z.size and plane_z[k] <= z_to:
                status = transport_function(actor, ext, z, plane_z[k], crossed)
                if status != STATUS_OK:
                    return status
                z = plane_z[k]
                status = interact_function(actor, ext, k, 1.0)
                if status != STATUS_OK:
                    return status
                crossed += 1
                k += 1
        else:
            k = search_sorted(plane_z, z_from, True) - 1  # last plane with z <= z_from
            while k >= 0 and plane_z[k] > z_to:
                status = transport_function(actor, ext, z, plane_z[k], crossed)
                if status != STATUS_OK:
                    return status
                z = plane_z[k]
                status = interact_function(actor, ext, k, -1.0)
                if status != STATUS_OK:
                    return status
                crossed += 1
                k -= 1
        return transport_function(actor, ext, z, z_to, crossed)

    return navigate


#: The navigator for any registered actor (`register_actor`), dispatched on its class.
propagate = propagator(transport, interact)


# ----------------------------------------------------------------------------------
# Stepper
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, inline="always")
def in_envelope(state):
    """Whether a transported state is finite with |tx|, |ty| ≤ MAX_SLOPE (beyond, the
    track curls away from z: outside what a z-parametrised state describes)."""
    for i in range(5):
        if not math.isfinite(state[i]):
            return False
    return not (abs(state[2]) > MAX_SLOPE or abs(state[3]) > MAX_SLOPE)


@nb.njit(cache=True, inline="always")
def rk4_segment(ext, state, z_from, z_to, seg, jac, tmp, stages):
    """RK4 of `state` (x, y, tx, ty, q/p) from z_from to z_to ≠ z_from [mm] through the
    field, in place; seg receives the segment's Jacobian S and jac ← S·jac (tmp 5×5
    scratch, stages (4, ≥4, 5) the RK stages' scratch, `rk4_transport_jacobian`).
    False if the state leaves the envelope (`in_envelope`)."""
    rk4_transport_jacobian(state, z_from, z_to, ext.max_step, ext.field_kind, ext.field_params, ext.field_grid,
                           seg, stages)
    if not in_envelope(state):
        return False
    matmul55(seg, jac, tmp)
    copy55(tmp, jac)
    return True


# ----------------------------------------------------------------------------------
# Material
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, inline="always")
def plane_path_x0(ext, k, state):
    """Path t [X0] of the track at `state` through plane k, x/X0·√(1 + tx² + ty²); 0 where
    it misses the plane's active area or has q/p = 0 (no momentum to scatter)."""
    if not in_active_area(state[0], state[1], ext.plane_half_x[k], ext.plane_half_y[k],
                          ext.plane_hole_radius[k], ext.plane_hole_half_x[k], ext.plane_hole_half_y[k],
                          ext.plane_side[k], ext.plane_side_overlap[k]):
        return 0.0
    if state[4] == 0.0:
        return 0.0
    return path_length_x0(ext.plane_x_over_x0[k], state[2], state[3])


@nb.njit(cache=True, inline="always")
def scattering_width(ext, t, qop):
    """Highland width θ0 [rad] of the projected angle after t [X0] at q/p [1/MeV] ≠ 0."""
    return highland_theta0(1.0 / abs(qop), ext.mass, 1.0, t)


@nb.njit(cache=True, inline="always")
def mean_energy_loss(ext, t, qop, direction):
    """(q/p′, ∂q/p′/∂q/p) after the Bethe mean loss in t [X0] of silicon at q/p [1/MeV] ≠ 0:
    energy lost going downstream (direction +1.0), regained going upstream (−1.0)."""
    p = 1.0 / abs(qop)
    delta_e = direction * bethe_mean_loss(p, ext.mass, t * SI_X0_MM)
    d = energy_loss_qop_derivative(qop, ext.mass, delta_e)
    return apply_energy_loss_to_qop(qop, ext.mass, delta_e), d


@nb.njit(cache=True, inline="always")
def add_plane_material(ext, k, state, direction, jac, noise):
    """Material of plane k at `state` crossed in `direction` (±1.0), Kalman form.

    Adds the Highland slope noise (`scattering_noise`) to `noise` and, with energy loss
    on, changes q/p in `state` by the Bethe mean loss and scales row 4 of `jac` and
    row/column 4 of `noise` by ∂qop′/∂qop. Nothing where the plane is not crossed.
    """
    t = plane_path_x0(ext, k, state)
    if t <= 0.0:
        return
    tx = state[2]
    ty = state[3]
    qop = state[4]
    theta0 = scattering_width(ext, t, qop)
    q_txtx, q_txty, q_tyty = scattering_noise(tx, ty, theta0 * theta0)
    noise[2, 2] += q_txtx
    noise[3, 3] += q_tyty
    noise[2, 3] += q_txty
    noise[3, 2] += q_txty
    if ext.energy_loss:
        new_qop, d = mean_energy_loss(ext, t, qop, direction)
        state[4] = new_qop
        for j in range(5):
            jac[4, j] *= d
            noise[4, j] *= d
            noise[j, 4] *= d


# ----------------------------------------------------------------------------------
# The Kalman actor: one state, its transport Jacobian and process noise
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, inline="always")
def _kalman_transport(actor, ext, z_from, z_to, crossed):
    """RK4 segment; jac ← S·jac, noise ← S·noise·Sᵀ (work[0] S, work[1] scratch, work[2:6]
    the RK stages)."""
    if z_to == z_from:
        return STATUS_OK
    work = actor.work
    seg = work[0]
    tmp = work[1]
    if not rk4_segment(ext, actor.state, z_from, z_to, seg, actor.jac, tmp, work[2:6]):
        return STATUS_EXTRAPOLATION_FAILED
    sandwich(seg, actor.noise, tmp, actor.noise)  # in place: sandwich reads c only into tmp
    return STATUS_OK


@nb.njit(cache=True, inline="always")
def kalman_interact(actor, ext, k, direction):
    """Plane k's material on the Kalman actor (`add_plane_material`)."""
    add_plane_material(ext, k, actor.state, direction, actor.jac, actor.noise)
    return STATUS_OK


class KalmanMaterial(NamedTuple):
    """Actor of a Kalman extrapolation: `state` (5) transported in place, `jac` (5×5)
    accumulating the transport Jacobian, `noise` (5×5) the process noise Q at the end
    point (C_out = F·C·Fᵀ + Q), work (6, 5, 5) scratch. (Built once per propagation;
    the Kalman core is compiled without reference counting, `pkf.jit.NO_REFCOUNT`, so
    building it costs no atomic operations.)"""

    state: np.ndarray
    jac: np.ndarray
    noise: np.ndarray
    work: np.ndarray


register_actor(KalmanMaterial, _kalman_transport, kalman_interact)

#: The navigator with the Kalman actor called directly (the reference extrapolation).
propagate_kalman = propagator(_kalman_transport, kalman_interact)
