"""The paper's extrapolation formulas: analytic Jacobians against finite differences."""

import numpy as np
import pytest

from pkf.params.formulas import (
    LAYER_TX_MONOMIALS,
    LAYER_TX_OFFSET,
    LAYER_TY_MONOMIALS,
    LAYER_TY_OFFSET,
    N_EXTRAPOLATION_PARAMS,
    layer_step,
    parametrized_noise,
    velo_step,
    velo_to_ut_step,
)

STATES = [
    np.array([3.0, -12.0, 0.05, -0.12, 1 / 4000.0]),
    np.array([-250.0, 80.0, -0.2, 0.15, -1 / 20000.0]),
    np.array([40.0, 300.0, 0.22, 0.2, 1 / 3000.0]),
]


def _numeric_jacobian(step, p, s, z0, z1):
    jac = np.empty((5, 5))
    out = np.empty(5)
    scratch = np.empty((5, 5))
    h = np.array([1e-2, 1e-2, 1e-5, 1e-5, 1e-4 * abs(s[4])])
    for j in range(5):
        plus, minus = s.copy(), s.copy()
        plus[j] += h[j]
        minus[j] -= h[j]
        step(p, plus, z0, z1, out, scratch)
        a = out.copy()
        step(p, minus, z0, z1, out, scratch)
        jac[:, j] = (a - out) / (2 * h[j])
    return jac


def _extended_layer_params():
    """Eq. 14 parameters with every degree-4 monomial p15…p49 switched on, each scaled to
    change the kick by O(1e-3)·qop·Δz at |x|, |y| ~ 300 mm, slopes ~ 0.2."""
    p = np.zeros(N_EXTRAPOLATION_PARAMS)
    p[:15] = [-0.08, 1e-4 * 0, 1e-9, 0.45, 2e-3, 0.5, -0.1, -0.03, 0.3, 2e-9, -4e-9, 3e-5, -2e-5, 1e-10, -2e-10]
    rng = np.random.default_rng(3)
    for offset, exponents in ((LAYER_TX_OFFSET, LAYER_TX_MONOMIALS), (LAYER_TY_OFFSET, LAYER_TY_MONOMIALS)):
        for i, (a, b, c, d) in enumerate(exponents):
            size = 300.0 ** (a + c) * 0.2 ** (b + d)
            p[offset + i] = rng.normal(0, 1e-3) / size
    return p


@pytest.mark.parametrize("state", STATES)
@pytest.mark.parametrize(
    "step, params, z0, z1",
    [
        (velo_step, np.array([-1.2e-7, 300.0] + [0] * 13), 100.0, 250.0),
        (layer_step, np.array([-0.08, 1e-4 * 0, 1e-9, 0.45, 2e-3, 0.5, -0.1, -0.03, 0.3, 2e-9, -4e-9, 3e-5, -2e-5, 1e-10, -2e-10]), 2327.5, 2372.5),
        (layer_step, _extended_layer_params(), 8036.0, 8508.0),
        (velo_to_ut_step, np.array([3.0, -60.0, 0.01, 20.0, 1200.0, 0.1, 1e-5, 50.0, 0.5, 0, 0, 0, 0, 0, 0]), 300.0, 2327.5),
    ],
)
def test_jacobian_matches_finite_differences(step, params, z0, z1, state):
    out = np.empty(5)
    jac = np.empty((5, 5))
    step(params, state, z0, z1, out, jac)
    numeric = _numeric_jacobian(step, params, state, z0, z1)
    # relative 1e-4, with an absolute floor of 1e-6 of the row's largest element
    # (finite-difference round-off on elements many orders below it)
    tolerance = 1e-4 * np.abs(jac) + 1e-6 * np.max(np.abs(jac), axis=1, keepdims=True)
    assert np.all(np.abs(jac - numeric) <= tolerance)
    assert out[4] == state[4]  # q/p is the momentum at production: unchanged


def test_velo_to_ut_is_a_kink_at_z_mag():
    """With p0 = p3 = p7 = 0 and p8 = 1 the step is a straight line to z_mag, a kink of
    qop·∫(dl×B)_x in tx/N, then a straight line (eqs. 15, 16)."""
    p = np.array([0.0, -1000.0, 0.0, 0.0, 1500.0, 0.0, 0.0, 0.0, 1.0])
    s = np.array([1.0, 2.0, 0.1, 0.05, 1 / 10000.0])
    out = np.empty(5)
    velo_to_ut_step(p, s, 500.0, 2500.0, out, np.empty((5, 5)))
    n1 = np.sqrt(1 + s[2] ** 2 + s[3] ** 2)
    n2 = np.sqrt(1 + out[2] ** 2 + out[3] ** 2)
    assert out[2] / n2 == pytest.approx(s[2] / n1 + s[4] * p[1], rel=1e-12)
    assert out[0] == pytest.approx(s[0] + 1000.0 * s[2] + 1000.0 * out[2], rel=1e-12)
    assert out[1] == pytest.approx(s[1] + 2000.0 * s[3], rel=1e-12)


