"""The least-squares seed's trajectory through the field map (`pkf.fit.seed`): whether its linear
kick model describes the track, and a Gauss–Newton refinement where it does not.

The kick integrals are taken along the straight line of the first hits; a steep low-momentum
track's real path bends far from that line in the dipole (whose field grows with |y|), and the
linear model's q/p then misses by tens of per cent, outside the seed's own 10 % prior. Where the
model's slope change |q/p·∫g dz| exceeds `pkf.fit.seed.LINEAR_BEND`, `linear_model_qop_step`
checks it: one quasi-Newton step with the residuals to the seed's RK4 trajectory and the model's
rows; where that step moves q/p by more than the prior's width (`pkf.fit.seed.SEED_QOP_FRACTION`
of |q/p|, UPSTREAM_QOP_FRACTION for upstream tracks; VELO-only tracks are not checked) or the
trajectory leaves the envelope, the seed is refitted by Gauss–Newton through the field map (RK4
with its transport Jacobian to every node, all hits, the same q/p prior, no scattering; steps
halved until χ² does not grow).

Measured on the 3,605 long truth tracks of 15 minimum-bias events (ν = 7.6, seed 31, truth
pattern): 350 refined (9.7 %; true momenta 1–3 GeV mostly); their seed's q/p error median 15.0 %
→ 0.49 %, 90 % quantile 27.7 % → 0.99 %; 7 stay > 20 % off, where the scattering the model
leaves out dominates the residuals (a 1.13 GeV track: 1.58 GeV). Tracks fitted of 4,158:
parametrized 4,152 → 4,157, reference 4,150 → 4,156, GX2F 4,130 → 4,145, GSF 4,152 → 4,156; q/p
pull core of the refined tracks: reference 1.215 → 1.150, GX2F 1.257 → 1.186 (parametrized 1.188
→ 1.186); every other seed is the least-squares one bit for bit. Cost (`seed_track` over those
4,158 tracks in one process, without and with the check and the refinement alternating, 3 rounds):
15 → 33 µs per track; the check ~13 µs where it runs (46 % of the tracks), the refinement ~150 µs
per refined track.
Where the pattern recognition hands over its estimate (the triplet pattern's long tracks,
`pkf.fit.seed.pattern_seed`) it replaces this seed: the minimum-bias tables of the default path
(benchmarks/table_hashes.py) are unchanged bit for bit; on its π gun (2–100 GeV, truth
pattern) 3 of 400 seeds changed, on its electron gun 6 of 150.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.propagate import in_envelope
from pkf.physics.linalg import copy55, invert_spd, matmul55, matvec5
from pkf.physics.transport import rk4_propagate_scalar, rk4_transport_jacobian

#: RK4 step limit [mm] of the seed's trajectory through the field map (`refine_through_field`)
#: and of the check whether it is needed (`linear_model_qop_step`).
SEED_RK4_STEP = 400.0
#: Gauss–Newton iterations of `refine_through_field` at most, and their stopping rule: the
#: step moves q/p by at most REFINE_TOLERANCE·|q/p|.
REFINE_MAX_ITERATIONS = 20
REFINE_TOLERANCE = 1e-3
#: Halvings of a Gauss–Newton step (or of the starting q/p) at most before giving up.
REFINE_MAX_HALVINGS = 20


@nb.njit(cache=True)
def linear_model_qop_step(state, inv, z, n_meas, hx, hy, m, sigma, kx, ky, qop_prior_sigma, field_kind,
                          field_params, field_grid):
    """q/p change [1/MeV] of one quasi-Newton step from the least-squares seed state (5 at z[0]):
    the residuals of the hits to the seed's RK4 trajectory through the field map, weighted by
    the linear model's rows (1, dz, kick integrals kx, ky at the nodes) and its inverse normal
    matrix inv (5×5, the q/p prior N(0, qop_prior_sigma²) [1/MeV] included). ≈ 0 where the
    linear model describes the track; inf where the trajectory leaves the envelope
    (`pkf.fit.propagate.in_envelope`)."""
    gradient = np.zeros(5)
    point = state.copy()  # the trajectory's state at the current node
    zc = z[0]
    for k in range(z.size):
        point[0], point[1], point[2], point[3] = rk4_propagate_scalar(
            point[0], point[1], point[2], point[3], state[4], zc, z[k], SEED_RK4_STEP, field_kind, field_params,
            field_grid)
        zc = z[k]
        if not in_envelope(point):
            return np.inf
        x, y = point[0], point[1]
        dz = z[k] - z[0]
        for j in range(n_meas[k]):
            w = (m[k, j] - hx[k, j] * x - hy[k, j] * y) / (sigma[k, j] * sigma[k, j])
            gradient[0] += hx[k, j] * w
            gradient[1] += hy[k, j] * w
            gradient[2] += hx[k, j] * dz * w
            gradient[3] += hy[k, j] * dz * w
            gradient[4] += (hx[k, j] * kx[k] + hy[k, j] * ky[k]) * w
    gradient[4] -= state[4] / (qop_prior_sigma * qop_prior_sigma)
    step = 0.0
    for i in range(5):
        step += inv[4, i] * gradient[i]
    return step


class _GaussNewtonScratch(NamedTuple):
    """Work arrays of `refine_through_field`: normal equations (a 5×5, b 5) of the current and of
    a trial point, the accumulated transport Jacobian (jac) and one interval's (step), a product
    (tmp), the RK4 stages (4, 4, 5), the inverse with its scratch (inv, work, vec 10), the step
    (delta), the transported state (state) and the trial point (point)."""
    a: np.ndarray
    b: np.ndarray
    trial_a: np.ndarray
    trial_b: np.ndarray
    jac: np.ndarray
    step: np.ndarray
    tmp: np.ndarray
    stages: np.ndarray
    inv: np.ndarray
    work: np.ndarray
    vec: np.ndarray
    delta: np.ndarray
    state: np.ndarray
    point: np.ndarray


@nb.njit(cache=True)
def _gauss_newton_scratch():
    return _GaussNewtonScratch(np.empty((5, 5)), np.empty(5), np.empty((5, 5)), np.empty(5), np.empty((5, 5)),
                               np.empty((5, 5)), np.empty((5, 5)), np.empty((4, 4, 5)), np.empty((5, 5)),
                               np.empty((5, 5)), np.empty(10), np.empty(5), np.empty(5), np.empty(5))


@nb.njit(cache=True)
def _trajectory_normal_equations(p, z, n_meas, hx, hy, m, sigma, qop_prior_sigma, field_kind, field_params,
                                 field_grid, a, b, w):
    """χ² of the hits to the RK4 trajectory of p (x, y, tx, ty, q/p at z[0]) plus the q/p prior
    (q/p/qop_prior_sigma)², and the Gauss–Newton normal equations a·δ = b (a 5×5, b 5) of its
    correction: rows H·J_k with J_k = ∂state(z_k)/∂p the product of the RK4 transport Jacobians
    (`rk4_transport_jacobian`). inf where the trajectory leaves the envelope. w: scratch."""
    state = w.state
    for i in range(5):
        state[i] = p[i]
    for i in range(5):
        b[i] = 0.0
        for j in range(5):
            a[i, j] = 0.0
            w.jac[i, j] = 1.0 if i == j else 0.0
    chi2 = 0.0
    zc = z[0]
    for k in range(z.size):
        if z[k] != zc:
            rk4_transport_jacobian(state, zc, z[k], SEED_RK4_STEP, field_kind, field_params, field_grid,
                                   w.step, w.stages)
            zc = z[k]
            if not in_envelope(state):
                return np.inf
            matmul55(w.step, w.jac, w.tmp)
            copy55(w.tmp, w.jac)
        for j in range(n_meas[k]):
            weight = 1.0 / (sigma[k, j] * sigma[k, j])
            r = m[k, j] - hx[k, j] * state[0] - hy[k, j] * state[1]
            chi2 += r * r * weight
            for c in range(5):
                rc = hx[k, j] * w.jac[0, c] + hy[k, j] * w.jac[1, c]
                b[c] += rc * r * weight
                for d in range(5):
                    a[c, d] += rc * (hx[k, j] * w.jac[0, d] + hy[k, j] * w.jac[1, d]) * weight
    prior = 1.0 / (qop_prior_sigma * qop_prior_sigma)
    chi2 += p[4] * p[4] * prior
    a[4, 4] += prior
    b[4] -= p[4] * prior
    return chi2


@nb.njit(cache=True)
def refine_through_field(state, z, n_meas, hx, hy, m, sigma, qop_prior_sigma, field_kind, field_params,
                         field_grid):
    """Gauss–Newton fit of the seed state (5 at z[0], in place) to the hits through the field
    map with the q/p prior N(0, qop_prior_sigma²) [1/MeV] of the least-squares fit (module
    docstring).

    Starts from state (its q/p halved until the trajectory stays in the envelope), steps
    δ = a⁻¹·b (`_trajectory_normal_equations`), halved until χ² does not grow, until
    |δq/p| ≤ REFINE_TOLERANCE·|q/p| or REFINE_MAX_ITERATIONS. Returns the q/p variance
    (a⁻¹)₄₄ [1/MeV²] at the result, or NaN (state unchanged) where no step could be made."""
    w = _gauss_newton_scratch()
    p = np.empty(5)
    for i in range(5):
        p[i] = state[i]
    chi2 = _trajectory_normal_equations(p, z, n_meas, hx, hy, m, sigma, qop_prior_sigma, field_kind,
                                        field_params, field_grid, w.a, w.b, w)
    for _ in range(REFINE_MAX_HALVINGS):
        if math.isfinite(chi2):
            break
        p[4] *= 0.5
        chi2 = _trajectory_normal_equations(p, z, n_meas, hx, hy, m, sigma, qop_prior_sigma, field_kind,
                                            field_params, field_grid, w.a, w.b, w)
    if not math.isfinite(chi2):
        return np.nan
    point = w.point
    for _ in range(REFINE_MAX_ITERATIONS):
        if not invert_spd(w.a, w.inv, w.work, w.vec):
            return np.nan
        matvec5(w.inv, w.b, w.delta)
        scale = 1.0
        trial_chi2 = np.inf
        for _ in range(REFINE_MAX_HALVINGS):
            for i in range(5):
                point[i] = p[i] + scale * w.delta[i]
            trial_chi2 = _trajectory_normal_equations(point, z, n_meas, hx, hy, m, sigma, qop_prior_sigma,
                                                      field_kind, field_params, field_grid, w.trial_a,
                                                      w.trial_b, w)
            if trial_chi2 <= chi2:
                break
            scale *= 0.5
        if not trial_chi2 <= chi2:
            break  # no step lowers χ²: p is the minimum along δ
        converged = abs(point[4] - p[4]) <= REFINE_TOLERANCE * abs(point[4])
        for i in range(5):
            p[i] = point[i]
        copy55(w.trial_a, w.a)
        for i in range(5):
            w.b[i] = w.trial_b[i]
        chi2 = trial_chi2
        if converged:
            break
    if not invert_spd(w.a, w.inv, w.work, w.vec):
        return np.nan
    for i in range(5):
        state[i] = p[i]
    return w.inv[4, 4]
