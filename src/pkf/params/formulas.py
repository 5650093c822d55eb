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
T1→T2 gap by 95 µrad and 30 µm (tests/params/test_layer_steps.py). A generic list keeps
the Jacobian exact (`_monomial_sum`) and old parameter files (15 entries) valid: absent
coefficients are zero. For full sets the same sums run unrolled (`_tx_monomials`,
`_ty_monomials`, written by `pkf.params.monomial_codegen`): bitwise the same numbers, ~4×
faster.

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

from pkf.jit import fma

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
    """Paper eq. 10 (VELO ↔ VELO)."""
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
def _powers(v):
    v2 = v * v
    return (1.0, v, v2, v2 * v, v2 * v2)


@nb.njit(cache=True, inline="always")
def _add_monomial(acc, c, f0, e0, f1, e1, f2, e2, f3, e3):
    """acc + c·f0·f1·f2·f3 for factors f_i = v_i^e_i (f_i = 1.0 where e_i = 0) as the
    unrolled sums form it: the product from the left up to the last factor of non-zero
    exponent, fused with it (`pkf.jit.fma`: c·f0·f1·f2 then fma(·, f3, acc) if e3 > 0, …);
    acc + c if every exponent is 0. The unit factors are exact, so this is the unrolled
    code's arithmetic, which leaves them out."""
    if e3 > 0:
        return fma(c * f0 * f1 * f2, f3, acc)
    if e2 > 0:
        return fma(c * f0 * f1, f2, acc)
    if e1 > 0:
        return fma(c * f0, f1, acc)
    if e0 > 0:
        return fma(c, f0, acc)
    return acc + c


@nb.njit(cache=True, inline="always")
def _monomial_sum(p, offset, exponents, px, ptx, py, pty):
    """Σ_i p[offset+i]·x^a·tx^b·y^c·ty^d over the rows (a, b, c, d) of `exponents` present
    in `p`, and its derivatives by x, y, tx, ty. px… are the powers 0…4 (`_powers`). Each
    term is added by `_add_monomial`: one fused multiply–add with its last factor."""
    val = 0.0
    d_x = 0.0
    d_y = 0.0
    d_tx = 0.0
    d_ty = 0.0
    n = min(exponents.shape[0], p.size - offset)
    for i in range(n):
        c = p[offset + i]
        if c == 0.0:
            continue
        a = exponents[i, 0]
        b = exponents[i, 1]
        e = exponents[i, 2]
        d = exponents[i, 3]
        fx = px[a]
        ftx = ptx[b]
        fy = py[e]
        fty = pty[d]
        val = _add_monomial(val, c, fx, a, ftx, b, fy, e, fty, d)
        if a > 0:
            d_x = _add_monomial(d_x, c * a, px[a - 1], a - 1, ftx, b, fy, e, fty, d)
        if b > 0:
            d_tx = _add_monomial(d_tx, c * b, fx, a, ptx[b - 1], b - 1, fy, e, fty, d)
        if e > 0:
            d_y = _add_monomial(d_y, c * e, fx, a, ftx, b, py[e - 1], e - 1, fty, d)
        if d > 0:
            d_ty = _add_monomial(d_ty, c * d, fx, a, ftx, b, fy, e, pty[d - 1], d - 1)
    return val, d_x, d_y, d_tx, d_ty


