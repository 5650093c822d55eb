"""The beamline state: straight line to the point of closest approach to the z axis (docs/physics.md#the-kalman-core).

The same code for every fitter, as in the paper: from the optimal state at the first
hit, a straight-line extrapolation to z_pca = z − (x·tx + y·ty)/(tx² + ty²), adding the
Highland noise of every material plane crossed on the way (in the plane's active
area), with no energy loss. The straight line is the reference extrapolator in a field
of zero (Runge–Kutta is exact for it), so the material handling is the reference's.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pkf.fit.extrapolator import extrapolate
from pkf.fit.reference import ReferenceExtrapolator, reference_extrapolator
from pkf.geometry.detector import Geometry
from pkf.geometry.field import uniform_field
from pkf.jit import NO_REFCOUNT
from pkf.physics.constants import MASS_PION
from pkf.physics.linalg import sandwich

#: RK4 step of the straight line: any length is exact in zero field.
STRAIGHT_LINE_STEP = 1e6


def straight_line_extrapolator(geometry: Geometry, mass: float = MASS_PION) -> ReferenceExtrapolator:
    """The beamline extrapolator of `geometry`: straight lines through its material planes."""
    return reference_extrapolator(geometry, mass=mass, max_step=STRAIGHT_LINE_STEP, energy_loss=False,
                                  field=uniform_field(0.0, 0.0, 0.0))


@nb.njit(cache=True)
def beamline_states(ext, z_first, first_states, first_covs, out_z, out_states, out_covs):
    """Beamline state of each track from its optimal state at the first hit (z_first [mm])."""
    _beamline_loop(ext, z_first, first_states, first_covs, out_z, out_states, out_covs, np.empty((5, 5)),
                   np.empty((5, 5)), np.empty((6, 5, 5)))


@nb.njit(cache=True, **NO_REFCOUNT)
def _beamline_loop(ext, z_first, first_states, first_covs, out_z, out_states, out_covs, jac, noise, work):
    """`beamline_states` with the caller's scratch (jac, noise 5×5, work (6, 5, 5)): no
    allocation, so compiled without reference counting (`pkf.jit.NO_REFCOUNT`)."""
    for t in range(z_first.size):
        s = first_states[t]
        t2 = s[2] * s[2] + s[3] * s[3]
        z_pca = z_first[t]
        if t2 > 0.0:
            z_pca = z_first[t] - (s[0] * s[2] + s[1] * s[3]) / t2
        out_z[t] = z_pca
        extrapolate(ext, s, z_first[t], z_pca, out_states[t], jac, noise, work)
        sandwich(jac, first_covs[t], work[0], out_covs[t])
        for i in range(5):
            for j in range(5):
                out_covs[t, i, j] += noise[i, j]
