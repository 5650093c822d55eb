"""Allocation-free 5×5 linear algebra for the compiled Kalman kernels.

Plain loops over small float64 arrays (numba unrolls them); every function writes into
arrays the caller owns, so the per-node work allocates nothing. Inverses of symmetric
positive-definite matrices go through a Cholesky factorisation and report failure
instead of returning garbage for a non-positive-definite matrix.
"""

from __future__ import annotations

import math

import numba as nb


@nb.njit(cache=True, inline="always")
def copy5(src, dst):
    """dst[:] = src[:] for a 5-vector."""
    for i in range(5):
        dst[i] = src[i]


@nb.njit(cache=True, inline="always")
def copy55(src, dst):
    """dst[:, :] = src[:, :] for a 5×5 matrix."""
    for i in range(5):
        for j in range(5):
            dst[i, j] = src[i, j]


@nb.njit(cache=True)
def set_identity(a):
    """a = 1 (5×5)."""
    for i in range(5):
        for j in range(5):
            a[i, j] = 1.0 if i == j else 0.0


@nb.njit(cache=True)
def matmul55(a, b, out):
    """out = a·b (5×5); out must not alias a or b."""
    for i in range(5):
        for j in range(5):
            s = 0.0
            for k in range(5):
                s += a[i, k] * b[k, j]
            out[i, j] = s


@nb.njit(cache=True)
def matvec5(a, v, out):
    """out = a·v (5×5 times 5-vector)."""
    for i in range(5):
        s = 0.0
        for k in range(5):
            s += a[i, k] * v[k]
        out[i] = s


@nb.njit(cache=True)
def sandwich(f, c, tmp, out):
    """out = f·c·fᵀ (5×5), symmetrised; tmp is 5×5 scratch."""
    for i in range(5):
        for j in range(5):
            s = 0.0
            for k in range(5):
                s += f[i, k] * c[k, j]
            tmp[i, j] = s
    for i in range(5):
        for j in range(i, 5):
            s = 0.0
            for k in range(5):
                s += tmp[i, k] * f[j, k]
            out[i, j] = s
            out[j, i] = s


@nb.njit(cache=True)
def symmetrise(a):
    """a = (a + aᵀ)/2 in place (5×5)."""
    for i in range(5):
        for j in range(i + 1, 5):
            m = 0.5 * (a[i, j] + a[j, i])
            a[i, j] = m
            a[j, i] = m


@nb.njit(cache=True)
def invert_spd(a, out, work, vec):
    """out = a⁻¹ for a symmetric positive-definite 5×5 matrix via Cholesky a = L·Lᵀ.

    work (5×5) holds L, vec (5) is scratch. Returns False (out undefined) when a is not
    positive definite.
    """
    n = 5
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= work[j, k] * work[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        work[j, j] = d
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t -= work[i, k] * work[j, k]
            work[i, j] = t / d
    for col in range(n):
        # column col of a⁻¹: solve L·y = e_col, then Lᵀ·x = y
        for i in range(n):
            t = 1.0 if i == col else 0.0
            for k in range(i):
                t -= work[i, k] * vec[k]
            vec[i] = t / work[i, i]
        for i in range(n - 1, -1, -1):
            t = vec[i]
            for k in range(i + 1, n):
                t -= work[k, i] * out[k, col]
            out[i, col] = t / work[i, i]
    symmetrise(out)
    return True


@nb.njit(cache=True)
def is_positive_definite_diag(a):
    """True if every diagonal element of a 5×5 matrix is positive and finite."""
    for i in range(5):
        if not (a[i, i] > 0.0 and math.isfinite(a[i, i])):
            return False
    return True
