"""Parametrized transport for the forward extension: reference trajectories and q/p scans.

DESIGN §7.4, §9.2. The forward extension (`pkf.seeding.forward`) needs, for one VELO
track, many transports of the same start state with different q/p hypotheses. This
module provides them with the paper's parametrized steps (`pkf.params.formulas`, the
shipped or tuned parameter set of `pkf.fit.parametrized`), without a field map:

- `transport`: one downstream transport between two layers (chained paper steps, as
  `pkf.fit.parametrized.parametrized_step`), writing the state, the Jacobian and the
  process noise evaluated at a chosen |q/p| (the noise of the paper's eq. 11 is ∝ (q/p)²:
  a search needs it at the hypothesis, not at the linearisation point);
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

from pkf.fit.parametrized import STEP_UT_TO_SCIFI, STEP_VELO, STEP_VELO_TO_UT, next_step
from pkf.params.formulas import layer_step, parametrized_noise, velo_step, velo_to_ut_step
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

TRANSPORT_OK = 0
TRANSPORT_FAILED = 2  # an unphysical step (|tx/N| ≥ 1 after the VELO→UT kink, NaN)
TRANSPORT_BELOW_P_MIN = 4  # the UT→SciFi table was continued beyond |w| = 1


@nb.njit(cache=True)
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


@nb.njit(cache=True)
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


@nb.njit(cache=True)
def _paper_step(ext, poly, ref, quadratic, kind, slot, cur, nxt, s_in, s_out, jac):
    """One paper step of `kind` from layer cur to nxt (parameters of `slot`)."""
    p = ext.extrapolation[slot]
    z0 = ext.layer_z[cur]
    z1 = ext.layer_z[nxt]
    if kind == STEP_VELO:
        velo_step(p, s_in, z0, z1, s_out, jac)
    elif kind == STEP_VELO_TO_UT:
        if not velo_to_ut_step(p, s_in, z0, z1, s_out, jac):
            return TRANSPORT_FAILED
    elif kind == STEP_UT_TO_SCIFI:
        return table_step(ext.uts_meta, poly, ref, p[0], s_in, s_out, jac, quadratic)
    else:
        layer_step(p, s_in, z0, z1, s_out, jac)
    return TRANSPORT_OK


@nb.njit(cache=True)
def transport(ext, poly, ref, quadratic, cur, target, s_in, q_noise, s_out, jac, noise, work):
    """Transport s_in (5) at layer `cur` to layer `target` (downstream) through the chain
    of paper steps. Writes s_out, the Jacobian jac (5×5) and the process noise (5×5,
    paper eq. 11 with |q/p| = q_noise, accumulated as J·Q·Jᵀ + Q_step). work: (5, 5, 5)
    scratch. Returns the worst status of the steps (TRANSPORT_*); s_out is finite only
    if the status is not TRANSPORT_FAILED."""
    for i in range(5):
        s_out[i] = s_in[i]
        for k in range(5):
            jac[i, k] = 1.0 if i == k else 0.0
            noise[i, k] = 0.0
    status = TRANSPORT_OK
    seg = work[0, 0]
    snoise = work[0, 1]
    sjac = work[1]
    sq = work[2]
    tmp = work[3]
    tmp2 = work[4]
    first = True
    while cur < target:
        kind, slot, nxt = next_step(ext.layer_sub, ext.sub_last, ext.within_type, ext.between_type,
                                    cur, target)
        st = _paper_step(ext, poly, ref, quadratic, kind, slot, cur, nxt, s_out, seg, sjac)
        if st == TRANSPORT_FAILED:
            return st
        if st > status:
            status = st
        for i in range(5):
            snoise[i] = s_out[i]
        snoise[4] = q_noise
        parametrized_noise(ext.noise[slot], snoise, ext.layer_z[nxt] - ext.layer_z[cur], sq)
        if first:
            for i in range(5):
                for k in range(5):
                    jac[i, k] = sjac[i, k]
                    noise[i, k] = sq[i, k]
            first = False
        else:
            for i in range(5):
                for k in range(5):
                    acc = 0.0
                    for m in range(5):
                        acc += sjac[i, m] * jac[m, k]
                    tmp[i, k] = acc
            for i in range(5):
                for k in range(5):
                    jac[i, k] = tmp[i, k]
            # noise ← J·noise·Jᵀ + Q
            for i in range(5):
                for k in range(5):
                    acc = 0.0
                    for m in range(5):
                        acc += sjac[i, m] * noise[m, k]
                    tmp[i, k] = acc
            for i in range(5):
                for k in range(5):
                    acc = 0.0
                    for m in range(5):
                        acc += tmp[i, m] * sjac[k, m]
                    tmp2[i, k] = acc + sq[i, k]
            for i in range(5):
                for k in range(5):
                    noise[i, k] = tmp2[i, k]
        for i in range(5):
            s_out[i] = seg[i]
        cur = nxt
    for i in range(5):
        if not np.isfinite(s_out[i]):
            return TRANSPORT_FAILED
    return status


@nb.njit(cache=True)
def scan_states(ext, poly, ref, quadratic, cur, layers, s0, ds0, q_nodes, xs, dxs, ys, dys, work):
    """States along `layers` (sorted, downstream of `cur`) for each q/p node.

    The start state at layer `cur` for the hypothesis q is s0[:4] + ds0[:4]·(q − s0[4])
    (a conditional mean given q, e.g. of a fitted UT state); the outputs are x, y and
    their total derivatives d/dq at each layer: xs, dxs, ys, dys (n_nodes, n_layers).
    Returns the worst TRANSPORT_* status.
    """
    s = work[0, 0]
    s_next = work[0, 1]
    d = work[0, 2]
    d_next = work[0, 3]
    jac = work[1]
    status = TRANSPORT_OK
    n_layers = layers.shape[0]
    for k in range(q_nodes.shape[0]):
        q = q_nodes[k]
        for i in range(4):
            s[i] = s0[i] + ds0[i] * (q - s0[4])
            d[i] = ds0[i]
        s[4] = q
        d[4] = 1.0
        c = cur
        li = 0
        while li < n_layers:
            target = layers[li]
            while c < target:
                kind, slot, nxt = next_step(ext.layer_sub, ext.sub_last, ext.within_type,
                                            ext.between_type, c, target)
                st = _paper_step(ext, poly, ref, quadratic, kind, slot, c, nxt, s, s_next, jac)
                if st == TRANSPORT_FAILED:
                    return st
                if st > status:
                    status = st
                for i in range(5):
                    acc = 0.0
                    for m in range(5):
                        acc += jac[i, m] * d[m]
                    d_next[i] = acc
                for i in range(5):
                    s[i] = s_next[i]
                    d[i] = d_next[i]
                c = nxt
            xs[k, li] = s[0]
            ys[k, li] = s[1]
            dxs[k, li] = d[0]
            dys[k, li] = d[1]
            li += 1
        for i in range(5):
            if not np.isfinite(s[i]):
                return TRANSPORT_FAILED
    return status


def new_table_buffers(ext) -> tuple[np.ndarray, np.ndarray]:
    """Scratch (poly, ref) for `table_localize` sized for the extrapolator's table."""
    return np.zeros((3, 4, max(ext.uts_coef.shape[3], 1))), np.zeros(2)
