"""Particle hypotheses of the Kalman fitters: the electron's bremsstrahlung as q/p noise (docs/physics.md#particle-hypotheses).

The Kalman fitters (reference and parametrized) assume the pion unless told otherwise
(`KalmanOptions.hypothesis`, ``pkf reconstruct --hypothesis``). Under the electron
hypothesis, as LHCb's electron fit does (StateElectronEnergyCorrectionTool), every step
that crosses material adds the Bethe–Heitler mean loss to q/p and its variance to the
q/p noise: with t [X0] the path through the material planes crossed and z = E_f/E_i,
E[z] = e^{−t}, Var z = e^{−t·ln 3/ln 2} − e^{−2t} (`bremsstrahlung_fraction_moments`),

- downstream: q/p′ = q/p / E[z], ∂q/p′/∂q/p = 1/E[z], added variance (q/p′)²·Var z / E[z]²
  (the linearisation of q/p / z, as the GSF's components);
- upstream: q/p′ = q/p·E[z], ∂q/p′/∂q/p = E[z], added variance (q/p)²·Var z.

`ElectronHypothesis` wraps any registered extrapolator (`pkf.fit.extrapolator`): its step
is the wrapped one's, then the bremsstrahlung of the planes in (z_from, z_to], each at
the track's position there (the straight line between the step's end states: the planes
lie in no or little field) and counted only where the track crosses the plane's active
area (`pkf.fit.propagate.plane_path_x0`). The compounded fractions of several planes
are exactly the Bethe–Heitler fraction of their summed thickness (−ln z adds, Gamma
shapes add), so applying the sum at the step's end is exact for q/p; what it leaves out
is the q/p change's bending between a plane and the step's end, which matters only for
the two passive planes between the VELO and the UT (fringe field of the magnet).

- Reference fitter: the wrapped extrapolator is the reference one with the electron
  mass (Highland scattering and Bethe ionisation of an electron), its planes those of
  the field-map propagation.
- Parametrized fitter: the wrapped extrapolator is the parametrized one as tuned (on
  pions: its scattering noise and the ionisation absorbed into q/p at production are
  a pion's, which above 1 GeV differ from an electron's by < 1e−3); the planes are the
  geometry's, used only for their thickness and acceptance: the paper's steps have no
  material map, so this is the one place the parametrized fitter reads one. Its q/p is
  then the production momentum less the expected radiation upstream of the state.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.extrapolator import STATUS_OK, extrapolate, register_extrapolator
from pkf.fit.options import HYPOTHESES
from pkf.fit.propagate import plane_path_x0
from pkf.fit.reference import ReferenceExtrapolator, reference_extrapolator
from pkf.geometry.detector import Geometry
from pkf.physics.constants import MASS_ELECTRON
from pkf.physics.linalg import search_sorted
from pkf.physics.materials import bremsstrahlung_fraction_moments


#: Least q/p width of the seed prior under the electron hypothesis, as a fraction of |q/p|
#: (see `widen_seed_qop`; the GSF's `pkf.fit.gsf.SEED_QOP_FRACTION`).
ELECTRON_SEED_QOP_FRACTION = 1.0


def widen_seed_qop(seeds: np.ndarray, seed_covs: np.ndarray, fraction: float) -> np.ndarray:
    """Seed covariances (T, 5, 5) whose q/p width is at least `fraction`·|q/p| of `seeds`
    (T, 5), the q/p row and column scaled (a copy). The seed's q/p is the magnet's
    measurement from all the hits: kept as a prior at the first hit with its 10 % width it
    is counted twice and, with bremsstrahlung between the first hit and the magnet, pulls
    the first-hit q/p to "no radiation" (the GSF does the same, `pkf.fit.gsf`)."""
    covs = np.array(seed_covs, dtype=np.float64, copy=True)
    var = covs[:, 4, 4]
    wide = (fraction * seeds[:, 4]) ** 2
    scale = np.ones_like(var)
    widen = np.isfinite(wide) & (wide > var)
    positive = widen & (var > 0.0)
    scale[positive] = np.sqrt(wide[positive] / var[positive])
    covs[:, 4, :] *= scale[:, None]
    covs[:, :, 4] *= scale[:, None]
    zero = widen & ~positive
    covs[zero, 4, :] = 0.0
    covs[zero, :, 4] = 0.0
    covs[zero, 4, 4] = wide[zero]
    return covs


class ElectronHypothesis(NamedTuple):
    """An extrapolator (`inner`, any registered context) with the electron's bremsstrahlung
    added at the material planes of `planes` (a `ReferenceExtrapolator`: plane z [mm],
    thickness [X0] and active areas)."""

    inner: tuple
    planes: ReferenceExtrapolator


@nb.njit(cache=True, inline="always")
def crossed_path_x0(planes, state_in, state_out, z_from, z_to, point):
    """Σ path [X0] through the planes of `planes` with z in (min z, max z] of a step from
    state_in at z_from to state_out at z_to [mm], each at the straight line between them
    (`plane_path_x0`: 0 where the track misses a plane's active area); `point` (5) scratch."""
    lo = min(z_from, z_to)
    hi = max(z_from, z_to)
    plane_z = planes.plane_z
    total = 0.0
    k = search_sorted(plane_z, lo, True)  # first plane with z > lo
    while k < plane_z.size and plane_z[k] <= hi:
        f = (plane_z[k] - z_from) / (z_to - z_from)
        for i in range(4):
            point[i] = state_in[i] + f * (state_out[i] - state_in[i])
        point[4] = state_out[4]
        total += plane_path_x0(planes, k, point)
        k += 1
    return total


@nb.njit(cache=True, inline="always")
def add_bremsstrahlung(t, direction, state, jac, noise):
    """Bethe–Heitler mean loss and variance of t [X0] on q/p of `state` (see the module
    docstring), crossed downstream (direction +1.0) or upstream (−1.0); scales row 4 of
    the transport Jacobian `jac` and row/column 4 of the process noise `noise`."""
    mean_z, var_z = bremsstrahlung_fraction_moments(t)
    qop = state[4]
    if direction > 0.0:
        d = 1.0 / mean_z
        new_qop = qop * d
        add = new_qop * new_qop * var_z / (mean_z * mean_z)
    else:
        d = mean_z
        new_qop = qop * d
        add = qop * qop * var_z
    state[4] = new_qop
    for j in range(5):
        jac[4, j] *= d
        noise[4, j] *= d
        noise[j, 4] *= d
    noise[4, 4] += add


@nb.njit(cache=True)
def electron_step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
    """The wrapped extrapolator's step, then the bremsstrahlung of the planes crossed."""
    status = extrapolate(ext.inner, state_in, z_from, z_to, state_out, jac_out, noise_out, work)
    if status != STATUS_OK or z_to == z_from or not math.isfinite(state_out[4]) or state_out[4] == 0.0:
        return status
    t = crossed_path_x0(ext.planes, state_in, state_out, z_from, z_to, work[4, 0])
    if t > 0.0:
        add_bremsstrahlung(t, 1.0 if z_to > z_from else -1.0, state_out, jac_out, noise_out)
    return STATUS_OK


register_extrapolator(ElectronHypothesis, electron_step)


def with_hypothesis(extrapolator, geometry: Geometry, hypothesis: str):
    """`extrapolator` (a Kalman fitter's context for `geometry`) under `hypothesis`, one of
    HYPOTHESES: itself for the pion; for the electron an `ElectronHypothesis` around it
    (a reference extrapolator rebuilt with the electron mass)."""
    if hypothesis not in HYPOTHESES:
        raise ValueError(f"hypothesis must be one of {', '.join(HYPOTHESES)}, not {hypothesis!r}")
    if hypothesis == "pion":
        return extrapolator
    if isinstance(extrapolator, ReferenceExtrapolator):
        extrapolator = extrapolator._replace(mass=MASS_ELECTRON)
        return ElectronHypothesis(extrapolator, extrapolator)
    return ElectronHypothesis(extrapolator, reference_extrapolator(geometry, mass=MASS_ELECTRON))
