"""Analytic helices in a homogeneous field for the triplet-fit tests (numpy, vectorised).

Units: mm, MeV, tesla, rad. A particle of charge q and momentum p moves on a helix
around B̂: dd/ds = κ_c·(q/p)·(d × B), i.e. the direction rotates about B̂ at the rate
Ω = −κ_c·(q/p)·|B| per unit path length (DESIGN §2 equations of motion).
"""

from __future__ import annotations

import numpy as np

from pkf.physics.materials import highland_theta0

C_LIGHT = 0.299792458
PION_MASS = 139.57039


def _rodrigues(d, axis, angle):
    """Rotate unit vectors d (n, 3) about unit axis (3,) by angle (n,)."""
    c = np.cos(angle)[:, None]
    s = np.sin(angle)[:, None]
    ax = np.broadcast_to(axis, d.shape)
    return d * c + np.cross(ax, d) * s + ax * (ax * d).sum(1, keepdims=True) * (1.0 - c)


def helix_point(pos, d, qop, bvec, s):
    """Position and direction after path length s (n,) along the helix."""
    bmag = float(np.linalg.norm(bvec))
    if bmag == 0.0:
        return pos + d * s[:, None], d.copy()
    bhat = np.asarray(bvec, dtype=float) / bmag
    omega = -C_LIGHT * qop * bmag
    dpar = (d @ bhat)[:, None] * bhat
    dperp = d - dpar
    u = omega * s
    small = np.abs(omega) * np.maximum(np.abs(s), 1.0) < 1e-12
    om = np.where(small, 1.0, omega)
    sin_term = np.where(small, s, np.sin(u) / om)
    cos_term = np.where(small, 0.5 * omega * s * s, (1.0 - np.cos(u)) / om)
    new = (pos + dpar * s[:, None] + dperp * sin_term[:, None]
           + np.cross(bhat, dperp) * cos_term[:, None])
    return new, _rodrigues(d, bhat, u)


def helix_to_plane(pos, d, qop, bvec, z_plane):
    """Propagate to the plane z = z_plane (Newton in the path length, to ~1e-13 mm)."""
    z_plane = np.broadcast_to(np.asarray(z_plane, dtype=float), (pos.shape[0],))
    s = (z_plane - pos[:, 2]) / d[:, 2]
    for _ in range(30):
        x, dd = helix_point(pos, d, qop, bvec, s)
        f = x[:, 2] - z_plane
        s = s - f / dd[:, 2]
        if np.max(np.abs(f)) < 1e-12:
            break
    return helix_point(pos, d, qop, bvec, s)


def kick(d, theta0, rng):
    """Multiple-scattering kick: two independent N(0, θ0²) angles ⟂ d, exact rotation."""
    n = d.shape[0]
    ref = np.where(np.abs(d[:, [0]]) < 0.9, np.array([[1.0, 0.0, 0.0]]),
                   np.array([[0.0, 1.0, 0.0]]))
    u = np.cross(d, ref)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(d, u)
    t1 = rng.normal(size=n) * theta0
    t2 = rng.normal(size=n) * theta0
    ang = np.hypot(t1, t2)
    safe = np.where(ang > 0.0, ang, 1.0)
    axis_dir = (t1[:, None] * u + t2[:, None] * v) / safe[:, None]
    out = d * np.cos(ang)[:, None] + axis_dir * np.sin(ang)[:, None]
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def highland(p, tx, ty, x_over_x0=0.01, mass=PION_MASS):
    """θ0 for unit charge with path length (x/X0)·√(1+tx²+ty²)."""
    t = x_over_x0 * np.sqrt(1.0 + tx * tx + ty * ty)
    return np.array([highland_theta0(float(pi), mass, 1.0, float(ti))
                     for pi, ti in zip(np.atleast_1d(p), np.atleast_1d(t))])


def random_tracks(rng, n, p_range=(500.0, 20000.0), slope=0.3, log_p=True):
    """Random momenta [MeV] (log-uniform), charges ±1, unit directions, start points."""
    lo, hi = p_range
    p = np.exp(rng.uniform(np.log(lo), np.log(hi), n)) if log_p else rng.uniform(lo, hi, n)
    q = rng.choice([-1.0, 1.0], n)
    tx = rng.uniform(-slope, slope, n)
    ty = rng.uniform(-slope, slope, n)
    d = np.stack([tx, ty, np.ones(n)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pos = np.stack([rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), np.zeros(n)], axis=1)
    return p, q, pos, d


def track_hits(p, q, pos, d, bvec, planes, rng=None, scatter_at=(), x_over_x0=0.01,
               mass=PION_MASS, sigma=0.0):
    """Hits (n, len(planes), 3) of helices through z planes; returns (hits, dirs).

    scatter_at: indices into planes where a Highland kick (true p, `mass`, x/X0 along the
    path) is applied after the hit. sigma: Gaussian smearing of x and y [mm].
    dirs: the direction at each plane before any kick there.
    """
    qop = q / p
    n = p.shape[0]
    hits = np.empty((n, len(planes), 3))
    dirs = np.empty((n, len(planes), 3))
    for k, zp in enumerate(planes):
        pos, d = helix_to_plane(pos, d, qop, bvec, zp)
        hits[:, k] = pos
        dirs[:, k] = d
        if k in scatter_at:
            tx = d[:, 0] / d[:, 2]
            ty = d[:, 1] / d[:, 2]
            d = kick(d, highland(p, tx, ty, x_over_x0, mass), rng)
    if sigma > 0.0:
        hits[:, :, :2] += rng.normal(size=(n, len(planes), 2)) * sigma
    return hits, dirs
