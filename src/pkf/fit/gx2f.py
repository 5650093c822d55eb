"""The global χ² fitter (GX2F, docs/physics.md#the-global-χ²-fitter-gx2f, seeds/002): track parameters plus scattering angles.

Unknowns of a track: the five parameters α = (x, y, tx, ty, q/p) at its first node
and two scattering angles θ_j = (θ1, θ2) at every material plane j it crosses between
its first and last node (z_first < z_j ≤ z_last, only where it crosses the plane's
active area, as in the reference extrapolator). θ1, θ2 are the projected angles
along u = (1, 0, −tx)/√(1+tx²) and v = d × u (d the direction; the convention of
`pkf.physics.materials.deflect`); each has the Highland width θ0_j (docs/physics.md#material-effects) as a
Gaussian prior (evaluated at the local q/p; for VELO-only tracks at the momentum
assumption's, `_width_shift`). Minimised:

    χ²(α, θ) = Σ_nodes Σ_meas (m − h·s_k(α, θ))²/σ² + Σ_planes |θ_j|²/θ0_j²

with s_k the state at node k from the reference propagation (RK4 with Jacobian through
the field map, Bethe mean energy loss applied to q/p at each plane for the mass
hypothesis, exactly as `pkf.fit.reference`). At plane j the slopes receive the kick
(tx, ty) += K_j·θ_j with K_j = ∂(tx, ty)/∂(θ1, θ2) at θ = 0:

    K = [[N·√(1+tx²), 0], [N·tx·ty/√(1+tx²), N²/√(1+tx²)]],  N = √(1+tx²+ty²),

for which θ0²·K·Kᵀ is the Kalman fitters' thin-scatterer noise Q (docs/physics.md#material-effects), so
the two fitters minimise the same χ² and their states agree at convergence.

Gauss–Newton (ACTS `nUpdateMax` = 5, `relChi2changeCutOff` = 1e−7): propagate
(α, θ), linearise, solve the normal equations for (δα, δθ), update, repeat until the
relative χ² change between successive trajectories is below 1e−7 (converged) or 5
updates were made. The covariance of α is the inverse of the final normal matrix's
5×5 block after the angles are marginalised (its Schur complement).

Solving in linear time (the band structure). The normal matrix over (α, θ_1…θ_M) is
dense in the angles (an angle couples to every later measurement through the
Jacobian chain), so it is never built. Instead the angles are eliminated one plane at
a time from the last node backwards — dynamic programming on the quadratic form
δsᵀY δs − 2 yᵀδs of "all downstream measurements and angles, minimised over those
angles", as a function of the state deviation δs at the current node:

- node k:  Y += hᵀh/σ², y += hᵀr/σ² (r = m − h·s_k the residual on the trajectory);
- plane j between nodes k−1 and k, with G_j = (Jacobian from plane j to node k)·K_j
  (5×2) and Λ_j = 1/θ0_j²: S = G_jᵀY G_j + Λ_j (2×2), L_j = S⁻¹G_jᵀY,
  a_j = S⁻¹(G_jᵀy − Λ_j θ̄_j); then Y ← Y − Y G_j L_j, y ← y − Y G_j a_j
  (the Schur complement of θ_j; θ̄_j its current value);
- step k−1 → k with Jacobian F_k (energy loss included): Y ← F_kᵀ Y F_k, y ← F_kᵀ y.

At the first node δα = Y⁻¹y and Cov(α) = Y⁻¹ (the marginalised 5×5 block). A forward
sweep then substitutes: δθ_j = a_j − L_j·v (v the state deviation accumulated so far at
node k), v += G_j δθ_j, and carries the posterior covariance of each node's state
C ← (I − G_j L_j)·C·(I − G_j L_j)ᵀ + G_j S⁻¹ G_jᵀ, C ← F·C·Fᵀ — exact, because the
posterior factorises as p(α)·Π_j p(θ_j | state upstream of j). Cost per iteration:
one propagation plus O(5³) per node and per plane — linear in the number of planes.

Material of a fit: the planes whose active area a fit's *first* trajectory crosses carry
its scattering angles for all its Gauss–Newton updates (the path length still follows the
slopes). Re-deciding the crossings at every update let planes, and the angles fitted at
them, come and go between updates for tracks that skim an active-area edge (the VELO's
5.1 mm inner hole): Gauss–Newton then alternated without converging (a Pythia VELO-only
track: χ² 7,407 after 5 updates, 2,902 after 50, against 22.5 with the crossings kept;
271 of 16,546 fits of 60 minbias events changed, none of those whose crossings never
flipped). The refit after an outlier decides them again from its own first trajectory.

Per-node output states are the final trajectory (fitted α propagated with the fitted
angles); χ² its value at the last trajectory, ndf = Σ measurement dimensions − 5.
Outliers are removed as in the Kalman core (`pkf.fit.kalman`): the node whose
standardised smoothed χ² exceeds its cut by the largest factor is deactivated and the
track refitted from the current solution, at most `max_outliers` times. The number
of Gauss–Newton updates and the converged flag of each track's last fit are in
`GX2FResult.iterations` / `.converged`.

Not converged. A fit still above the relative-change cut after 5 updates is judged by
the χ² decrease its next Gauss–Newton step predicts, D = bᵀA⁻¹b (b the gradient, A the
normal matrix of the final trajectory; `GX2FResult.decrease`). D = δᵀAδ is the squared
distance from the trajectory to the minimum of its linearisation in units of the fit's
covariance: D ≤ `MAX_PREDICTED_DECREASE` (1) keeps status ok — within one standard
deviation of the minimum in every direction; only the cut of 1e−7 is not met — and a
larger D gives status "did not converge" and NaN states, as the other fitters' failures. Measured
on the 4,158 lhcb-like minimum-bias truth tracks of 15 events (ν = 7.6, seed 31):
converged fits end with D ≤ 7e−10; the 232 others kept have median D 1e−11, at most 0.13;
5 did not converge, D = 2.5–7,900 (3 upstream tracks, whose q/p only the VELO–UT kick
measures, e.g. tests/fit/data/gx2f_does_not_converge.npz: D = 1,036 after 5 updates and
372 after 50, where the Highland widths that follow q/p keep moving the minimum).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.options import GX2FOptions
from pkf.fit.driver import max_nodes, register_fitter
from pkf.fit.kalman import add_node_information, transport_information
from pkf.physics.linalg import (
    copy5,
    invert_spd,
    matmul52,
    sandwich,
    search_sorted,
    set_identity,
    symmetrise,
    zero5,
    zero55,
)
from pkf.fit.propagate import (
    mean_energy_loss,
    plane_path_x0,
    propagator,
    register_actor,
    rk4_segment,
    scattering_width,
)
from pkf.fit.seed import TRACK_VELO
from pkf.physics.materials import path_length_x0
from pkf.fit.status import (
    STATUS_EXTRAPOLATION_FAILED,
    STATUS_NO_SEED,
    STATUS_NOT_CONVERGED,
    STATUS_NOT_POSITIVE_DEFINITE,
    STATUS_OK,
)
from pkf.jit import NO_REFCOUNT
from pkf.fit.tracks import FitResult, collect_track_states, fit_locations, run_fitter

#: ACTS Gx2FitterOptions defaults (seeds/002).
MAX_UPDATES = GX2FOptions.max_updates  # the defaults live with the option object
RELATIVE_CHI2_CHANGE = GX2FOptions.relative_chi2_change
#: A fit not converged within its updates whose next step predicts a χ² decrease above
#: this is "did not converge" (module docstring).
MAX_PREDICTED_DECREASE = 1.0


@dataclass
class GX2FResult(FitResult):
    """`FitResult` plus, per track, the Gauss–Newton updates made in its last fit and
    whether that fit converged (relative χ² change < 1e−7 within `MAX_UPDATES`), and the
    χ² decrease D = bᵀA⁻¹b the next Gauss–Newton step predicts at its final trajectory
    (NaN for a failed fit)."""

    iterations: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    converged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.bool_))
    decrease: np.ndarray = field(default_factory=lambda: np.zeros(0))


# ----------------------------------------------------------------------------------
# Propagation of (α, θ) with the Jacobians the solver needs
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, inline="always")
def _left_multiply_52(seg, g):
    """g = seg·g for a 5×2 g."""
    for c in range(2):
        v0 = g[0, c]
        v1 = g[1, c]
        v2 = g[2, c]
        v3 = g[3, c]
        v4 = g[4, c]
        for i in range(5):
            g[i, c] = seg[i, 0] * v0 + seg[i, 1] * v1 + seg[i, 2] * v2 + seg[i, 3] * v3 + seg[i, 4] * v4


class ScatteringAngles(NamedTuple):
    """Propagator actor of the GX2F trajectory, one step k−1 → k at a time (k = cursor[0]):
    node_state[k] (5) transported in place with the current angles θ applied at each
    plane, jac[k] (5×5) the step's Jacobian; for the plane slots p (plane index
    plane_lo + p) crossed so far in this step, from p_first = cursor[1] to cursor[2] − 1
    (the interaction advances cursor[2]: the slots need no search of the plane list), their G_p
    (g, 5×2 each, effect of θ_p on the state downstream) and Highland widths theta0
    (0: no material crossed there); seg, tmp 5×5 scratch, stages (4, 5, 5) the RK stages'
    scratch; width_shift [1/MeV] added to the local q/p where the Highland widths are
    evaluated (0: the state's own q/p; VELO-only tracks: prior − α's q/p, so that the widths
    are those of the momentum assumption of `pkf.fit.seed`, see `_width_shift`); crossed
    (per slot): whether the trajectory crosses the plane's active area — recorded, or with
    `freeze` read: the material of a fit's Gauss–Newton updates is that of its first
    trajectory (`_gx2f_fit`). Built once per trajectory."""

    node_state: np.ndarray
    jac: np.ndarray
    g: np.ndarray
    theta: np.ndarray
    theta0: np.ndarray
    cursor: np.ndarray
    plane_lo: int
    seg: np.ndarray
    tmp: np.ndarray
    stages: np.ndarray
    width_shift: float
    crossed: np.ndarray
    freeze: bool


@nb.njit(cache=True, inline="always")
def _angles_transport(actor, ext, z_from, z_to, crossed):
    """RK4 segment; jac = S·jac and G_p = S·G_p for the slots crossed so far."""
    if z_to == z_from:
        return STATUS_OK
    k = actor.cursor[0]
    if not rk4_segment(ext, actor.node_state[k], z_from, z_to, actor.seg, actor.jac[k], actor.tmp, actor.stages):
        return STATUS_EXTRAPOLATION_FAILED
    p_first = actor.cursor[1]
    for p in range(p_first, p_first + crossed):
        _left_multiply_52(actor.seg, actor.g[p])
    return STATUS_OK


@nb.njit(cache=True, inline="always")
def _angles_interact(actor, ext, k, direction):
    """Plane k: its slot's Highland width and G = K (module docstring), the Bethe mean loss
    on q/p (row 4 of jac scaled by ∂qop′/∂qop), then the kick K·θ on the slopes."""
    s = actor.node_state[actor.cursor[0]]
    p = k - actor.plane_lo
    actor.cursor[2] = p + 1
    gp = actor.g[p]
    for i in range(5):
        gp[i, 0] = 0.0
        gp[i, 1] = 0.0
    actor.theta0[p] = 0.0
    tx = s[2]
    ty = s[3]
    qop = s[4]
    if actor.freeze:
        t = path_length_x0(ext.plane_x_over_x0[k], tx, ty) if actor.crossed[p] and qop != 0.0 else 0.0
    else:
        t = plane_path_x0(ext, k, s)
        actor.crossed[p] = t > 0.0
    if t > 0.0:
        n2 = 1.0 + tx * tx + ty * ty
        nn = math.sqrt(n2)
        actor.theta0[p] = scattering_width(ext, t, qop + actor.width_shift)
        r = math.sqrt(1.0 + tx * tx)
        k00 = nn * r
        k10 = nn * tx * ty / r
        k11 = n2 / r
        gp[2, 0] = k00
        gp[3, 0] = k10
        gp[3, 1] = k11
        if ext.energy_loss:
            new_qop, d = mean_energy_loss(ext, t, qop, direction)
            s[4] = new_qop
            jk = actor.jac[actor.cursor[0]]
            for j in range(5):
                jk[4, j] *= d
            if not math.isfinite(s[4]):
                return STATUS_EXTRAPOLATION_FAILED
        s[2] = tx + k00 * actor.theta[p, 0]
        s[3] = ty + k10 * actor.theta[p, 0] + k11 * actor.theta[p, 1]
    return STATUS_OK


register_actor(ScatteringAngles, _angles_transport, _angles_interact)
_propagate_angles = propagator(_angles_transport, _angles_interact)


@nb.njit(cache=True, **NO_REFCOUNT)
def _propagate(ext, alpha, theta, z, n, plane_lo, node_state, jac, g, theta0, step_plane, seg, tmp, cursor, stages,
               crossed, width_shift=0.0, freeze=False):
    """Trajectory of (α, θ): node states, step Jacobians jac[k] (node k−1 → k), for each
    plane slot p (plane index plane_lo + p) its G_p (5×2, effect of θ_p on the state at
    the next node) and Highland width theta0[p] (0: no material crossed there), and the
    slots of step k in step_plane[k]…step_plane[k+1]−1; cursor (3) int scratch, stages
    (4, 5, 5) the RK stages' scratch; width_shift, crossed (per slot) and freeze as in
    `ScatteringAngles`. Returns a status code."""
    copy5(alpha, node_state[0])
    step_plane[0] = 0
    step_plane[1] = 0
    actor = ScatteringAngles(node_state, jac, g, theta, theta0, cursor, plane_lo, seg, tmp, stages, width_shift,
                             crossed, freeze)
    for k in range(1, n):
        copy5(node_state[k - 1], node_state[k])
        set_identity(jac[k])
        p_first = step_plane[k]  # the planes of step k follow those of step k − 1
        cursor[0] = k
        cursor[1] = p_first
        cursor[2] = p_first
        status = _propagate_angles(ext, actor, z[k - 1], z[k])
        if status != STATUS_OK:
            return status
        step_plane[k + 1] = cursor[2]
    return STATUS_OK


@nb.njit(cache=True, **NO_REFCOUNT)
def _chi2(node_state, n, n_meas, hx, hy, m, sigma, active, theta, theta0, n_slots):
    """χ² of a trajectory: measurement residuals plus the angles' priors."""
    chi2 = 0.0
    for k in range(n):
        if active[k]:
            for j in range(n_meas[k]):
                r = m[k, j] - (hx[k, j] * node_state[k, 0] + hy[k, j] * node_state[k, 1])
                chi2 += r * r / (sigma[k, j] * sigma[k, j])
    for p in range(n_slots):
        if theta0[p] > 0.0:
            chi2 += (theta[p, 0] * theta[p, 0] + theta[p, 1] * theta[p, 1]) / (theta0[p] * theta0[p])
    return chi2


