"""Runge–Kutta transport of a track state in z through a magnetic field, with its Jacobian.

docs/physics.md (equations of motion, simulation transport, reference fitter). State at a plane
z: (x, y, tx, ty, qop) in mm, mm, 1, 1, 1/MeV; field in tesla through
``pkf.geometry.field.field_at(kind, params, grid, x, y, z)``. Equations of motion
(N = √(1+tx²+ty²), κ = 0.299792458 MeV/(T·mm)):

    dx/dz = tx,  dy/dz = ty
    dtx/dz = κ·qop·N·[tx·ty·Bx − (1+tx²)·By + ty·Bz]
    dty/dz = κ·qop·N·[(1+ty²)·Bx − tx·ty·By − tx·Bz]

κ: a particle of p = 1000 MeV in 1 T has radius p/(κB) = 3335.64 mm (3.3356 m per GeV
and tesla), so with qop in 1/MeV and lengths in mm the constant is 0.299792458 — the
speed of light in units of 1e9 m/s, not 1e-3 of it.

Integration is classical fixed-step RK4 with |Δz| split into ceil(|Δz|/max_step) equal
steps, forwards or backwards. qop is constant (no material inside a step). The
Jacobian is the exact derivative of that discrete RK4 map (forward-mode: each stage's
derivative is chained through the stage), with the field gradients ∂B/∂x and ∂B/∂y
(z is the integration variable, so ∂B/∂z is not needed): for the trilinear field map the
exact derivative of the interpolation, from the same 8 grid points as the field
(`pkf.geometry.field.map_field_and_gradient`; at a cell boundary the slope of the cell the
point is in); for the analytic dipole central differences of `field_at` with a step of
FIELD_GRADIENT_STEP = 1 µm (~1e-9 relative: truncation ∝ step², rounding ~1e-16 T/step);
for a uniform field zero, not evaluated. The map's gradient was central differences too
(4 more lookups per RK4 stage): they gave the same derivative within 1e-9 but within 1 µm of
a cell boundary (4.5e-5 of random points), where they gave the mean of the two one-sided
slopes. Issue 18.1, measured (benchmarks/fit_core.py --sample minbias, 257,055 nodes, the old
and new code alternating in separate processes, 2 rounds): the reference fit 3,122–3,134 →
1,961–1,964 ns/node (×0.63), the GX2F 3,054–3,128 → 1,994–2,030 (×0.65), the parametrized
fit unchanged (its RK4 fallback below the UT→SciFi table's p_min: 102 of 8,246 steps); the GSF
(`gsf_components` electrons, 3 rounds) 2.61–2.62 → 2.51–2.69 ms per track. Outputs
(benchmarks/table_hashes.py --against): candidates bitwise the same; χ² within 1e-6
relative, states within 3.3e-4 and pulls within 7e-5 of each column's RMS (a derivative
that differs by the jump of the slope across a cell boundary, where a lookup falls within
1 µm of one; elsewhere the two agree within 1e-9). A 0.5 mm
difference step would have smoothed across cell boundaries and disagreed with finite
differences of the map transport at the 1e-3 level in the small ∂(tx, ty)/∂(x, y) elements.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.geometry.field import FIELD_MAP, FIELD_UNIFORM, field_at, map_at_cell_z, map_cell_z, map_field_and_gradient
from pkf.jit import NO_REFCOUNT

C_LIGHT = 0.299792458  # κ, MeV/(T·mm): curvature [1/mm] = κ·B[T]/p[MeV]
FIELD_GRADIENT_STEP = 1e-3  # mm, central-difference step for the dipole's ∂B/∂x and ∂B/∂y


@nb.njit(cache=True)
def slope_derivatives(tx, ty, qop, bx, by, bz):
    """(dtx/dz, dty/dz) [1/mm] at slopes (tx, ty), q/p [1/MeV] and field (bx, by, bz) [T]."""
    n = math.sqrt(1.0 + tx * tx + ty * ty)
    kn = C_LIGHT * qop * n
    ax = tx * ty * bx - (1.0 + tx * tx) * by + ty * bz
    ay = (1.0 + ty * ty) * bx - tx * ty * by - tx * bz
    return kn * ax, kn * ay


@nb.njit(cache=True)
def rk4_propagate(state, z_from, z_to, max_step, field_kind, field_params, field_grid):
    """Transport `state` (x, y, tx, ty, qop) from z_from to z_to [mm]; returns a new array.

    Classical RK4 with ceil(|z_to − z_from|/max_step) equal steps (max_step > 0, mm).
    """
    out = np.empty(5)
    x, y, tx, ty = rk4_propagate_scalar(
        state[0], state[1], state[2], state[3], state[4],
        z_from, z_to, max_step, field_kind, field_params, field_grid,
    )
    out[0] = x
    out[1] = y
    out[2] = tx
    out[3] = ty
    out[4] = state[4]
    return out


@nb.njit(cache=True, **NO_REFCOUNT)
def rk4_propagate_scalar(x, y, tx, ty, qop, z_from, z_to, max_step,
                         field_kind, field_params, field_grid):
    """Allocation-free core of `rk4_propagate`: returns the new (x, y, tx, ty)."""
    dz = z_to - z_from
    if dz == 0.0:
        return x, y, tx, ty
    nsteps = max(1, int(math.ceil(abs(dz) / max_step)))
    h = dz / nsteps
    z = z_from
    for _ in range(nsteps):
        # stage 1
        bx, by, bz = field_at(field_kind, field_params, field_grid, x, y, z)
        k1tx, k1ty = slope_derivatives(tx, ty, qop, bx, by, bz)
        # stage 2 (midpoint)
        x2 = x + 0.5 * h * tx
        y2 = y + 0.5 * h * ty
        tx2 = tx + 0.5 * h * k1tx
        ty2 = ty + 0.5 * h * k1ty
        bx, by, bz = field_at(field_kind, field_params, field_grid, x2, y2, z + 0.5 * h)
        k2tx, k2ty = slope_derivatives(tx2, ty2, qop, bx, by, bz)
        # stage 3 (midpoint)
        x3 = x + 0.5 * h * tx2
        y3 = y + 0.5 * h * ty2
        tx3 = tx + 0.5 * h * k2tx
        ty3 = ty + 0.5 * h * k2ty
        bx, by, bz = field_at(field_kind, field_params, field_grid, x3, y3, z + 0.5 * h)
        k3tx, k3ty = slope_derivatives(tx3, ty3, qop, bx, by, bz)
        # stage 4 (end)
        x4 = x + h * tx3
        y4 = y + h * ty3
        tx4 = tx + h * k3tx
        ty4 = ty + h * k3ty
        bx, by, bz = field_at(field_kind, field_params, field_grid, x4, y4, z + h)
        k4tx, k4ty = slope_derivatives(tx4, ty4, qop, bx, by, bz)
        # combine: the position stages are k_x,i = tx_i
        x = x + h / 6.0 * (tx + 2.0 * tx2 + 2.0 * tx3 + tx4)
        y = y + h / 6.0 * (ty + 2.0 * ty2 + 2.0 * ty3 + ty4)
        tx = tx + h / 6.0 * (k1tx + 2.0 * k2tx + 2.0 * k3tx + k4tx)
        ty = ty + h / 6.0 * (k1ty + 2.0 * k2ty + 2.0 * k3ty + k4ty)
        z = z + h
    return x, y, tx, ty


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def rk4_propagate_map_many(s, n, z_from, z_to, max_step, field_params, field_grid):
    """`rk4_propagate_scalar` through a field map (FIELD_MAP) of n states side by side,
    bitwise: s (5, ≥ n) rows x, y, tx, ty, q/p, propagated in place. Every state takes
    the same steps, so the z part of each stage's map lookup (`map_cell_z`) is taken once
    for all of them, and the lookups have no branches: ×0.72 against one state at a time
    with the lookup as a function (12 GSF components through the lhcb-like magnet,
    48 → 35 µs)."""
    dz = z_to - z_from
    if dz == 0.0:
        return
    nsteps = max(1, int(math.ceil(abs(dz) / max_step)))
    h = dz / nsteps
    z = z_from
    xs, ys, txs, tys, qops = s[0], s[1], s[2], s[3], s[4]
    for _ in range(nsteps):
        a_ok, a_iz, a_uz = map_cell_z(field_params, field_grid, z)
        b_ok, b_iz, b_uz = map_cell_z(field_params, field_grid, z + 0.5 * h)
        e_ok, e_iz, e_uz = map_cell_z(field_params, field_grid, z + h)
        for c in range(n):
            x = xs[c]
            y = ys[c]
            tx = txs[c]
            ty = tys[c]
            qop = qops[c]
            bx, by, bz = map_at_cell_z(field_params, field_grid, x, y, a_ok, a_iz, a_uz)
            k1tx, k1ty = slope_derivatives(tx, ty, qop, bx, by, bz)
            x2 = x + 0.5 * h * tx
            y2 = y + 0.5 * h * ty
            tx2 = tx + 0.5 * h * k1tx
            ty2 = ty + 0.5 * h * k1ty
            bx, by, bz = map_at_cell_z(field_params, field_grid, x2, y2, b_ok, b_iz, b_uz)
            k2tx, k2ty = slope_derivatives(tx2, ty2, qop, bx, by, bz)
            x3 = x + 0.5 * h * tx2
            y3 = y + 0.5 * h * ty2
            tx3 = tx + 0.5 * h * k2tx
            ty3 = ty + 0.5 * h * k2ty
            bx, by, bz = map_at_cell_z(field_params, field_grid, x3, y3, b_ok, b_iz, b_uz)
            k3tx, k3ty = slope_derivatives(tx3, ty3, qop, bx, by, bz)
            x4 = x + h * tx3
            y4 = y + h * ty3
            tx4 = tx + h * k3tx
            ty4 = ty + h * k3ty
            bx, by, bz = map_at_cell_z(field_params, field_grid, x4, y4, e_ok, e_iz, e_uz)
            k4tx, k4ty = slope_derivatives(tx4, ty4, qop, bx, by, bz)
            xs[c] = x + h / 6.0 * (tx + 2.0 * tx2 + 2.0 * tx3 + tx4)
            ys[c] = y + h / 6.0 * (ty + 2.0 * ty2 + 2.0 * ty3 + ty4)
            txs[c] = tx + h / 6.0 * (k1tx + 2.0 * k2tx + 2.0 * k3tx + k4tx)
            tys[c] = ty + h / 6.0 * (k1ty + 2.0 * k2ty + 2.0 * k3ty + k4ty)
        z = z + h


@nb.njit(cache=True, inline="always")
def _central_difference(field_kind, field_params, field_grid, x, y, z, sx, sy):
    """(∂Bx, ∂By, ∂Bz) along (sx, sy, 0) [T/mm] at (x, y, z) by central differences of
    step (sx, sy) [mm] (one of them 0)."""
    pbx, pby, pbz = field_at(field_kind, field_params, field_grid, x + sx, y + sy, z)
    mbx, mby, mbz = field_at(field_kind, field_params, field_grid, x - sx, y - sy, z)
    inv2s = 0.5 / (sx + sy)
    return (pbx - mbx) * inv2s, (pby - mby) * inv2s, (pbz - mbz) * inv2s


@nb.njit(cache=True, **NO_REFCOUNT)
def _stage_jacobian(x, y, z, tx, ty, qop, field_kind, field_params, field_grid):
    """Slope derivatives at one RK stage and their partials.

    Returns (dtx/dz, dty/dz, row_tx, row_ty) with row_tx = ∂(dtx/dz)/∂(x, y, tx, ty, qop)
    and row_ty = ∂(dty/dz)/∂(x, y, tx, ty, qop) (5-tuples: no scratch array).
    """
    if field_kind == FIELD_MAP:
        bx, by, bz, gxx, gxy, gxz, gyx, gyy, gyz = map_field_and_gradient(field_params, field_grid, x, y, z)
    else:
        bx, by, bz = field_at(field_kind, field_params, field_grid, x, y, z)
    n = math.sqrt(1.0 + tx * tx + ty * ty)
    ax = tx * ty * bx - (1.0 + tx * tx) * by + ty * bz
    ay = (1.0 + ty * ty) * bx - tx * ty * by - tx * bz
    kq = C_LIGHT * qop
    kqn = kq * n
    ftx = kqn * ax
    fty = kqn * ay
    # ∂/∂tx, ∂/∂ty: product rule on N·A, ∂N/∂tx = tx/N, ∂N/∂ty = ty/N
    dax_dtx = ty * bx - 2.0 * tx * by
    dax_dty = tx * bx + bz
    day_dtx = -ty * by - bz
    day_dty = 2.0 * ty * bx - tx * by
    j02 = kq * (tx / n * ax + n * dax_dtx)
    j03 = kq * (ty / n * ax + n * dax_dty)
    j12 = kq * (tx / n * ay + n * day_dtx)
    j13 = kq * (ty / n * ay + n * day_dty)
    # ∂/∂qop
    j04 = C_LIGHT * n * ax
    j14 = C_LIGHT * n * ay
    # ∂/∂x, ∂/∂y through the field gradient (the map's exact one; the dipole's by central
    # differences), then A's combinations of ∂B/∂x and of ∂B/∂y once for both
    if field_kind == FIELD_UNIFORM:
        return ftx, fty, (0.0, 0.0, j02, j03, j04), (0.0, 0.0, j12, j13, j14)
    if field_kind != FIELD_MAP:
        gxx, gxy, gxz = _central_difference(field_kind, field_params, field_grid, x, y, z, FIELD_GRADIENT_STEP, 0.0)
        gyx, gyy, gyz = _central_difference(field_kind, field_params, field_grid, x, y, z, 0.0, FIELD_GRADIENT_STEP)
    j00 = kqn * (tx * ty * gxx - (1.0 + tx * tx) * gxy + ty * gxz)
    j10 = kqn * ((1.0 + ty * ty) * gxx - tx * ty * gxy - tx * gxz)
    j01 = kqn * (tx * ty * gyx - (1.0 + tx * tx) * gyy + ty * gyz)
    j11 = kqn * ((1.0 + ty * ty) * gyx - tx * ty * gyy - tx * gyz)
    return ftx, fty, (j00, j01, j02, j03, j04), (j10, j11, j12, j13, j14)


@nb.njit(cache=True, **NO_REFCOUNT)
def _stage_derivative(row_tx, row_ty, d, kprev, c, kout):
    """kout = ∂k_i/∂s0 for a stage evaluated at s + c·k_{i−1}.

    row_tx, row_ty: the stage's partials (`_stage_jacobian`); d = ∂s/∂s0 at the start of
    the step (rows 0–3; row 4 is e4), kprev = ∂k_{i−1}/∂s0 (rows 0–3), c = h·a_i (0 for
    the first stage). The position rows of k are the slope rows of the stage point; the
    slope rows are the partials times ∂(stage point)/∂s0.
    """
    for j in range(5):
        if c == 0.0:
            m0 = d[0, j]
            m1 = d[1, j]
            m2 = d[2, j]
            m3 = d[3, j]
        else:
            m0 = d[0, j] + c * kprev[0, j]
            m1 = d[1, j] + c * kprev[1, j]
            m2 = d[2, j] + c * kprev[2, j]
            m3 = d[3, j] + c * kprev[3, j]
        m4 = 1.0 if j == 4 else 0.0
        kout[0, j] = m2
        kout[1, j] = m3
        kout[2, j] = (row_tx[0] * m0 + row_tx[1] * m1 + row_tx[2] * m2
                      + row_tx[3] * m3 + row_tx[4] * m4)
        kout[3, j] = (row_ty[0] * m0 + row_ty[1] * m1 + row_ty[2] * m2
                      + row_ty[3] * m3 + row_ty[4] * m4)


@nb.njit(cache=True, **NO_REFCOUNT)
def rk4_transport_jacobian(state, z_from, z_to, max_step, field_kind, field_params, field_grid, jac_out,
                           stages):
    """`rk4_propagate_jacobian` in place, allocating nothing: `state` (x, y, tx, ty, qop) is
    transported from z_from to z_to [mm] (qop unchanged) and jac_out (5×5) receives
    ∂state_out/∂state_in. stages (≥ 4, ≥ 4, 5) is scratch for the derivatives of the four
    RK stages (rows 0–3 of stages[0…3]); it must not overlap state or jac_out."""
    x = state[0]
    y = state[1]
    tx = state[2]
    ty = state[3]
    qop = state[4]
    for i in range(5):
        for j in range(5):
            jac_out[i, j] = 1.0 if i == j else 0.0
    dz = z_to - z_from
    if dz != 0.0:
        nsteps = max(1, int(math.ceil(abs(dz) / max_step)))
        h = dz / nsteps
        z = z_from
        k1 = stages[0]
        k2 = stages[1]
        k3 = stages[2]
        k4 = stages[3]
        for _ in range(nsteps):
            # stage 1
            k1tx, k1ty, row_tx, row_ty = _stage_jacobian(x, y, z, tx, ty, qop, field_kind, field_params,
                                                         field_grid)
            _stage_derivative(row_tx, row_ty, jac_out, k1, 0.0, k1)
            # stage 2
            x2 = x + 0.5 * h * tx
            y2 = y + 0.5 * h * ty
            tx2 = tx + 0.5 * h * k1tx
            ty2 = ty + 0.5 * h * k1ty
            k2tx, k2ty, row_tx, row_ty = _stage_jacobian(x2, y2, z + 0.5 * h, tx2, ty2, qop,
                                                         field_kind, field_params, field_grid)
            _stage_derivative(row_tx, row_ty, jac_out, k1, 0.5 * h, k2)
            # stage 3
            x3 = x + 0.5 * h * tx2
            y3 = y + 0.5 * h * ty2
            tx3 = tx + 0.5 * h * k2tx
            ty3 = ty + 0.5 * h * k2ty
            k3tx, k3ty, row_tx, row_ty = _stage_jacobian(x3, y3, z + 0.5 * h, tx3, ty3, qop,
                                                         field_kind, field_params, field_grid)
            _stage_derivative(row_tx, row_ty, jac_out, k2, 0.5 * h, k3)
            # stage 4
            x4 = x + h * tx3
            y4 = y + h * ty3
            tx4 = tx + h * k3tx
            ty4 = ty + h * k3ty
            k4tx, k4ty, row_tx, row_ty = _stage_jacobian(x4, y4, z + h, tx4, ty4, qop,
                                                         field_kind, field_params, field_grid)
            _stage_derivative(row_tx, row_ty, jac_out, k3, h, k4)
            # combine state and Jacobian
            x = x + h / 6.0 * (tx + 2.0 * tx2 + 2.0 * tx3 + tx4)
            y = y + h / 6.0 * (ty + 2.0 * ty2 + 2.0 * ty3 + ty4)
            tx = tx + h / 6.0 * (k1tx + 2.0 * k2tx + 2.0 * k3tx + k4tx)
            ty = ty + h / 6.0 * (k1ty + 2.0 * k2ty + 2.0 * k3ty + k4ty)
            for i in range(4):
                for j in range(5):
                    jac_out[i, j] += h / 6.0 * (
                        k1[i, j] + 2.0 * k2[i, j] + 2.0 * k3[i, j] + k4[i, j]
                    )
            z = z + h
    state[0] = x
    state[1] = y
    state[2] = tx
    state[3] = ty


@nb.njit(cache=True)
def rk4_propagate_jacobian(state, z_from, z_to, max_step,
                           field_kind, field_params, field_grid, jac_out):
    """`rk4_propagate` plus the transport Jacobian ∂state_out/∂state_in written to jac_out (5×5).

    Same steps and result as `rk4_propagate`. The Jacobian is integrated alongside the
    state as the derivative of the discrete RK4 map (see the module docstring); the
    qop row is (0, 0, 0, 0, 1). Returns a new array; kernels that call it per step use
    `rk4_transport_jacobian` (in place, with the caller's scratch) instead.
    """
    out = state.copy()
    rk4_transport_jacobian(out, z_from, z_to, max_step, field_kind, field_params, field_grid, jac_out,
                           np.empty((4, 4, 5)))
    return out


@nb.njit(cache=True)
def rk4_propagate_many(states, z_from, z_to, max_step, field_kind, field_params, field_grid):
    """`rk4_propagate` for each row of `states` (n×5) from z_from to z_to; returns n×5."""
    n = states.shape[0]
    out = np.empty((n, 5))
    for i in range(n):
        x, y, tx, ty = rk4_propagate_scalar(
            states[i, 0], states[i, 1], states[i, 2], states[i, 3], states[i, 4],
            z_from, z_to, max_step, field_kind, field_params, field_grid,
        )
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = tx
        out[i, 3] = ty
        out[i, 4] = states[i, 4]
    return out
