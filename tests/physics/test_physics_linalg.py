"""The small 5×5 helpers the fitters share (pkf.physics.linalg) against numpy."""

import numpy as np
import pytest

from pkf.physics.linalg import add_matvec5, matmul52, matmul55_tn, matvec5, matvec5_t, zero5, zero55


@pytest.fixture
def rng():
    return np.random.default_rng(14)


def test_products_match_numpy(rng):
    a = rng.normal(size=(5, 5))
    b = rng.normal(size=(5, 5))
    g = rng.normal(size=(5, 2))
    v = rng.normal(size=5)
    out55 = np.empty((5, 5))
    out52 = np.empty((5, 2))
    out5 = np.empty(5)
    matmul55_tn(a, b, out55)
    np.testing.assert_allclose(out55, a.T @ b, rtol=1e-13, atol=1e-13)
    matmul52(a, g, out52)
    np.testing.assert_allclose(out52, a @ g, rtol=1e-13, atol=1e-13)
    matvec5_t(a, v, out5)
    np.testing.assert_allclose(out5, a.T @ v, rtol=1e-13, atol=1e-13)
    matvec5(a, v, out5)
    np.testing.assert_allclose(out5, a @ v, rtol=1e-13, atol=1e-13)


def test_add_matvec5_in_place_on_x(rng):
    """out = x + a·v, also when out is x itself (the smoothers' state update)."""
    a = rng.normal(size=(5, 5))
    v = rng.normal(size=5)
    x = rng.normal(size=5)
    expected = x + a @ v
    add_matvec5(x, a, v, x)
    np.testing.assert_allclose(x, expected, rtol=1e-13, atol=1e-13)


def test_zero(rng):
    a = rng.normal(size=(5, 5))
    v = rng.normal(size=5)
    zero55(a)
    zero5(v)
    assert not a.any() and not v.any()