# ----------------------------------------------------------------------------------
# Linear-time Gauss–Newton step: backward elimination of the angles, forward substitution
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, **NO_REFCOUNT)
def _solve(n, n_meas, hx, hy, m, sigma, active, node_state, jac, g, theta, theta0, step_plane,
           gain, offset, s_inv, d_alpha, d_theta, node_cov, info, vec, yg, tmp, tmp2, tmp3, lu, spd_vec,
           qop_weight=0.0, qop_prior=0.0):
    """One Gauss–Newton step (see the module docstring). Writes δα, δθ and the posterior
    covariance of every node's state; returns the χ² decrease the step predicts,
    D = bᵀA⁻¹b = Σ_j b_jᵀS_j⁻¹b_j + yᵀY⁻¹y (each elimination of θ_j lowers the minimum of
    the quadratic form by b_jᵀS_j⁻¹b_j = b_j·a_j), or NaN if the reduced normal matrix at
    the first node is not positive definite. qop_weight [MeV²] > 0 adds the Gaussian prior
    qop_weight·(q/p − qop_prior)² on the first node's q/p (VELO-only tracks)."""
    zero5(vec)
    zero55(info)
    decrease = 0.0
    for k in range(n - 1, -1, -1):
        if active[k]:
            add_node_information(info, vec, n_meas[k], hx[k], hy[k], m[k], sigma[k], node_state[k])
        if k == 0:
            break
        # eliminate the angles of step k−1 → k, downstream plane first
        for p in range(step_plane[k + 1] - 1, step_plane[k] - 1, -1):
            if not theta0[p] > 0.0:
                continue
            gp = g[p]
            lam = 1.0 / (theta0[p] * theta0[p])
            matmul52(info, gp, yg)
            s00 = lam
            s01 = 0.0
            s11 = lam
            b0 = -lam * theta[p, 0]
            b1 = -lam * theta[p, 1]
            for l in range(5):
                s00 += gp[l, 0] * yg[l, 0]
                s01 += gp[l, 0] * yg[l, 1]
                s11 += gp[l, 1] * yg[l, 1]
                b0 += gp[l, 0] * vec[l]
                b1 += gp[l, 1] * vec[l]
            det = s00 * s11 - s01 * s01
            si = s_inv[p]
            si[0, 0] = s11 / det
            si[1, 1] = s00 / det
            si[0, 1] = -s01 / det
            si[1, 0] = -s01 / det
            a0 = si[0, 0] * b0 + si[0, 1] * b1
            a1 = si[1, 0] * b0 + si[1, 1] * b1
            offset[p, 0] = a0
            offset[p, 1] = a1
            decrease += a0 * b0 + a1 * b1
            lp = gain[p]
            for i in range(5):
                # L = S⁻¹·(Y·G)ᵀ (Y symmetric)
                lp[0, i] = si[0, 0] * yg[i, 0] + si[0, 1] * yg[i, 1]
                lp[1, i] = si[1, 0] * yg[i, 0] + si[1, 1] * yg[i, 1]
            for i in range(5):
                vec[i] -= yg[i, 0] * a0 + yg[i, 1] * a1
                for j in range(5):
                    info[i, j] -= yg[i, 0] * lp[0, j] + yg[i, 1] * lp[1, j]
            symmetrise(info)
        # transport to node k−1: Y ← FᵀYF, y ← Fᵀy
        transport_information(jac[k], info, vec, info, tmp, tmp2[0])
    info[4, 4] += qop_weight
    vec[4] += qop_weight * (qop_prior - node_state[0, 4])
    if not invert_spd(info, node_cov[0], lu, spd_vec):
        return np.nan
    for i in range(5):
        if not (node_cov[0, i, i] > 0.0 and math.isfinite(node_cov[0, i, i])):
            return np.nan
    for i in range(5):
        s = 0.0
        for j in range(5):
            s += node_cov[0, i, j] * vec[j]
        d_alpha[i] = s
        decrease += s * vec[i]
    # forward substitution: δθ and node covariances
    v = vec  # reuse: v is the state deviation at the current position
    copy5(d_alpha, v)
    for k in range(1, n):
        f = jac[k]
        for i in range(5):
            s = 0.0
            for l in range(5):
                s += f[i, l] * v[l]
            tmp2[0, i] = s
        for i in range(5):
            v[i] = tmp2[0, i]
        sandwich(f, node_cov[k - 1], tmp, node_cov[k])
        c = node_cov[k]
        for p in range(step_plane[k], step_plane[k + 1]):
            if not theta0[p] > 0.0:
                d_theta[p, 0] = 0.0
                d_theta[p, 1] = 0.0
                continue
            gp = g[p]
            lp = gain[p]
            e0 = offset[p, 0]
            e1 = offset[p, 1]
            for l in range(5):
                e0 -= lp[0, l] * v[l]
                e1 -= lp[1, l] * v[l]
            d_theta[p, 0] = e0
            d_theta[p, 1] = e1
            for i in range(5):
                v[i] += gp[i, 0] * e0 + gp[i, 1] * e1
            # C ← (I − G L) C (I − G L)ᵀ + G S⁻¹ Gᵀ
            for i in range(5):
                for j in range(5):
                    tmp[i, j] = (1.0 if i == j else 0.0) - (gp[i, 0] * lp[0, j] + gp[i, 1] * lp[1, j])
            sandwich(tmp, c, tmp2, tmp3)
            si = s_inv[p]
            for i in range(5):
                for j in range(5):
                    c[i, j] = tmp3[i, j] + (
                        gp[i, 0] * (si[0, 0] * gp[j, 0] + si[0, 1] * gp[j, 1])
                        + gp[i, 1] * (si[1, 0] * gp[j, 0] + si[1, 1] * gp[j, 1]))
            symmetrise(c)
        for i in range(5):
            if not (c[i, i] > 0.0 and math.isfinite(c[i, i])):
                return np.nan
    return decrease


