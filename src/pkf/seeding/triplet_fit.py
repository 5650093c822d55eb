"""Hit-triplet fit with multiple scattering and hit uncertainties (docs/physics.md#pattern-recognition).

Implements the triplet fit of Schöning (“the triplet paper”, seeds/001; geometry and
eq. 1 from Berger, Kozlinskiy, Kiehn, Schöning, NIM A 844 (2017) 135) for many
triplets at once. Units: mm, MeV, tesla, rad; curvature in 1/mm, q/p in 1/MeV.

Three fits share one geometry table (`triplet_geometry`, one row per triplet):

* **Radius form, MS only** — paper eq. 1 (`triplet_fit_ms`): one scattering kink at the
  middle hit, hit positions exact, the 3-D radius R3D from the linearisation around the
  circle through the three hits. R3D does not depend on σ_MS; σ_MS is Highland (eq. 2)
  at p = κ_c·|B|·R3D afterwards.
* **Radius form with hit uncertainties** — §2.1.2, App. A and App. C
  (`triplet_fit_hit_errors`): the hit errors are propagated to the two kink angles and
  added to the scattering variances; R3D is the root of the App. C cubic (Cardano).
* **Curvature form** — the same linearised kinks written as functions of the signed
  3-D curvature κ = ±1/R3D (as traccc does, docs/physics.md):
  kink(κ) = ψ + ρ·κ with finite ψ, ρ for every triplet, including exactly collinear
  hits and B = 0 (`triplet_fit_curvature`). Below a field threshold σ_MS is taken at
  the seeding momentum p_min; above it σ_MS = b·|κ| and κ solves the App. C-type cubic.
  It is `fit_triplets`' default in every field: it equals the radius form to
  linearisation order where R_C is well measured, and unlike the radius form it keeps
  correct κ errors where hit errors dominate (the R3D linearisation around R_C fails
  when R_C is noise; tests/seeding/test_triplet_statistics.py::test_radius_form_limit).

`fit_triplets` is the one-call interface (hits → κ, q/p, χ², kinks, direction, status);
`combine_triplets` / `combine_triplet_chain` give the combined χ² of conjoined triplets
(paper eqs. 3–6) used when merging triplets into tracklets.

Conventions (all per triplet; hits are ordered along the motion, 0 → 1 → 2):

* The fit frame has its z′ axis along the field at the middle hit, B̂ (rows of the
  rotation matrix: e1, e2, e3 = B̂, right-handed, x′ = R·x). Below the field threshold
  the axis is B̂ (or the lab y axis when B = 0) made orthogonal to the chord x2 − x0:
  any axis is as good for isotropic scattering, and one orthogonal to the track keeps
  sin ϑ ≈ 1 (curvature is then not a momentum measurement).
* Transverse turning is counted positive counter-clockwise about +z′ (right-handed
  about B̂). A positive charge turns clockwise, so the **signed curvature κ has the sign
  of the charge**: κ = q·κ_c·|B|/p, q/p = κ/(κ_c·|B|), κ_c = 0.299792458 MeV/(T·mm)
  (a 1 GeV particle in 1 T has R3D = 3335.64 mm).
* The transverse kink Φ_MS = φ_out − φ_in (counter-clockwise positive) and the
  longitudinal kink Θ_MS = θ_out − θ_in (θ = polar angle from +z′) at the middle hit.
  Scattering is isotropic: var(Φ_MS) = σ_MS²/sin²ϑ, var(Θ_MS) = σ_MS².
* Highland (docs/physics.md#material-effects) for unit charge with a mass hypothesis (pion by default), with
  path length t = (x/X0)·N, N = √(1 + tx² + ty²) from the circle-solution direction at
  the middle hit (detector planes are normal to z; `x_over_x0` is the plane thickness).
* ndf = 1: two kink angles, one parameter (R3D or κ) — “assuming energy conservation
  the fit has one degree of freedom” (paper §2.1.1). With hit errors the effective
  χ² of §2.1.2 keeps one degree of freedom (the hit positions are not fitted). With
  `straight_below_threshold`, κ ≡ 0 below the field threshold and ndf = 2.

Reading of the paper where its text is ambiguous (the choices made here):

* App. C: the cubic is the stationarity condition of the effective χ² with σ_MS held at
  the solution (the weights are not differentiated); with σ_MS = b/R3D it is exactly
  the paper's cubic. It is *not* the minimum of χ²(R3D) with R3D-dependent σ_MS
  (that one drifts to small momenta, which inflate σ_MS). “b” is b = θ0(p)·R3D from the
  full Highland formula, updated with p (three passes).
* App. A eq. 7 is written for a barrel layout (radial/azimuthal/axial errors, tilt
  angles ω_i) and without a Φ–Θ covariance; here the same chord-angle propagation is
  done with the 3-D hit covariance in any orientation, keeping the Φ–Θ covariance.
  It reduces to eq. 7 for a barrel layout (tested).
* Eq. 4: R̄ = ΣR_i²/σ_i² / ΣR_i/σ_i² is the minimiser of eq. 3 when σ_i ∝ R̄ (the
  “σ_i(R3D)” of eq. 3 is evaluated at the combined R̄); with σ_i(R̄) = R̄·σ(κ_i)/|κ_i|
  eqs. 3–4 are then identical to eqs. 5–6 in h = κ.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT
from pkf.physics.constants import MASS_PION
from pkf.physics.materials import highland_theta0
from pkf.physics.transport import C_LIGHT

__all__ = [
    "C_LIGHT",
    "MASS_PION",
    "DEFAULT_B_THRESHOLD",
    "DEFAULT_P_MIN",
    "FORM_RADIUS",
    "FORM_CURVATURE",
    "COMBINE_CURVATURE",
    "COMBINE_RADIUS",
    "STATUS_DEGENERATE",
    "STATUS_WEAK_FIELD",
    "STATUS_CURVATURE_FALLBACK",
    "STATUS_ROOT_FALLBACK",
    "STATUS_LARGE_BENDING",
    "STATUS_NO_VARIANCE",
    "STATUS_BACKWARD",
    "STATUS_INVALID",
    "GEOMETRY_COLUMNS",
    "N_GEOMETRY_COLUMNS",
    "FIT_COLUMNS",
    "N_FIT_COLUMNS",
    "TripletFit",
    "triplet_geometry",
    "triplet_fit_ms",
    "triplet_fit_hit_errors",
    "triplet_fit_curvature",
    "fit_triplets",
    "fit_triplets_kernel",
    "fit_triplet_row",
    "fit_triplet_kinks",
    "triplet_geometry_row",
    "fit_ms_row",
    "fit_hit_errors_row",
    "fit_curvature_row",
    "combine_triplets",
    "combine_triplet_chain",
    "solve_cubic",
    "highland_sigma",
]

DEFAULT_B_THRESHOLD = 0.05  # T
DEFAULT_P_MIN = 1000.0  # MeV
P_MAX = 1.0e8  # MeV: momentum cap for Highland (σ_MS > 0 for straight tracks in a field)

FORM_RADIUS = 0  # paper: eq. 1 / App. C in R3D where |B| ≥ threshold, curvature form below
FORM_CURVATURE = 1  # curvature form everywhere

COMBINE_CURVATURE = 0  # paper eqs. 5–6 (average of h3D = κ)
COMBINE_RADIUS = 1  # paper eqs. 3–4 (average of R3D)

# Status bits (int32). STATUS_INVALID is the mask of bits that make a fit unusable.
STATUS_DEGENERATE = 1  # coincident hits, or a segment along the field axis
STATUS_WEAK_FIELD = 2  # |B| < threshold: σ_MS at p_min, q/p not measured (qop = 0)
STATUS_CURVATURE_FALLBACK = 4  # radius form requested but not defined: curvature form used
STATUS_ROOT_FALLBACK = 8  # no acceptable cubic root: the fixed-point iterate was kept
STATUS_LARGE_BENDING = 16  # Φ_1C + Φ_2C > π: beyond a half turn, linearisation doubtful
STATUS_NO_VARIANCE = 32  # zero kink variance (no material, no hit errors)
STATUS_BACKWARD = 64  # direction at the middle hit ⟂ z: slopes (tx, ty) undefined
STATUS_INVALID = STATUS_DEGENERATE | STATUS_NO_VARIANCE

# ------------------------------------------------------------------------------------
# Geometry table columns (triplet_geometry). Φ_iC, R3D_iC, θ_iC, α_i, Φ̃, η, Θ̃, β, ϑ as
# in docs/physics.md#pattern-recognition (unsigned circle solution); ψ/ρ the curvature form (signed).
# ------------------------------------------------------------------------------------
GEOMETRY_COLUMNS = (
    "d01", "d12", "d02",          # transverse distances [mm]
    "z01", "z12",                 # longitudinal distances along B̂ [mm]
    "r_c",                        # circle radius [mm] (inf for collinear hits)
    "turn",                       # +1 counter-clockwise about B̂, −1 clockwise
    "phi1c", "phi2c",             # Φ_1C, Φ_2C: transverse bending angles ≥ 0 [rad]
    "r3d1c", "r3d2c",             # R3D_1C, R3D_2C [mm] (inf for collinear hits)
    "theta1c", "theta2c",         # θ_1C, θ_2C polar angles of the segments [rad]
    "alpha1", "alpha2",           # α_1, α_2
    "phi_tilde", "eta",           # Φ̃ [rad], η [1/mm]
    "theta_tilde", "beta",        # Θ̃ [rad], β [1/mm]
    "vartheta",                   # ϑ = (θ_1C + θ_2C)/2 [rad]
    "s1", "s2",                   # 3-D arc lengths of the segments [mm]
    "psi_phi", "rho_phi",         # Φ_MS(κ) = ψ_Φ + ρ_Φ·κ  [rad], [mm]
    "psi_theta", "rho_theta",     # Θ_MS(κ) = ψ_Θ + ρ_Θ·κ  [rad], [mm]
    "vhit_phiphi", "vhit_phitheta", "vhit_thetatheta",  # hit errors → kinks [rad²]
    "bmag",                       # |B| at the middle hit [T]
    "tx_c", "ty_c",               # circle-solution slopes at the middle hit (lab)
    "phi01", "phi12",             # azimuths of the chords in the fit frame [rad]
    "r00", "r01", "r02", "r10", "r11", "r12", "r20", "r21", "r22",  # lab → fit frame
    "status",                     # geometry status bits (as float)
)
N_GEOMETRY_COLUMNS = len(GEOMETRY_COLUMNS)
(G_D01, G_D12, G_D02, G_Z01, G_Z12, G_RC, G_TURN, G_PHI1, G_PHI2, G_R3D1, G_R3D2,
 G_THETA1, G_THETA2, G_ALPHA1, G_ALPHA2, G_PHI_TILDE, G_ETA, G_THETA_TILDE, G_BETA,
 G_VARTHETA, G_S1, G_S2, G_PSI_PHI, G_RHO_PHI, G_PSI_THETA, G_RHO_THETA, G_VPP, G_VPT,
 G_VTT, G_BMAG, G_TXC, G_TYC, G_PHI01, G_PHI12, G_ROT, _G_R01, _G_R02, _G_R10, _G_R11,
 _G_R12, _G_R20, _G_R21, _G_R22, G_STATUS) = range(N_GEOMETRY_COLUMNS)


# Output columns of fit_triplet_row / fit_triplets_kernel (see TripletFit).
FIT_COLUMNS = (
    "kappa", "var_kappa", "qop", "var_qop", "chi2", "ndf",
    "kink_phi", "kink_theta", "var_kink_phi", "var_kink_theta",
    "tx", "ty", "sigma_ms", "status",
)
N_FIT_COLUMNS = len(FIT_COLUMNS)
(F_KAPPA, F_VAR_KAPPA, F_QOP, F_VAR_QOP, F_CHI2, F_NDF, F_KINK_PHI, F_KINK_THETA,
 F_VAR_KINK_PHI, F_VAR_KINK_THETA, F_TX, F_TY, F_SIGMA_MS, F_STATUS) = range(N_FIT_COLUMNS)


# ------------------------------------------------------------------------------------
# Small numerical helpers
# ------------------------------------------------------------------------------------


@nb.njit(cache=True, **NO_REFCOUNT)
def _x_over_sin(x):
    """x/sin x for 0 ≤ x < π (→ 1 at x = 0)."""
    if x < 1e-4:
        return 1.0 + x * x / 6.0
    return x / math.sin(x)


@nb.njit(cache=True, **NO_REFCOUNT)
def _xcotx_minus_one(x):
    """x·cot x − 1 (≤ 0), series below |x| = 0.1."""
    if abs(x) < 0.1:
        x2 = x * x
        return -x2 * (1.0 / 3.0 + x2 * (1.0 / 45.0 + x2 * (2.0 / 945.0 + x2 / 4725.0)))
    return x * math.cos(x) / math.sin(x) - 1.0


@nb.njit(cache=True, **NO_REFCOUNT)
def _xcotx_minus_one_over_2x(x):
    """(x·cot x − 1)/(2x), finite at x = 0 (used as (g − 1)/Φ with x = Φ/2)."""
    if abs(x) < 0.1:
        x2 = x * x
        return -x * (1.0 / 6.0 + x2 * (1.0 / 90.0 + x2 * (1.0 / 945.0 + x2 / 9450.0)))
    return (x * math.cos(x) / math.sin(x) - 1.0) / (2.0 * x)


@nb.njit(cache=True, **NO_REFCOUNT)
def _wrap(a):
    """Angle wrapped to (−π, π]."""
    while a > math.pi:
        a -= 2.0 * math.pi
    while a <= -math.pi:
        a += 2.0 * math.pi
    return a


@nb.njit(cache=True, **NO_REFCOUNT)
def highland_sigma(p, mass, t):
    """σ_MS [rad] for unit charge: Highland (paper eq. 2, docs/physics.md#material-effects) at p [MeV], path t [X0].

    p is capped at 1e8 MeV so that σ_MS stays positive for straight tracks in a field.
    """
    return highland_theta0(min(p, P_MAX), mass, 1.0, t)


@nb.njit(cache=True, **NO_REFCOUNT)
def _cbrt(x):
    if x >= 0.0:
        return x ** (1.0 / 3.0)
    return -((-x) ** (1.0 / 3.0))


@nb.njit(cache=True, **NO_REFCOUNT)
def _newton_polish(c3, c2, c1, c0, u):
    for _ in range(4):
        f = ((c3 * u + c2) * u + c1) * u + c0
        fp = (3.0 * c3 * u + 2.0 * c2) * u + c1
        if fp == 0.0:
            break
        un = u - f / fp
        fn = ((c3 * un + c2) * un + c1) * un + c0
        if abs(fn) < abs(f):
            u = un
        else:
            break
    return u


@nb.njit(cache=True, **NO_REFCOUNT)
def solve_cubic(a3, a2, a1, a0, scale):
    """Real roots of a3·x³ + a2·x² + a1·x + a0 = 0 (Cardano), for App. C.

    `scale` (> 0) is the expected size of the root of interest: the polynomial is solved
    in u = x/scale with coefficients normalised to max |c_k| = 1, a negligible leading
    coefficient (|c3| < 1e-13, e.g. no hit errors in App. C) lowers the degree, and every
    root is polished with Newton steps on the original polynomial.
    Returns (n_roots, r0, r1, r2) with the unused roots set to 0.
    """
    if not scale > 0.0 or not math.isfinite(scale):
        scale = 1.0
    c3 = a3 * scale * scale * scale
    c2 = a2 * scale * scale
    c1 = a1 * scale
    c0 = a0
    m = max(abs(c3), abs(c2), abs(c1), abs(c0))
    if m == 0.0 or not math.isfinite(m):
        return 0, 0.0, 0.0, 0.0
    c3 /= m
    c2 /= m
    c1 /= m
    c0 /= m
    u0 = 0.0
    u1 = 0.0
    u2 = 0.0
    n = 0
    if abs(c3) < 1e-13:
        if abs(c2) < 1e-13:
            if c1 != 0.0:
                u0 = -c0 / c1
                n = 1
        else:
            disc = c1 * c1 - 4.0 * c2 * c0
            if disc >= 0.0:
                sq = math.sqrt(disc)
                q = -0.5 * (c1 + math.copysign(sq, c1))
                u0 = q / c2
                n = 1
                if q != 0.0:
                    u1 = c0 / q
                    n = 2
    else:
        # depressed cubic t³ + p t + q = 0, u = t − b/3
        b = c2 / c3
        c = c1 / c3
        d = c0 / c3
        p = c - b * b / 3.0
        q = 2.0 * b * b * b / 27.0 - b * c / 3.0 + d
        disc = 0.25 * q * q + p * p * p / 27.0
        if disc > 0.0:
            sq = math.sqrt(disc)
            # numerically stable: take the larger-magnitude cube root first
            w = _cbrt(-0.5 * q - math.copysign(sq, q))
            t = w - p / (3.0 * w) if w != 0.0 else 0.0
            u0 = t - b / 3.0
            n = 1
        elif p == 0.0:
            u0 = -b / 3.0
            n = 1
        else:
            # three real roots (trigonometric form of Cardano's formula)
            r = math.sqrt(-p / 3.0)
            arg = min(1.0, max(-1.0, -0.5 * q / (r * r * r)))
            phi = math.acos(arg) / 3.0
            u0 = 2.0 * r * math.cos(phi) - b / 3.0
            u1 = 2.0 * r * math.cos(phi - 2.0 * math.pi / 3.0) - b / 3.0
            u2 = 2.0 * r * math.cos(phi - 4.0 * math.pi / 3.0) - b / 3.0
            n = 3
    # Newton polish on the normalised polynomial (keeps a step only if |f| decreases)
    if n > 0:
        u0 = _newton_polish(c3, c2, c1, c0, u0)
    if n > 1:
        u1 = _newton_polish(c3, c2, c1, c0, u1)
    if n > 2:
        u2 = _newton_polish(c3, c2, c1, c0, u2)
    return n, u0 * scale, u1 * scale, u2 * scale


# ------------------------------------------------------------------------------------
# Geometry (docs/physics.md#pattern-recognition; Berger et al. §3; triplet paper Figure 2, App. A)
# ------------------------------------------------------------------------------------


@nb.njit(cache=True, **NO_REFCOUNT)
def _fit_frame(bx, by, bz, cx, cy, cz, weak):
    """Rotation lab → fit frame, rows e1, e2, e3 (x′ = R·x), for the field (bx, by, bz) [T]
    and the chord c = x2 − x0 [mm]: returns (ok, r00 … r22). Scalars only (array
    arguments of a non-inlined call cost reference-count updates)."""
    bmag = math.sqrt(bx * bx + by * by + bz * bz)
    if bmag > 0.0:
        ux, uy, uz = bx / bmag, by / bmag, bz / bmag
    else:
        ux, uy, uz = 0.0, 1.0, 0.0
    if weak:
        cn = math.sqrt(cx * cx + cy * cy + cz * cz)
        if cn == 0.0:
            return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        cx /= cn
        cy /= cn
        cz /= cn
        dot = ux * cx + uy * cy + uz * cz
        vx, vy, vz = ux - dot * cx, uy - dot * cy, uz - dot * cz
        vn = math.sqrt(vx * vx + vy * vy + vz * vz)
        if vn < 0.5:  # axis within 30° of the chord: use the lab axis least aligned with it
            ax, ay, az = abs(cx), abs(cy), abs(cz)
            if ax <= ay and ax <= az:
                ux, uy, uz = 1.0, 0.0, 0.0
            elif ay <= az:
                ux, uy, uz = 0.0, 1.0, 0.0
            else:
                ux, uy, uz = 0.0, 0.0, 1.0
            dot = ux * cx + uy * cy + uz * cz
            vx, vy, vz = ux - dot * cx, uy - dot * cy, uz - dot * cz
            vn = math.sqrt(vx * vx + vy * vy + vz * vz)
        ux, uy, uz = vx / vn, vy / vn, vz / vn
    # e1: the lab axis least aligned with e3, made orthogonal; e2 = e3 × e1
    if abs(ux) <= abs(uy) and abs(ux) <= abs(uz):
        ax, ay, az = 1.0, 0.0, 0.0
    elif abs(uy) <= abs(uz):
        ax, ay, az = 0.0, 1.0, 0.0
    else:
        ax, ay, az = 0.0, 0.0, 1.0
    dot = ax * ux + ay * uy + az * uz
    e1x, e1y, e1z = ax - dot * ux, ay - dot * uy, az - dot * uz
    n1 = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
    e1x /= n1
    e1y /= n1
    e1z /= n1
    e2x = uy * e1z - uz * e1y
    e2y = uz * e1x - ux * e1z
    e2z = ux * e1y - uy * e1x
    return True, e1x, e1y, e1z, e2x, e2y, e2z, ux, uy, uz


@nb.njit(cache=True, **NO_REFCOUNT)
def _chord_gradients(cx, cy, cz):
    """∂φ/∂c and ∂θ/∂c of a chord c (fit frame), φ = atan2(c_y, c_x), θ = atan2(d, c_z):
    returns (φ_x, φ_y, θ_x, θ_y, θ_z); ∂φ/∂c_z = 0."""
    d2 = cx * cx + cy * cy
    d = math.sqrt(d2)
    s2 = d2 + cz * cz
    return -cy / d2, cx / d2, cz * cx / (d * s2), cz * cy / (d * s2), -d / s2


@nb.njit(cache=True, **NO_REFCOUNT)
def _rotate(r00, r01, r02, r10, r11, r12, r20, r21, r22, v0, v1, v2):
    """(R·v) for a rotation R given as 9 numbers (row-major)."""
    return (r00 * v0 + r01 * v1 + r02 * v2,
            r10 * v0 + r11 * v1 + r12 * v2,
            r20 * v0 + r21 * v1 + r22 * v2)


@nb.njit(cache=True, **NO_REFCOUNT)
def triplet_geometry_row(h, b, hv, b_threshold, g):
    """Fill one geometry row g (length N_GEOMETRY_COLUMNS) for hits h (3×3, mm).

    b: field (3,) [T] at the middle hit; hv: hit variances (3×3, [hit, x/y/z], mm²,
    lab frame, uncorrelated). See `triplet_geometry` for the quantities.
    """
    # element loops, not slices: a slice is an array view (reference counting)
    for u in range(g.shape[0]):
        g[u] = 0.0
    status = 0
    bmag = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    weak = bmag < b_threshold
    ok, r00, r01, r02, r10, r11, r12, r20, r21, r22 = _fit_frame(
        b[0], b[1], b[2], h[2, 0] - h[0, 0], h[2, 1] - h[0, 1], h[2, 2] - h[0, 2], weak)
    if not ok:
        g[G_STATUS] = STATUS_DEGENERATE
        return
    g[G_ROT + 0] = r00
    g[G_ROT + 1] = r01
    g[G_ROT + 2] = r02
    g[G_ROT + 3] = r10
    g[G_ROT + 4] = r11
    g[G_ROT + 5] = r12
    g[G_ROT + 6] = r20
    g[G_ROT + 7] = r21
    g[G_ROT + 8] = r22
    ax, ay, az = h[1, 0] - h[0, 0], h[1, 1] - h[0, 1], h[1, 2] - h[0, 2]
    c01x, c01y, c01z = _rotate(r00, r01, r02, r10, r11, r12, r20, r21, r22, ax, ay, az)
    ax, ay, az = h[2, 0] - h[1, 0], h[2, 1] - h[1, 1], h[2, 2] - h[1, 2]
    c12x, c12y, c12z = _rotate(r00, r01, r02, r10, r11, r12, r20, r21, r22, ax, ay, az)
    c02x = c01x + c12x
    c02y = c01y + c12y
    d01 = math.hypot(c01x, c01y)
    d12 = math.hypot(c12x, c12y)
    d02 = math.hypot(c02x, c02y)
    z01 = c01z
    z12 = c12z
    if not (d01 > 0.0 and d12 > 0.0):
        g[G_STATUS] = STATUS_DEGENERATE
        return
    cross = c01x * c12y - c01y * c12x  # > 0: counter-clockwise about B̂
    turn = 1.0 if cross >= 0.0 else -1.0
    acr = abs(cross)
    # Bending angles Φ_1C, Φ_2C = twice the inscribed angle opposite each chord (exactly
    # 2·asin(d_i/(2R_C)) of docs/physics.md#pattern-recognition for Φ < π, and defined beyond a half turn).
    phi1 = 2.0 * math.atan2(acr, c02x * c12x + c02y * c12y)
    phi2 = 2.0 * math.atan2(acr, c01x * c02x + c01y * c02y)
    if phi1 + phi2 > math.pi:
        status |= STATUS_LARGE_BENDING
    # R_C = d01 d12 d02 / √(2d01²d12² + …) = d01 d12 d02 / (2|c01 × c12|)
    r_c = d01 * d12 * d02 / (2.0 * acr) if acr > 0.0 else np.inf
    # transverse arc lengths a_i = R_C Φ_iC, 3-D arc lengths s_i = Φ_iC·R3D_iC
    a1 = d01 * _x_over_sin(0.5 * phi1)
    a2 = d12 * _x_over_sin(0.5 * phi2)
    s1 = math.hypot(a1, z01)
    s2 = math.hypot(a2, z12)
    theta1 = math.atan2(a1, z01)  # = acos(z_i/(Φ_iC R3D_iC))
    theta2 = math.atan2(a2, z12)
    if a1 < 1e-12 * s1 or a2 < 1e-12 * s2:
        g[G_STATUS] = STATUS_DEGENERATE
        return
    cot1 = z01 / a1
    cot2 = z12 / a2
    # α_i = (R_C²Φ² + z²)/(½R_C²Φ³cot(Φ/2) + z²) = s²/(a²g + z²), g = (Φ/2)cot(Φ/2);
    # 1 − α_i = a²(g − 1)/(a²g + z²) without cancellation.
    gm1_1 = _xcotx_minus_one(0.5 * phi1)
    gm1_2 = _xcotx_minus_one(0.5 * phi2)
    den1 = a1 * a1 * (1.0 + gm1_1) + z01 * z01
    den2 = a2 * a2 * (1.0 + gm1_2) + z12 * z12
    oma1 = a1 * a1 * gm1_1 / den1
    oma2 = a2 * a2 * gm1_2 / den2
    alpha1 = 1.0 - oma1
    alpha2 = 1.0 - oma2
    # (1 − α_i)/Φ_iC, finite at Φ = 0
    q1 = a1 * a1 * _xcotx_minus_one_over_2x(0.5 * phi1) / den1
    q2 = a2 * a2 * _xcotx_minus_one_over_2x(0.5 * phi2) / den2
    k1 = phi1 / s1  # 1/R3D_iC
    k2 = phi2 / s2
    # radius form (unsigned), docs/physics.md#pattern-recognition
    phi_tilde = -0.5 * (phi1 * alpha1 + phi2 * alpha2)
    eta = 0.5 * (phi1 * alpha1 * k1 + phi2 * alpha2 * k2)
    theta_tilde = theta2 - theta1 - oma2 * cot2 + oma1 * cot1
    beta = oma2 * k2 * cot2 - oma1 * k1 * cot1
    vartheta = 0.5 * (theta1 + theta2)
    # curvature form (κ signed like the charge): linearising Φ_i and θ_i in κ around
    # the circle solution, dΦ_i/dκ = α_i·s_i and dθ_i/dκ = −(1 − α_i)·R3D_i/tan θ_i.
    psi_phi = turn * 0.5 * (alpha1 * phi1 + alpha2 * phi2)
    rho_phi = 0.5 * (alpha1 * s1 + alpha2 * s2)
    psi_theta = theta2 - theta1 + oma2 * cot2 - oma1 * cot1
    rho_theta = turn * (q2 * s2 * cot2 - q1 * s1 * cot1)
    # hit errors → kink angles (App. A eq. 7, generalised: chord-angle Jacobian with the
    # full 3-D hit covariance, which reproduces eq. 7 for a barrel layout).
    # Φ = φ12 − φ01, Θ = θ12 − θ01; ∂/∂x0 = +∂/∂c01, ∂/∂x1 = −∂/∂c01 − ∂/∂c12,
    # ∂/∂x2 = +∂/∂c12 (fit frame), then J_lab = J′·R.
    pa_x, pa_y, ta_x, ta_y, ta_z = _chord_gradients(c01x, c01y, c01z)
    pb_x, pb_y, tb_x, tb_y, tb_z = _chord_gradients(c12x, c12y, c12z)
    vpp = 0.0
    vpt = 0.0
    vtt = 0.0
    for k in range(3):
        if hv[k, 0] == 0.0 and hv[k, 1] == 0.0 and hv[k, 2] == 0.0:
            continue
        if k == 0:
            jpx, jpy, jtx, jty, jtz = pa_x, pa_y, ta_x, ta_y, ta_z
        elif k == 1:
            jpx, jpy = -(pa_x + pb_x), -(pa_y + pb_y)
            jtx, jty, jtz = -(ta_x + tb_x), -(ta_y + tb_y), -(ta_z + tb_z)
        else:
            jpx, jpy, jtx, jty, jtz = pb_x, pb_y, tb_x, tb_y, tb_z
        for m in range(3):
            lp = jpx * g[G_ROT + m] + jpy * g[G_ROT + 3 + m]
            lt = jtx * g[G_ROT + m] + jty * g[G_ROT + 3 + m] + jtz * g[G_ROT + 6 + m]
            vpp += lp * lp * hv[k, m]
            vpt += lp * lt * hv[k, m]
            vtt += lt * lt * hv[k, m]
    # circle-solution direction at the middle hit (lab slopes)
    phi01 = math.atan2(c01y, c01x)
    phi12 = math.atan2(c12y, c12x)
    phim = phi01 + 0.5 * turn * phi1
    st = math.sin(vartheta)
    dpx = st * math.cos(phim)
    dpy = st * math.sin(phim)
    dpz = math.cos(vartheta)
    dz = r02 * dpx + r12 * dpy + r22 * dpz
    if abs(dz) > 1e-12:
        g[G_TXC] = (r00 * dpx + r10 * dpy + r20 * dpz) / dz
        g[G_TYC] = (r01 * dpx + r11 * dpy + r21 * dpz) / dz
    else:
        status |= STATUS_BACKWARD
    g[G_D01] = d01
    g[G_D12] = d12
    g[G_D02] = d02
    g[G_Z01] = z01
    g[G_Z12] = z12
    g[G_RC] = r_c
    g[G_TURN] = turn
    g[G_PHI1] = phi1
    g[G_PHI2] = phi2
    g[G_R3D1] = s1 / phi1 if phi1 > 0.0 else np.inf
    g[G_R3D2] = s2 / phi2 if phi2 > 0.0 else np.inf
    g[G_THETA1] = theta1
    g[G_THETA2] = theta2
    g[G_ALPHA1] = alpha1
    g[G_ALPHA2] = alpha2
    g[G_PHI_TILDE] = phi_tilde
    g[G_ETA] = eta
    g[G_THETA_TILDE] = theta_tilde
    g[G_BETA] = beta
    g[G_VARTHETA] = vartheta
    g[G_S1] = s1
    g[G_S2] = s2
    g[G_PSI_PHI] = psi_phi
    g[G_RHO_PHI] = rho_phi
    g[G_PSI_THETA] = psi_theta
    g[G_RHO_THETA] = rho_theta
    g[G_VPP] = vpp
    g[G_VPT] = vpt
    g[G_VTT] = vtt
    g[G_BMAG] = bmag
    g[G_PHI01] = phi01
    g[G_PHI12] = phi12
    g[G_STATUS] = status


@nb.njit(cache=True)
def _geometry_kernel(hits, bfield, hit_var, b_threshold):
    n = hits.shape[0]
    out = np.empty((n, N_GEOMETRY_COLUMNS))
    for i in range(n):
        triplet_geometry_row(hits[i], bfield[i], hit_var[i], b_threshold, out[i])
    return out


# ------------------------------------------------------------------------------------
# Fits on one geometry row
# ------------------------------------------------------------------------------------


@nb.njit(cache=True, **NO_REFCOUNT)
def _path_x0(g, x_over_x0):
    """Path length [X0] through the middle plane (normal z) along the circle direction."""
    tx = g[G_TXC]
    ty = g[G_TYC]
    return x_over_x0 * math.sqrt(1.0 + tx * tx + ty * ty)


@nb.njit(cache=True, **NO_REFCOUNT)
def _weighted_2x2(cpp, cpt, ctt, rp, rt, pp, pt):
    """For C = [[cpp, cpt], [cpt, ctt]] and K = C⁻¹: (ρᵀKρ, ρᵀKψ, ψᵀKψ), ρ = (rp, rt),
    ψ = (pp, pt). Returns zeros if C is singular."""
    det = cpp * ctt - cpt * cpt
    if not det > 0.0:
        return 0.0, 0.0, 0.0
    kpp = ctt / det
    kpt = -cpt / det
    ktt = cpp / det
    rkr = rp * (kpp * rp + kpt * rt) + rt * (kpt * rp + ktt * rt)
    rkp = rp * (kpp * pp + kpt * pt) + rt * (kpt * pp + ktt * pt)
    pkp = pp * (kpp * pp + kpt * pt) + pt * (kpt * pp + ktt * pt)
    return rkr, rkp, pkp


@nb.njit(cache=True, **NO_REFCOUNT)
def _ms_only_radius(g):
    """Paper eq. 1: R3D = −(ηΦ̃ sin²ϑ + βΘ̃)/(η² sin²ϑ + β²) and its geometric weight."""
    s2 = math.sin(g[G_VARTHETA]) ** 2
    eta = g[G_ETA]
    beta = g[G_BETA]
    w = eta * eta * s2 + beta * beta
    if not w > 0.0:
        return 0.0, 0.0
    return -(eta * g[G_PHI_TILDE] * s2 + beta * g[G_THETA_TILDE]) / w, w


@nb.njit(cache=True, **NO_REFCOUNT)
def fit_ms_row(g, x_over_x0, mass, bias_correction):
    """MS-only radius fit (paper eq. 1) on one geometry row.

    Returns (R3D [mm], σ(R3D) [mm], χ²_min, σ_MS [rad], ok) with
    σ(R3D)² = σ_MS²/(η² sin²ϑ + β²), χ²_min = (βΦ̃ − ηΘ̃)²/(σ_MS²(η² + β²/sin²ϑ)) and
    σ_MS from Highland at p = κ_c·|B|·R3D (R3D does not depend on σ_MS).
    bias_correction: multiply R3D by ¾ + ¼√(1 − 8δ² sin²ϑ),
    δ = (βΦ̃ − ηΘ̃)/(ηΦ̃ sin²ϑ + βΘ̃) (Belle II, docs/physics.md).
    """
    if int(g[G_STATUS]) & STATUS_DEGENERATE:
        return 0.0, 0.0, np.inf, 0.0, False
    r3d, w = _ms_only_radius(g)
    if not (r3d > 0.0 and math.isfinite(r3d)):
        return 0.0, 0.0, np.inf, 0.0, False
    s2 = math.sin(g[G_VARTHETA]) ** 2
    eta = g[G_ETA]
    beta = g[G_BETA]
    phit = g[G_PHI_TILDE]
    thet = g[G_THETA_TILDE]
    if bias_correction:
        den = eta * phit * s2 + beta * thet
        if den != 0.0:
            delta = (beta * phit - eta * thet) / den
            arg = 1.0 - 8.0 * delta * delta * s2
            r3d *= 0.75 + 0.25 * math.sqrt(max(arg, 0.0))
    p = C_LIGHT * g[G_BMAG] * r3d
    sms = highland_sigma(p, mass, _path_x0(g, x_over_x0))
    if not sms > 0.0:
        return r3d, 0.0, np.inf, 0.0, False
    sig_r = sms / math.sqrt(w)
    num = beta * phit - eta * thet
    chi2 = num * num / (sms * sms * (eta * eta + beta * beta / s2))
    return r3d, sig_r, chi2, sms, True


@nb.njit(cache=True, **NO_REFCOUNT)
def _radius_cubic_coefficients(eta, beta, phit, thet, s2, vpp, vpt, vtt, b):
    """App. C cubic a3 R³ + a2 R² + a1 R + a0 = 0 for σ_MS = b/R3D.

    It is the stationarity condition ∂χ²/∂R = 0 of
    χ² = (Φ̃ + ηR, Θ̃ + βR)·C⁻¹·(…)ᵀ, C = [[b²/(R² sin²ϑ) + V_ΦΦ, V_ΦΘ], [V_ΦΘ, b²/R² + V_ΘΘ]]
    with C held at the solution (σ_MS is not differentiated), multiplied by R²·det C.
    With V_ΦΘ = 0 these are the paper's coefficients:
    a3 = η²σ²_θhit + β²σ²_φhit, a2 = ηΦ̃σ²_θhit + βΘ̃σ²_φhit, a1 = b²(η² + β²/sin²ϑ),
    a0 = b²(ηΦ̃ + βΘ̃/sin²ϑ).
    """
    a3 = eta * eta * vtt - 2.0 * vpt * eta * beta + beta * beta * vpp
    a2 = eta * phit * vtt - vpt * (eta * thet + beta * phit) + beta * thet * vpp
    a1 = b * b * (eta * eta + beta * beta / s2)
    a0 = b * b * (eta * phit + beta * thet / s2)
    return a3, a2, a1, a0


@nb.njit(cache=True, **NO_REFCOUNT)
def _pick_root(n, r0, r1, r2, ref, positive):
    """The real root nearest to ref (optionally only positive ones); ok flag."""
    best = 0.0
    bestd = np.inf
    for k in range(n):
        r = r0 if k == 0 else (r1 if k == 1 else r2)
        if positive and not r > 0.0:
            continue
        dd = abs(r - ref)
        if dd < bestd:
            bestd = dd
            best = r
    return best, bestd < np.inf


@nb.njit(cache=True, **NO_REFCOUNT)
def fit_hit_errors_row(g, x_over_x0, mass):
    """Radius fit with hit uncertainties (paper §2.1.2, App. A, App. C) on one row.

    Effective kink variances σ²_φ,eff = σ_MS²/sin²ϑ + σ²_φhit, σ²_θ,eff = σ_MS² + σ²_θhit
    (+ the Φ–Θ hit covariance, zero in the paper's eq. 7), σ_MS = b/R3D with
    b = θ0(p)·R3D from Highland at p = κ_c|B|R3D.

    Root choice: all fixed points R = −(ρᵀKψ)/(ρᵀKρ) (K at R) lie between the
    single-kink solutions −Φ̃/η and −Θ̃/β; the physical root is the one continuously
    connected to eq. 1 as the hit errors vanish. We start from eq. 1, do three
    fixed-point iterations with K frozen, take the positive real Cardano root nearest to
    that iterate; then b is recomputed at the new momentum (β and the logarithm of
    Highland make b = θ0·R3D depend weakly on p) and the cubic solved again (root
    nearest to the previous one), at most three passes, fewer once b is stable to 1e-10.
    The returned R3D is the exact root of the cubic with the returned b.

    Returns (R3D, σ(R3D), χ², b [rad·mm], σ_MS = b/R3D, status) with
    σ(R3D)² = 1/(ρᵀKρ), χ² = rᵀKr at the root, r = (Φ̃ + ηR, Θ̃ + βR).
    """
    status = int(g[G_STATUS])
    if status & STATUS_DEGENERATE:
        return 0.0, 0.0, np.inf, 0.0, 0.0, status
    s2 = math.sin(g[G_VARTHETA]) ** 2
    eta = g[G_ETA]
    beta = g[G_BETA]
    phit = g[G_PHI_TILDE]
    thet = g[G_THETA_TILDE]
    vpp = g[G_VPP]
    # the radius form's transverse residual Φ̃ + ηR counts turning along the bending
    # direction (= turn × the counter-clockwise kink the covariance refers to)
    vpt = g[G_TURN] * g[G_VPT]
    vtt = g[G_VTT]
    r, w = _ms_only_radius(g)
    if not (r > 0.0 and math.isfinite(r)):
        return 0.0, 0.0, np.inf, 0.0, 0.0, status | STATUS_CURVATURE_FALLBACK
    t = _path_x0(g, x_over_x0)
    bmag = g[G_BMAG]
    b = highland_sigma(C_LIGHT * bmag * r, mass, t) * r
    # fixed-point iterations with the weights frozen, from eq. 1
    for _ in range(3):
        cpp = b * b / (r * r * s2) + vpp
        ctt = b * b / (r * r) + vtt
        rkr, rkp, _pkp = _weighted_2x2(cpp, vpt, ctt, eta, beta, phit, thet)
        if not rkr > 0.0:
            break
        rn = -rkp / rkr
        if rn > 0.0:
            r = rn
    for it in range(3):
        if it > 0:  # b at the current momentum (β and the logarithm of Highland)
            b_new = highland_sigma(C_LIGHT * bmag * r, mass, t) * r
            if abs(b_new - b) <= 1e-10 * b:
                break
            b = b_new
        a3, a2, a1, a0 = _radius_cubic_coefficients(eta, beta, phit, thet, s2,
                                                    vpp, vpt, vtt, b)
        n, x0, x1, x2 = solve_cubic(a3, a2, a1, a0, r)
        root, ok = _pick_root(n, x0, x1, x2, r, True)
        if ok:
            r = root
        else:
            status |= STATUS_ROOT_FALLBACK
    sms = b / r
    cpp = sms * sms / s2 + vpp
    ctt = sms * sms + vtt
    rp = phit + eta * r
    rt = thet + beta * r
    rkr, rkp, pkp = _weighted_2x2(cpp, vpt, ctt, eta, beta, rp, rt)
    if not rkr > 0.0:
        return r, 0.0, np.inf, b, sms, status | STATUS_NO_VARIANCE
    return r, 1.0 / math.sqrt(rkr), pkp, b, sms, status


@nb.njit(cache=True, **NO_REFCOUNT)
def _curvature_cubic_coefficients(rp, rt, pp, pt, s2, vpp, vpt, vtt, b):
    """Curvature-form analogue of App. C: σ_MS = b·|κ|, frozen-weight stationarity
    κ·ρᵀadj(C)ρ + ρᵀadj(C)ψ = 0 with C = [[b²κ²/sin²ϑ + V_ΦΦ, V_ΦΘ], [V_ΦΘ, b²κ² + V_ΘΘ]]."""
    a3 = b * b * (rp * rp + rt * rt / s2)
    a2 = b * b * (rp * pp + rt * pt / s2)
    a1 = rp * rp * vtt - 2.0 * vpt * rp * rt + rt * rt * vpp
    a0 = rp * pp * vtt - vpt * (rp * pt + rt * pp) + rt * pt * vpp
    return a3, a2, a1, a0


@nb.njit(cache=True, **NO_REFCOUNT)
def fit_curvature_row(g, x_over_x0, mass, b_threshold, p_min, straight):
    """Curvature-form fit (docs/physics.md#pattern-recognition last item; traccc's form) on one geometry row.

    Kinks linear in the signed curvature κ: r(κ) = ψ + ρκ (columns psi_*/rho_*),
    C = diag(σ_MS²/sin²ϑ, σ_MS²) + V_hit, K = C⁻¹:
    κ̂ = −ρᵀKψ/ρᵀKρ, var κ̂ = 1/ρᵀKρ, χ² = ψᵀKψ − (ρᵀKψ)²/ρᵀKρ.
    Below `b_threshold` σ_MS is Highland at p_min (C fixed: one linear solve); with
    `straight` κ is fixed to 0 there (χ² = ψᵀKψ, ndf 2). Above it σ_MS = b|κ| with b
    from Highland at p = κ_c|B|/|κ|, solved like App. C (cubic in κ, root nearest to
    the fixed-point iterate started from the MS-only solution; three passes updating b,
    the returned κ is the exact root for the b of the last pass, σ_MS = b·|κ|).
    Without hit errors κ̂ is the MS-only solution (σ_MS cancels) and σ_MS is Highland
    at p = κ_c|B|/|κ̂|. p is capped at 1e8 MeV (σ_MS > 0 for straight tracks).

    Returns (κ [1/mm], var κ [1/mm²], χ², σ_MS [rad], ndf, status).
    """
    status = int(g[G_STATUS])
    if status & STATUS_DEGENERATE:
        return 0.0, np.inf, np.inf, 0.0, 1, status
    s2 = math.sin(g[G_VARTHETA]) ** 2
    rp = g[G_RHO_PHI]
    rt = g[G_RHO_THETA]
    pp = g[G_PSI_PHI]
    pt = g[G_PSI_THETA]
    vpp = g[G_VPP]
    vpt = g[G_VPT]
    vtt = g[G_VTT]
    t = _path_x0(g, x_over_x0)
    bmag = g[G_BMAG]
    if bmag < b_threshold:
        status |= STATUS_WEAK_FIELD
        sms = highland_sigma(p_min, mass, t)
        cpp = sms * sms / s2 + vpp
        ctt = sms * sms + vtt
        rkr, rkp, pkp = _weighted_2x2(cpp, vpt, ctt, rp, rt, pp, pt)
        if not rkr > 0.0:
            return 0.0, np.inf, np.inf, sms, 1, status | STATUS_NO_VARIANCE
        if straight:
            return 0.0, 1.0 / rkr, pkp, sms, 2, status
        return -rkp / rkr, 1.0 / rkr, max(pkp - rkp * rkp / rkr, 0.0), sms, 1, status
    # MS-only solution (σ_MS common factor): weights diag(sin²ϑ, 1)
    w = rp * rp * s2 + rt * rt
    kap = -(rp * pp * s2 + rt * pt) / w
    kc = C_LIGHT * bmag
    hit_errors = vpp > 0.0 or vtt > 0.0
    b = highland_sigma(kc / max(abs(kap), kc / P_MAX), mass, t) / max(abs(kap), kc / P_MAX)
    if hit_errors:
        for _ in range(3):  # fixed-point iterations with the weights frozen
            sm = b * max(abs(kap), kc / P_MAX)
            rkr, rkp, _pkp = _weighted_2x2(sm * sm / s2 + vpp, vpt, sm * sm + vtt,
                                           rp, rt, pp, pt)
            if not rkr > 0.0:
                break
            kap = -rkp / rkr
        for it in range(3):
            if it > 0:  # b at the current momentum
                ak = max(abs(kap), kc / P_MAX)
                b_new = highland_sigma(kc / ak, mass, t) / ak
                if abs(b_new - b) <= 1e-10 * b:
                    break
                b = b_new
            a3, a2, a1, a0 = _curvature_cubic_coefficients(rp, rt, pp, pt, s2,
                                                           vpp, vpt, vtt, b)
            scale = max(abs(kap), kc / P_MAX)
            n, x0, x1, x2 = solve_cubic(a3, a2, a1, a0, scale)
            root, ok = _pick_root(n, x0, x1, x2, kap, False)
            if ok:
                kap = root
            else:
                status |= STATUS_ROOT_FALLBACK
    sms = b * max(abs(kap), kc / P_MAX)
    cpp = sms * sms / s2 + vpp
    ctt = sms * sms + vtt
    rkr, rkp, pkp = _weighted_2x2(cpp, vpt, ctt, rp, rt, pp + rp * kap, pt + rt * kap)
    if not rkr > 0.0:
        return kap, np.inf, np.inf, sms, 1, status | STATUS_NO_VARIANCE
    return kap, 1.0 / rkr, pkp, sms, 1, status


@nb.njit(cache=True, **NO_REFCOUNT)
def _fitted_theta(phi, s, z, theta, turn, kap):
    """Polar angle θ_i(κ) of a segment, linearised around the circle solution:
    θ_iC + (1 − α_i) cot θ_iC + κ·turn·((1 − α_i)/Φ_iC)·s_i·cot θ_iC."""
    a = s * math.sin(theta)
    if a <= 0.0:
        return theta
    x = 0.5 * phi
    gm1 = _xcotx_minus_one(x)
    den = a * a * (1.0 + gm1) + z * z
    oma = a * a * gm1 / den
    q = a * a * _xcotx_minus_one_over_2x(x) / den
    cot = z / a
    return theta + oma * cot + kap * turn * q * s * cot


@nb.njit(cache=True, **NO_REFCOUNT)
def fit_triplet_kinks(g, x_over_x0, mass, b_threshold, p_min, form, straight):
    """The fit of `fit_triplet_row` without the direction at the middle hit (for pattern
    recognition, which needs only κ and χ²; the direction costs seven more trigonometric
    calls). Returns (κ [1/mm], var κ [1/mm²], χ², ndf, σ_MS [rad], Φ_MS, Θ_MS [rad],
    status) exactly as `fit_triplet_row` stores them (its status may add
    STATUS_BACKWARD)."""
    status = int(g[G_STATUS])
    ndf = 1
    kap = 0.0
    var_k = np.inf
    chi2 = np.inf
    sms = 0.0
    bmag = g[G_BMAG]
    turn = g[G_TURN]
    done = False
    kphi = 0.0
    ktheta = 0.0
    if not (status & STATUS_DEGENERATE):
        hit_errors = g[G_VPP] > 0.0 or g[G_VTT] > 0.0
        if form == FORM_RADIUS and bmag >= b_threshold:
            if hit_errors:
                r, sr, c2, _b, sm, st = fit_hit_errors_row(g, x_over_x0, mass)
                ok = not (st & (STATUS_CURVATURE_FALLBACK | STATUS_NO_VARIANCE))
            else:
                r, sr, c2, sm, ok = fit_ms_row(g, x_over_x0, mass, False)
                st = status
            if ok and r > 0.0:
                kap = -turn / r
                var_k = (sr / (r * r)) ** 2
                chi2 = c2
                sms = sm
                status = st
                done = True
                kphi = turn * (g[G_PHI_TILDE] + g[G_ETA] * r)
                ktheta = g[G_THETA_TILDE] + g[G_BETA] * r
            else:
                status |= STATUS_CURVATURE_FALLBACK
        if not done:
            kap, var_k, chi2, sms, ndf, st = fit_curvature_row(
                g, x_over_x0, mass, b_threshold, p_min, straight)
            status |= st
            if straight and (st & STATUS_WEAK_FIELD):
                kap = 0.0
            kphi = g[G_PSI_PHI] + g[G_RHO_PHI] * kap
            ktheta = g[G_PSI_THETA] + g[G_RHO_THETA] * kap
    return kap, var_k, chi2, ndf, sms, kphi, ktheta, status


@nb.njit(cache=True, **NO_REFCOUNT)
def fit_triplet_row(g, x_over_x0, mass, b_threshold, p_min, form, straight, out):
    """Full fit of one triplet from its geometry row; writes `out` (N_FIT_COLUMNS).

    form = FORM_RADIUS: App. C (or eq. 1 without hit errors) where |B| ≥ b_threshold,
    the curvature form below it (and as a fallback where R3D is not defined, e.g.
    collinear hits in a field); FORM_CURVATURE: the curvature form everywhere.
    out = (κ, var κ, q/p, var q/p, χ², ndf, Φ_MS, Θ_MS, var Φ_MS, var Θ_MS, tx, ty,
    σ_MS, status); see `TripletFit`.
    """
    kap, var_k, chi2, ndf, sms, kphi, ktheta, status = fit_triplet_kinks(
        g, x_over_x0, mass, b_threshold, p_min, form, straight)
    bmag = g[G_BMAG]
    turn = g[G_TURN]
    for u in range(out.shape[0]):  # element loop, not a slice (a view)
        out[u] = 0.0
    out[F_KAPPA] = kap
    out[F_VAR_KAPPA] = var_k
    out[F_CHI2] = chi2
    out[F_NDF] = ndf
    out[F_SIGMA_MS] = sms
    if status & STATUS_DEGENERATE:
        out[F_VAR_QOP] = np.inf
        out[F_STATUS] = status
        return
    if bmag >= b_threshold:
        kc = C_LIGHT * bmag
        out[F_QOP] = kap / kc
        out[F_VAR_QOP] = var_k / (kc * kc)
    else:
        out[F_QOP] = 0.0
        out[F_VAR_QOP] = 1.0 / (p_min * p_min)
    # kinks at the fitted curvature and their effective variances
    s2 = math.sin(g[G_VARTHETA]) ** 2
    out[F_KINK_PHI] = kphi
    out[F_KINK_THETA] = ktheta
    out[F_VAR_KINK_PHI] = sms * sms / s2 + g[G_VPP]
    out[F_VAR_KINK_THETA] = sms * sms + g[G_VTT]
    # direction at the middle hit: mean of the fitted in/out tangents. Transverse turning
    # of segment i at κ (counter-clockwise): turn·Φ_iC + α_i s_i (−κ − turn·Φ_iC/s_i).
    phi1 = g[G_PHI1]
    phi2 = g[G_PHI2]
    kccw = -kap
    turn1 = turn * phi1 + g[G_ALPHA1] * (g[G_S1] * kccw - turn * phi1)
    turn2 = turn * phi2 + g[G_ALPHA2] * (g[G_S2] * kccw - turn * phi2)
    phi_in = g[G_PHI01] + 0.5 * turn1
    phi_out = g[G_PHI12] - 0.5 * turn2
    phim = phi_in + 0.5 * _wrap(phi_out - phi_in)
    th1 = _fitted_theta(phi1, g[G_S1], g[G_Z01], g[G_THETA1], turn, kap)
    th2 = _fitted_theta(phi2, g[G_S2], g[G_Z12], g[G_THETA2], turn, kap)
    thm = 0.5 * (th1 + th2)
    st = math.sin(thm)
    dpx = st * math.cos(phim)
    dpy = st * math.sin(phim)
    dpz = math.cos(thm)
    dx = g[G_ROT + 0] * dpx + g[G_ROT + 3] * dpy + g[G_ROT + 6] * dpz
    dy = g[G_ROT + 1] * dpx + g[G_ROT + 4] * dpy + g[G_ROT + 7] * dpz
    dz = g[G_ROT + 2] * dpx + g[G_ROT + 5] * dpy + g[G_ROT + 8] * dpz
    if abs(dz) > 1e-12:
        out[F_TX] = dx / dz
        out[F_TY] = dy / dz
    else:
        status |= STATUS_BACKWARD
    out[F_STATUS] = status


@nb.njit(cache=True)
def fit_triplets_kernel(hits, bfield, x_over_x0, hit_var, mass, b_threshold, p_min,
                        form, straight):
    """Compiled batch fit: hits (n, 3, 3) [mm], bfield (n, 3) [T] at the middle hit,
    x_over_x0 (n,), hit_var (n, 3, 3) [mm²]. Returns (geometry (n, N_GEOMETRY_COLUMNS),
    fit (n, N_FIT_COLUMNS)); columns GEOMETRY_COLUMNS and FIT_COLUMNS."""
    n = hits.shape[0]
    geo = np.empty((n, N_GEOMETRY_COLUMNS))
    fit = np.empty((n, N_FIT_COLUMNS))
    for i in range(n):
        triplet_geometry_row(hits[i], bfield[i], hit_var[i], b_threshold, geo[i])
        fit_triplet_row(geo[i], x_over_x0[i], mass, b_threshold, p_min, form, straight,
                        fit[i])
    return geo, fit


@nb.njit(cache=True)
def _ms_kernel(geo, x_over_x0, mass, bias_correction):
    n = geo.shape[0]
    out = np.empty((n, 4))
    ok = np.empty(n, dtype=np.bool_)
    for i in range(n):
        r, sr, c2, sms, good = fit_ms_row(geo[i], x_over_x0[i], mass, bias_correction)
        out[i, 0] = r
        out[i, 1] = sr
        out[i, 2] = c2
        out[i, 3] = sms
        ok[i] = good
    return out, ok


@nb.njit(cache=True)
def _hit_errors_kernel(geo, x_over_x0, mass):
    n = geo.shape[0]
    out = np.empty((n, 5))
    status = np.empty(n, dtype=np.int32)
    for i in range(n):
        r, sr, c2, b, sms, st = fit_hit_errors_row(geo[i], x_over_x0[i], mass)
        out[i, 0] = r
        out[i, 1] = sr
        out[i, 2] = c2
        out[i, 3] = b
        out[i, 4] = sms
        status[i] = st
    return out, status


@nb.njit(cache=True)
def _curvature_kernel(geo, x_over_x0, mass, b_threshold, p_min, straight):
    n = geo.shape[0]
    out = np.empty((n, 4))
    ndf = np.empty(n, dtype=np.int32)
    status = np.empty(n, dtype=np.int32)
    for i in range(n):
        k, vk, c2, sms, nd, st = fit_curvature_row(geo[i], x_over_x0[i], mass,
                                                   b_threshold, p_min, straight)
        out[i, 0] = k
        out[i, 1] = vk
        out[i, 2] = c2
        out[i, 3] = sms
        ndf[i] = nd
        status[i] = st
    return out, ndf, status


# ------------------------------------------------------------------------------------
# Combination of conjoined triplets (paper §3, eqs. 3–6)
# ------------------------------------------------------------------------------------


@nb.njit(cache=True)
def _combine_chain(offsets, kappa, var_kappa, chi2, ndf, mode):
    """Combined κ, var κ, χ², ndf and status of each chain offsets[j]:offsets[j+1]."""
    m = offsets.shape[0] - 1
    k_out = np.zeros(m)
    v_out = np.full(m, np.inf)
    c_out = np.full(m, np.inf)
    n_out = np.zeros(m, dtype=np.int32)
    s_out = np.zeros(m, dtype=np.int32)
    for j in range(m):
        lo = offsets[j]
        hi = offsets[j + 1]
        nt = hi - lo
        if nt <= 0:
            s_out[j] = STATUS_DEGENERATE
            continue
        csum = 0.0
        nsum = 0
        bad = False
        for i in range(lo, hi):
            csum += chi2[i]
            nsum += ndf[i]
            if not (var_kappa[i] > 0.0 and math.isfinite(var_kappa[i])
                    and math.isfinite(chi2[i])):
                bad = True
        n_out[j] = nsum + nt - 1
        if bad:
            s_out[j] = STATUS_INVALID
            continue
        if mode == COMBINE_RADIUS:
            # eqs. 3–4 with σ_i(R̄) = ε_i·R̄, ε_i = σ(R_i)/|R_i| = σ(κ_i)/|κ_i| (MS-dominated
            # triplets have a constant relative error): R̄ = ΣR_i²/ε_i² / ΣR_i/ε_i²
            # minimises Σ(R_i − R̄)²/(ε_i R̄)².
            num = 0.0
            den = 0.0
            for i in range(lo, hi):
                if kappa[i] == 0.0:
                    bad = True
                    break
                r = 1.0 / kappa[i]
                e2 = var_kappa[i] / (kappa[i] * kappa[i])
                num += r * r / e2
                den += r / e2
            if bad or den == 0.0:
                s_out[j] = STATUS_INVALID
                continue
            rbar = num / den
            extra = 0.0
            winv = 0.0
            for i in range(lo, hi):
                r = 1.0 / kappa[i]
                e2 = var_kappa[i] / (kappa[i] * kappa[i])
                sig2 = e2 * rbar * rbar
                extra += (r - rbar) ** 2 / sig2
                winv += 1.0 / sig2
            k_out[j] = 1.0 / rbar
            v_out[j] = (1.0 / winv) / (rbar ** 4)
            c_out[j] = csum + extra
        else:
            # eqs. 5–6: h̄ = Σ h_i/σ(h_i)² / Σ 1/σ(h_i)², χ² += Σ (h_i − h̄)²/σ(h_i)²
            num = 0.0
            den = 0.0
            for i in range(lo, hi):
                num += kappa[i] / var_kappa[i]
                den += 1.0 / var_kappa[i]
            hbar = num / den
            extra = 0.0
            for i in range(lo, hi):
                extra += (kappa[i] - hbar) ** 2 / var_kappa[i]
            k_out[j] = hbar
            v_out[j] = 1.0 / den
            c_out[j] = csum + extra
    return k_out, v_out, c_out, n_out, s_out


# ------------------------------------------------------------------------------------
# Python interface (argument checking and broadcasting; the work is in the kernels)
# ------------------------------------------------------------------------------------


class TripletFit(NamedTuple):
    """Per-triplet result of `fit_triplets` (arrays of length n).

    kappa        signed 3-D curvature κ = ±1/R3D [1/mm], sign of the charge (fit frame
                 z′ = B̂); below the field threshold the sign is with respect to the
                 chosen axis and κ is not a momentum measurement
    var_kappa    variance of κ [1/mm²] (with `straight_below_threshold`, below the
                 threshold: the variance κ would have if it were fitted)
    qop          q/p = κ/(κ_c|B|) [1/MeV]; 0 below the field threshold
    var_qop      its variance [1/MeV²]; 1/p_min² below the field threshold
    chi2, ndf    χ² of the kink fit and its degrees of freedom (1; 2 for straight lines
                 with `straight_below_threshold`)
    kink_phi     transverse kink Φ_MS at the fit [rad] (counter-clockwise about B̂)
    kink_theta   longitudinal kink Θ_MS = θ_out − θ_in at the fit [rad]
    var_kink_phi, var_kink_theta   their effective variances σ²_φ,eff, σ²_θ,eff [rad²]
                 (App. A: MS plus propagated hit errors)
    phi_tilde, theta_tilde         the paper's Φ̃ and Θ̃ [rad] (geometry, radius form)
    tx, ty       slopes at the middle hit (lab frame)
    sigma_ms     σ_MS used [rad]
    status       bit flags (STATUS_*); `valid` is status & STATUS_INVALID == 0
    geometry     the geometry table (n, N_GEOMETRY_COLUMNS), columns GEOMETRY_COLUMNS
    """

    kappa: np.ndarray
    var_kappa: np.ndarray
    qop: np.ndarray
    var_qop: np.ndarray
    chi2: np.ndarray
    ndf: np.ndarray
    kink_phi: np.ndarray
    kink_theta: np.ndarray
    var_kink_phi: np.ndarray
    var_kink_theta: np.ndarray
    phi_tilde: np.ndarray
    theta_tilde: np.ndarray
    tx: np.ndarray
    ty: np.ndarray
    sigma_ms: np.ndarray
    status: np.ndarray
    geometry: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """True where the fit is usable (no STATUS_INVALID bit)."""
        return (self.status & STATUS_INVALID) == 0

    @property
    def r3d(self) -> np.ndarray:
        """|1/κ| [mm] (inf where κ = 0)."""
        with np.errstate(divide="ignore"):
            return 1.0 / np.abs(self.kappa)


def _as_hits(hits) -> np.ndarray:
    h = np.ascontiguousarray(hits, dtype=np.float64)
    if h.ndim != 3 or h.shape[1:] != (3, 3):
        raise ValueError(f"hits must have shape (n, 3, 3) [triplet, hit, xyz], got {h.shape}")
    return h


def _per_triplet(value, n: int, shape: tuple, name: str) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    try:
        return np.ascontiguousarray(np.broadcast_to(a, (n,) + shape))
    except ValueError:
        raise ValueError(f"{name} must broadcast to {(n,) + shape}, got {a.shape}") from None


def triplet_geometry(hits, bfield, hit_var=None,
                     b_threshold: float = DEFAULT_B_THRESHOLD) -> np.ndarray:
    """Triplet geometry in the frame with z′ along the field at the middle hit (§7.2).

    hits: (n, 3, 3) positions [mm] (triplet, hit 0/1/2 along the motion, x/y/z);
    bfield: (3,) or (n, 3) field [T] at the middle hit; hit_var: None or broadcastable
    to (n, 3, 3) per-hit variances of x, y, z [mm²] (lab frame, uncorrelated).
    Below b_threshold [T] the z′ axis is made orthogonal to the chord (module docstring).

    Returns an (n, N_GEOMETRY_COLUMNS) array, columns GEOMETRY_COLUMNS:
    d01, d12, d02 transverse distances; z01, z12 along B̂; R_C = d01 d12 d02/√(2d01²d12²
    + 2d12²d02² + 2d02²d01² − d01⁴ − d12⁴ − d02⁴); Φ_iC = 2 asin(d_i/(2R_C));
    R3D_iC = √(R_C² + z_i²/Φ_iC²); θ_iC = acos(z_i/(Φ_iC R3D_iC));
    α_i = (R_C²Φ_iC² + z_i²)/(½R_C²Φ_iC³ cot(Φ_iC/2) + z_i²); Φ̃ = −½Σα_iΦ_iC;
    η = ½Σα_iΦ_iC/R3D_iC; Θ̃ = θ_2C − θ_1C − (1−α_2)/tan θ_2C + (1−α_1)/tan θ_1C;
    β = (1−α_2)/(R3D_2C tan θ_2C) − (1−α_1)/(R3D_1C tan θ_1C); ϑ = (θ_1C + θ_2C)/2;
    the curvature form ψ, ρ; the hit-error kink covariance (App. A); the circle-solution
    slopes at the middle hit; the rotation matrix; status bits. All evaluated in forms
    that stay finite for collinear hits (R_C and R3D_iC are then inf).
    """
    h = _as_hits(hits)
    n = h.shape[0]
    b = _per_triplet(bfield, n, (3,), "bfield")
    hv = np.zeros((n, 3, 3)) if hit_var is None else _per_triplet(hit_var, n, (3, 3), "hit_var")
    return _geometry_kernel(h, b, hv, float(b_threshold))


def triplet_fit_ms(geometry, x_over_x0, mass: float = MASS_PION,
                   bias_correction: bool = False):
    """MS-only triplet fit, paper eq. 1, from a `triplet_geometry` table.

    Returns (r3d [mm], sigma_r3d [mm], chi2, sigma_ms [rad], ok):
    R3D = −(ηΦ̃ sin²ϑ + βΘ̃)/(η² sin²ϑ + β²), σ(R3D) = σ_MS/√(η² sin²ϑ + β²),
    χ²_min = (βΦ̃ − ηΘ̃)²/(σ_MS²(η² + β²/sin²ϑ)) (1 dof); σ_MS = Highland (eq. 2) at
    p = κ_c|B|R3D for unit charge and `mass` [MeV] through x/X0 (plane thickness) at the
    middle hit. bias_correction applies the Belle II factor (docs/physics.md).
    ok is False for collinear hits or a non-positive R3D (use the curvature form).
    """
    g = np.ascontiguousarray(geometry, dtype=np.float64)
    xx0 = _per_triplet(x_over_x0, g.shape[0], (), "x_over_x0")
    out, ok = _ms_kernel(g, xx0, float(mass), bool(bias_correction))
    return out[:, 0], out[:, 1], out[:, 2], out[:, 3], ok


def triplet_fit_hit_errors(geometry, x_over_x0, mass: float = MASS_PION):
    """Triplet fit with hit uncertainties in R3D (paper §2.1.2, App. A, App. C).

    The geometry must have been built with the hit variances. Returns
    (r3d [mm], sigma_r3d [mm], chi2, b [rad·mm], sigma_ms [rad], status) where R3D is
    the root of the App. C cubic a3R³ + a2R² + a1R + a0 = 0 (Cardano; root choice in
    `fit_hit_errors_row`) for the returned b, σ_MS = b/R3D (Highland, b = θ0(p)·R3D
    updated with p over three passes), χ² the effective two-kink χ².
    """
    g = np.ascontiguousarray(geometry, dtype=np.float64)
    xx0 = _per_triplet(x_over_x0, g.shape[0], (), "x_over_x0")
    out, status = _hit_errors_kernel(g, xx0, float(mass))
    return out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4], status


def triplet_fit_curvature(geometry, x_over_x0, mass: float = MASS_PION,
                          b_threshold: float = DEFAULT_B_THRESHOLD,
                          p_min: float = DEFAULT_P_MIN,
                          straight_below_threshold: bool = False):
    """Curvature-form triplet fit (finite as B → 0 and for collinear hits).

    Returns (kappa [1/mm], var_kappa [1/mm²], chi2, sigma_ms [rad], ndf, status); see
    `fit_curvature_row`. Below b_threshold [T], σ_MS is Highland at p_min [MeV].
    """
    g = np.ascontiguousarray(geometry, dtype=np.float64)
    xx0 = _per_triplet(x_over_x0, g.shape[0], (), "x_over_x0")
    out, ndf, status = _curvature_kernel(g, xx0, float(mass), float(b_threshold),
                                         float(p_min), bool(straight_below_threshold))
    return out[:, 0], out[:, 1], out[:, 2], out[:, 3], ndf, status


def fit_triplets(hits, bfield, x_over_x0, hit_var=None, *, mass: float = MASS_PION,
                 b_threshold: float = DEFAULT_B_THRESHOLD, p_min: float = DEFAULT_P_MIN,
                 form: int = FORM_CURVATURE,
                 straight_below_threshold: bool = False) -> TripletFit:
    """Fit many hit triplets at once (docs/physics.md#pattern-recognition); one compiled pass, no Python loop.

    hits: (n, 3, 3) [mm], hits 0 → 1 → 2 along the motion; bfield: (3,) or (n, 3) [T] at
    the middle hit; x_over_x0: scalar or (n,) thickness of the middle plane (normal z)
    in X0; hit_var: None (hits exact: paper eq. 1) or broadcastable to (n, 3, 3) hit
    variances of x, y, z [mm²] (App. A/C); mass [MeV]: Highland hypothesis (pion);
    b_threshold [T] (default 0.05): below it the curvature form with σ_MS at p_min
    [MeV] (default 1 GeV). 0.05 T is where a triplet's bending over a 100 mm lever arm
    equals ~1.4 σ_MS for x/X0 = 0.01 at any momentum (κ_c·B·L/(13.6 MeV·√(x/X0)·0.83));
    below it the curvature carries no useful momentum information.
    form: FORM_CURVATURE (default: the curvature form in every field) or FORM_RADIUS
    (the paper's R3D fit, eq. 1 / App. C, where |B| ≥ b_threshold). Both agree where
    the circle solution is well measured; when hit errors dominate (relative momentum
    error ≳ 30%) the R3D linearisation around R_C fails (the fitted R3D can be many
    times R_C and σ(κ) is then far too small) while the curvature form stays linear.
    straight_below_threshold: fix κ = 0 below the threshold (ndf 2).
    """
    h = _as_hits(hits)
    n = h.shape[0]
    b = _per_triplet(bfield, n, (3,), "bfield")
    xx0 = _per_triplet(x_over_x0, n, (), "x_over_x0")
    hv = np.zeros((n, 3, 3)) if hit_var is None else _per_triplet(hit_var, n, (3, 3), "hit_var")
    if form not in (FORM_RADIUS, FORM_CURVATURE):
        raise ValueError(f"form must be FORM_RADIUS or FORM_CURVATURE, got {form!r}")
    geo, fit = fit_triplets_kernel(h, b, xx0, hv, float(mass), float(b_threshold),
                                   float(p_min), int(form), bool(straight_below_threshold))
    return TripletFit(
        kappa=fit[:, F_KAPPA],
        var_kappa=fit[:, F_VAR_KAPPA],
        qop=fit[:, F_QOP],
        var_qop=fit[:, F_VAR_QOP],
        chi2=fit[:, F_CHI2],
        ndf=fit[:, F_NDF].astype(np.int32),
        kink_phi=fit[:, F_KINK_PHI],
        kink_theta=fit[:, F_KINK_THETA],
        var_kink_phi=fit[:, F_VAR_KINK_PHI],
        var_kink_theta=fit[:, F_VAR_KINK_THETA],
        phi_tilde=geo[:, G_PHI_TILDE],
        theta_tilde=geo[:, G_THETA_TILDE],
        tx=fit[:, F_TX],
        ty=fit[:, F_TY],
        sigma_ms=fit[:, F_SIGMA_MS],
        status=fit[:, F_STATUS].astype(np.int32),
        geometry=geo,
    )


def combine_triplet_chain(offsets, kappa, var_kappa, chi2, ndf=None,
                          mode: int = COMBINE_CURVATURE):
    """Combined χ² of chains of conjoined triplets (paper eqs. 3–6), CSR layout.

    Chain j holds triplets offsets[j]:offsets[j+1] (consecutive triplets share two hits).
    mode COMBINE_CURVATURE (eqs. 5–6): h̄ = Σ(h_i/σ(h_i)²)/Σ(1/σ(h_i)²),
    χ²_comb = Σχ²_i + Σ(h_i − h̄)²/σ(h_i)², h = κ (signed). mode COMBINE_RADIUS (eqs.
    3–4): R̄ = ΣR_i²/σ_i² / ΣR_i/σ_i² and χ²_comb = Σχ²_i + Σ(R_i − R̄)²/σ_i(R̄)², with the
    σ_i of the paper evaluated at the common R̄ through the triplet's relative error
    (σ_i(R̄) = R̄·σ(κ_i)/|κ_i|), which makes eq. 4 the minimiser of eq. 3.
    ndf_comb = Σndf_i + (n_triplets − 1). Returns (kappa, var_kappa, chi2, ndf, status).
    """
    off = np.ascontiguousarray(offsets, dtype=np.int64)
    k = np.ascontiguousarray(kappa, dtype=np.float64)
    n = k.shape[0]
    v = _per_triplet(var_kappa, n, (), "var_kappa")
    c = _per_triplet(chi2, n, (), "chi2")
    d = np.ones(n, dtype=np.int32) if ndf is None else np.ascontiguousarray(
        np.broadcast_to(np.asarray(ndf, dtype=np.int32), (n,)))
    if off.ndim != 1 or off.size < 1 or off[0] != 0 or off[-1] != n or np.any(np.diff(off) < 0):
        raise ValueError("offsets must be non-decreasing, start at 0 and end at len(kappa)")
    if mode not in (COMBINE_CURVATURE, COMBINE_RADIUS):
        raise ValueError(f"mode must be COMBINE_CURVATURE or COMBINE_RADIUS, got {mode!r}")
    return _combine_chain(off, k, v, c, d, int(mode))


def combine_triplets(kappa_a, var_kappa_a, chi2_a, kappa_b, var_kappa_b, chi2_b,
                     ndf_a=1, ndf_b=1, mode: int = COMBINE_CURVATURE):
    """Combined χ² of pairs of conjoined triplets a, b (paper eqs. 3–6), elementwise.

    Returns (kappa, var_kappa, chi2, ndf, status) per pair; see `combine_triplet_chain`.
    For two MS-dominated triplets of one track, chi2 follows χ² with ndf = 3.
    """
    ka = np.atleast_1d(np.asarray(kappa_a, dtype=np.float64))
    n = ka.shape[0]
    k = np.empty(2 * n)
    v = np.empty(2 * n)
    c = np.empty(2 * n)
    d = np.empty(2 * n, dtype=np.int32)
    k[0::2] = ka
    k[1::2] = np.broadcast_to(np.asarray(kappa_b, dtype=np.float64), (n,))
    v[0::2] = np.broadcast_to(np.asarray(var_kappa_a, dtype=np.float64), (n,))
    v[1::2] = np.broadcast_to(np.asarray(var_kappa_b, dtype=np.float64), (n,))
    c[0::2] = np.broadcast_to(np.asarray(chi2_a, dtype=np.float64), (n,))
    c[1::2] = np.broadcast_to(np.asarray(chi2_b, dtype=np.float64), (n,))
    d[0::2] = np.broadcast_to(np.asarray(ndf_a, dtype=np.int32), (n,))
    d[1::2] = np.broadcast_to(np.asarray(ndf_b, dtype=np.int32), (n,))
    return combine_triplet_chain(np.arange(0, 2 * n + 1, 2), k, v, c, d, mode)