# ---- generated by pkf.params.monomial_codegen: do not edit ----
@nb.njit(cache=True, inline="always")
def _tx_monomials(p, px, ptx, py, pty):
    """Unrolled `_monomial_sum` for the coefficients at LAYER_TX_OFFSET (powers 0…4 of x, tx, y, ty
    as `_powers` gives them)."""
    o = LAYER_TX_OFFSET
    _, x, x2, x3, x4 = px
    _, tx, tx2, tx3, tx4 = ptx
    _, y, y2, y3, y4 = py
    _, ty, ty2, ty3, ty4 = pty
    val = 0.0
    d_x = 0.0
    d_tx = 0.0
    d_y = 0.0
    d_ty = 0.0
    c = p[o + 0]  # x^1 tx^1
    val = fma(c * x, tx, val)
    d_x = fma(c, tx, d_x)
    d_tx = fma(c, x, d_tx)
    c = p[o + 1]  # x^4
    val = fma(c, x4, val)
    d_x = fma(4.0 * c, x3, d_x)
    c = p[o + 2]  # x^3 tx^1
    val = fma(c * x3, tx, val)
    d_x = fma(3.0 * c * x2, tx, d_x)
    d_tx = fma(c, x3, d_tx)
    c = p[o + 3]  # x^2 tx^2
    val = fma(c * x2, tx2, val)
    d_x = fma(2.0 * c * x, tx2, d_x)
    d_tx = fma(2.0 * c * x2, tx, d_tx)
    c = p[o + 4]  # x^1 tx^3
    val = fma(c * x, tx3, val)
    d_x = fma(c, tx3, d_x)
    d_tx = fma(3.0 * c * x, tx2, d_tx)
    c = p[o + 5]  # tx^4
    val = fma(c, tx4, val)
    d_tx = fma(4.0 * c, tx3, d_tx)
    c = p[o + 6]  # y^4
    val = fma(c, y4, val)
    d_y = fma(4.0 * c, y3, d_y)
    c = p[o + 7]  # y^2 ty^2
    val = fma(c * y2, ty2, val)
    d_y = fma(2.0 * c * y, ty2, d_y)
    d_ty = fma(2.0 * c * y2, ty, d_ty)
    c = p[o + 8]  # y^1 ty^3
    val = fma(c * y, ty3, val)
    d_y = fma(c, ty3, d_y)
    d_ty = fma(3.0 * c * y, ty2, d_ty)
    c = p[o + 9]  # ty^4
    val = fma(c, ty4, val)
    d_ty = fma(4.0 * c, ty3, d_ty)
    c = p[o + 10]  # x^2 y^2
    val = fma(c * x2, y2, val)
    d_x = fma(2.0 * c * x, y2, d_x)
    d_y = fma(2.0 * c * x2, y, d_y)
    c = p[o + 11]  # x^2 y^1 ty^1
    val = fma(c * x2 * y, ty, val)
    d_x = fma(2.0 * c * x * y, ty, d_x)
    d_y = fma(c * x2, ty, d_y)
    d_ty = fma(c * x2, y, d_ty)
    c = p[o + 12]  # x^2 ty^2
    val = fma(c * x2, ty2, val)
    d_x = fma(2.0 * c * x, ty2, d_x)
    d_ty = fma(2.0 * c * x2, ty, d_ty)
    c = p[o + 13]  # x^1 tx^1 y^2
    val = fma(c * x * tx, y2, val)
    d_x = fma(c * tx, y2, d_x)
    d_tx = fma(c * x, y2, d_tx)
    d_y = fma(2.0 * c * x * tx, y, d_y)
    c = p[o + 14]  # x^1 tx^1 y^1 ty^1
    val = fma(c * x * tx * y, ty, val)
    d_x = fma(c * tx * y, ty, d_x)
    d_tx = fma(c * x * y, ty, d_tx)
    d_y = fma(c * x * tx, ty, d_y)
    d_ty = fma(c * x * tx, y, d_ty)
    c = p[o + 15]  # x^1 tx^1 ty^2
    val = fma(c * x * tx, ty2, val)
    d_x = fma(c * tx, ty2, d_x)
    d_tx = fma(c * x, ty2, d_tx)
    d_ty = fma(2.0 * c * x * tx, ty, d_ty)
    c = p[o + 16]  # tx^2 y^2
    val = fma(c * tx2, y2, val)
    d_tx = fma(2.0 * c * tx, y2, d_tx)
    d_y = fma(2.0 * c * tx2, y, d_y)
    c = p[o + 17]  # tx^2 y^1 ty^1
    val = fma(c * tx2 * y, ty, val)
    d_tx = fma(2.0 * c * tx * y, ty, d_tx)
    d_y = fma(c * tx2, ty, d_y)
    d_ty = fma(c * tx2, y, d_ty)
    c = p[o + 18]  # tx^2 ty^2
    val = fma(c * tx2, ty2, val)
    d_tx = fma(2.0 * c * tx, ty2, d_tx)
    d_ty = fma(2.0 * c * tx2, ty, d_ty)
    return val, d_x, d_y, d_tx, d_ty


