"""Runge–Kutta transport (pkf.physics.transport): helix accuracy and the transport Jacobian."""

import math

import numba as nb
import numpy as np
import pytest

from pkf.geometry.field import build_field_map, dipole_field, uniform_field
from pkf.physics.transport import (
    C_LIGHT,
    rk4_propagate,
    rk4_propagate_jacobian,
    rk4_propagate_many,
    rk4_transport_jacobian,
    slope_derivatives,
)
from pkf.jit import NO_REFCOUNT

TELESCOPE_FIELD = uniform_field(0.0, 1.0, 0.0)  # DESIGN §3.2: 1 T along y
DIPOLE_FIELD = dipole_field()  # DESIGN §3.1


def exact_helix(state, z_from, z_to, by):
    """Exact solution of the DESIGN §2 equations of motion in a uniform field (0, by, 0).

    The projection on the x–z plane is a circle: with tx = tan φ the equations give
    dφ/ds = ω along the x–z arc length s, ω = −κ·qop·by·N/√(1+tx²) (constant, because
    the momentum along y is conserved: ty/√(1+tx²) = p_y/p_xz = const). Integrating,
    sin φ = sin φ0 + ω(z − z0), x − x0 = (cos φ0 − cos φ)/ω, y − y0 = c·(φ − φ0)/ω with
    c = ty0/√(1+tx0²), and the slopes are tx = tan φ, ty = c/cos φ.
    """
    x0, y0, tx0, ty0, qop = state
    r0 = math.sqrt(1.0 + tx0 * tx0)
    sin0, cos0 = tx0 / r0, 1.0 / r0
    omega = -C_LIGHT * qop * by * math.sqrt(1.0 + tx0 * tx0 + ty0 * ty0) / r0
    c = ty0 / r0
    sin1 = sin0 + omega * (z_to - z_from)
    cos1 = math.sqrt(1.0 - sin1 * sin1)
    dphi = math.atan2(sin1, cos1) - math.atan2(sin0, cos0)
    return np.array([
        x0 + (cos0 - cos1) / omega,
        y0 + c * dphi / omega,
        sin1 / cos1,
        c / cos1,
        qop,
    ])


def test_curvature_constant_gives_the_textbook_radius():
    # p = 1 GeV/c in 1 T: R = p/(0.299792458 GeV/(T·m)) = 3.33564 m.
    dtx, dty = slope_derivatives(0.0, 0.0, 1.0 / 1000.0, 0.0, 1.0, 0.0)
    assert dty == 0.0
    assert 1.0 / abs(dtx) == pytest.approx(3335.641, abs=1e-3)
    # positive particle in B along +y bends towards −x (F = q v × B, v = z, B = y → −x)
    assert dtx < 0.0


HELIX_CASES = [
    (p, q, tx, ty)
    for p in (1000.0, 3000.0, 20000.0, 100000.0)
    for q in (+1, -1)
    for tx, ty in ((0.0, 0.0), (0.3, -0.2), (-0.25, 0.3), (0.05, 0.4))
]


@pytest.mark.parametrize("p, q, tx, ty", HELIX_CASES)
def test_rk4_reproduces_exact_helix_over_one_metre(p, q, tx, ty):
    state = np.array([1.5, -2.0, tx, ty, q / p])
    args = TELESCOPE_FIELD.args
    for z_from, z_to in ((0.0, 1000.0), (1000.0, 0.0)):  # forwards and backwards
        got = rk4_propagate(state, z_from, z_to, 100.0, *args)
        want = exact_helix(state, z_from, z_to, 1.0)
        assert abs(got[0] - want[0]) < 1e-3  # < 1 µm
        assert abs(got[1] - want[1]) < 1e-3
        assert abs(got[2] - want[2]) < 1e-6
        assert abs(got[3] - want[3]) < 1e-6
        assert got[4] == state[4]


