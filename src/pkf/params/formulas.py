"""The parametrized extrapolation formulas of the paper §4, with analytic Jacobians and noise.

Every function transports ``s = (x, y, tx, ty, qop)`` over one step of a given type,
writing the new state and the Jacobian F = ∂out/∂in (5×5); q/p is the momentum at
production and is left unchanged (f_qop = identity, paper §3). Units: mm, 1/MeV.

Step types (docs/parameters.md#step-kinds-and-their-extrapolation-coefficients):

- `velo_step` — paper eq. 10: f_tx = tx + p0·qop·(z0 + p1)·Δz, f_x = x + ½(tx + f_tx)·Δz,
  f_y = y + ty·Δz, f_ty = ty; z0 = the start z. Parameters (p0, p1).
- `layer_step` — paper eq. 14 (UT and SciFi, one set per layer step):
  f_tx = tx + (p0·qop + p1·qop³ + p2·y²·qop + p6·qop·tx² + p7·qop·ty²)·Δz,
  f_x = x + [p3·tx + (1 − p3)·f_tx]·Δz, f_ty = ty + p4·qop·tx·sign(y) + p8·qop·tx·ty,
  f_y = y + [p5·ty + (1 − p5)·f_ty]·Δz, plus p9·qop·x² + (p11 + p13·y²)·qop·ty·y in the
  kick of f_tx and p10·qop·x·y + (p12 + p14·y²)·qop·tx·y in f_ty. p0…p5 are the paper's; p6…p8 add the slope dependence of the
  equations of motion, dtx/dz ∝ N·(1 + tx²) ≈ 1 + 1.5·tx² + 0.5·ty² and dty/dz ∝
  −N·tx·ty (docs/physics.md#equations-of-motion-and-the-field): without them the curvature of a track with slope 0.25 is off by
  ~10% (measured: σ(q/p) pulls 1.29 on the telescope); p9, p10 the field's fall with |x|
  (B_y ∝ 1 + k·(x² − y²)/L², B_x ∝ x·y, docs/geometry.md#field), which at the SciFi's |x| ≤ 3 m
  changes the kick by tens of percent; p11, p12 the fringe field's B_z = b′(z)·y (the
  ty·B_z and −tx·B_z terms of the equations of motion), as large as B_y at the SciFi for |y| ~ 1 m
  (measured: a 1 mrad error at 3–5 GeV in the first SciFi step without them); p13, p14
  its y³ term (B_z = b′·y − b‴·y³/6). p15…p33 and p34…p49 complete the tx and ty kicks
  to *every* monomial x^a·tx^b·y^c·ty^d of degree a+b+c+d ≤ 4 allowed by the field's
  symmetry (`LAYER_TX_MONOMIALS`, `LAYER_TY_MONOMIALS`, below).
- `velo_to_ut_step` — paper eqs. 15–20: ty_UT = ty_V + p0·qop·tx_V·sign(y_V) (17);
  ∫(dl×B)_x = p1 + p2·z_V + p3·ty_V² (18) so that tx_UT/N_UT = tx_V/N_V + qop·∫(dl×B)_x
  (15); z_mag = p4 + p5·z_V + p6·z_V² + p7·ty_V² (19); x_UT = x_V + (z_mag − z_V)·tx_V +
  (z_UT − z_mag)·tx_UT (16); y_UT = y_V + [p8·ty_V + (1 − p8)·ty_UT]·Δz (20).

Why the degree-4 kick (issue 6). In the SciFi, behind the magnet, the field of docs/geometry.md#field
is b(z)·[1 + k(x² − y²)/L²] − b″(z)·y²/2 for B_y, b′(z)·[y + k(x²y − y³/3)/L²] − b‴(z)·y³/6
for B_z and 2k·b(z)·x·y/L² for B_x, with b ∝ e^(−z/λ), λ = 420 mm, so b″·y²/2 = b·y²/(2λ²):
B_y changes sign at |y| ≈ 0.6 m and is several times the on-axis value at |y| ~ 1.5 m.
Integrated along the step, y → y + ty·s and x → x + tx·s, and multiplied by
N·(1 + tx²), tx·ty and N·(1 + ty²) (the equations of motion), the kick on tx is a polynomial in
(x, tx, y, ty) that is *even* under (x, tx) → −(x, tx) and under (y, ty) → −(y, ty), and the
kick on ty is odd under both. Terms such as x·tx, y²·tx², y²·ty² (tx) and x·ty,
tx·ty·y² (ty) are as large as the terms p0…p14 hold, and without them the SciFi steps were
off by 0.4–1.7 mrad RMS in tx at 3–5 GeV (4.7 mrad for |y| > 1.5 m in the T1→T2 gap) —
more than the step's scattering noise (0.36 mrad) — which made the parametrized momentum
resolution 5–13% worse than the reference's at 3–10 GeV (the B_s mass resolution 2%
worse). With all monomials up to degree 4 (shipped lhcb-like set, RK4 through the map as
truth, 3–5 GeV pions) the SciFi steps are off by 1–29 µrad RMS in tx and ≤ 1 µm in x, the
T1→T2 gap by 95 µrad and 30 µm (tests/params/test_layer_steps.py). Old parameter files
(15 entries) stay valid: absent coefficients are zero. The kicks and their exact
derivatives are evaluated factored over (x², x·tx, tx²) and (y², y·ty, ty²)
(`_tx_kick_polynomial`, `_ty_kick_polynomial`; tests/params/test_formulas.py checks them
against the monomials of the lists term by term).

`parametrized_noise` is paper eq. 11 with the path-length factors of Highland scattering
and a noise floor p̃4 (docs/parameters.md#noise-coefficients-all-step-kinds: Allen's failure mode for high-momentum, large-slope
tracks, where the ∝ 1/p noise vanishes below the parametrization error). p̃5 [MeV] is
the spread of the energy lost before a step (straggling): it enters as q/p noise
(p̃5·qop²)² at the start of the step, propagated through the step's Jacobian (see
`pkf.params.transport`) — the state carries the production momentum, so the
fluctuation of the energy lost upstream of the magnet is a real uncertainty there.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.jit import fma, stack_array

#: Exponents (a, b, c, d) of the monomials x^a·tx^b·y^c·ty^d [x, y in mm] that complete the
#: eq. 14 tx kick (coefficient × qop·Δz) to every symmetry-allowed monomial of degree ≤ 4
#: (a+b and c+d even); the ones p0, p2, p6, p7, p9, p11, p13 already hold are left out.
LAYER_TX_MONOMIALS = np.array([
    (1, 1, 0, 0),  # x·tx
    (4, 0, 0, 0), (3, 1, 0, 0), (2, 2, 0, 0), (1, 3, 0, 0), (0, 4, 0, 0),
    (0, 0, 4, 0), (0, 0, 2, 2), (0, 0, 1, 3), (0, 0, 0, 4),
    (2, 0, 2, 0), (2, 0, 1, 1), (2, 0, 0, 2),
    (1, 1, 2, 0), (1, 1, 1, 1), (1, 1, 0, 2),
    (0, 2, 2, 0), (0, 2, 1, 1), (0, 2, 0, 2),
], dtype=np.int64)
#: Their parameter slots: p15…p33.
LAYER_TX_OFFSET = 15
#: Exponents of the monomials completing the eq. 14 ty kick (coefficient × qop, no Δz, as
#: p4, p8, p10, p12, p14) to every monomial of degree ≤ 4 with a+b and c+d odd; the ones
#: p8 (tx·ty), p10 (x·y), p12 (tx·y) and p14 (tx·y³) hold are left out.
LAYER_TY_MONOMIALS = np.array([
    (1, 0, 0, 1),  # x·ty
    (1, 0, 3, 0), (1, 0, 2, 1), (1, 0, 1, 2), (1, 0, 0, 3),
    (0, 1, 2, 1), (0, 1, 1, 2), (0, 1, 0, 3),
    (3, 0, 1, 0), (2, 1, 1, 0), (1, 2, 1, 0), (0, 3, 1, 0),
    (3, 0, 0, 1), (2, 1, 0, 1), (1, 2, 0, 1), (0, 3, 0, 1),
], dtype=np.int64)
#: Their parameter slots: p34…p49.
LAYER_TY_OFFSET = LAYER_TX_OFFSET + LAYER_TX_MONOMIALS.shape[0]

N_EXTRAPOLATION_PARAMS = LAYER_TY_OFFSET + LAYER_TY_MONOMIALS.shape[0]  # 50: the longest set (extended eq. 14)
N_NOISE_PARAMS = 6


@nb.njit(cache=True, inline="always")
def _sign(v):
    return 1.0 if v >= 0.0 else -1.0


@nb.njit(cache=True)
def _identity(jac):
    for i in range(5):
        for j in range(5):
            jac[i, j] = 1.0 if i == j else 0.0


@nb.njit(cache=True)
def velo_step(p, s, z_from, z_to, out, jac):
    """Paper eq. 10 (VELO ↔ VELO).

    A call, not inlined: inlined (with `_identity` and `parametrized_noise`; branch inl,
    issue 18.1) the VELO → VELO steps of benchmarks/fit_core.py's minimum-bias tracks took
    30.7 → 40.7 ns per step and the forward filter did not change (162.3 → 161.6 ns per
    node; one process, both compiled side by side, alternating, 6 rounds, min of 5)."""
    dz = z_to - z_from
    x, y, tx, ty, qop = s[0], s[1], s[2], s[3], s[4]
    k = p[0] * (z_from + p[1]) * dz
    f_tx = tx + k * qop
    out[0] = x + 0.5 * (tx + f_tx) * dz
    out[1] = y + ty * dz
    out[2] = f_tx
    out[3] = ty
    out[4] = qop
    _identity(jac)
    jac[2, 4] = k
    jac[0, 2] = dz
    jac[0, 4] = 0.5 * k * dz
    jac[1, 3] = dz


@nb.njit(cache=True, inline="always")
def _tx_kick_polynomial(p, x, tx, y, ty, u0, u1, u2, v0, v1, v2):
    """T = the eq. 14 tx kick per q/p·Δz without p0 + p1·qop² (p2·y² + p6·tx² + p7·ty² +
    p9·x² + (p11 + p13·y²)·y·ty + Σ p15…p33 monomials) and ∂T/∂x, ∂T/∂y, ∂T/∂tx, ∂T/∂ty.

    Factored over u = (x², x·tx, tx²) and v = (y², y·ty, ty²): every term is even in
    (x, tx) and in (y, ty), so T = p15·u1 + uᵀ·M·v + (quadratic form in u) + (quadratic
    form in v) + (linear in u and v), M the 3×3 coefficients p25…p33 of the mixed terms.
    The gradients g = ∂T/∂u, h = ∂T/∂v give the derivatives by the chain rule (∂u/∂x =
    (2x, tx, 0), ∂u/∂tx = (0, x, 2tx), likewise v). ~60 floating-point operations where
    the term-by-term sums took ~130 (`layer_step`)."""
    o = LAYER_TX_OFFSET
    w0 = fma(p[o + 12], v2, fma(p[o + 11], v1, p[o + 10] * v0))  # (M·v)_i
    w1 = fma(p[o + 15], v2, fma(p[o + 14], v1, p[o + 13] * v0))
    w2 = fma(p[o + 18], v2, fma(p[o + 17], v1, p[o + 16] * v0))
    z0 = fma(p[o + 16], u2, fma(p[o + 13], u1, p[o + 10] * u0))  # (uᵀ·M)_j
    z1 = fma(p[o + 17], u2, fma(p[o + 14], u1, p[o + 11] * u0))
    z2 = fma(p[o + 18], u2, fma(p[o + 15], u1, p[o + 12] * u0))
    qa = fma(p[o + 3], u2, fma(p[o + 2], u1, p[o + 1] * u0))  # x⁴, x³tx, x²tx² over u0
    qb = fma(p[o + 5], u2, p[o + 4] * u1)  # x·tx³, tx⁴ over u2
    ra = fma(p[o + 7], v2, fma(p[13], v1, p[o + 6] * v0))  # y⁴, y³ty, y²ty² over v0
    rb = fma(p[o + 9], v2, p[o + 8] * v1)  # y·ty³, ty⁴ over v2
    g0 = fma(p[o + 1], u0, qa) + (w0 + p[9])
    g1 = fma(p[o + 2], u0, fma(p[o + 4], u2, p[o + 0])) + w1
    g2 = fma(p[o + 3], u0, fma(p[o + 5], u2, qb)) + (w2 + p[6])
    h0 = fma(p[o + 6], v0, ra) + (z0 + p[2])
    h1 = fma(p[13], v0, fma(p[o + 8], v2, z1)) + p[11]
    h2 = fma(p[o + 7], v0, fma(p[o + 9], v2, rb)) + (z2 + p[7])
    t = fma(u2, qb + (w2 + p[6]), fma(u1, w1 + p[o + 0], fma(u0, qa + (w0 + p[9]),
            fma(v2, rb + p[7], fma(v1, p[11], v0 * (ra + p[2]))))))
    t_x = fma(2.0 * x, g0, tx * g1)
    t_y = fma(2.0 * y, h0, ty * h1)
    t_tx = fma(2.0 * tx, g2, x * g1)
    t_ty = fma(2.0 * ty, h2, y * h1)
    return t, t_x, t_y, t_tx, t_ty


@nb.njit(cache=True, inline="always")
def _ty_kick_polynomial(p, x, tx, y, ty, u0, u1, u2, v0, v1, v2):
    """S = the eq. 14 ty kick per q/p without the p4·tx·sign(y) term (p8·tx·ty + p10·x·y +
    (p12 + p14·y²)·tx·y + Σ p34…p49 monomials) and ∂S/∂x, ∂S/∂y, ∂S/∂tx, ∂S/∂ty.

    Every term is odd in (x, tx) and in (y, ty): S = x·A + tx·B + y·C + ty·D with A, B
    odd polynomials in (y, ty) (linear + cubic) and C, D cubic forms in (x, tx), each
    written over u = (x², x·tx, tx²) or v = (y², y·ty, ty²) with its two derivatives.
    ~75 operations where the term-by-term sums took ~125."""
    o = LAYER_TY_OFFSET
    # A = p10·y + p34·ty + p35·y³ + p36·y²ty + p37·y·ty² + p38·ty³
    a_y = fma(p[o + 3], v2, fma(p[o + 2], v1, p[o + 1] * v0)) + p[10]
    a = fma(ty, fma(p[o + 4], v2, p[o]), y * a_y)
    a_dy = fma(p[o + 3], v2, fma(2.0 * p[o + 2], v1, 3.0 * p[o + 1] * v0)) + p[10]
    a_dty = fma(3.0 * p[o + 4], v2, fma(2.0 * p[o + 3], v1, p[o + 2] * v0)) + p[o]
    # B = p12·y + p8·ty + p14·y³ + p39·y²ty + p40·y·ty² + p41·ty³
    b_y = fma(p[o + 6], v2, fma(p[o + 5], v1, p[14] * v0)) + p[12]
    b = fma(ty, fma(p[o + 7], v2, p[8]), y * b_y)
    b_dy = fma(p[o + 6], v2, fma(2.0 * p[o + 5], v1, 3.0 * p[14] * v0)) + p[12]
    b_dty = fma(3.0 * p[o + 7], v2, fma(2.0 * p[o + 6], v1, p[o + 5] * v0)) + p[8]
    # C = p42·x³ + p43·x²tx + p44·x·tx² + p45·tx³
    c_x = fma(p[o + 10], u2, fma(p[o + 9], u1, p[o + 8] * u0))
    c = fma(tx, p[o + 11] * u2, x * c_x)
    c_dx = fma(p[o + 10], u2, fma(2.0 * p[o + 9], u1, 3.0 * p[o + 8] * u0))
    c_dtx = fma(3.0 * p[o + 11], u2, fma(2.0 * p[o + 10], u1, p[o + 9] * u0))
    # D = p46·x³ + p47·x²tx + p48·x·tx² + p49·tx³
    d_x = fma(p[o + 14], u2, fma(p[o + 13], u1, p[o + 12] * u0))
    d = fma(tx, p[o + 15] * u2, x * d_x)
    d_dx = fma(p[o + 14], u2, fma(2.0 * p[o + 13], u1, 3.0 * p[o + 12] * u0))
    d_dtx = fma(3.0 * p[o + 15], u2, fma(2.0 * p[o + 14], u1, p[o + 13] * u0))
    s = fma(ty, d, fma(y, c, fma(tx, b, x * a)))
    s_x = fma(ty, d_dx, fma(y, c_dx, a))
    s_y = fma(tx, b_dy, fma(x, a_dy, c))
    s_tx = fma(ty, d_dtx, fma(y, c_dtx, b))
    s_ty = fma(tx, b_dty, fma(x, a_dty, d))
    return s, s_x, s_y, s_tx, s_ty


@nb.njit(cache=True, inline="always")
def _layer_step_full(p, s, z_from, z_to, out, jac):
    """`layer_step` for a set of all N_EXTRAPOLATION_PARAMS coefficients."""
    dz = z_to - z_from
    x, y, tx, ty, qop = s[0], s[1], s[2], s[3], s[4]
    u0 = x * x
    u1 = x * tx
    u2 = tx * tx
    v0 = y * y
    v1 = y * ty
    v2 = ty * ty
    t, t_x, t_y, t_tx, t_ty = _tx_kick_polynomial(p, x, tx, y, ty, u0, u1, u2, v0, v1, v2)
    g, g_x, g_y, g_tx, g_ty = _ty_kick_polynomial(p, x, tx, y, ty, u0, u1, u2, v0, v1, v2)
    q2 = qop * qop
    qdz = qop * dz
    sign_term = p[4] * _sign(y)
    f_tx = fma(qdz, fma(p[1], q2, p[0]) + t, tx)  # tx + (p0·qop + p1·qop³ + T·qop)·Δz
    f_ty = fma(qop, fma(sign_term, tx, g), ty)  # ty + (p4·tx·sign(y) + S)·qop
    out[0] = x + (p[3] * tx + (1.0 - p[3]) * f_tx) * dz
    out[1] = y + (p[5] * ty + (1.0 - p[5]) * f_ty) * dz
    out[2] = f_tx
    out[3] = f_ty
    out[4] = qop
    _identity(jac)
    # ∂f_tx
    dtx_dx = t_x * qdz
    dtx_dy = t_y * qdz
    dtx_dtx = fma(t_tx, qdz, 1.0)
    dtx_dty = t_ty * qdz
    dtx_dqop = (fma(3.0 * p[1], q2, p[0]) + t) * dz
    jac[2, 0] = dtx_dx
    jac[2, 1] = dtx_dy
    jac[2, 2] = dtx_dtx
    jac[2, 3] = dtx_dty
    jac[2, 4] = dtx_dqop
    # ∂f_ty
    dty_dx = g_x * qop
    dty_dy = g_y * qop
    dty_dtx = (sign_term + g_tx) * qop
    dty_dty = fma(g_ty, qop, 1.0)
    dty_dqop = fma(sign_term, tx, g)
    jac[3, 0] = dty_dx
    jac[3, 1] = dty_dy
    jac[3, 2] = dty_dtx
    jac[3, 3] = dty_dty
    jac[3, 4] = dty_dqop
    # ∂f_x = ∂x + [p3·∂tx + (1 − p3)·∂f_tx]·Δz
    w = (1.0 - p[3]) * dz
    jac[0, 0] = 1.0 + w * dtx_dx
    jac[0, 1] = w * dtx_dy
    jac[0, 2] = p[3] * dz + w * dtx_dtx
    jac[0, 3] = w * dtx_dty
    jac[0, 4] = w * dtx_dqop
    # ∂f_y
    v = (1.0 - p[5]) * dz
    jac[1, 0] = v * dty_dx
    jac[1, 1] = 1.0 + v * dty_dy
    jac[1, 2] = v * dty_dtx
    jac[1, 3] = p[5] * dz + v * dty_dty
    jac[1, 4] = v * dty_dqop


@nb.njit(cache=True, inline="always")
def layer_step(p, s, z_from, z_to, out, jac):
    """Paper eq. 14 (UT ↔ UT, SciFi ↔ SciFi), extended by slope and field-shape terms p6…p14
    and the remaining degree-≤ 4 monomials p15…p49 (module docstring); a shorter (old) set
    is the full one with its absent coefficients zero.

    The kicks are evaluated factored (`_tx_kick_polynomial`, `_ty_kick_polynomial`: ~135
    operations for both kicks and their derivatives where the sums term by term took ~300),
    so the rounding differs from the sums in the order of the paper's formula by ≤ 5e−16
    of each output's scale (the largest |value| over 10⁵ random UT and SciFi states).
    Measured (issue 18.1; benchmarks/fit_core.py's minimum-bias tracks, the step groups and
    forward filter of benchmarks/parametrized_steps.py, the term-by-term sums and this code
    compiled side by side in one process, alternating, 6 rounds, min of 5 each): SciFi →
    SciFi 74.0 → 49.2 ns per step (×0.66), UT → UT 117.5 → 93.2 (×0.79), the forward filter
    (steps, covariance transport, updates) 123.3 → 116.1 ns per node (×0.94). The fit's
    outputs (benchmarks/table_hashes.py --against the term-by-term sums): the same
    candidates, χ² within 1e−10 relative, states within 3e−10 and pulls within 5e−9 of each
    column's RMS; fit_core's tracks with the same seeds: node states median 1e−11 σ, max
    1e−8 σ apart, q/p ≤ 1.8e−11 relative, the same status. That is a last-bit change of the
    steps' tx seen through the fit: the q/p information is the kick, ~1e−5 of tx for the
    straightest tracks, so one unit in the last place of tx is ~1e−11 of their q/p.

    Inlined into its callers (the fit's step, the forward search's transports): as a call it
    took its six arguments' ~34 machine words by value and wrote out and jac through memory
    (the parametrized fit of 2,000 telescope pion tracks 2.95 → 2.76 µs per track)."""
    if p.size >= N_EXTRAPOLATION_PARAMS:
        _layer_step_full(p, s, z_from, z_to, out, jac)
    else:
        full = stack_array((N_EXTRAPOLATION_PARAMS,))
        for i in range(N_EXTRAPOLATION_PARAMS):
            full[i] = p[i] if i < p.size else 0.0
        _layer_step_full(full, s, z_from, z_to, out, jac)


@nb.njit(cache=True)
def velo_to_ut_step(p, s, z_from, z_to, out, jac):
    """Paper eqs. 15–20 (last VELO state → first UT layer). Returns False if the kink
    is unphysical (|tx_UT/N_UT| ≥ 1)."""
    dz = z_to - z_from
    x, y, tx, ty, qop = s[0], s[1], s[2], s[3], s[4]
    sy = _sign(y)
    ty_ut = ty + p[0] * qop * tx * sy  # (17)
    field_integral = p[1] + p[2] * z_from + p[3] * ty * ty  # (18)
    n_v = math.sqrt(1.0 + tx * tx + ty * ty)
    a = tx / n_v + qop * field_integral  # (15): tx_UT / N_UT
    if not abs(a) < 1.0:
        return False
    r = math.sqrt(1.0 + ty_ut * ty_ut)
    c = math.sqrt(1.0 - a * a)
    tx_ut = a * r / c
    z_mag = p[4] + p[5] * z_from + p[6] * z_from * z_from + p[7] * ty * ty  # (19)
    out[0] = x + (z_mag - z_from) * tx + (z_to - z_mag) * tx_ut  # (16)
    out[1] = y + (p[8] * ty + (1.0 - p[8]) * ty_ut) * dz  # (20)
    out[2] = tx_ut
    out[3] = ty_ut
    out[4] = qop
    _identity(jac)
    # derivatives of ty_UT
    dtyut_dtx = p[0] * qop * sy
    dtyut_dqop = p[0] * tx * sy
    # derivatives of a = tx/N + qop·I
    n3 = n_v * n_v * n_v
    da_dtx = (1.0 + ty * ty) / n3
    da_dty = -tx * ty / n3 + qop * 2.0 * p[3] * ty
    da_dqop = field_integral
    # tx_UT = a·r/c: ∂/∂a = r/c³, ∂/∂ty_UT = a·ty_UT/(r·c)
    dtxut_da = r / (c * c * c)
    dtxut_dtyut = a * ty_ut / (r * c)
    dtxut_dtx = dtxut_da * da_dtx + dtxut_dtyut * dtyut_dtx
    dtxut_dty = dtxut_da * da_dty + dtxut_dtyut  # ∂ty_UT/∂ty = 1
    dtxut_dqop = dtxut_da * da_dqop + dtxut_dtyut * dtyut_dqop
    jac[2, 2] = dtxut_dtx
    jac[2, 3] = dtxut_dty
    jac[2, 4] = dtxut_dqop
    jac[3, 2] = dtyut_dtx
    jac[3, 3] = 1.0
    jac[3, 4] = dtyut_dqop
    # x_UT: ∂z_mag/∂ty = 2·p7·ty
    dzmag_dty = 2.0 * p[7] * ty
    lever = z_to - z_mag
    jac[0, 2] = (z_mag - z_from) + lever * dtxut_dtx
    jac[0, 3] = dzmag_dty * (tx - tx_ut) + lever * dtxut_dty
    jac[0, 4] = lever * dtxut_dqop
    # y_UT
    w = (1.0 - p[8]) * dz
    jac[1, 2] = w * dtyut_dtx
    jac[1, 3] = p[8] * dz + w
    jac[1, 4] = w * dtyut_dqop
    return True


@nb.njit(cache=True)
def parametrized_noise(pn, state, dz, noise):
    """Paper eq. 11 with a noise floor pn[4] and the path-length factors of Highland
    scattering: fills the 5×5 noise matrix of a step of length dz [mm] at `state`.

    Q_txtx = (p̃0·qop)²·N³·(1 + tx²) + p̃4², Q_tyty likewise with ty (docs/physics.md#material-effects: θ0² ∝ t
    ∝ N and Q_txtx = θ0²·N²·(1 + tx²)); Q_xx = (p̃1·Δz)²·Q_txtx, Q_x,tx = p̃2·√(Q_xx·Q_txtx),
    and y likewise with p̃3. No noise on q/p.
    """
    for i in range(5):
        for j in range(5):
            noise[i, j] = 0.0
    tx = state[2]
    ty = state[3]
    n2 = 1.0 + tx * tx + ty * ty
    scatter = (pn[0] * state[4]) ** 2 * n2 * math.sqrt(n2)
    floor = pn[4] * pn[4]
    lever = (pn[1] * dz) ** 2
    q_txtx = scatter * (1.0 + tx * tx) + floor
    q_tyty = scatter * (1.0 + ty * ty) + floor
    noise[2, 2] = q_txtx
    noise[3, 3] = q_tyty
    noise[0, 0] = lever * q_txtx
    noise[1, 1] = lever * q_tyty
    noise[0, 2] = noise[2, 0] = pn[2] * math.sqrt(lever) * q_txtx
    noise[1, 3] = noise[3, 1] = pn[3] * math.sqrt(lever) * q_tyty