# ----------------------------------------------------------------------------------
# The batch kernel
# ----------------------------------------------------------------------------------


class Gx2fFitter(NamedTuple):
    """The GX2F as a fitter of `pkf.fit.driver.fit_tracks`: the reference extrapolator
    context, the Gauss–Newton options, the per-track outputs `iterations`, `converged`
    and `decrease`, and scratch for the batch's longest track and every plane slot
    (`gx2f_fitter` allocates it; `theta0_last`: the Highland widths of the trajectory the
    current update was linearised on, for the line search). α and θ carry over from a
    fit to the refit after an outlier (the refit starts from the current solution)."""

    ext: tuple
    max_updates: int
    relative_chi2_change: float
    measurement_only_fallback: bool
    out_iterations: np.ndarray
    out_converged: np.ndarray
    out_decrease: np.ndarray
    node_state: np.ndarray
    jac: np.ndarray
    step_plane: np.ndarray
    cursor: np.ndarray
    g: np.ndarray
    theta: np.ndarray
    theta0: np.ndarray
    gain: np.ndarray
    offset: np.ndarray
    s_inv: np.ndarray
    d_theta: np.ndarray
    alpha: np.ndarray
    d_alpha: np.ndarray
    info: np.ndarray
    vec: np.ndarray
    yg: np.ndarray
    tmp: np.ndarray
    tmp2: np.ndarray
    tmp3: np.ndarray
    lu: np.ndarray
    spd_vec: np.ndarray
    seg: np.ndarray
    stages: np.ndarray
    qop_weight: np.ndarray
    qop_prior: np.ndarray
    crossed: np.ndarray
    theta0_last: np.ndarray


