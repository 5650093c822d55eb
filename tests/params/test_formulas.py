"""The paper's extrapolation formulas: analytic Jacobians against finite differences."""

import numpy as np
import pytest

from pkf.params.formulas import layer_step, parametrized_noise, velo_step, velo_to_ut_step

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


@pytest.mark.parametrize("state", STATES)
@pytest.mark.parametrize(
    "step, params, z0, z1",
    [
        (velo_step, np.array([-1.2e-7, 300.0] + [0] * 13), 100.0, 250.0),
        (layer_step, np.array([-0.08, 1e-4 * 0, 1e-9, 0.45, 2e-3, 0.5, -0.1, -0.03, 0.3, 2e-9, -4e-9, 3e-5, -2e-5, 1e-10, -2e-10]), 2327.5, 2372.5),
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