def test_rk4_is_fourth_order_and_accurate():
    """Halving the step divides the error by ≈ 16; report the worst 1 GeV deviation."""
    state = np.array([0.0, 0.0, 0.3, -0.2, 1.0 / 1000.0])
    want = exact_helix(state, 0.0, 1000.0, 1.0)
    errors = []
    for step in (200.0, 100.0, 50.0):
        got = rk4_propagate(state, 0.0, 1000.0, step, *TELESCOPE_FIELD.args)
        errors.append(math.hypot(got[0] - want[0], got[1] - want[1]))
    assert errors[1] < 2e-4  # mm, at the telescope plane spacing of 100 mm
    assert 12.0 < errors[0] / errors[1] < 20.0
    assert 12.0 < errors[1] / errors[2] < 20.0


def test_forward_then_backward_returns_to_start():
    state = np.array([120.0, -40.0, 0.08, -0.03, -1.0 / 4000.0])
    out = rk4_propagate(state, 2300.0, 7800.0, 50.0, *DIPOLE_FIELD.args)
    back = rk4_propagate(out, 7800.0, 2300.0, 50.0, *DIPOLE_FIELD.args)
    np.testing.assert_allclose(back[:2], state[:2], atol=1e-4)
    np.testing.assert_allclose(back[2:4], state[2:4], atol=1e-8)


def test_propagate_many_matches_single():
    states = np.array([[1.0, 2.0, 0.1, -0.05, 1 / 5000.0], [-3.0, 0.0, -0.2, 0.1, -1 / 2000.0]])
    args = DIPOLE_FIELD.args
    many = rk4_propagate_many(states, 2300.0, 7800.0, 100.0, *args)
    for row, state in zip(many, states):
        np.testing.assert_array_equal(row, rk4_propagate(state, 2300.0, 7800.0, 100.0, *args))


# --- Jacobian ----------------------------------------------------------------------


def finite_difference_jacobian(state, z_from, z_to, max_step, args):
    """Central differences of rk4_propagate (the map the analytic Jacobian differentiates)."""
    steps = (1e-3, 1e-3, 1e-6, 1e-6, 1e-5 * abs(state[4]))
    jac = np.zeros((5, 5))
    for j, h in enumerate(steps):
        up = state.copy()
        up[j] += h
        down = state.copy()
        down[j] -= h
        jac[:, j] = (rk4_propagate(up, z_from, z_to, max_step, *args)
                     - rk4_propagate(down, z_from, z_to, max_step, *args)) / (2.0 * h)
    return jac


def analytic_jacobian(state, z_from, z_to, max_step, args):
    jac = np.full((5, 5), np.nan)
    out = rk4_propagate_jacobian(state, z_from, z_to, max_step, *args, jac)
    # same steps as rk4_propagate, bit for bit
    np.testing.assert_array_equal(out, rk4_propagate(state, z_from, z_to, max_step, *args))
    np.testing.assert_array_equal(jac[4], [0.0, 0.0, 0.0, 0.0, 1.0])
    return jac


@pytest.mark.parametrize("q", (+1, -1))
@pytest.mark.parametrize("p", (1000.0, 5000.0))
@pytest.mark.parametrize("tx, ty", ((0.0, 0.0), (0.3, -0.2)))
def test_jacobian_matches_finite_differences_uniform(p, q, tx, ty):
    state = np.array([1.0, -2.0, tx, ty, q / p])
    for z_from, z_to in ((0.0, 900.0), (900.0, 0.0), (0.0, 100.0)):
        jac = analytic_jacobian(state, z_from, z_to, 100.0, TELESCOPE_FIELD.args)
        fd = finite_difference_jacobian(state, z_from, z_to, 100.0, TELESCOPE_FIELD.args)
        np.testing.assert_allclose(jac, fd, rtol=1e-4, atol=1e-12)


@pytest.mark.parametrize("q", (+1, -1))
@pytest.mark.parametrize("p", (3000.0, 10000.0, 100000.0))
@pytest.mark.parametrize("x, y, tx, ty", ((300.0, -150.0, 0.12, -0.06),
                                          (-50.0, 400.0, -0.02, 0.15)))
def test_jacobian_matches_finite_differences_dipole(p, q, x, y, tx, ty):
    """UT → SciFi through the analytic dipole: every element, including ∂(tx,ty)/∂(x,y)."""
    state = np.array([x, y, tx, ty, q / p])
    jac = analytic_jacobian(state, 2300.0, 7800.0, 100.0, DIPOLE_FIELD.args)
    fd = finite_difference_jacobian(state, 2300.0, 7800.0, 100.0, DIPOLE_FIELD.args)
    np.testing.assert_allclose(jac, fd, rtol=1e-4, atol=1e-12)
    assert abs(jac[2, 0]) > 1e-9  # the field gradient enters (it is not trivially zero)


