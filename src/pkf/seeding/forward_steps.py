"""Parametrized transport for the forward extension: reference trajectories and q/p scans.

DESIGN §7.4, §9.2. The forward extension (`pkf.seeding.forward`) needs, for one VELO
track, many transports of the same start state with different q/p hypotheses. This
module provides them with the paper's parametrized steps (`pkf.params.formulas`, the
shipped or tuned parameter set of `pkf.fit.parametrized`), without a field map:

- `reference_trajectory`: the transport of a VELO state through every UT and SciFi layer
  (one paper step per layer pair, as `pkf.fit.parametrized.parametrized_step` chains
  them), with the Jacobian and the process noise of each step evaluated at a chosen |q/p|
  (the noise of the paper's eq. 11 is ∝ (q/p)²: a search needs it at the hypothesis, not
  at the linearisation point);
- `scan_states`: x, y and d/dq on the SciFi layers for a list of q/p hypotheses;
- `table_localize` / `table_step`: the UT→SciFi step (paper eqs. 21–23) with the
  coefficients interpolated once per track at (x/z, y/z) of the last UT layer and then
  corrected to first order in (x, y): a q/p scan costs one interpolation instead of one
  per hypothesis. The Jacobian columns x, y use the interpolation derivatives of the
  localisation point (as the table's own Jacobian does at its point).

Below the table's p_min (|w| = |q/p|·p_min > 1) the table is not valid. The table module
continues every polynomial linearly from the edge (status 4). For the *search* this
module continues quadratically instead, P(w) = P(w_c) + P′(w_c)·e + ½P″(w_c)·e²,
e = w − w_c, w_c = ±1: on lhcb-like minimum bias the x error at the first SciFi layer for
2.0–2.5 GeV tracks is ≈ 15 mm (median) instead of ≈ 30 mm, and the error is mostly a
common rescaling of the deflection that the search absorbs in q/p (measured by
`tests/seeding/test_forward.py`). Such states carry status `TRANSPORT_BELOW_P_MIN` (4):
the hits found are usable, the q/p estimate is flagged (the Kalman fit decides what to
do with a status-4 parametrization).

Units: mm, 1/MeV (q/p at production, DESIGN §9.2).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT
from pkf.params import formulas
from pkf.params.ut_to_scifi import (
    META_BEND,
    META_DEGREES,
    META_NX,
    META_NY,
    META_P_MIN,
    META_SLOPE_DX,
    META_SLOPE_DY,
    META_SLOPE_X0,
    META_SLOPE_Y0,
    META_Z_FROM,
    META_Z_TO,
    _axis_lookup,
    interpolation_weights,
)

# The per-layer formula (pkf.params.formulas), compiled again for inlining: the search calls
# it ~10⁵ times per event. The rare, large steps (VELO→UT, the table) stay ordinary calls:
# inlining them into the step dispatch makes every step ~5× slower.
_INLINE = dict(cache=True, inline="always", **NO_REFCOUNT)
layer_step = nb.njit(**_INLINE)(getattr(formulas.layer_step, "py_func", formulas.layer_step))
velo_step = formulas.velo_step
velo_to_ut_step = formulas.velo_to_ut_step
parametrized_noise = nb.njit(**_INLINE)(getattr(formulas.parametrized_noise, "py_func",
                                                   formulas.parametrized_noise))

TRANSPORT_OK = 0
TRANSPORT_FAILED = 2  # an unphysical step (|tx/N| ≥ 1 after the VELO→UT kink, NaN)
TRANSPORT_BELOW_P_MIN = 4  # the UT→SciFi table was continued beyond |w| = 1


@nb.njit(cache=True, **NO_REFCOUNT)
def table_localize(meta, coef, x, y, poly, ref):
    """Interpolate the UT→SciFi coefficients (paper eqs. 22–23) at (x/z, y/z) of z_from.

    poly (3, 4, n_coef): [0] the coefficients, [1] ∂/∂x and [2] ∂/∂y [1/mm] (through the
    interpolation weights); ref (2) = (x, y) of the localisation point [mm].
    """
    z0 = meta[META_Z_FROM]
    nx = int(meta[META_NX])
    ny = int(meta[META_NY])
    i, xi, fx = _axis_lookup(x / z0, meta[META_SLOPE_X0], meta[META_SLOPE_DX], nx)
    j, psi, fy = _axis_lookup(y / z0, meta[META_SLOPE_Y0], meta[META_SLOPE_DY], ny)
    ex, ey, w, wx, wy = interpolation_weights(xi, psi)
    dxi_dx = fx / z0
    dpsi_dy = fy / z0
    for u in range(4):
        n = int(meta[META_DEGREES + 2 * u]) + 2 * int(meta[META_DEGREES + 2 * u + 1])
        for c in range(n):
            c00 = coef[u, i, j, c]
            cp0 = coef[u, i + 1, j, c]
            cm0 = coef[u, i - 1, j, c]
            c0p = coef[u, i, j + 1, c]
            c0m = coef[u, i, j - 1, c]
            cee = coef[u, i + ex, j + ey, c]
            poly[0, u, c] = w[0] * c00 + w[1] * cp0 + w[2] * cm0 + w[3] * c0p + w[4] * c0m + w[5] * cee
            poly[1, u, c] = (wx[0] * c00 + wx[1] * cp0 + wx[2] * cm0 + wx[3] * c0p + wx[4] * c0m
                             + wx[5] * cee) * dxi_dx
            poly[2, u, c] = (wy[0] * c00 + wy[1] * cp0 + wy[2] * cm0 + wy[3] * c0p + wy[4] * c0m
                             + wy[5] * cee) * dpsi_dy
    ref[0] = x
    ref[1] = y


@nb.njit(cache=True, **NO_REFCOUNT)
def table_step(meta, poly, ref, eloss, s_in, s_out, jac, quadratic):
    """Paper eq. 21 from the last UT layer to the first SciFi layer with localised
    coefficients (`table_localize`). Writes s_out (5) and jac = ∂out/∂in (5×5).

    eloss [MeV]: the tuned energy loss upstream of the magnet (the slot's parameter 0):
    the table is evaluated at q′ = q/(1 − eloss·|q|), as `pkf.fit.parametrized` does.
    Beyond |w| = 1 each polynomial is continued quadratically (quadratic=True) or
    linearly from the edge. Returns TRANSPORT_OK or TRANSPORT_BELOW_P_MIN.
    """
    z0 = meta[META_Z_FROM]
    dz = meta[META_Z_TO] - z0
    bend = meta[META_BEND]
    p_min = meta[META_P_MIN]
    x = s_in[0]
    y = s_in[1]
    tx = s_in[2]
    ty = s_in[3]
    qop = s_in[4]
    shrink = 1.0 - eloss * abs(qop)
    q = qop / shrink
    dq_dqop = 1.0 / (shrink * shrink)
    ddx = x - ref[0]
    ddy = y - ref[1]
    inv_z0 = 1.0 / z0
    dtx = tx - x * inv_z0 - bend * q
    dty = ty - y * inv_z0
    w = q * p_min
    status = TRANSPORT_OK
    wc = w
    if w > 1.0:
        wc = 1.0
        status = TRANSPORT_BELOW_P_MIN
    elif w < -1.0:
        wc = -1.0
        status = TRANSPORT_BELOW_P_MIN
    e = w - wc
    e2 = 0.5 * e * e if quadratic else 0.0
    e1 = e if quadratic else 0.0
    for a in range(5):
        for b in range(5):
            jac[a, b] = 1.0 if a == b else 0.0
    for u in range(4):
        k1 = int(meta[META_DEGREES + 2 * u])
        k2 = int(meta[META_DEGREES + 2 * u + 1])
        val = 0.0
        val_w = 0.0
        val_x = 0.0
        val_y = 0.0
        poly_b = 0.0
        poly_c = 0.0
        col = 0
        for blk in range(3):
            degree = k1 if blk == 0 else k2
            p = 0.0
            pw = 0.0
            pww = 0.0
            px = 0.0
            pxw = 0.0
            pxww = 0.0
            py = 0.0
            pyw = 0.0
            pyww = 0.0
            wk1 = 1.0  # wc^(k−1)
            wk2 = 0.0  # wc^(k−2)
            for k in range(1, degree + 1):
                cx = poly[1, u, col]
                cy = poly[2, u, col]
                c = poly[0, u, col] + cx * ddx + cy * ddy
                wk = wk1 * wc
                p += c * wk
                pw += k * c * wk1
                pww += k * (k - 1) * c * wk2
                px += cx * wk
                pxw += k * cx * wk1
                pxww += k * (k - 1) * cx * wk2
                py += cy * wk
                pyw += k * cy * wk1
                pyww += k * (k - 1) * cy * wk2
                wk2 = wk1
                wk1 = wk
                col += 1
            if e != 0.0:
                p += pw * e + pww * e2
                pw += pww * e1
                px += pxw * e + pxww * e2
                py += pyw * e + pyww * e2
            if blk == 0:
                m = 1.0
            elif blk == 1:
                m = dtx
                poly_b = p
            else:
                m = dty
                poly_c = p
            val += m * p
            val_w += m * pw
            val_x += m * px
            val_y += m * py
        if u == 0:
            s_out[0] = x + tx * dz + val
            jac[0, 2] = dz
        elif u == 1:
            s_out[1] = y + ty * dz + val
            jac[1, 3] = dz
        elif u == 2:
            s_out[2] = tx + val
        else:
            s_out[3] = ty + val
        jac[u, 0] += val_x - poly_b * inv_z0
        jac[u, 1] += val_y - poly_c * inv_z0
        jac[u, 2] += poly_b
        jac[u, 3] += poly_c
        jac[u, 4] = (val_w * p_min - poly_b * bend) * dq_dqop
    s_out[4] = qop
    return status


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _noise_at(noise_par, slot, s, q_noise, dz, s_tmp, jac, out):
    """Paper eq. 11 for the step leaving `slot`, at the slopes of s and |q/p| = q_noise,
    plus the energy-loss straggling before the step (q/p noise (p̃5·q²)² through the
    step's Jacobian), as `pkf.fit.parametrized.parametrized_step` adds it."""
    for i in range(4):
        s_tmp[i] = s[i]
    s_tmp[4] = q_noise
    parametrized_noise(noise_par[slot], s_tmp, dz, out)
    if noise_par.shape[1] > 5 and noise_par[slot, 5] > 0.0:
        var_qop = (noise_par[slot, 5] * q_noise * q_noise) ** 2
        for i in range(5):
            for k in range(5):
                out[i, k] += var_qop * jac[i, 4] * jac[k, 4]


@nb.njit(cache=True, **NO_REFCOUNT)
def reference_trajectory(ext, poly, ref, quadratic, a, f_layer, n_ut, j_end, s_start, q_noise,
                         ref_s, ref_F, ref_Q, s_tmp):
    """Transport s_start (5, at VELO layer a) to the forward layers f_layer[0 … j_end−1]
    (the UT layers, then the SciFi layers, consecutive in the geometry): ref_s[j] (5),
    the Jacobian ref_F[j] of the step from the previous layer (from layer a for j = 0)
    and its noise ref_Q[j] at |q/p| = q_noise. One paper step per layer pair: VELO→UT
    (eqs. 15–20), UT/SciFi layer steps (eq. 14), UT→SciFi table (eqs. 21–23).
    Returns the worst TRANSPORT_* status.

    The two large steps are ordinary calls outside the per-layer loops: an un-taken
    call inside the loop makes every inlined layer step ~5× slower (numba keeps the
    array arguments reference counted).
    """
    layer_z = ext.layer_z
    extrap = ext.extrapolation
    noise_par = ext.noise
    status = TRANSPORT_OK
    z1 = layer_z[f_layer[0]]
    slot = ext.sub_last[ext.layer_sub[a]]
    if not velo_to_ut_step(extrap[slot], s_start, layer_z[a], z1, ref_s[0], ref_F[0]):
        return TRANSPORT_FAILED
    _noise_at(noise_par, slot, s_start, q_noise, z1 - layer_z[a], s_tmp, ref_F[0], ref_Q[0])
    for j in range(1, min(n_ut, j_end)):
        l0 = f_layer[j - 1]
        dz = layer_z[l0 + 1] - layer_z[l0]
        layer_step(extrap[l0], ref_s[j - 1], layer_z[l0], layer_z[l0 + 1], ref_s[j], ref_F[j])
        _noise_at(noise_par, l0, ref_s[j - 1], q_noise, dz, s_tmp, ref_F[j], ref_Q[j])
    if j_end > n_ut:
        l0 = f_layer[n_ut - 1]
        status = table_step(ext.uts_meta, poly, ref, extrap[l0, 0], ref_s[n_ut - 1], ref_s[n_ut],
                            ref_F[n_ut], quadratic)
        _noise_at(noise_par, l0, ref_s[n_ut - 1], q_noise, layer_z[l0 + 1] - layer_z[l0], s_tmp,
                  ref_F[n_ut], ref_Q[n_ut])
        for j in range(n_ut + 1, j_end):
            l0 = f_layer[j - 1]
            dz = layer_z[l0 + 1] - layer_z[l0]
            layer_step(extrap[l0], ref_s[j - 1], layer_z[l0], layer_z[l0 + 1], ref_s[j], ref_F[j])
            _noise_at(noise_par, l0, ref_s[j - 1], q_noise, dz, s_tmp, ref_F[j], ref_Q[j])
    for i in range(5):
        if not np.isfinite(ref_s[j_end - 1, i]):
            return TRANSPORT_FAILED
    return status


@nb.njit(cache=True, **NO_REFCOUNT)
def scan_states(ext, poly, ref, quadratic, l_from, sf_layers, s0, ds0, q_nodes, xs, dxs, ys, dys,
                work):
    """States on the SciFi layers for each q/p node, from the last UT layer l_from.

    sf_layers: the SciFi layers (consecutive, the first is l_from + 1). The start state
    for the hypothesis q is s0[:4] + ds0[:4]·(q − s0[4]) (a conditional mean given q,
    e.g. of a fitted UT state); outputs x, y and their total derivatives d/dq on each
    SciFi layer: xs, dxs, ys, dys (n_nodes, n_layers). work: (4, 5, 5) scratch.
    Returns the worst TRANSPORT_* status.
    """
    layer_z = ext.layer_z
    extrap = ext.extrapolation
    s = work[0, 0]
    s_next = work[0, 1]
    d = work[0, 2]
    d_next = work[0, 3]
    jac = work[1]
    status = TRANSPORT_OK
    n_layers = sf_layers.shape[0]
    eloss = extrap[l_from, 0]
    for k in range(q_nodes.shape[0]):
        q = q_nodes[k]
        for i in range(4):
            s[i] = s0[i] + ds0[i] * (q - s0[4])
            d[i] = ds0[i]
        s[4] = q
        d[4] = 1.0
        st = table_step(ext.uts_meta, poly, ref, eloss, s, s_next, jac, quadratic)
        status = max(status, st)
        for li in range(n_layers):
            if li > 0:
                l0 = sf_layers[li - 1]
                layer_step(extrap[l0], s, layer_z[l0], layer_z[l0 + 1], s_next, jac)
            for i in range(5):
                acc = 0.0
                for m in range(5):
                    acc += jac[i, m] * d[m]
                d_next[i] = acc
            for i in range(5):
                s[i] = s_next[i]
                d[i] = d_next[i]
            xs[k, li] = s[0]
            ys[k, li] = s[1]
            dxs[k, li] = d[0]
            dys[k, li] = d[1]
        for i in range(5):
            if not np.isfinite(s[i]):
                return TRANSPORT_FAILED
    return status


def new_table_buffers(ext) -> tuple[np.ndarray, np.ndarray]:
    """Scratch (poly, ref) for `table_localize` sized for the extrapolator's table."""
    return np.zeros((3, 4, max(ext.uts_coef.shape[3], 1))), np.zeros(2)