def gx2f_fitter(ext, n_nodes: int, n_tracks: int, max_updates: int = MAX_UPDATES,
                relative_chi2_change: float = RELATIVE_CHI2_CHANGE, qop_weight: np.ndarray | None = None,
                qop_prior: np.ndarray | None = None) -> Gx2fFitter:
    """The GX2F of reference context `ext` for `n_tracks` tracks of up to `n_nodes` nodes;
    qop_weight/qop_prior (T): each track's q/p prior (weight 0: none, `_solve`)."""
    if qop_weight is None or qop_prior is None:
        qop_weight = np.zeros(n_tracks)
        qop_prior = np.zeros(n_tracks)
    slots = ext.plane_z.size + 1
    return Gx2fFitter(
        ext, int(max_updates), float(relative_chi2_change), False, np.zeros(n_tracks, dtype=np.int64),
        np.zeros(n_tracks, dtype=np.bool_), np.full(n_tracks, np.nan), np.empty((n_nodes, 5)), np.empty((n_nodes, 5, 5)), np.zeros(n_nodes + 1, dtype=np.int64),
        np.zeros(3, dtype=np.int64),
        np.zeros((slots, 5, 2)), np.zeros((slots, 2)), np.zeros(slots), np.empty((slots, 2, 5)),
        np.empty((slots, 2)), np.empty((slots, 2, 2)), np.zeros((slots, 2)), np.empty(5), np.empty(5),
        np.empty((5, 5)), np.empty(5), np.empty((5, 2)), np.empty((5, 5)), np.empty((5, 5)), np.empty((5, 5)),
        np.empty((5, 5)), np.empty(10), np.empty((5, 5)), np.empty((4, 5, 5)),
        np.ascontiguousarray(qop_weight, dtype=np.float64), np.ascontiguousarray(qop_prior, dtype=np.float64),
        np.zeros(slots, dtype=np.bool_), np.zeros(slots))


