"""The reference ("default Kalman") extrapolator: Runge–Kutta through the field map (docs/physics.md#the-reference-fitter-two-passes).

Between two nodes the state is transported by RK4 with its Jacobian (paper §3: the
default LHCb Kalman filter), stopping at every material plane in between: Highland
scattering noise is added on the slopes (docs/physics.md#material-effects) and the Bethe mean energy loss is
applied to q/p (energy lost going downstream, regained going upstream), for a mass
hypothesis (pion by default). A plane's material counts only where the track crosses
its active area, as in the simulation.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.extrapolator import STATUS_EXTRAPOLATION_FAILED, STATUS_OK, register_extrapolator
from pkf.physics.linalg import copy5, copy55, matmul55, sandwich, search_sorted, set_identity
from pkf.geometry.acceptance import in_active_area
from pkf.geometry.detector import Geometry
from pkf.physics.materials import (
    SI_X0_MM,
    apply_energy_loss_to_qop,
    bethe_mean_loss,
    energy_loss_qop_derivative,
    highland_theta0,
)
from pkf.physics.transport import rk4_propagate_jacobian
from pkf.physics.constants import MASS_PION

#: Longest RK4 step [mm] of the reference extrapolation.
REFERENCE_MAX_STEP = 100.0
#: Largest |tx|, |ty| a transported state may reach (the simulation envelope, docs/physics.md#simulation).
MAX_SLOPE = 10.0


class ReferenceExtrapolator(NamedTuple):
    """Context of the reference extrapolator: field (map) and material planes.

    Plane arrays are sorted by z [mm]; x_over_x0 is the thickness in radiation lengths;
    the area arrays are those of `pkf.geometry.detector.Planes`. mass [MeV] is the
    hypothesis for scattering and energy loss; max_step [mm] the RK4 step limit.
    """

    field_kind: int
    field_params: np.ndarray
    field_grid: np.ndarray
    plane_z: np.ndarray
    plane_x_over_x0: np.ndarray
    plane_half_x: np.ndarray
    plane_half_y: np.ndarray
    plane_hole_radius: np.ndarray
    plane_hole_half_x: np.ndarray
    plane_hole_half_y: np.ndarray
    plane_side: np.ndarray
    plane_side_overlap: np.ndarray
    mass: float
    max_step: float
    energy_loss: bool


def reference_extrapolator(geometry: Geometry, mass: float = MASS_PION,
                           max_step: float = REFERENCE_MAX_STEP, energy_loss: bool = True,
                           field=None) -> ReferenceExtrapolator:
    """Build the reference extrapolator of `geometry` (its field map unless `field` given)."""
    field = geometry.reconstruction_field() if field is None else field
    planes = geometry.planes
    return ReferenceExtrapolator(
        int(field.kind), field.params, field.grid, planes.z, planes.x_over_x0,
        planes.half_x, planes.half_y, planes.hole_radius, planes.hole_half_x,
        planes.hole_half_y, planes.side, planes.side_overlap, float(mass), float(max_step),
        bool(energy_loss),
    )


@nb.njit(cache=True, inline="always")
def add_plane_material(ext, k, state, direction, jac, noise):
    """Material of plane k at `state` (x, y, tx, ty, q/p) crossed in `direction` (±1).

    Adds the Highland slope noise to `noise` and, with energy loss on, changes q/p in
    `state` by the Bethe mean loss and scales row 4 of `jac` and row/column 4 of `noise`
    by ∂qop′/∂qop. Does nothing outside the plane's active area.
    """
    x = state[0]
    y = state[1]
    if not in_active_area(x, y, ext.plane_half_x[k], ext.plane_half_y[k], ext.plane_hole_radius[k],
                          ext.plane_hole_half_x[k], ext.plane_hole_half_y[k], ext.plane_side[k],
                          ext.plane_side_overlap[k]):
        return
    tx = state[2]
    ty = state[3]
    qop = state[4]
    if qop == 0.0:
        return
    n2 = 1.0 + tx * tx + ty * ty
    t = ext.plane_x_over_x0[k] * math.sqrt(n2)
    if t <= 0.0:
        return
    p = 1.0 / abs(qop)
    theta0 = highland_theta0(p, ext.mass, 1.0, t)
    theta2n2 = theta0 * theta0 * n2
    noise[2, 2] += theta2n2 * (1.0 + tx * tx)
    noise[3, 3] += theta2n2 * (1.0 + ty * ty)
    noise[2, 3] += theta2n2 * tx * ty
    noise[3, 2] += theta2n2 * tx * ty
    if ext.energy_loss:
        delta_e = direction * bethe_mean_loss(p, ext.mass, t * SI_X0_MM)
        d = energy_loss_qop_derivative(qop, ext.mass, delta_e)
        state[4] = apply_energy_loss_to_qop(qop, ext.mass, delta_e)
        for j in range(5):
            jac[4, j] *= d
            noise[4, j] *= d
            noise[j, 4] *= d


@nb.njit(cache=True, inline="always")
def _transport_segment(ext, state, z_from, z_to, jac, noise, seg_jac, tmp, tmp2):
    """RK4 from z_from to z_to; accumulate jac = J·jac and noise = J·noise·Jᵀ."""
    if z_to == z_from:
        return True
    new = rk4_propagate_jacobian(state, z_from, z_to, ext.max_step, ext.field_kind,
                                 ext.field_params, ext.field_grid, seg_jac)
    for i in range(5):
        if not math.isfinite(new[i]):
            return False
        state[i] = new[i]
    if abs(state[2]) > MAX_SLOPE or abs(state[3]) > MAX_SLOPE:
        return False  # curling away from z: outside what a z-parametrised state describes
    matmul55(seg_jac, jac, tmp)
    copy55(tmp, jac)
    sandwich(seg_jac, noise, tmp, tmp2)
    copy55(tmp2, noise)
    return True


@nb.njit(cache=True, inline="always")
def reference_step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
    """Transport through the field map and the material planes in (min z, max z]."""
    copy5(state_in, state_out)
    set_identity(jac_out)
    for i in range(5):
        for j in range(5):
            noise_out[i, j] = 0.0
    if z_to == z_from:
        return STATUS_OK
    seg_jac = work[0]
    tmp = work[1]
    tmp2 = work[2]
    z = z_from
    if z_to > z_from:
        k = search_sorted(ext.plane_z, z_from, True)  # first plane with z > z_from
        while k < ext.plane_z.size and ext.plane_z[k] <= z_to:
            if not _transport_segment(ext, state_out, z, ext.plane_z[k], jac_out, noise_out, seg_jac, tmp, tmp2):
                return STATUS_EXTRAPOLATION_FAILED
            z = ext.plane_z[k]
            add_plane_material(ext, k, state_out, 1.0, jac_out, noise_out)
            k += 1
    else:
        k = search_sorted(ext.plane_z, z_from, True) - 1  # last plane with z <= z_from
        while k >= 0 and ext.plane_z[k] > z_to:
            if not _transport_segment(ext, state_out, z, ext.plane_z[k], jac_out, noise_out, seg_jac, tmp, tmp2):
                return STATUS_EXTRAPOLATION_FAILED
            z = ext.plane_z[k]
            add_plane_material(ext, k, state_out, -1.0, jac_out, noise_out)
            k -= 1
    if not _transport_segment(ext, state_out, z, z_to, jac_out, noise_out, seg_jac, tmp, tmp2):
        return STATUS_EXTRAPOLATION_FAILED
    if not math.isfinite(state_out[4]):
        return STATUS_EXTRAPOLATION_FAILED
    return STATUS_OK


register_extrapolator(ReferenceExtrapolator, reference_step)