@nb.njit(cache=True, inline="always")
def _ty_monomials(p, px, ptx, py, pty):
    """Unrolled `_monomial_sum` for the coefficients at LAYER_TY_OFFSET (powers 0…4 of x, tx, y, ty
    as `_powers` gives them)."""
    o = LAYER_TY_OFFSET
    _, x, x2, x3, x4 = px
    _, tx, tx2, tx3, tx4 = ptx
    _, y, y2, y3, y4 = py
    _, ty, ty2, ty3, ty4 = pty
    val = 0.0
    d_x = 0.0
    d_tx = 0.0
    d_y = 0.0
    d_ty = 0.0
    c = p[o + 0]  # x^1 ty^1
    val = fma(c * x, ty, val)
    d_x = fma(c, ty, d_x)
    d_ty = fma(c, x, d_ty)
    c = p[o + 1]  # x^1 y^3
    val = fma(c * x, y3, val)
    d_x = fma(c, y3, d_x)
    d_y = fma(3.0 * c * x, y2, d_y)
    c = p[o + 2]  # x^1 y^2 ty^1
    val = fma(c * x * y2, ty, val)
    d_x = fma(c * y2, ty, d_x)
    d_y = fma(2.0 * c * x * y, ty, d_y)
    d_ty = fma(c * x, y2, d_ty)
    c = p[o + 3]  # x^1 y^1 ty^2
    val = fma(c * x * y, ty2, val)
    d_x = fma(c * y, ty2, d_x)
    d_y = fma(c * x, ty2, d_y)
    d_ty = fma(2.0 * c * x * y, ty, d_ty)
    c = p[o + 4]  # x^1 ty^3
    val = fma(c * x, ty3, val)
    d_x = fma(c, ty3, d_x)
    d_ty = fma(3.0 * c * x, ty2, d_ty)
    c = p[o + 5]  # tx^1 y^2 ty^1
    val = fma(c * tx * y2, ty, val)
    d_tx = fma(c * y2, ty, d_tx)
    d_y = fma(2.0 * c * tx * y, ty, d_y)
    d_ty = fma(c * tx, y2, d_ty)
    c = p[o + 6]  # tx^1 y^1 ty^2
    val = fma(c * tx * y, ty2, val)
    d_tx = fma(c * y, ty2, d_tx)
    d_y = fma(c * tx, ty2, d_y)
    d_ty = fma(2.0 * c * tx * y, ty, d_ty)
    c = p[o + 7]  # tx^1 ty^3
    val = fma(c * tx, ty3, val)
    d_tx = fma(c, ty3, d_tx)
    d_ty = fma(3.0 * c * tx, ty2, d_ty)
    c = p[o + 8]  # x^3 y^1
    val = fma(c * x3, y, val)
    d_x = fma(3.0 * c * x2, y, d_x)
    d_y = fma(c, x3, d_y)
    c = p[o + 9]  # x^2 tx^1 y^1
    val = fma(c * x2 * tx, y, val)
    d_x = fma(2.0 * c * x * tx, y, d_x)
    d_tx = fma(c * x2, y, d_tx)
    d_y = fma(c * x2, tx, d_y)
    c = p[o + 10]  # x^1 tx^2 y^1
    val = fma(c * x * tx2, y, val)
    d_x = fma(c * tx2, y, d_x)
    d_tx = fma(2.0 * c * x * tx, y, d_tx)
    d_y = fma(c * x, tx2, d_y)
    c = p[o + 11]  # tx^3 y^1
    val = fma(c * tx3, y, val)
    d_tx = fma(3.0 * c * tx2, y, d_tx)
    d_y = fma(c, tx3, d_y)
    c = p[o + 12]  # x^3 ty^1
    val = fma(c * x3, ty, val)
    d_x = fma(3.0 * c * x2, ty, d_x)
    d_ty = fma(c, x3, d_ty)
    c = p[o + 13]  # x^2 tx^1 ty^1
    val = fma(c * x2 * tx, ty, val)
    d_x = fma(2.0 * c * x * tx, ty, d_x)
    d_tx = fma(c * x2, ty, d_tx)
    d_ty = fma(c * x2, tx, d_ty)
    c = p[o + 14]  # x^1 tx^2 ty^1
    val = fma(c * x * tx2, ty, val)
    d_x = fma(c * tx2, ty, d_x)
    d_tx = fma(2.0 * c * x * tx, ty, d_tx)
    d_ty = fma(c * x, tx2, d_ty)
    c = p[o + 15]  # tx^3 ty^1
    val = fma(c * tx3, ty, val)
    d_tx = fma(3.0 * c * tx2, ty, d_tx)
    d_ty = fma(c, tx3, d_ty)
    return val, d_x, d_y, d_tx, d_ty
# ---- end of generated code ----