@nb.njit(cache=True, **NO_REFCOUNT)
def _gx2f_begin(f, t, seed):
    """Start from α = seed, θ = 0; STATUS_NO_SEED for a non-finite seed."""
    f.out_iterations[t] = 0
    f.out_converged[t] = False
    f.out_decrease[t] = np.nan
    copy5(seed, f.alpha)
    for p in range(f.theta.shape[0]):
        f.theta[p, 0] = 0.0
        f.theta[p, 1] = 0.0
    for i in range(5):
        if not math.isfinite(f.alpha[i]):
            return STATUS_NO_SEED
    return STATUS_OK


@nb.njit(cache=True, inline="always")
def _width_shift(f, t):
    """Shift [1/MeV] of the q/p at which track t's Highland widths are evaluated: 0 without
    a q/p prior; with one (VELO-only tracks, whose q/p the hits do not measure) prior − α's
    q/p, so the widths are the momentum assumption's at every update. Widths that followed
    the free q/p made Gauss–Newton alternate between two trajectories (narrow widths → the
    scattering fitted as curvature, |q/p| ×10; wide widths → q/p back at the prior):
    measured on the real VELO-only tracks of 15 minbias events (ν = 7.6, triplet pattern),
    22 % converged within 5 updates and χ²/ndf had mean 18, >5 for 5.5 %."""
    if f.qop_weight[t] > 0.0:
        return f.qop_prior[t] - f.alpha[4]
    return 0.0