def test_jacobian_matches_finite_differences_field_map(tmp_path):
    """The reference fit's case: the trilinear map of the dipole (a reduced grid)."""
    field_map = build_field_map(DIPOLE_FIELD, spacing=100.0, x_range=(-1000.0, 1000.0),
                                y_range=(-1000.0, 1000.0), z_range=(2000.0, 8000.0),
                                cache_dir=tmp_path)
    state = np.array([300.0, -150.0, 0.12, -0.06, 1.0 / 5000.0])
    jac = analytic_jacobian(state, 2300.0, 7800.0, 100.0, field_map.args)
    fd = finite_difference_jacobian(state, 2300.0, 7800.0, 100.0, field_map.args)
    np.testing.assert_allclose(jac, fd, rtol=1e-4, atol=1e-12)


def test_forward_and_backward_jacobians_are_inverse():
    state = np.array([300.0, -150.0, 0.12, -0.06, -1.0 / 3000.0])
    forward = np.empty((5, 5))
    backward = np.empty((5, 5))
    out = rk4_propagate_jacobian(state, 2300.0, 7800.0, 20.0, *DIPOLE_FIELD.args, forward)
    rk4_propagate_jacobian(out, 7800.0, 2300.0, 20.0, *DIPOLE_FIELD.args, backward)
    # compare in units of typical state changes (mm, mm, mrad, mrad, |qop|)
    scale = np.array([1.0, 1.0, 1e-3, 1e-3, abs(state[4])])
    product = (backward @ forward) * scale[None, :] / scale[:, None]
    np.testing.assert_allclose(product, np.eye(5), atol=1e-7)


def test_zero_distance_is_identity():
    state = np.array([1.0, 2.0, 0.1, 0.2, 1e-3])
    jac = np.full((5, 5), 7.0)
    out = rk4_propagate_jacobian(state, 500.0, 500.0, 100.0, *DIPOLE_FIELD.args, jac)
    np.testing.assert_array_equal(out, state)
    np.testing.assert_array_equal(jac, np.eye(5))


def test_straight_line_without_field():
    state = np.array([1.0, 2.0, 0.1, -0.2, 1e-3])
    jac = np.empty((5, 5))
    out = rk4_propagate_jacobian(state, 0.0, 250.0, 100.0, *uniform_field(0.0, 0.0, 0.0).args, jac)
    np.testing.assert_allclose(out, [26.0, -48.0, 0.1, -0.2, 1e-3], rtol=0, atol=1e-12)
    expected = np.eye(5)
    expected[0, 2] = expected[1, 3] = 250.0
    np.testing.assert_allclose(jac, expected, rtol=0, atol=1e-12)


@nb.njit(**NO_REFCOUNT)
def _transport_in_place(state, z_from, z_to, max_step, kind, params, grid, jac, stages):
    # compiled without reference counting: numba refuses this if the transport allocates
    rk4_transport_jacobian(state, z_from, z_to, max_step, kind, params, grid, jac, stages)


@pytest.mark.parametrize("z_from, z_to", ((2300.0, 7800.0), (7800.0, 2300.0), (500.0, 500.0)))
def test_in_place_transport_allocates_nothing_and_equals_the_allocating_one(z_from, z_to):
    """The fitters' RK4 (in place, the caller's stage scratch) is the same map, bit for bit,
    as `rk4_propagate_jacobian`, and compiles in a kernel without reference counting."""
    start = np.array([1.0, -2.0, 0.1, -0.05, 1 / 4000.0])
    jac = np.full((5, 5), np.nan)
    out = rk4_propagate_jacobian(start, z_from, z_to, 20.0, *DIPOLE_FIELD.args, jac)
    state = start.copy()
    jac_in_place = np.full((5, 5), np.nan)
    _transport_in_place(state, z_from, z_to, 20.0, *DIPOLE_FIELD.args, jac_in_place, np.full((4, 5, 5), np.nan))
    np.testing.assert_array_equal(state, out)
    np.testing.assert_array_equal(jac_in_place, jac)