@nb.njit(cache=True, inline="always")
def layer_step(p, s, z_from, z_to, out, jac):
    """Paper eq. 14 (UT ↔ UT, SciFi ↔ SciFi), extended by slope and field-shape terms p6…p14
    and the remaining degree-≤ 4 monomials p15…p49 (module docstring).

    Inlined into its callers (the fit's step, the forward search's transports): as a call it
    took its six arguments' ~34 machine words by value and wrote out and jac through memory.
    Measured (issue 18; CPU, min per run, this code and the call alternating, same outputs bit
    for bit): the parametrized fit of 2,000 telescope pion tracks 2.95 → 2.76 µs per track
    (median of 6 runs); the minimum-bias forward filter of benchmarks/fit_core.py 196–203 →
    190–192 ns per node; the pattern unchanged within its noise."""
    dz = z_to - z_from
    x, y, tx, ty, qop = s[0], s[1], s[2], s[3], s[4]
    sy = _sign(y)
    px = _powers(x)
    ptx = _powers(tx)
    py = _powers(y)
    pty = _powers(ty)
    if p.size >= N_EXTRAPOLATION_PARAMS:  # a full set: the unrolled sums (bitwise the same, ~4× faster)
        ex_tx, ex_tx_x, ex_tx_y, ex_tx_tx, ex_tx_ty = _tx_monomials(p, px, ptx, py, pty)
        ex_ty, ex_ty_x, ex_ty_y, ex_ty_tx, ex_ty_ty = _ty_monomials(p, px, ptx, py, pty)
    else:  # an old, shorter set: absent coefficients are zero
        ex_tx, ex_tx_x, ex_tx_y, ex_tx_tx, ex_tx_ty = _monomial_sum(p, LAYER_TX_OFFSET, LAYER_TX_MONOMIALS,
                                                                   px, ptx, py, pty)
        ex_ty, ex_ty_x, ex_ty_y, ex_ty_tx, ex_ty_ty = _monomial_sum(p, LAYER_TY_OFFSET, LAYER_TY_MONOMIALS,
                                                                   px, ptx, py, pty)
    kick = (p[0] * qop + p[1] * qop * qop * qop + p[2] * y * y * qop
            + p[6] * qop * tx * tx + p[7] * qop * ty * ty + p[9] * qop * x * x
            + (p[11] + p[13] * y * y) * qop * ty * y + ex_tx * qop)
    f_tx = tx + kick * dz
    f_ty = (ty + p[4] * qop * tx * sy + p[8] * qop * tx * ty + p[10] * qop * x * y
            + (p[12] + p[14] * y * y) * qop * tx * y + ex_ty * qop)
    out[0] = x + (p[3] * tx + (1.0 - p[3]) * f_tx) * dz
    out[1] = y + (p[5] * ty + (1.0 - p[5]) * f_ty) * dz
    out[2] = f_tx
    out[3] = f_ty
    out[4] = qop
    _identity(jac)
    # ∂f_tx
    dtx_dx = (2.0 * p[9] * x + ex_tx_x) * qop * dz
    dtx_dy = (2.0 * p[2] * y + (p[11] + 3.0 * p[13] * y * y) * ty + ex_tx_y) * qop * dz
    dtx_dtx = 1.0 + (2.0 * p[6] * tx + ex_tx_tx) * qop * dz
    dtx_dty = (2.0 * p[7] * ty + (p[11] + p[13] * y * y) * y + ex_tx_ty) * qop * dz
    dtx_dqop = (p[0] + 3.0 * p[1] * qop * qop + p[2] * y * y + p[6] * tx * tx + p[7] * ty * ty
                + p[9] * x * x + (p[11] + p[13] * y * y) * ty * y + ex_tx) * dz
    jac[2, 0] = dtx_dx
    jac[2, 1] = dtx_dy
    jac[2, 2] = dtx_dtx
    jac[2, 3] = dtx_dty
    jac[2, 4] = dtx_dqop
    # ∂f_ty
    dty_dx = (p[10] * y + ex_ty_x) * qop
    dty_dy = (p[10] * x + (p[12] + 3.0 * p[14] * y * y) * tx + ex_ty_y) * qop
    dty_dtx = (p[4] * sy + p[8] * ty + (p[12] + p[14] * y * y) * y + ex_ty_tx) * qop
    dty_dty = 1.0 + (p[8] * tx + ex_ty_ty) * qop
    dty_dqop = p[4] * tx * sy + p[8] * tx * ty + p[10] * x * y + (p[12] + p[14] * y * y) * tx * y + ex_ty
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