#: A Gauss–Newton update that raises χ² by more than this fraction is halved (at most
#: MAX_STEP_HALVINGS times): a line search along the Newton direction. Without it, on the
#: real VELO-only tracks of 60 minbias events (ν = 7.6), 5.1 % ended with χ²/ndf > 5 and a
#: few at 10³–10⁵, status ok, where the Kalman fits of the same hits give ~1.
#: The χ² it compares is the one the update minimised: its Highland widths are those of
#: the trajectory the update was linearised on (`Gx2fFitter.theta0_last`); the widths move
#: to the new trajectory's between updates, as the Kalman fitters' noise follows their
#: linearisation point. Judged with the widths of the new trajectory (which follow q/p and
#: the slopes, terms the Newton direction does not contain), steps that Gauss–Newton
#: predicted to lower χ² by 2–20 were halved to nothing and the fit stalled: on the truth
#: tracks of 15 minimum-bias events (ν = 7.6, seed 31) 9 of 4,158 did not converge and 9
#: failed to extrapolate; with the update's own widths 5 and 4, converged 3,819 → 3,917,
#: first-hit pull widths unchanged (±0.001), 252 fits changed, 5 by more than 0.1σ (upstream
#: tracks with two χ² minima).
STEP_HALVING_TOLERANCE = 1e-6
MAX_STEP_HALVINGS = 8


