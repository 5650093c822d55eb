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
from pkf.physics.linalg import copy5, set_identity
from pkf.fit.propagate import KalmanMaterial, propagate_kalman
from pkf.geometry.detector import Geometry
from pkf.physics.constants import MASS_PION

#: Longest RK4 step [mm] of the reference extrapolation.
REFERENCE_MAX_STEP = 100.0


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
def reference_step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
    """Transport through the field map and the material planes in (min z, max z]
    (`pkf.fit.propagate.propagate` with the `KalmanMaterial` actor)."""
    copy5(state_in, state_out)
    set_identity(jac_out)
    for i in range(5):
        for j in range(5):
            noise_out[i, j] = 0.0
    if z_to == z_from:
        return STATUS_OK
    actor = KalmanMaterial(state_out, jac_out, noise_out, work)
    status = propagate_kalman(ext, actor, z_from, z_to)
    if status != STATUS_OK:
        return status
    if not math.isfinite(state_out[4]):
        return STATUS_EXTRAPOLATION_FAILED
    return STATUS_OK


register_extrapolator(ReferenceExtrapolator, reference_step)