def test_noise_matrix_follows_eq_11():
    noise = np.empty((5, 5))
    pn = np.array([2.0, 0.4, 0.8, -0.5, 1e-5, 0.0])
    state = np.array([0.0, 0.0, 0.3, -0.1, 1 / 5000.0])
    parametrized_noise(pn, state, 100.0, noise)
    n2 = 1 + 0.3**2 + 0.1**2
    q_txtx = (2.0 / 5000.0) ** 2 * n2**1.5 * (1 + 0.3**2) + 1e-10
    q_tyty = (2.0 / 5000.0) ** 2 * n2**1.5 * (1 + 0.1**2) + 1e-10
    assert noise[2, 2] == pytest.approx(q_txtx) and noise[3, 3] == pytest.approx(q_tyty)
    assert noise[0, 0] == pytest.approx((0.4 * 100) ** 2 * q_txtx)
    assert noise[0, 2] == pytest.approx(0.8 * np.sqrt(noise[0, 0] * q_txtx))
    assert noise[1, 3] == pytest.approx(-0.5 * np.sqrt(noise[1, 1] * q_tyty))
    assert np.all(noise[4] == 0) and np.all(np.linalg.eigvalsh(noise[:4, :4]) >= -1e-20)


def test_extended_layer_step_terms_are_the_listed_monomials():
    """Each of p15…p49 adds exactly coefficient·qop·x^a·tx^b·y^c·ty^d to the tx kick (×Δz)
    or to the ty kick, with the exponents of LAYER_TX/TY_MONOMIALS; a 15-entry (old) set
    is the same step as the 50-entry set with zeros."""
    s = np.array([-420.0, 910.0, -0.15, 0.12, 1 / 3500.0])
    z0, z1 = 8036.0, 8508.0
    base = np.zeros(N_EXTRAPOLATION_PARAMS)
    base[:15] = [-0.08, 0.0, 1e-9, 0.45, 2e-3, 0.5, -0.1, -0.03, 0.3, 2e-9, -4e-9, 3e-5, -2e-5, 1e-10, -2e-10]
    out0, out1, out_short = np.empty(5), np.empty(5), np.empty(5)
    jac = np.empty((5, 5))
    layer_step(base, s, z0, z1, out0, jac)
    layer_step(base[:15].copy(), s, z0, z1, out_short, jac)
    assert np.array_equal(out0, out_short)
    for offset, exponents, row, factor in ((LAYER_TX_OFFSET, LAYER_TX_MONOMIALS, 2, z1 - z0),
                                           (LAYER_TY_OFFSET, LAYER_TY_MONOMIALS, 3, 1.0)):
        for i, (a, b, c, d) in enumerate(exponents):
            p = base.copy()
            term = s[4] * s[0] ** a * s[2] ** b * s[1] ** c * s[3] ** d * factor
            p[offset + i] = 1e-6 / abs(term)  # a 1 µrad change of the slope
            layer_step(p, s, z0, z1, out1, jac)
            assert out1[row] - out0[row] == pytest.approx(p[offset + i] * term, rel=1e-8), (row, (a, b, c, d))
            other = 5 - row  # the other slope (tx ↔ ty) is untouched
            assert out1[other] == out0[other]


def test_monomial_lists_follow_the_field_symmetry():
    """tx kick: even in (x, tx) and in (y, ty); ty kick: odd in both (module docstring);
    degree ≤ 4, no duplicates, none of the monomials p0…p14 already hold."""
    tx_old = {(0, 0, 0, 0), (0, 0, 2, 0), (0, 2, 0, 0), (0, 0, 0, 2), (2, 0, 0, 0), (0, 0, 1, 1), (0, 0, 3, 1)}
    ty_old = {(0, 1, 0, 1), (1, 0, 1, 0), (0, 1, 1, 0), (0, 1, 3, 0)}
    for exponents, parity, old in ((LAYER_TX_MONOMIALS, 0, tx_old), (LAYER_TY_MONOMIALS, 1, ty_old)):
        rows = {tuple(int(v) for v in e) for e in exponents}
        assert len(rows) == len(exponents) and not rows & old
        for a, b, c, d in rows:
            assert a + b + c + d <= 4 and (a + b) % 2 == parity and (c + d) % 2 == parity
        # complete: every allowed monomial of degree ≤ 4 is either old or listed
        import itertools
        allowed = {e for e in itertools.product(range(5), repeat=4)
                   if sum(e) <= 4 and (e[0] + e[1]) % 2 == parity and (e[2] + e[3]) % 2 == parity}
        assert rows | old == allowed
    assert N_EXTRAPOLATION_PARAMS == LAYER_TY_OFFSET + len(LAYER_TY_MONOMIALS) == 50


