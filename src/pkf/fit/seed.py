"""First state estimate of a track from its hits alone: a linear least-squares "kick" fit.

The pattern recognition hands the fitter hits; the fitter needs a starting state at the
first node. Model (linear in the five parameters at z_ref = first node's z):

    x(z) = x0 + tx0·(z − z_ref) + qop·Kx(z),   y(z) = y0 + ty0·(z − z_ref) + qop·Ky(z)

with Kx, Ky the double integrals over z of the equations of motion per unit q/p
(docs/formats.md#conventions), evaluated along the straight line of the track's first hits. Each
measurement u = hx·x + hy·y enters with weight 1/σ². Multiple scattering is ignored,
which is harmless for a seed. A weak prior |q/p| ≲ 1/(100 MeV) keeps tracks without
field integral (straight lines) solvable; their q/p variance then says so.

Seed covariance for the Kalman filter (docs/physics.md#the-kalman-core, documented choice):
diag(100 mm², 100 mm², 0.01, 0.01, (0.1·q/p)² + σ²_LSQ(q/p)) — loose in position and
slope (the first measurements fix them), a 10% q/p prior, which the data outweigh by two
orders of magnitude for long tracks, widened by the least-squares q/p variance for
tracks whose hits hardly measure q/p.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.physics.linalg import invert_spd
from pkf.geometry.field import field_at
from pkf.physics.transport import C_LIGHT

SEED_STEP = 50.0  # mm, integration step of the kick integrals
QOP_PRIOR_SIGMA = 1.0 / 100.0  # 1/MeV
SEED_VARIANCES = (100.0, 100.0, 0.01, 0.01)
SEED_QOP_FRACTION = 0.1


@nb.njit(cache=True)
def _straight_line(z, n_meas, hx, hy, m, sigma, z_ref, out):
    """Straight line (x0, y0, tx, ty) at z_ref through the first three nodes (least squares;
    minimum-norm where they do not determine it)."""
    a = np.zeros((4, 4))
    b = np.zeros(4)
    row = np.empty(4)
    for k in range(min(z.size, 3)):
        for j in range(n_meas[k]):
            w = 1.0 / (sigma[k, j] * sigma[k, j])
            dz = z[k] - z_ref
            row[0] = hx[k, j]
            row[1] = hy[k, j]
            row[2] = hx[k, j] * dz
            row[3] = hy[k, j] * dz
            for r in range(4):
                b[r] += row[r] * m[k, j] * w
                for c in range(4):
                    a[r, c] += row[r] * row[c] * w
    sol = np.linalg.lstsq(a, b)[0]
    for i in range(4):
        out[i] = sol[i]


@nb.njit(cache=True)
def seed_track(z, n_meas, hx, hy, m, sigma, field_kind, field_params, field_grid, out_state, out_cov):
    """Fill out_state (5) at z[0] and the Kalman seed covariance out_cov (5×5).

    Returns the least-squares variance of q/p [1/MeV²] (large: q/p not measured).
    """
    n = z.size
    z_ref = z[0]
    line = np.empty(4)
    _straight_line(z, n_meas, hx, hy, m, sigma, z_ref, line)
    x0, y0, tx, ty = line[0], line[1], line[2], line[3]
    # Kick integrals along the line: K1 = ∫g dz, K = ∫K1 dz, for g = d(tx, ty)/dz per q/p.
    kx = np.zeros(n)
    ky = np.zeros(n)
    k1x = 0.0
    k1y = 0.0
    k2x = 0.0
    k2y = 0.0
    zc = z_ref
    nn = math.sqrt(1.0 + tx * tx + ty * ty)
    for k in range(1, n):
        while zc < z[k]:
            h = min(SEED_STEP, z[k] - zc)
            zm = zc + 0.5 * h
            bx, by, bz = field_at(field_kind, field_params, field_grid,
                                  x0 + tx * (zm - z_ref), y0 + ty * (zm - z_ref), zm)
            gx = C_LIGHT * nn * (tx * ty * bx - (1.0 + tx * tx) * by + ty * bz)
            gy = C_LIGHT * nn * ((1.0 + ty * ty) * bx - tx * ty * by - tx * bz)
            k2x += h * k1x + 0.5 * h * h * gx
            k2y += h * k1y + 0.5 * h * h * gy
            k1x += h * gx
            k1y += h * gy
            zc += h
        kx[k] = k2x
        ky[k] = k2y
    a = np.zeros((5, 5))
    b = np.zeros(5)
    row = np.empty(5)
    for k in range(n):
        dz = z[k] - z_ref
        for j in range(n_meas[k]):
            w = 1.0 / (sigma[k, j] * sigma[k, j])
            row[0] = hx[k, j]
            row[1] = hy[k, j]
            row[2] = hx[k, j] * dz
            row[3] = hy[k, j] * dz
            row[4] = hx[k, j] * kx[k] + hy[k, j] * ky[k]
            for r in range(5):
                b[r] += row[r] * m[k, j] * w
                for c in range(5):
                    a[r, c] += row[r] * row[c] * w
    a[4, 4] += 1.0 / (QOP_PRIOR_SIGMA * QOP_PRIOR_SIGMA)
    inv = np.empty((5, 5))
    work = np.empty((5, 5))
    vec = np.empty(10)
    if not invert_spd(a, inv, work, vec):
        for i in range(5):
            out_state[i] = np.nan
        return np.inf
    for i in range(5):
        s = 0.0
        for j in range(5):
            s += inv[i, j] * b[j]
        out_state[i] = s
    # the fitted line parameters are at z_ref already; tx0/ty0 are the slopes there
    for i in range(5):
        for j in range(5):
            out_cov[i, j] = 0.0
    for i in range(4):
        out_cov[i, i] = SEED_VARIANCES[i]
    # 10% of q/p, or the least-squares error where the hits hardly measure q/p (little
    # field integral, e.g. VELO-only tracks): the prior must never claim more than the data
    out_cov[4, 4] = (SEED_QOP_FRACTION * out_state[4]) ** 2 + inv[4, 4]
    return inv[4, 4]


@nb.njit(cache=True)
def seed_tracks(offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma,
                field_kind, field_params, field_grid, out_states, out_covs, out_qop_var):
    """`seed_track` for every track of a CSR batch."""
    for t in range(offsets.size - 1):
        lo = offsets[t]
        hi = offsets[t + 1]
        out_qop_var[t] = seed_track(node_z[lo:hi], node_n_meas[lo:hi], node_hx[lo:hi], node_hy[lo:hi],
                                    node_m[lo:hi], node_sigma[lo:hi], field_kind, field_params,
                                    field_grid, out_states[t], out_covs[t])