@nb.njit(cache=True, inline="always")
def _track_chi2(f, t, n, n_meas, hx, hy, m, sigma, active, widths, n_slots):
    """χ² of track t's current trajectory with the Highland widths `widths` (f.theta0: the
    trajectory's own; f.theta0_last: those of the update's linearisation point), plus its
    q/p prior term."""
    chi2 = _chi2(f.node_state, n, n_meas, hx, hy, m, sigma, active, f.theta, widths, n_slots)
    return chi2 + f.qop_weight[t] * (f.alpha[4] - f.qop_prior[t]) ** 2


@nb.njit(cache=True, **NO_REFCOUNT)
def _halve_step(f, t, z, n, plane_lo, n_slots, n_meas, hx, hy, m, sigma, active):
    """Take back half of the last update (d_alpha, d_theta halved), propagate again;
    returns (status, χ² of the trajectory with the widths of `theta0_last`)."""
    for i in range(5):
        f.d_alpha[i] *= 0.5
        f.alpha[i] -= f.d_alpha[i]
    for p in range(n_slots):
        f.d_theta[p, 0] *= 0.5
        f.d_theta[p, 1] *= 0.5
        f.theta[p, 0] -= f.d_theta[p, 0]
        f.theta[p, 1] -= f.d_theta[p, 1]
    status = _propagate(f.ext, f.alpha, f.theta, z, n, plane_lo, f.node_state, f.jac, f.g, f.theta0, f.step_plane,
                        f.seg, f.tmp, f.cursor, f.stages, f.crossed, _width_shift(f, t), True)
    if status != STATUS_OK:
        return status, np.nan
    return status, _track_chi2(f, t, n, n_meas, hx, hy, m, sigma, active, f.theta0_last, n_slots)


