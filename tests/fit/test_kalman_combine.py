"""The weighted-mean combination of the Kalman core in SIMD lanes (`_combine_nodes`)."""

import numpy as np

from pkf.physics.linalg import add_matvec5, invert_spd_ldl


def _combine_one_by_one(lo, hi, x_p, p, info, info_vec, out_state, out_cov):
    """The combination node by node, downstream first, as the core did before the lanes:
    C = (P⁻¹ + Y)⁻¹ and x = x_p + C·y with `invert_spd_ldl`, stopping at the first failure."""
    work, dinv, p_inv = np.zeros((5, 5)), np.zeros(5), np.zeros((5, 5))
    for k in range(hi - 1, lo - 1, -1):
        if not invert_spd_ldl(p[k], p_inv, work, dinv):
            return False
        if not invert_spd_ldl(p_inv + info[k], out_cov[k], work, dinv):
            return False
        add_matvec5(x_p[k], out_cov[k], info_vec[k], out_state[k])
        if not np.all(np.diag(out_cov[k]) > 0.0):
            return False
    return True


def _nodes(rng, n):
    scales = np.array([0.05, 0.05, 1e-4, 1e-4, 1e-7])
    a = rng.normal(size=(n, 5, 5))
    p = np.einsum("nij,nkj->nik", a, a) + 0.05 * np.eye(5)
    p *= np.outer(scales, scales)
    b = rng.normal(size=(n, 5, 3)) / scales[:, None]
    info = np.einsum("nij,nkj->nik", b, b)
    return rng.normal(size=(n, 5)), p, info, rng.normal(size=(n, 5)) * 1e3


def _in_lanes(a):
    """Per-node rows (n, ...) in the core's lanes layout (blocks, ..., LANES); the lanes past
    the last node NaN (`_combine_nodes` must discard them)."""
    from pkf.physics.linalg import LANES

    n = a.shape[0]
    blocks = -(-n // LANES)
    rows = np.full((blocks * LANES,) + a.shape[1:], np.nan)
    rows[:n] = a
    return np.ascontiguousarray(np.moveaxis(rows.reshape((blocks, LANES) + a.shape[1:]), 1, -1))


def test_lanes_give_bitwise_the_node_by_node_combination():
    """Tracks of 1…30 nodes (whole and partial blocks of lanes): every output bitwise equal;
    with a node that is not positive definite, the same nodes written (those downstream of
    it) and the same failure."""
    from pkf.fit.kalman import _combine_nodes

    rng = np.random.default_rng(5)
    for n in (1, 7, 8, 9, 17, 30):
        for broken in (None, n // 2, 0, n - 1):
            x_p, p, info, info_vec = _nodes(rng, n)
            if broken is not None:
                p[broken, 3, 3] = -p[broken, 3, 3]
            want_s, want_c = np.full((n, 5), 7.0), np.full((n, 5, 5), 7.0)
            got_s, got_c = want_s.copy(), want_c.copy()
            ok_want = _combine_one_by_one(0, n, x_p, p, info, info_vec, want_s, want_c)
            ok_got = _combine_nodes(
                0, n, _in_lanes(x_p), _in_lanes(p), _in_lanes(info), _in_lanes(info_vec), got_s, got_c
            )
            assert ok_got == ok_want == (broken is None)
            assert want_s.tobytes() == got_s.tobytes() and want_c.tobytes() == got_c.tobytes()


def test_solve5_is_bitwise_the_pivoting_loops():
    """solve5 (straight-line, `pkf.physics.lanes_codegen`) gives bitwise the b and v of the
    loops it writes out (`_solve_general`), on the backward filter's I + Y·Q (widely scaled:
    every pivot order occurs) and on plain random matrices, and rejects, untouched, a
    matrix with a zero or NaN pivot."""
    from pkf.fit.kalman import _solve_general
    from pkf.physics import lanes_codegen
    from pkf.physics.linalg import solve5

    assert lanes_codegen.current_block() == lanes_codegen.generated_block()
    rng = np.random.default_rng(18)
    pivots = set()
    for trial in range(400):
        if trial % 2:
            _, q, info, _ = _nodes(rng, 1)
            a = np.eye(5) + info[0] @ q[0]
        else:
            a = rng.normal(size=(5, 5))
        b = rng.normal(size=(5, 5)) * 10.0 ** rng.integers(-6, 7, size=(5, 1))
        v = rng.normal(size=5)
        want_b, want_v, got_b, got_v = b.copy(), v.copy(), b.copy(), v.copy()
        assert _solve_general(a.copy(), want_b, want_v)
        a_in = a.copy()
        assert solve5(a_in, got_b, got_v)
        assert a_in.tobytes() == a.tobytes()
        assert want_b.tobytes() == got_b.tobytes() and want_v.tobytes() == got_v.tobytes()
        pivots.add(int(np.argmax(np.abs(a[:, 0]))))
    assert pivots == {0, 1, 2, 3, 4}
    for bad in (0.0, np.nan):
        a = np.eye(5)
        a[2, :] = 0.0
        a[2, 2] = bad
        b, v = np.ones((5, 5)), np.ones(5)
        assert not solve5(a, b, v)
        assert not _solve_general(a.copy(), np.ones((5, 5)), np.ones(5))
        assert np.all(b == 1.0) and np.all(v == 1.0)
