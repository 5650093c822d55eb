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


def _spd(rng, scales):
    """A random SPD 5×5 matrix with the scale spread of a track covariance (mm … 1/MeV)."""
    a = rng.normal(size=(5, 5))
    corr = a @ a.T + 0.05 * np.eye(5)
    d = np.sqrt(np.diag(corr))
    corr /= np.outer(d, d)
    return corr * np.outer(scales, scales)


def test_triangular_inverse_equals_the_lu_path_and_numpy(rng):
    """invert_spd_triangular (inverse of the Cholesky factor) = invert_spd = numpy up to
    rounding, on covariances spanning 10⁸ in scale; both refuse a matrix that is not PD."""
    from pkf.physics.linalg import invert_spd, invert_spd_triangular

    scales = np.array([0.05, 0.05, 1e-4, 1e-4, 1e-7])
    work, vec = np.zeros((5, 5)), np.zeros(10)  # invert_spd needs vec of 10
    for _ in range(200):
        a = _spd(rng, scales)
        fast, slow = np.zeros((5, 5)), np.zeros((5, 5))
        assert invert_spd_triangular(a, fast, work, vec) and invert_spd(a, slow, work.copy(), vec.copy())
        ref = np.linalg.inv(a)
        norm = np.sqrt(np.outer(np.diag(ref), np.diag(ref)))
        assert np.max(np.abs(fast - ref) / norm) < 1e-9
        assert np.max(np.abs(fast - slow) / norm) < 1e-9
        assert np.array_equal(fast, fast.T)
    bad = _spd(rng, scales)
    bad[4, 4] = -bad[4, 4]
    assert not invert_spd_triangular(bad, np.zeros((5, 5)), work, vec)


def test_ldl_inverse_equals_the_cholesky_inverse_and_numpy(rng):
    """invert_spd_ldl (L·D·Lᵀ, no equilibration, no square root) = invert_spd_triangular =
    numpy up to rounding on covariances spanning 10⁸ in scale and with correlations up to
    0.999 (the scale does not matter to an unpivoted triangular factorisation); it refuses
    a matrix that is not positive definite, or NaN."""
    from pkf.physics.linalg import invert_spd_ldl, invert_spd_triangular

    scales = np.array([0.05, 0.05, 1e-4, 1e-4, 1e-7])
    work, vec = np.zeros((5, 5)), np.zeros(10)
    for _ in range(200):
        a = _spd(rng, scales)
        fast, chol = np.zeros((5, 5)), np.zeros((5, 5))
        assert invert_spd_ldl(a, fast, work, vec) and invert_spd_triangular(a, chol, work.copy(), vec.copy())
        ref = np.linalg.inv(a)
        norm = np.sqrt(np.outer(np.diag(ref), np.diag(ref)))
        assert np.max(np.abs(fast - ref) / norm) < 1e-9
        assert np.max(np.abs(fast - chol) / norm) < 1e-9
        assert np.array_equal(fast, fast.T)
    bad = _spd(rng, scales)
    bad[4, 4] = -bad[4, 4]
    assert not invert_spd_ldl(bad, np.zeros((5, 5)), work, vec)
    bad[4, 4] = np.nan
    assert not invert_spd_ldl(bad, np.zeros((5, 5)), work, vec)


def test_structured_transports_are_bitwise_the_dense_ones(rng):
    """transport_cov = sandwich and transport_info = aᵀ… products bitwise, for a VELO-step
    Jacobian (identity but f02, f04, f13, f24), one that keeps q/p (last row e4) and a
    dense one; the structured paths are taken only for those structures."""
    from pkf.physics.linalg import (
        is_straight_velo,
        is_unit_last_row,
        matmul55,
        matmul55_tn,
        sandwich,
        transport_cov,
        transport_info,
    )

    velo = np.eye(5)
    velo[0, 2], velo[0, 4], velo[1, 3], velo[2, 4] = 12.5, -3e-3, 12.5, 4e-4
    keeps_qop = rng.normal(size=(5, 5))
    keeps_qop[4] = (0.0, 0.0, 0.0, 0.0, 1.0)
    dense = rng.normal(size=(5, 5))
    assert is_straight_velo(velo) and not is_straight_velo(keeps_qop) and not is_straight_velo(dense)
    assert is_unit_last_row(keeps_qop) and not is_unit_last_row(dense)
    for f in (velo, keeps_qop, dense):
        for _ in range(20):
            c = _spd(rng, np.array([0.05, 0.05, 1e-4, 1e-4, 1e-7]))
            c[0, 1] = c[1, 0] = -0.0
            want, got, tmp = np.zeros((5, 5)), np.zeros((5, 5)), np.zeros((5, 5))
            sandwich(f, c, tmp, want)
            transport_cov(f, c, tmp, got)
            assert want.tobytes() == got.tobytes()
            matmul55(c, f, tmp)
            matmul55_tn(f, tmp, want)
            transport_info(f, c, np.zeros((5, 5)), got)
            assert want.tobytes() == got.tobytes()


def test_noise_product_is_bitwise_the_dense_one(rng):
    """matmul_noise = matmul55 bitwise, for a block-structured noise (x–tx and y–ty blocks,
    q/p untouched: paper eq. 11) and a dense one (the structured path only for the former)."""
    from pkf.physics.linalg import is_block_noise, matmul55, matmul_noise

    block = np.zeros((5, 5))
    block[np.ix_([0, 2], [0, 2])] = [[4e-3, -2e-5], [-2e-5, 3e-7]]
    block[np.ix_([1, 3], [1, 3])] = [[5e-3, 1e-5], [1e-5, 2e-7]]
    dense = _spd(rng, np.array([0.05, 0.05, 1e-4, 1e-4, 1e-7]))
    assert is_block_noise(block) and not is_block_noise(dense)
    for q in (block, dense):
        for _ in range(20):
            a = _spd(rng, np.array([1e2, 1e2, 1e6, 1e6, 1e12]))
            a[0, 1] = -0.0
            want, got = np.zeros((5, 5)), np.zeros((5, 5))
            matmul55(a, q, want)
            matmul_noise(a, q, got)
            assert want.tobytes() == got.tobytes()


def test_lane_inverse_is_bitwise_the_scalar_one(rng):
    """invert_spd_ldl_lane (straight-line code for SIMD lanes) gives, lane by lane, bitwise
    the inverse of invert_spd_ldl, and flags (instead of returning early) a lane that is not
    positive definite or NaN; its code is what pkf.physics.lanes_codegen writes."""
    from pkf.physics import lanes_codegen
    from pkf.physics.linalg import LANES, invert_spd_ldl, invert_spd_ldl_lane

    assert lanes_codegen.current_block() == lanes_codegen.generated_block()
    scales = np.array([0.05, 0.05, 1e-4, 1e-4, 1e-7])
    a = np.stack([_spd(rng, scales) for _ in range(LANES)], axis=-1)
    a[4, 4, 2] = -a[4, 4, 2]
    a[1, 1, 5] = np.nan
    out, bad = np.zeros((5, 5, LANES)), np.zeros(LANES)
    for lane in range(LANES):
        invert_spd_ldl_lane(a, out, bad, lane)
    for lane in range(LANES):
        want = np.zeros((5, 5))
        ok = invert_spd_ldl(np.ascontiguousarray(a[:, :, lane]), want, np.zeros((5, 5)), np.zeros(5))
        assert ok == (bad[lane] == 0.0)
        if ok:
            assert want.tobytes() == np.ascontiguousarray(out[:, :, lane]).tobytes()
    assert list(np.flatnonzero(bad)) == [2, 5]
