"""The beamline state: straight line to the point of closest approach to the z axis (DESIGN §8).

The same code for every fitter, as in the paper: from the optimal state at the first
hit, a straight-line extrapolation to z_pca = z − (x·tx + y·ty)/(tx² + ty²), adding the
Highland noise of every material plane crossed on the way (in the plane's active
area), with no energy loss.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.extrapolator import STATUS_OK, extrapolate, register_extrapolator
from pkf.fit.linalg import copy5, copy55, sandwich, search_sorted, set_identity
from pkf.fit.reference import add_plane_material
from pkf.geometry.detector import Geometry
from pkf.simulation.species import MASS_PION


class StraightLineExtrapolator(NamedTuple):
    """Straight lines through material planes (no field, no energy loss). Plane arrays as
    in `ReferenceExtrapolator`; mass [MeV] is the scattering hypothesis."""

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
    energy_loss: bool


def straight_line_extrapolator(geometry: Geometry, mass: float = MASS_PION) -> StraightLineExtrapolator:
    """The beamline extrapolator of `geometry`."""
    p = geometry.planes
    return StraightLineExtrapolator(p.z, p.x_over_x0, p.half_x, p.half_y, p.hole_radius,
                                    p.hole_half_x, p.hole_half_y, p.side, p.side_overlap,
                                    float(mass), False)


@nb.njit(cache=True, inline="always")
def _straight_segment(state, dz, jac, noise, seg, tmp, tmp2):
    state[0] += state[2] * dz
    state[1] += state[3] * dz
    set_identity(seg)
    seg[0, 2] = dz
    seg[1, 3] = dz
    for i in range(5):
        for j in range(5):
            s = 0.0
            for k in range(5):
                s += seg[i, k] * jac[k, j]
            tmp[i, j] = s
    copy55(tmp, jac)
    sandwich(seg, noise, tmp, tmp2)
    copy55(tmp2, noise)


@nb.njit(cache=True, inline="always")
def straight_line_step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
    """Straight line with the material of the planes in (min z, max z]."""
    copy5(state_in, state_out)
    set_identity(jac_out)
    for i in range(5):
        for j in range(5):
            noise_out[i, j] = 0.0
    z = z_from
    if z_to > z_from:
        k = search_sorted(ext.plane_z, z_from, True)
        while k < ext.plane_z.size and ext.plane_z[k] <= z_to:
            _straight_segment(state_out, ext.plane_z[k] - z, jac_out, noise_out, work[0], work[1], work[2])
            z = ext.plane_z[k]
            add_plane_material(ext, k, state_out, 1.0, jac_out, noise_out)
            k += 1
    else:
        k = search_sorted(ext.plane_z, z_from, True) - 1
        while k >= 0 and ext.plane_z[k] > z_to:
            _straight_segment(state_out, ext.plane_z[k] - z, jac_out, noise_out, work[0], work[1], work[2])
            z = ext.plane_z[k]
            add_plane_material(ext, k, state_out, -1.0, jac_out, noise_out)
            k -= 1
    _straight_segment(state_out, z_to - z, jac_out, noise_out, work[0], work[1], work[2])
    return STATUS_OK


register_extrapolator(StraightLineExtrapolator, straight_line_step)


@nb.njit(cache=True)
def beamline_states(ext, z_first, first_states, first_covs, out_z, out_states, out_covs):
    """Beamline state of each track from its optimal state at the first hit (z_first [mm])."""
    jac = np.empty((5, 5))
    noise = np.empty((5, 5))
    work = np.empty((6, 5, 5))
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