#: The eq. 14 terms p0…p14 hold that belong to the kick polynomials (slot, exponents of x, tx, y, ty).
_TX_BASE_TERMS = ((2, (0, 0, 2, 0)), (6, (0, 2, 0, 0)), (7, (0, 0, 0, 2)), (9, (2, 0, 0, 0)), (11, (0, 0, 1, 1)),
                  (13, (0, 0, 3, 1)))
_TY_BASE_TERMS = ((8, (0, 1, 0, 1)), (10, (1, 0, 1, 0)), (12, (0, 1, 1, 0)), (14, (0, 1, 3, 0)))


def _monomial_sums(p, state, base_terms, offset, exponents):
    """Σ p_k·x^a·tx^b·y^c·ty^d over the listed terms, term by term, and its derivatives by
    x, y, tx, ty; with the sum of the terms' magnitudes (the scale of the rounding)."""
    x, y, tx, ty = state[:4]
    terms = list(base_terms) + [(offset + i, tuple(e)) for i, e in enumerate(exponents)]
    value = np.zeros(5)
    scale = np.zeros(5)
    for slot, (a, b, c, d) in terms:
        def term(ea, eb, ec, ed, factor):
            return factor * p[slot] * x ** ea * tx ** eb * y ** ec * ty ** ed if factor else 0.0
        parts = (term(a, b, c, d, 1), term(a - 1, b, c, d, a), term(a, b, c - 1, d, c),
                 term(a, b - 1, c, d, b), term(a, b, c, d - 1, d))
        value += parts
        scale += np.abs(parts)
    return value, scale


def test_factored_kicks_equal_the_monomial_sums():
    """The factored kick polynomials of `layer_step` (value and derivatives by x, y, tx, ty)
    are the sums of the listed monomials term by term to within 4e−15 of the terms' sizes,
    over random coefficients and states across the SciFi (every p0…p49 non-zero)."""
    from pkf.params.formulas import _tx_kick_polynomial, _ty_kick_polynomial

    rng = np.random.default_rng(7)
    for _ in range(200):
        p = rng.normal(size=N_EXTRAPOLATION_PARAMS) * 1e-6
        x, y = rng.uniform(-3000, 3000, size=2)
        tx, ty = rng.uniform(-0.3, 0.3, size=2)
        powers = (x, tx, y, ty, x * x, x * tx, tx * tx, y * y, y * ty, ty * ty)
        state = np.array([x, y, tx, ty])
        for kick, base, offset, exponents in ((_tx_kick_polynomial, _TX_BASE_TERMS, LAYER_TX_OFFSET,
                                                LAYER_TX_MONOMIALS),
                                               (_ty_kick_polynomial, _TY_BASE_TERMS, LAYER_TY_OFFSET,
                                                LAYER_TY_MONOMIALS)):
            expected, scale = _monomial_sums(p, state, base, offset, exponents)
            got = np.array(kick(p, *powers))
            assert np.all(np.abs(got - expected) <= 4e-15 * scale + 1e-300), (kick, got - expected, scale)


def test_short_parameter_sets_are_zero_padded():
    """A set without its last coefficients is the full set with those coefficients zero,
    bit for bit."""
    p = _extended_layer_params()
    s = np.array([-420.0, 910.0, -0.15, 0.12, 1 / 3500.0])
    for n in (15, 34, 49):
        q = p.copy()
        q[n:] = 0.0
        out_full, out_short = np.empty(5), np.empty(5)
        jac_full, jac_short = np.empty((5, 5)), np.empty((5, 5))
        layer_step(q, s, 8036.0, 8508.0, out_full, jac_full)
        layer_step(p[:n].copy(), s, 8036.0, 8508.0, out_short, jac_short)
        assert np.array_equal(out_full, out_short) and np.array_equal(jac_full, jac_short)
