"""The global χ² fitter (GX2F, docs/physics.md#the-global-χ²-fitter-gx2f, seeds/002): track parameters plus scattering angles.

Unknowns of a track: the five parameters α = (x, y, tx, ty, q/p) at its first node
and two scattering angles θ_j = (θ1, θ2) at every material plane j it crosses between
its first and last node (z_first < z_j ≤ z_last, only where it crosses the plane's
active area, as in the reference extrapolator). θ1, θ2 are the projected angles
along u = (1, 0, −tx)/√(1+tx²) and v = d × u (d the direction; the convention of
`pkf.physics.materials.deflect`); each has the Highland width θ0_j (docs/physics.md#material-effects) as a
Gaussian prior. Minimised:

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

Per-node output states are the final trajectory (fitted α propagated with the fitted
angles); χ² its value at the last trajectory, ndf = Σ measurement dimensions − 5.
Outliers are removed as in the Kalman core (`pkf.fit.kalman`): the node whose
standardised smoothed χ² exceeds its cut by the largest factor is deactivated and the
track refitted from the current solution, at most `max_outliers` times. The number
of Gauss–Newton updates and the converged flag of each track's last fit are in
`GX2FResult.iterations` / `.converged`; a fit that did not converge within 5
updates keeps status ok (its state is the 5th update's), as the flag says.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from pkf.fit.extrapolator import (
    STATUS_EXTRAPOLATION_FAILED,
    STATUS_NO_SEED,
    STATUS_NOT_POSITIVE_DEFINITE,
    STATUS_OK,
    STATUS_TOO_FEW_HITS,
)
from pkf.fit.kalman import add_node_information, count_ndf, find_outlier, transport_information
from pkf.physics.linalg import (
    copy5,
    copy55,
    invert_spd,
    sandwich,
    search_sorted,
    set_identity,
    symmetrise,
)
from pkf.fit.reference import MAX_SLOPE
from pkf.fit.tracks import FitResult, fit_locations
from pkf.geometry.acceptance import in_active_area
from pkf.physics.materials import (
    SI_X0_MM,
    apply_energy_loss_to_qop,
    bethe_mean_loss,
    energy_loss_qop_derivative,
    highland_theta0,
)
from pkf.physics.transport import rk4_propagate_jacobian

#: ACTS Gx2FitterOptions defaults (seeds/002).
MAX_UPDATES = 5
RELATIVE_CHI2_CHANGE = 1e-7


@dataclass
class GX2FResult(FitResult):
    """`FitResult` plus, per track, the Gauss–Newton updates made in its last fit and
    whether that fit converged (relative χ² change < 1e−7 within `MAX_UPDATES`)."""

    iterations: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    converged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.bool_))


# ----------------------------------------------------------------------------------
# Propagation of (α, θ) with the Jacobians the solver needs
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, inline="always")
def _left_multiply(seg, a, tmp):
    """a = seg·a for a 5×5 a (tmp scratch)."""
    for i in range(5):
        for j in range(5):
            s = 0.0
            for l in range(5):
                s += seg[i, l] * a[l, j]
            tmp[i, j] = s
    copy55(tmp, a)


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


@nb.njit(cache=True)
def _segment(ext, s, z_from, z_to, jac, g, p_first, p_end, seg, tmp):
    """RK4 from z_from to z_to; jac = S·jac and G_p = S·G_p for planes p_first…p_end−1."""
    if z_to == z_from:
        return True
    new = rk4_propagate_jacobian(s, z_from, z_to, ext.max_step, ext.field_kind, ext.field_params,
                                 ext.field_grid, seg)
    for i in range(5):
        if not math.isfinite(new[i]):
            return False
        s[i] = new[i]
    if abs(s[2]) > MAX_SLOPE or abs(s[3]) > MAX_SLOPE:
        return False
    _left_multiply(seg, jac, tmp)
    for p in range(p_first, p_end):
        _left_multiply_52(seg, g[p])
    return True


@nb.njit(cache=True)
def _propagate(ext, alpha, theta, z, n, plane_lo, node_state, jac, g, theta0, step_plane, seg, tmp):
    """Trajectory of (α, θ): node states, step Jacobians jac[k] (node k−1 → k), for each
    plane slot p (plane index plane_lo + p) its G_p (5×2, effect of θ_p on the state at
    the next node) and Highland width theta0[p] (0: no material crossed there), and the
    slots of step k in step_plane[k]…step_plane[k+1]−1. Returns a status code."""
    s = node_state[0]
    copy5(alpha, s)
    n_planes = ext.plane_z.size
    pz = plane_lo
    step_plane[0] = 0
    step_plane[1] = 0
    for k in range(1, n):
        s_prev = node_state[k - 1]
        s = node_state[k]
        copy5(s_prev, s)
        jk = jac[k]
        set_identity(jk)
        p_first = pz - plane_lo
        step_plane[k] = p_first
        zc = z[k - 1]
        while pz < n_planes and ext.plane_z[pz] <= z[k]:
            p = pz - plane_lo
            if not _segment(ext, s, zc, ext.plane_z[pz], jk, g, p_first, p, seg, tmp):
                return STATUS_EXTRAPOLATION_FAILED
            zc = ext.plane_z[pz]
            gp = g[p]
            for i in range(5):
                gp[i, 0] = 0.0
                gp[i, 1] = 0.0
            theta0[p] = 0.0
            tx = s[2]
            ty = s[3]
            qop = s[4]
            if qop != 0.0 and in_active_area(
                    s[0], s[1], ext.plane_half_x[pz], ext.plane_half_y[pz], ext.plane_hole_radius[pz],
                    ext.plane_hole_half_x[pz], ext.plane_hole_half_y[pz], ext.plane_side[pz],
                    ext.plane_side_overlap[pz]):
                n2 = 1.0 + tx * tx + ty * ty
                nn = math.sqrt(n2)
                t = ext.plane_x_over_x0[pz] * nn
                if t > 0.0:
                    mom = 1.0 / abs(qop)
                    theta0[p] = highland_theta0(mom, ext.mass, 1.0, t)
                    r = math.sqrt(1.0 + tx * tx)
                    k00 = nn * r
                    k10 = nn * tx * ty / r
                    k11 = n2 / r
                    gp[2, 0] = k00
                    gp[3, 0] = k10
                    gp[3, 1] = k11
                    if ext.energy_loss:
                        delta_e = bethe_mean_loss(mom, ext.mass, t * SI_X0_MM)
                        d = energy_loss_qop_derivative(qop, ext.mass, delta_e)
                        s[4] = apply_energy_loss_to_qop(qop, ext.mass, delta_e)
                        for j in range(5):
                            jk[4, j] *= d
                        if not math.isfinite(s[4]):
                            return STATUS_EXTRAPOLATION_FAILED
                    s[2] = tx + k00 * theta[p, 0]
                    s[3] = ty + k10 * theta[p, 0] + k11 * theta[p, 1]
            pz += 1
        step_plane[k + 1] = pz - plane_lo
        if not _segment(ext, s, zc, z[k], jk, g, p_first, pz - plane_lo, seg, tmp):
            return STATUS_EXTRAPOLATION_FAILED
    return STATUS_OK


@nb.njit(cache=True)
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


@nb.njit(cache=True)
def _solve(n, n_meas, hx, hy, m, sigma, active, node_state, jac, g, theta, theta0, step_plane,
           gain, offset, s_inv, d_alpha, d_theta, node_cov, info, vec, yg, tmp, tmp2, tmp3, lu, spd_vec):
    """One Gauss–Newton step (see the module docstring). Writes δα, δθ and the posterior
    covariance of every node's state; returns False if the reduced normal matrix at the
    first node is not positive definite."""
    for i in range(5):
        vec[i] = 0.0
        for j in range(5):
            info[i, j] = 0.0
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
            for i in range(5):
                for c in range(2):
                    s = 0.0
                    for l in range(5):
                        s += info[i, l] * gp[l, c]
                    yg[i, c] = s
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
    if not invert_spd(info, node_cov[0], lu, spd_vec):
        return False
    for i in range(5):
        if not (node_cov[0, i, i] > 0.0 and math.isfinite(node_cov[0, i, i])):
            return False
    for i in range(5):
        s = 0.0
        for j in range(5):
            s += node_cov[0, i, j] * vec[j]
        d_alpha[i] = s
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
                return False
    return True


# ----------------------------------------------------------------------------------
# The batch kernel
# ----------------------------------------------------------------------------------


@nb.njit(cache=True)
def gx2f_fit_tracks(ext, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds,
                    outlier_cuts, max_outliers, max_updates, relative_chi2_change,
                    out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2, out_ndf,
                    out_n_outliers, out_iterations, out_converged):
    """GX2F of a batch of tracks (CSR nodes, as `pkf.fit.kalman.fit_tracks`) with the
    reference extrapolator context `ext`; seeds (T, 5) at each first node are the
    starting parameters (angles start at 0)."""
    n_tracks = offsets.size - 1
    max_nodes = 1
    for t in range(n_tracks):
        max_nodes = max(max_nodes, offsets[t + 1] - offsets[t])
    max_slots = ext.plane_z.size + 1
    node_state = np.empty((max_nodes, 5))
    jac = np.empty((max_nodes, 5, 5))
    step_plane = np.zeros(max_nodes + 1, dtype=np.int64)
    g = np.zeros((max_slots, 5, 2))
    theta = np.zeros((max_slots, 2))
    theta0 = np.zeros(max_slots)
    gain = np.empty((max_slots, 2, 5))
    offset = np.empty((max_slots, 2))
    s_inv = np.empty((max_slots, 2, 2))
    d_theta = np.zeros((max_slots, 2))
    alpha = np.empty(5)
    d_alpha = np.empty(5)
    info = np.empty((5, 5))
    vec = np.empty(5)
    yg = np.empty((5, 2))
    tmp = np.empty((5, 5))
    tmp2 = np.empty((5, 5))
    tmp3 = np.empty((5, 5))
    lu = np.empty((5, 5))
    spd_vec = np.empty(10)
    seg = np.empty((5, 5))
    for t in range(n_tracks):
        lo = offsets[t]
        hi = offsets[t + 1]
        n = hi - lo
        z = node_z[lo:hi]
        n_meas = node_n_meas[lo:hi]
        hx = node_hx[lo:hi]
        hy = node_hy[lo:hi]
        m = node_m[lo:hi]
        sigma = node_sigma[lo:hi]
        active = out_active[lo:hi]
        active[:] = True
        cov = out_cov[lo:hi]
        status = STATUS_OK
        chi2 = np.nan
        n_out = 0
        updates = 0
        converged = False
        ndf = 0
        plane_lo = search_sorted(ext.plane_z, z[0], True) if n > 0 else 0
        copy5(seeds[t], alpha)
        for p in range(max_slots):
            theta[p, 0] = 0.0
            theta[p, 1] = 0.0
        ok_seed = True
        for i in range(5):
            if not math.isfinite(alpha[i]):
                ok_seed = False
        if not ok_seed:
            status = STATUS_NO_SEED
        while status == STATUS_OK:
            ndf = count_ndf(n_meas, active)
            if ndf <= 0:
                status = STATUS_TOO_FEW_HITS
                break
            # ---- Gauss–Newton
            status = _propagate(ext, alpha, theta, z, n, plane_lo, node_state, jac, g, theta0, step_plane,
                                seg, tmp)
            if status != STATUS_OK:
                break
            n_slots = step_plane[n] if n > 1 else 0
            chi2 = _chi2(node_state, n, n_meas, hx, hy, m, sigma, active, theta, theta0, n_slots)
            updates = 0
            converged = False
            while True:
                if not _solve(n, n_meas, hx, hy, m, sigma, active, node_state, jac, g, theta, theta0,
                              step_plane, gain, offset, s_inv, d_alpha, d_theta, cov, info, vec, yg, tmp,
                              tmp2, tmp3, lu, spd_vec):
                    status = STATUS_NOT_POSITIVE_DEFINITE
                    break
                if converged or updates == max_updates:
                    break  # the covariance of the final trajectory is now in `cov`
                for i in range(5):
                    alpha[i] += d_alpha[i]
                for p in range(n_slots):
                    theta[p, 0] += d_theta[p, 0]
                    theta[p, 1] += d_theta[p, 1]
                updates += 1
                status = _propagate(ext, alpha, theta, z, n, plane_lo, node_state, jac, g, theta0,
                                    step_plane, seg, tmp)
                if status != STATUS_OK:
                    break
                if step_plane[n] != n_slots:  # (cannot happen: the plane range is fixed by z)
                    n_slots = step_plane[n]
                new_chi2 = _chi2(node_state, n, n_meas, hx, hy, m, sigma, active, theta, theta0, n_slots)
                if abs(new_chi2 - chi2) <= relative_chi2_change * new_chi2:
                    converged = True
                chi2 = new_chi2
            if status != STATUS_OK:
                break
            # ---- outliers (the Kalman core's rule)
            status, worst = find_outlier(node_state, cov, n_meas, hx, hy, m, sigma, active, outlier_cuts,
                                         out_node_chi2[lo:hi], False)
            if status != STATUS_OK:
                break
            if n_out < max_outliers and worst >= 0:
                active[worst] = False
                n_out += 1
                continue
            break
        if status == STATUS_OK:
            for k in range(n):
                copy5(node_state[k], out_state[lo + k])
        else:
            cov[:] = np.nan
        out_status[t] = status
        out_chi2[t] = chi2 if status == STATUS_OK else np.nan
        out_ndf[t] = ndf
        out_n_outliers[t] = n_out
        out_iterations[t] = updates
        out_converged[t] = converged and status == STATUS_OK


# ----------------------------------------------------------------------------------
# Python entry point
# ----------------------------------------------------------------------------------


def fit_batch_gx2f(extrapolator, batch, options, seeds: np.ndarray, seed_covs: np.ndarray | None = None,
                   beamline_extrapolator=None, max_updates: int = MAX_UPDATES,
                   relative_chi2_change: float = RELATIVE_CHI2_CHANGE) -> GX2FResult:
    """GX2F of every track of `batch` (a `TrackBatch`) with the reference extrapolator
    context `extrapolator` (`pkf.fit.reference.reference_extrapolator`), starting from
    `seeds` (T, 5) at the first nodes. `options` (`FitOptions`): the outlier cut and
    maximum number of outliers (iterations/smoother do not apply). seed_covs is accepted
    for the common fit signature and unused: the GX2F needs no prior covariance."""
    t = batch.n_tracks
    result = GX2FResult.empty(batch, iterations=np.zeros(t, dtype=np.int64), converged=np.zeros(t, dtype=np.bool_))
    gx2f_fit_tracks(extrapolator, batch.offsets, batch.z, batch.n_meas, batch.hx, batch.hy, batch.m,
                    batch.sigma, np.ascontiguousarray(seeds, dtype=np.float64), options.outlier_cuts(),
                    int(options.max_outliers), int(max_updates), float(relative_chi2_change),
                    result.node_state, result.node_cov, result.node_chi2, result.node_active, result.status,
                    result.chi2, result.ndf, result.n_outliers, result.iterations, result.converged)
    fit_locations(result, batch, beamline_extrapolator)
    return result