@nb.njit(cache=True, **NO_REFCOUNT)
def _gx2f_fit(f, t, lo, hi, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, out_state, out_cov):
    """Gauss–Newton from the current (α, θ) (module docstring): node states of the final
    trajectory and their covariances into out_state/out_cov; returns (status, χ²)."""
    n = z.size
    plane_lo = search_sorted(f.ext.plane_z, z[0], True)
    chi2 = np.nan
    status = _propagate(f.ext, f.alpha, f.theta, z, n, plane_lo, f.node_state, f.jac, f.g, f.theta0, f.step_plane,
                        f.seg, f.tmp, f.cursor, f.stages, f.crossed, _width_shift(f, t), False)
    if status != STATUS_OK:
        return status, chi2
    n_slots = f.step_plane[n] if n > 1 else 0
    chi2 = _track_chi2(f, t, n, n_meas, hx, hy, m, sigma, active, f.theta0, n_slots)
    updates = 0
    converged = False
    decrease = np.nan
    while True:
        decrease = _solve(n, n_meas, hx, hy, m, sigma, active, f.node_state, f.jac, f.g, f.theta, f.theta0,
                          f.step_plane, f.gain, f.offset, f.s_inv, f.d_alpha, f.d_theta, out_cov, f.info, f.vec,
                          f.yg, f.tmp, f.tmp2, f.tmp3, f.lu, f.spd_vec, f.qop_weight[t], f.qop_prior[t])
        if math.isnan(decrease):
            status = STATUS_NOT_POSITIVE_DEFINITE
            break
        if converged or updates == f.max_updates:
            break  # the covariance of the final trajectory is now in `out_cov`
        for p in range(n_slots):
            f.theta0_last[p] = f.theta0[p]
        for i in range(5):
            f.alpha[i] += f.d_alpha[i]
        for p in range(n_slots):
            f.theta[p, 0] += f.d_theta[p, 0]
            f.theta[p, 1] += f.d_theta[p, 1]
        updates += 1
        status = _propagate(f.ext, f.alpha, f.theta, z, n, plane_lo, f.node_state, f.jac, f.g, f.theta0,
                            f.step_plane, f.seg, f.tmp, f.cursor, f.stages, f.crossed, _width_shift(f, t), True)
        if status != STATUS_OK:
            break
        if f.step_plane[n] != n_slots:  # (cannot happen: the plane range is fixed by z)
            n_slots = f.step_plane[n]
        line_chi2 = _track_chi2(f, t, n, n_meas, hx, hy, m, sigma, active, f.theta0_last, n_slots)
        halvings = 0
        while line_chi2 > chi2 * (1.0 + STEP_HALVING_TOLERANCE) and halvings < MAX_STEP_HALVINGS:
            status, line_chi2 = _halve_step(f, t, z, n, plane_lo, n_slots, n_meas, hx, hy, m, sigma, active)
            if status != STATUS_OK:
                break
            halvings += 1
        if status != STATUS_OK:
            break
        new_chi2 = _track_chi2(f, t, n, n_meas, hx, hy, m, sigma, active, f.theta0, n_slots)
        if abs(new_chi2 - chi2) <= f.relative_chi2_change * new_chi2:
            converged = True
        chi2 = new_chi2
    f.out_iterations[t] = updates
    f.out_converged[t] = converged
    f.out_decrease[t] = decrease
    if status == STATUS_OK and not converged and decrease > MAX_PREDICTED_DECREASE:
        status = STATUS_NOT_CONVERGED
    if status == STATUS_OK:
        for k in range(n):
            copy5(f.node_state[k], out_state[k])
    return status, chi2


@nb.njit(cache=True, **NO_REFCOUNT)
def _gx2f_end(f, t, lo, hi, status, out_state, out_cov):
    """A failed track has NaN states and covariances and is not converged."""
    if status != STATUS_OK:
        out_state[:] = np.nan
        out_cov[:] = np.nan
        f.out_converged[t] = False


register_fitter(Gx2fFitter, _gx2f_begin, _gx2f_fit, _gx2f_end, allocates=False)


# ----------------------------------------------------------------------------------
# Python entry point
# ----------------------------------------------------------------------------------


def fit_batch_gx2f(extrapolator, batch, options, seeds: np.ndarray, seed_covs: np.ndarray | None = None,
                   beamline_extrapolator=None, track_states: bool = False) -> GX2FResult:
    """GX2F of every track of `batch` (a `TrackBatch`) with the reference extrapolator
    context `extrapolator` (`pkf.fit.reference.reference_extrapolator`), starting from
    `seeds` (T, 5) at the first nodes. `options` (`FitOptions`): the outlier cut,
    maximum number of outliers and the Gauss–Newton options `options.gx2f`. The GX2F needs
    no prior covariance, except on the q/p of VELO-only tracks (``batch.track_type``), which
    the hits do not measure: there the seed's q/p and its variance from seed_covs are a
    Gaussian prior (the momentum assumption of `pkf.fit.seed`). With `track_states`,
    `result.track_states` holds the node states as "smoothed" only: a global fit has no
    predicted or filtered state (as ACTS's GX2F)."""
    qop_weight = np.zeros(batch.n_tracks)
    if batch.track_type is not None and seed_covs is not None:
        velo = batch.track_type == TRACK_VELO
        qop_weight[velo] = 1.0 / seed_covs[velo, 4, 4]
    fitter = gx2f_fitter(extrapolator, max_nodes(batch.offsets), batch.n_tracks, options.gx2f.max_updates,
                         options.gx2f.relative_chi2_change, qop_weight, np.ascontiguousarray(seeds[:, 4]))
    result = GX2FResult.empty(batch, iterations=fitter.out_iterations, converged=fitter.out_converged,
                              decrease=fitter.out_decrease)
    run_fitter(fitter, batch, options, seeds, np.zeros((batch.n_tracks, 5, 5)), result)
    fit_locations(result, batch, beamline_extrapolator)
    if track_states:
        result.track_states = collect_track_states(
            batch, result, {"smoothed": (result.node_state.copy(), result.node_cov.copy())})
    return result
