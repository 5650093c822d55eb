"""Allocation-free 5×5 linear algebra for the compiled Kalman kernels.

Plain loops over small float64 arrays (numba unrolls them); every function writes into
arrays the caller owns, so the per-node work allocates nothing. Inverses of symmetric
positive-definite matrices go through a Cholesky factorisation and report failure
instead of returning garbage for a non-positive-definite matrix.

Structured variants (`transport_cov`, `transport_info`, `matmul_noise`) leave out the
terms that are exact zeros of a known Jacobian or noise structure and are bitwise the
dense products. The multiply–adds are `pkf.jit.fma` (a·b + c rounded once) on both
sides: fma(0, y, s) = s and fma(1, y, s) = s + y for finite y, so leaving out the zero
terms and adding the unit ones plainly keeps the dense result. `invert_spd_ldl_lane`
is `invert_spd_ldl` for one lane of a stack of matrices, written out for SIMD loops over
the lanes (`pkf.physics.lanes_codegen`).
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT, fma


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


@nb.njit(cache=True, inline="always")
def zero5(v):
    """v[:] = 0 for a 5-vector."""
    for i in range(5):
        v[i] = 0.0


@nb.njit(cache=True, inline="always")
def zero55(a):
    """a[:, :] = 0 for a 5×5 matrix."""
    for i in range(5):
        for j in range(5):
            a[i, j] = 0.0


@nb.njit(cache=True, inline="always")
def set_identity(a):
    """a = 1 (5×5)."""
    for i in range(5):
        for j in range(5):
            a[i, j] = 1.0 if i == j else 0.0


@nb.njit(cache=True, inline="always")
def matmul55(a, b, out):
    """out = a·b (5×5); out must not alias a or b."""
    for i in range(5):
        for j in range(5):
            s = 0.0
            for k in range(5):
                s = fma(a[i, k], b[k, j], s)
            out[i, j] = s


@nb.njit(cache=True, inline="always")
def matmul52(a, b, out):
    """out = a·b for a 5×5 a and a 5×2 b; out (5×2) must not alias a or b."""
    for i in range(5):
        for j in range(2):
            s = 0.0
            for k in range(5):
                s = fma(a[i, k], b[k, j], s)
            out[i, j] = s


@nb.njit(cache=True, inline="always")
def matmul55_tn(a, b, out):
    """out = aᵀ·b (5×5); out must not alias a or b."""
    for i in range(5):
        for j in range(5):
            s = 0.0
            for k in range(5):
                s = fma(a[k, i], b[k, j], s)
            out[i, j] = s


@nb.njit(cache=True, inline="always")
def matvec5(a, v, out):
    """out = a·v (5×5 times 5-vector)."""
    for i in range(5):
        s = 0.0
        for k in range(5):
            s = fma(a[i, k], v[k], s)
        out[i] = s


@nb.njit(cache=True, inline="always")
def matvec5_t(a, v, out):
    """out = aᵀ·v (5×5 transposed times 5-vector)."""
    for i in range(5):
        s = 0.0
        for k in range(5):
            s = fma(a[k, i], v[k], s)
        out[i] = s


@nb.njit(cache=True, inline="always")
def add_matvec5(x, a, v, out):
    """out = x + a·v (5-vectors, a 5×5), summed from x[i] upwards; out may be x."""
    for i in range(5):
        s = x[i]
        for k in range(5):
            s = fma(a[i, k], v[k], s)
        out[i] = s


@nb.njit(cache=True, inline="always")
def sandwich(f, c, tmp, out):
    """out = f·c·fᵀ (5×5), symmetrised; tmp is 5×5 scratch. out may be c (c is read only
    into tmp), not f or tmp."""
    for i in range(5):
        for j in range(5):
            s = 0.0
            for k in range(5):
                s = fma(f[i, k], c[k, j], s)
            tmp[i, j] = s
    for i in range(5):
        for j in range(i, 5):
            s = 0.0
            for k in range(5):
                s = fma(tmp[i, k], f[j, k], s)
            out[i, j] = s
            out[j, i] = s


@nb.njit(cache=True, inline="always")
def is_unit_last_row(f):
    """True if row 4 of the 5×5 f is (0, 0, 0, 0, 1): a transport that keeps q/p (every
    parametrized step, and RK4 without energy loss in the Jacobian)."""
    return f[4, 0] == 0.0 and f[4, 1] == 0.0 and f[4, 2] == 0.0 and f[4, 3] == 0.0 and f[4, 4] == 1.0


@nb.njit(cache=True, inline="always")
def is_straight_velo(f):
    """True if f = 1 except f[0, 2], f[0, 4], f[1, 3], f[2, 4] (the VELO step, paper eq. 10:
    x′ = x + tx·Δz + ½k·Δz·q/p, y′ = y + ty·Δz, tx′ = tx + k·q/p, and a straight line)."""
    return (
        f[0, 0] == 1.0
        and f[0, 1] == 0.0
        and f[0, 3] == 0.0
        and f[1, 0] == 0.0
        and f[1, 1] == 1.0
        and f[1, 2] == 0.0
        and f[1, 4] == 0.0
        and f[2, 0] == 0.0
        and f[2, 1] == 0.0
        and f[2, 2] == 1.0
        and f[2, 3] == 0.0
        and f[3, 0] == 0.0
        and f[3, 1] == 0.0
        and f[3, 2] == 0.0
        and f[3, 3] == 1.0
        and f[3, 4] == 0.0
        and is_unit_last_row(f)
    )


@nb.njit(cache=True, inline="always")
def transport_cov(f, c, tmp, out):
    """out = f·c·fᵀ (5×5), bitwise equal to `sandwich` (same products, same order of the
    sums, starting from 0.0; only terms that are exact zeros, f[i, k] = 0, are left out and
    products by f[i, k] = 1 taken as they are), for the Jacobians of known structure:
    the VELO step (`is_straight_velo`: ~30 multiply–adds instead of 200) and any step
    that keeps q/p (`is_unit_last_row`: 150); otherwise `sandwich`. tmp is 5×5 scratch;
    out may be c, not f or tmp. For finite inputs."""
    if is_straight_velo(f):
        a = f[0, 2]
        b = f[0, 4]
        d = f[1, 3]
        e = f[2, 4]
        for j in range(5):
            tmp[0, j] = fma(b, c[4, j], fma(a, c[2, j], 0.0 + c[0, j]))
            tmp[1, j] = fma(d, c[3, j], 0.0 + c[1, j])
            tmp[2, j] = fma(e, c[4, j], 0.0 + c[2, j])
            tmp[3, j] = 0.0 + c[3, j]
            tmp[4, j] = 0.0 + c[4, j]
        for i in range(5):
            t0 = fma(b, tmp[i, 4], fma(a, tmp[i, 2], 0.0 + tmp[i, 0]))
            t1 = fma(d, tmp[i, 3], 0.0 + tmp[i, 1])
            t2 = fma(e, tmp[i, 4], 0.0 + tmp[i, 2])
            t3 = 0.0 + tmp[i, 3]
            t4 = 0.0 + tmp[i, 4]
            if i <= 0:
                out[0, i] = t0
                out[i, 0] = t0
            if i <= 1:
                out[1, i] = t1
                out[i, 1] = t1
            if i <= 2:
                out[2, i] = t2
                out[i, 2] = t2
            if i <= 3:
                out[3, i] = t3
                out[i, 3] = t3
            out[4, i] = t4
            out[i, 4] = t4
        return
    if is_unit_last_row(f):
        for i in range(4):
            for j in range(5):
                s = 0.0
                for k in range(5):
                    s = fma(f[i, k], c[k, j], s)
                tmp[i, j] = s
        for j in range(5):
            tmp[4, j] = 0.0 + c[4, j]
        for i in range(5):
            for j in range(i, 4):
                s = 0.0
                for k in range(5):
                    s = fma(tmp[i, k], f[j, k], s)
                out[i, j] = s
                out[j, i] = s
            out[i, 4] = 0.0 + tmp[i, 4]
            out[4, i] = out[i, 4]
        return
    sandwich(f, c, tmp, out)


@nb.njit(cache=True, inline="always")
def transport_info(f, a, tmp, out):
    """out = fᵀ·a·f (5×5, not symmetrised), bitwise equal to `matmul55` (tmp = a·f) then
    `matmul55_tn` (out = fᵀ·tmp), with the exact-zero terms of a VELO step's f left out
    (`is_straight_velo`, as in `transport_cov`): ~40 multiply–adds instead of 250; of a
    step that keeps q/p (`is_unit_last_row`): 210. out must not alias f or tmp; for finite
    inputs."""
    if is_straight_velo(f):
        p = f[0, 2]
        b = f[0, 4]
        d = f[1, 3]
        e = f[2, 4]
        for i in range(5):
            tmp[i, 0] = 0.0 + a[i, 0]
            tmp[i, 1] = 0.0 + a[i, 1]
            tmp[i, 2] = fma(a[i, 0], p, 0.0) + a[i, 2]
            tmp[i, 3] = fma(a[i, 1], d, 0.0) + a[i, 3]
            tmp[i, 4] = fma(a[i, 2], e, fma(a[i, 0], b, 0.0)) + a[i, 4]
        for j in range(5):
            out[0, j] = 0.0 + tmp[0, j]
            out[1, j] = 0.0 + tmp[1, j]
            out[2, j] = fma(p, tmp[0, j], 0.0) + tmp[2, j]
            out[3, j] = fma(d, tmp[1, j], 0.0) + tmp[3, j]
            out[4, j] = fma(e, tmp[2, j], fma(b, tmp[0, j], 0.0)) + tmp[4, j]
        return
    if is_unit_last_row(f):  # the terms of f's last row (0, 0, 0, 0, 1) are exact zeros and ones
        for i in range(5):
            for j in range(4):
                s = 0.0
                for k in range(4):
                    s = fma(a[i, k], f[k, j], s)
                tmp[i, j] = s
            s = 0.0
            for k in range(4):
                s = fma(a[i, k], f[k, 4], s)
            tmp[i, 4] = s + a[i, 4]
        for j in range(5):
            for i in range(4):
                s = 0.0
                for k in range(4):
                    s = fma(f[k, i], tmp[k, j], s)
                out[i, j] = s
            s = 0.0
            for k in range(4):
                s = fma(f[k, 4], tmp[k, j], s)
            out[4, j] = s + tmp[4, j]
        return
    matmul55(a, f, tmp)
    matmul55_tn(f, tmp, out)


@nb.njit(cache=True, inline="always")
def is_block_noise(q):
    """True if the 5×5 process noise q couples only x with tx and y with ty and leaves q/p
    alone: zero except q[0|2, 0|2] and q[1|3, 1|3] (paper eq. 11, `parametrized_noise`, and
    the Highland noise of a thin plane in the reference's straight-line limit)."""
    return (
        q[0, 1] == 0.0
        and q[0, 3] == 0.0
        and q[0, 4] == 0.0
        and q[1, 0] == 0.0
        and q[1, 2] == 0.0
        and q[1, 4] == 0.0
        and q[2, 1] == 0.0
        and q[2, 3] == 0.0
        and q[2, 4] == 0.0
        and q[3, 0] == 0.0
        and q[3, 2] == 0.0
        and q[3, 4] == 0.0
        and q[4, 0] == 0.0
        and q[4, 1] == 0.0
        and q[4, 2] == 0.0
        and q[4, 3] == 0.0
        and q[4, 4] == 0.0
    )


@nb.njit(cache=True, inline="always")
def matmul_noise(a, q, out):
    """out = a·q (5×5), bitwise equal to `matmul55`, with the exact-zero terms of a
    block-structured noise q left out (`is_block_noise`: 40 multiply–adds instead of 125);
    otherwise `matmul55`. out must not alias a or q; for finite inputs."""
    if is_block_noise(q):
        for i in range(5):
            out[i, 0] = fma(a[i, 2], q[2, 0], fma(a[i, 0], q[0, 0], 0.0))
            out[i, 1] = fma(a[i, 3], q[3, 1], fma(a[i, 1], q[1, 1], 0.0))
            out[i, 2] = fma(a[i, 2], q[2, 2], fma(a[i, 0], q[0, 2], 0.0))
            out[i, 3] = fma(a[i, 3], q[3, 3], fma(a[i, 1], q[1, 3], 0.0))
            out[i, 4] = 0.0
        return
    matmul55(a, q, out)


@nb.njit(cache=True, inline="always")
def symmetrise(a):
    """a = (a + aᵀ)/2 in place (5×5)."""
    for i in range(5):
        for j in range(i + 1, 5):
            m = 0.5 * (a[i, j] + a[j, i])
            a[i, j] = m
            a[j, i] = m


@nb.njit(cache=True, inline="always")
def equilibrated_cholesky(a, work, scale):
    """Lower Cholesky factor L (in work, 5×5) of a′ = D·a·D, D = diag(scale), scale[i] =
    1/√a_ii written into scale (5): the common first half of `invert_spd` and
    `invert_spd_triangular`. Returns False if a is not positive definite."""
    n = 5
    for i in range(n):
        if not a[i, i] > 0.0:
            return False
        scale[i] = 1.0 / math.sqrt(a[i, i])
    for j in range(n):
        s = a[j, j] * scale[j] * scale[j]
        for k in range(j):
            s = fma(-work[j, k], work[j, k], s)
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        work[j, j] = d
        for i in range(j + 1, n):
            t = a[i, j] * scale[i] * scale[j]
            for k in range(j):
                t = fma(-work[i, k], work[j, k], t)
            work[i, j] = t / d
    return True


@nb.njit(cache=True, inline="always")
def invert_spd(a, out, work, vec):
    """out = a⁻¹ for a symmetric positive-definite 5×5 matrix.

    The matrix is first equilibrated, a′ = D·a·D with D = diag(1/√a_ii), so that the
    result is accurate however differently the parameters are scaled (mm, slopes,
    1/MeV), then inverted by Cholesky a′ = L·Lᵀ, and a⁻¹ = D·a′⁻¹·D. work (5×5) and
    vec (10) are scratch. Returns False (out undefined) if a is not positive definite.
    """
    n = 5
    scale = vec[5:10]
    col = vec[0:5]
    if not equilibrated_cholesky(a, work, scale):
        return False
    for c in range(n):
        # column c of a′⁻¹: solve L·y = e_c, then Lᵀ·x = y
        for i in range(n):
            t = 1.0 if i == c else 0.0
            for k in range(i):
                t = fma(-work[i, k], col[k], t)
            col[i] = t / work[i, i]
        for i in range(n - 1, -1, -1):
            t = col[i]
            for k in range(i + 1, n):
                t = fma(-work[k, i], out[k, c], t)
            out[i, c] = t / work[i, i]
    for i in range(n):
        for j in range(n):
            out[i, j] *= scale[i] * scale[j]
    symmetrise(out)
    return True


@nb.njit(cache=True, inline="always")
def invert_spd_triangular(a, out, work, vec):
    """out = a⁻¹ for a symmetric positive-definite 5×5 matrix, as `invert_spd` (same
    equilibration and Cholesky factor a′ = L·Lᵀ, same failures) but through the inverse
    of the factor (LAPACK's potri): L⁻¹ in place of L, then a′⁻¹ = L⁻ᵀ·L⁻¹ on one triangle.
    20 divisions instead of 65 and about half the products; equal to `invert_spd` up to
    rounding (not bitwise). work (5×5) and vec (≥ 5) are scratch; out is exactly symmetric.
    """
    n = 5
    scale = vec[0:5]
    if not equilibrated_cholesky(a, work, scale):
        return False
    # L⁻¹ in place, last column first; within a column from the bottom, so that the
    # entries of L still needed (rows above) are not yet overwritten
    for j in range(n - 1, -1, -1):
        inv_d = 1.0 / work[j, j]
        for i in range(n - 1, j, -1):
            t = 0.0
            for k in range(j + 1, i + 1):
                t = fma(work[i, k], work[k, j], t)
            work[i, j] = -t * inv_d
        work[j, j] = inv_d
    # a⁻¹ = D·(L⁻ᵀ·L⁻¹)·D, one triangle
    for i in range(n):
        for j in range(i, n):
            t = 0.0
            for k in range(j, n):
                t = fma(work[k, i], work[k, j], t)
            v = t * scale[i] * scale[j]
            out[i, j] = v
            out[j, i] = v
    return True


@nb.njit(cache=True, inline="always")
def invert_spd_ldl(a, out, work, dinv):
    """out = a⁻¹ for a symmetric positive-definite 5×5 matrix through a = L·D·Lᵀ (L unit
    lower triangular, D diagonal: no square roots) and a⁻¹ = L⁻ᵀ·D⁻¹·L⁻¹ on one triangle.

    Five divisions (the reciprocal pivots) and ~130 multiply–adds: about half the latency
    of `invert_spd_triangular`, whose equilibration a′ = S·a·S adds ten square roots and
    five divisions without making the result more accurate — a triangular factorisation
    without pivoting commutes with a diagonal scaling (S·L·S⁻¹ and S·D·S), so its
    rounding errors are those of the equilibrated matrix already (van der Sluis); scaling
    only protects against over- and underflow, far away for covariances in mm and 1/MeV.
    Equal to `invert_spd_triangular` up to rounding (not bitwise). work (5×5): L below
    the diagonal, above it first (L·D)ᵀ, then (L⁻¹)ᵀ; dinv (≥ 5): D⁻¹. Returns False
    (out undefined) if a pivot is not positive (a not positive definite, or NaN).
    """
    for j in range(5):
        d = a[j, j]
        for k in range(j):
            d = fma(-work[j, k], work[k, j], d)
        if not d > 0.0:
            return False
        r = 1.0 / d
        dinv[j] = r
        for i in range(j + 1, 5):
            t = a[i, j]
            for k in range(j):
                t = fma(-work[i, k], work[k, j], t)
            work[j, i] = t  # L[i, j]·D[j], read by the later columns
            work[i, j] = t * r
    # L⁻¹ (unit lower), stored transposed above the diagonal: work[j, i] = (L⁻¹)[i, j], i > j
    for j in range(4):
        for i in range(j + 1, 5):
            t = -work[i, j]
            for k in range(j + 1, i):
                t = fma(-work[i, k], work[j, k], t)
            work[j, i] = t
    # a⁻¹[i, j] = Σ_{k ≥ j} (L⁻¹)[k, i]·D⁻¹[k]·(L⁻¹)[k, j], i ≤ j, (L⁻¹)[k, k] = 1
    for i in range(5):
        for j in range(i, 5):
            t = dinv[j] * (work[i, j] if j > i else 1.0)
            for k in range(j + 1, 5):
                t = fma(work[i, k] * dinv[k], work[j, k], t)
            out[i, j] = t
            out[j, i] = t
    return True


#: Lanes of the vectorised kernels (`invert_spd_ldl_lanes`): 8 float64, one AVX-512 register
#: or two AVX2 ones.
LANES = 8


# ---- generated by pkf.physics.lanes_codegen: do not edit ----
@nb.njit(cache=True, inline="always")
def invert_spd_ldl_lane(a, out, bad, l):
    """`invert_spd_ldl` of lane l of a stack of matrices: out[:, :, l] = a[:, :, l]⁻¹ (a, out:
    5×5×lanes, different arrays; bad: lanes), the same operations in the same order as
    `invert_spd_ldl` (bitwise the same out), written out as straight-line code
    (`pkf.physics.lanes_codegen`): called in a loop over the lanes, it is the body of that
    loop, which LLVM's loop vectoriser issues as SIMD instructions over the lanes. The
    factor's entries are scalars: u{j}{i} (i > j) holds work[j, i] of `invert_spd_ldl`
    (first L[i, j]·D[j], then L⁻¹[i, j]), w{i}{j} = L[i, j], r{j} = 1/D[j]. No early
    return: a lane whose pivot is not positive (or NaN) gets bad[l] = 1 (set, never
    cleared) and an undefined out; compile the caller with error_model="numpy" (such a
    lane may divide by zero)."""
    d = a[0, 0, l]
    bad[l] = bad[l] if d > 0.0 else 1.0
    r0 = 1.0 / d
    t = a[1, 0, l]
    u01 = t
    w10 = t * r0
    t = a[2, 0, l]
    u02 = t
    w20 = t * r0
    t = a[3, 0, l]
    u03 = t
    w30 = t * r0
    t = a[4, 0, l]
    u04 = t
    w40 = t * r0
    d = a[1, 1, l]
    d = fma(-w10, u01, d)
    bad[l] = bad[l] if d > 0.0 else 1.0
    r1 = 1.0 / d
    t = a[2, 1, l]
    t = fma(-w20, u01, t)
    u12 = t
    w21 = t * r1
    t = a[3, 1, l]
    t = fma(-w30, u01, t)
    u13 = t
    w31 = t * r1
    t = a[4, 1, l]
    t = fma(-w40, u01, t)
    u14 = t
    w41 = t * r1
    d = a[2, 2, l]
    d = fma(-w20, u02, d)
    d = fma(-w21, u12, d)
    bad[l] = bad[l] if d > 0.0 else 1.0
    r2 = 1.0 / d
    t = a[3, 2, l]
    t = fma(-w30, u02, t)
    t = fma(-w31, u12, t)
    u23 = t
    w32 = t * r2
    t = a[4, 2, l]
    t = fma(-w40, u02, t)
    t = fma(-w41, u12, t)
    u24 = t
    w42 = t * r2
    d = a[3, 3, l]
    d = fma(-w30, u03, d)
    d = fma(-w31, u13, d)
    d = fma(-w32, u23, d)
    bad[l] = bad[l] if d > 0.0 else 1.0
    r3 = 1.0 / d
    t = a[4, 3, l]
    t = fma(-w40, u03, t)
    t = fma(-w41, u13, t)
    t = fma(-w42, u23, t)
    u34 = t
    w43 = t * r3
    d = a[4, 4, l]
    d = fma(-w40, u04, d)
    d = fma(-w41, u14, d)
    d = fma(-w42, u24, d)
    d = fma(-w43, u34, d)
    bad[l] = bad[l] if d > 0.0 else 1.0
    r4 = 1.0 / d
    t = -w10
    u01 = t
    t = -w20
    t = fma(-w21, u01, t)
    u02 = t
    t = -w30
    t = fma(-w31, u01, t)
    t = fma(-w32, u02, t)
    u03 = t
    t = -w40
    t = fma(-w41, u01, t)
    t = fma(-w42, u02, t)
    t = fma(-w43, u03, t)
    u04 = t
    t = -w21
    u12 = t
    t = -w31
    t = fma(-w32, u12, t)
    u13 = t
    t = -w41
    t = fma(-w42, u12, t)
    t = fma(-w43, u13, t)
    u14 = t
    t = -w32
    u23 = t
    t = -w42
    t = fma(-w43, u23, t)
    u24 = t
    t = -w43
    u34 = t
    t = r0 * 1.0
    t = fma(u01 * r1, u01, t)
    t = fma(u02 * r2, u02, t)
    t = fma(u03 * r3, u03, t)
    t = fma(u04 * r4, u04, t)
    out[0, 0, l] = t
    t = r1 * u01
    t = fma(u02 * r2, u12, t)
    t = fma(u03 * r3, u13, t)
    t = fma(u04 * r4, u14, t)
    out[0, 1, l] = t
    out[1, 0, l] = t
    t = r2 * u02
    t = fma(u03 * r3, u23, t)
    t = fma(u04 * r4, u24, t)
    out[0, 2, l] = t
    out[2, 0, l] = t
    t = r3 * u03
    t = fma(u04 * r4, u34, t)
    out[0, 3, l] = t
    out[3, 0, l] = t
    t = r4 * u04
    out[0, 4, l] = t
    out[4, 0, l] = t
    t = r1 * 1.0
    t = fma(u12 * r2, u12, t)
    t = fma(u13 * r3, u13, t)
    t = fma(u14 * r4, u14, t)
    out[1, 1, l] = t
    t = r2 * u12
    t = fma(u13 * r3, u23, t)
    t = fma(u14 * r4, u24, t)
    out[1, 2, l] = t
    out[2, 1, l] = t
    t = r3 * u13
    t = fma(u14 * r4, u34, t)
    out[1, 3, l] = t
    out[3, 1, l] = t
    t = r4 * u14
    out[1, 4, l] = t
    out[4, 1, l] = t
    t = r2 * 1.0
    t = fma(u23 * r3, u23, t)
    t = fma(u24 * r4, u24, t)
    out[2, 2, l] = t
    t = r3 * u23
    t = fma(u24 * r4, u34, t)
    out[2, 3, l] = t
    out[3, 2, l] = t
    t = r4 * u24
    out[2, 4, l] = t
    out[4, 2, l] = t
    t = r3 * 1.0
    t = fma(u34 * r4, u34, t)
    out[3, 3, l] = t
    t = r4 * u34
    out[3, 4, l] = t
    out[4, 3, l] = t
    t = r4 * 1.0
    out[4, 4, l] = t


@nb.njit(cache=True, inline="always", error_model="numpy")
def solve5(a, b, v):
    """b ← a⁻¹·b (5×5) and v ← a⁻¹·v (5) for a general 5×5 matrix a: the Gaussian
    elimination with partial pivoting of `pkf.fit.kalman._solve_general` (bitwise its b and
    v), written out as straight-line code on scalars (`pkf.physics.lanes_codegen`): each
    column's pivot search, the swap of the pivot row into place (entries of a left of the
    column are dead and not swapped), the elimination, then the back substitution. a is
    read only. Returns False, with b and v untouched, if a pivot is zero or not finite
    (`_solve_general` returns False there too, having written part of them). Compile the
    caller with error_model="numpy" (a rejected pivot may divide by zero)."""
    a00, a01, a02, a03, a04 = a[0, 0], a[0, 1], a[0, 2], a[0, 3], a[0, 4]
    a10, a11, a12, a13, a14 = a[1, 0], a[1, 1], a[1, 2], a[1, 3], a[1, 4]
    a20, a21, a22, a23, a24 = a[2, 0], a[2, 1], a[2, 2], a[2, 3], a[2, 4]
    a30, a31, a32, a33, a34 = a[3, 0], a[3, 1], a[3, 2], a[3, 3], a[3, 4]
    a40, a41, a42, a43, a44 = a[4, 0], a[4, 1], a[4, 2], a[4, 3], a[4, 4]
    b00, b01, b02, b03, b04 = b[0, 0], b[0, 1], b[0, 2], b[0, 3], b[0, 4]
    b10, b11, b12, b13, b14 = b[1, 0], b[1, 1], b[1, 2], b[1, 3], b[1, 4]
    b20, b21, b22, b23, b24 = b[2, 0], b[2, 1], b[2, 2], b[2, 3], b[2, 4]
    b30, b31, b32, b33, b34 = b[3, 0], b[3, 1], b[3, 2], b[3, 3], b[3, 4]
    b40, b41, b42, b43, b44 = b[4, 0], b[4, 1], b[4, 2], b[4, 3], b[4, 4]
    v0, v1, v2, v3, v4 = v[0], v[1], v[2], v[3], v[4]
    bad = False
    best = abs(a00)
    pivot = 0
    if abs(a10) > best:
        best = abs(a10)
        pivot = 1
    if abs(a20) > best:
        best = abs(a20)
        pivot = 2
    if abs(a30) > best:
        best = abs(a30)
        pivot = 3
    if abs(a40) > best:
        best = abs(a40)
        pivot = 4
    bad = bad | (not (best > 0.0 and best < math.inf))
    if pivot == 1:
        a00, a10 = a10, a00
        a01, a11 = a11, a01
        a02, a12 = a12, a02
        a03, a13 = a13, a03
        a04, a14 = a14, a04
        b00, b10 = b10, b00
        b01, b11 = b11, b01
        b02, b12 = b12, b02
        b03, b13 = b13, b03
        b04, b14 = b14, b04
        v0, v1 = v1, v0
    if pivot == 2:
        a00, a20 = a20, a00
        a01, a21 = a21, a01
        a02, a22 = a22, a02
        a03, a23 = a23, a03
        a04, a24 = a24, a04
        b00, b20 = b20, b00
        b01, b21 = b21, b01
        b02, b22 = b22, b02
        b03, b23 = b23, b03
        b04, b24 = b24, b04
        v0, v2 = v2, v0
    if pivot == 3:
        a00, a30 = a30, a00
        a01, a31 = a31, a01
        a02, a32 = a32, a02
        a03, a33 = a33, a03
        a04, a34 = a34, a04
        b00, b30 = b30, b00
        b01, b31 = b31, b01
        b02, b32 = b32, b02
        b03, b33 = b33, b03
        b04, b34 = b34, b04
        v0, v3 = v3, v0
    if pivot == 4:
        a00, a40 = a40, a00
        a01, a41 = a41, a01
        a02, a42 = a42, a02
        a03, a43 = a43, a03
        a04, a44 = a44, a04
        b00, b40 = b40, b00
        b01, b41 = b41, b01
        b02, b42 = b42, b02
        b03, b43 = b43, b03
        b04, b44 = b44, b04
        v0, v4 = v4, v0
    a00 = 1.0 / a00
    f = a10 * a00
    a11 = fma(-f, a01, a11)
    a12 = fma(-f, a02, a12)
    a13 = fma(-f, a03, a13)
    a14 = fma(-f, a04, a14)
    b10 = fma(-f, b00, b10)
    b11 = fma(-f, b01, b11)
    b12 = fma(-f, b02, b12)
    b13 = fma(-f, b03, b13)
    b14 = fma(-f, b04, b14)
    v1 = fma(-f, v0, v1)
    f = a20 * a00
    a21 = fma(-f, a01, a21)
    a22 = fma(-f, a02, a22)
    a23 = fma(-f, a03, a23)
    a24 = fma(-f, a04, a24)
    b20 = fma(-f, b00, b20)
    b21 = fma(-f, b01, b21)
    b22 = fma(-f, b02, b22)
    b23 = fma(-f, b03, b23)
    b24 = fma(-f, b04, b24)
    v2 = fma(-f, v0, v2)
    f = a30 * a00
    a31 = fma(-f, a01, a31)
    a32 = fma(-f, a02, a32)
    a33 = fma(-f, a03, a33)
    a34 = fma(-f, a04, a34)
    b30 = fma(-f, b00, b30)
    b31 = fma(-f, b01, b31)
    b32 = fma(-f, b02, b32)
    b33 = fma(-f, b03, b33)
    b34 = fma(-f, b04, b34)
    v3 = fma(-f, v0, v3)
    f = a40 * a00
    a41 = fma(-f, a01, a41)
    a42 = fma(-f, a02, a42)
    a43 = fma(-f, a03, a43)
    a44 = fma(-f, a04, a44)
    b40 = fma(-f, b00, b40)
    b41 = fma(-f, b01, b41)
    b42 = fma(-f, b02, b42)
    b43 = fma(-f, b03, b43)
    b44 = fma(-f, b04, b44)
    v4 = fma(-f, v0, v4)
    best = abs(a11)
    pivot = 1
    if abs(a21) > best:
        best = abs(a21)
        pivot = 2
    if abs(a31) > best:
        best = abs(a31)
        pivot = 3
    if abs(a41) > best:
        best = abs(a41)
        pivot = 4
    bad = bad | (not (best > 0.0 and best < math.inf))
    if pivot == 2:
        a11, a21 = a21, a11
        a12, a22 = a22, a12
        a13, a23 = a23, a13
        a14, a24 = a24, a14
        b10, b20 = b20, b10
        b11, b21 = b21, b11
        b12, b22 = b22, b12
        b13, b23 = b23, b13
        b14, b24 = b24, b14
        v1, v2 = v2, v1
    if pivot == 3:
        a11, a31 = a31, a11
        a12, a32 = a32, a12
        a13, a33 = a33, a13
        a14, a34 = a34, a14
        b10, b30 = b30, b10
        b11, b31 = b31, b11
        b12, b32 = b32, b12
        b13, b33 = b33, b13
        b14, b34 = b34, b14
        v1, v3 = v3, v1
    if pivot == 4:
        a11, a41 = a41, a11
        a12, a42 = a42, a12
        a13, a43 = a43, a13
        a14, a44 = a44, a14
        b10, b40 = b40, b10
        b11, b41 = b41, b11
        b12, b42 = b42, b12
        b13, b43 = b43, b13
        b14, b44 = b44, b14
        v1, v4 = v4, v1
    a11 = 1.0 / a11
    f = a21 * a11
    a22 = fma(-f, a12, a22)
    a23 = fma(-f, a13, a23)
    a24 = fma(-f, a14, a24)
    b20 = fma(-f, b10, b20)
    b21 = fma(-f, b11, b21)
    b22 = fma(-f, b12, b22)
    b23 = fma(-f, b13, b23)
    b24 = fma(-f, b14, b24)
    v2 = fma(-f, v1, v2)
    f = a31 * a11
    a32 = fma(-f, a12, a32)
    a33 = fma(-f, a13, a33)
    a34 = fma(-f, a14, a34)
    b30 = fma(-f, b10, b30)
    b31 = fma(-f, b11, b31)
    b32 = fma(-f, b12, b32)
    b33 = fma(-f, b13, b33)
    b34 = fma(-f, b14, b34)
    v3 = fma(-f, v1, v3)
    f = a41 * a11
    a42 = fma(-f, a12, a42)
    a43 = fma(-f, a13, a43)
    a44 = fma(-f, a14, a44)
    b40 = fma(-f, b10, b40)
    b41 = fma(-f, b11, b41)
    b42 = fma(-f, b12, b42)
    b43 = fma(-f, b13, b43)
    b44 = fma(-f, b14, b44)
    v4 = fma(-f, v1, v4)
    best = abs(a22)
    pivot = 2
    if abs(a32) > best:
        best = abs(a32)
        pivot = 3
    if abs(a42) > best:
        best = abs(a42)
        pivot = 4
    bad = bad | (not (best > 0.0 and best < math.inf))
    if pivot == 3:
        a22, a32 = a32, a22
        a23, a33 = a33, a23
        a24, a34 = a34, a24
        b20, b30 = b30, b20
        b21, b31 = b31, b21
        b22, b32 = b32, b22
        b23, b33 = b33, b23
        b24, b34 = b34, b24
        v2, v3 = v3, v2
    if pivot == 4:
        a22, a42 = a42, a22
        a23, a43 = a43, a23
        a24, a44 = a44, a24
        b20, b40 = b40, b20
        b21, b41 = b41, b21
        b22, b42 = b42, b22
        b23, b43 = b43, b23
        b24, b44 = b44, b24
        v2, v4 = v4, v2
    a22 = 1.0 / a22
    f = a32 * a22
    a33 = fma(-f, a23, a33)
    a34 = fma(-f, a24, a34)
    b30 = fma(-f, b20, b30)
    b31 = fma(-f, b21, b31)
    b32 = fma(-f, b22, b32)
    b33 = fma(-f, b23, b33)
    b34 = fma(-f, b24, b34)
    v3 = fma(-f, v2, v3)
    f = a42 * a22
    a43 = fma(-f, a23, a43)
    a44 = fma(-f, a24, a44)
    b40 = fma(-f, b20, b40)
    b41 = fma(-f, b21, b41)
    b42 = fma(-f, b22, b42)
    b43 = fma(-f, b23, b43)
    b44 = fma(-f, b24, b44)
    v4 = fma(-f, v2, v4)
    best = abs(a33)
    pivot = 3
    if abs(a43) > best:
        best = abs(a43)
        pivot = 4
    bad = bad | (not (best > 0.0 and best < math.inf))
    if pivot == 4:
        a33, a43 = a43, a33
        a34, a44 = a44, a34
        b30, b40 = b40, b30
        b31, b41 = b41, b31
        b32, b42 = b42, b32
        b33, b43 = b43, b33
        b34, b44 = b44, b34
        v3, v4 = v4, v3
    a33 = 1.0 / a33
    f = a43 * a33
    a44 = fma(-f, a34, a44)
    b40 = fma(-f, b30, b40)
    b41 = fma(-f, b31, b41)
    b42 = fma(-f, b32, b42)
    b43 = fma(-f, b33, b43)
    b44 = fma(-f, b34, b44)
    v4 = fma(-f, v3, v4)
    best = abs(a44)
    pivot = 4
    bad = bad | (not (best > 0.0 and best < math.inf))
    a44 = 1.0 / a44
    if bad:
        return False
    t = b40
    b40 = t * a44
    t = b41
    b41 = t * a44
    t = b42
    b42 = t * a44
    t = b43
    b43 = t * a44
    t = b44
    b44 = t * a44
    t = v4
    v4 = t * a44
    t = b30
    t = fma(-a34, b40, t)
    b30 = t * a33
    t = b31
    t = fma(-a34, b41, t)
    b31 = t * a33
    t = b32
    t = fma(-a34, b42, t)
    b32 = t * a33
    t = b33
    t = fma(-a34, b43, t)
    b33 = t * a33
    t = b34
    t = fma(-a34, b44, t)
    b34 = t * a33
    t = v3
    t = fma(-a34, v4, t)
    v3 = t * a33
    t = b20
    t = fma(-a23, b30, t)
    t = fma(-a24, b40, t)
    b20 = t * a22
    t = b21
    t = fma(-a23, b31, t)
    t = fma(-a24, b41, t)
    b21 = t * a22
    t = b22
    t = fma(-a23, b32, t)
    t = fma(-a24, b42, t)
    b22 = t * a22
    t = b23
    t = fma(-a23, b33, t)
    t = fma(-a24, b43, t)
    b23 = t * a22
    t = b24
    t = fma(-a23, b34, t)
    t = fma(-a24, b44, t)
    b24 = t * a22
    t = v2
    t = fma(-a23, v3, t)
    t = fma(-a24, v4, t)
    v2 = t * a22
    t = b10
    t = fma(-a12, b20, t)
    t = fma(-a13, b30, t)
    t = fma(-a14, b40, t)
    b10 = t * a11
    t = b11
    t = fma(-a12, b21, t)
    t = fma(-a13, b31, t)
    t = fma(-a14, b41, t)
    b11 = t * a11
    t = b12
    t = fma(-a12, b22, t)
    t = fma(-a13, b32, t)
    t = fma(-a14, b42, t)
    b12 = t * a11
    t = b13
    t = fma(-a12, b23, t)
    t = fma(-a13, b33, t)
    t = fma(-a14, b43, t)
    b13 = t * a11
    t = b14
    t = fma(-a12, b24, t)
    t = fma(-a13, b34, t)
    t = fma(-a14, b44, t)
    b14 = t * a11
    t = v1
    t = fma(-a12, v2, t)
    t = fma(-a13, v3, t)
    t = fma(-a14, v4, t)
    v1 = t * a11
    t = b00
    t = fma(-a01, b10, t)
    t = fma(-a02, b20, t)
    t = fma(-a03, b30, t)
    t = fma(-a04, b40, t)
    b00 = t * a00
    t = b01
    t = fma(-a01, b11, t)
    t = fma(-a02, b21, t)
    t = fma(-a03, b31, t)
    t = fma(-a04, b41, t)
    b01 = t * a00
    t = b02
    t = fma(-a01, b12, t)
    t = fma(-a02, b22, t)
    t = fma(-a03, b32, t)
    t = fma(-a04, b42, t)
    b02 = t * a00
    t = b03
    t = fma(-a01, b13, t)
    t = fma(-a02, b23, t)
    t = fma(-a03, b33, t)
    t = fma(-a04, b43, t)
    b03 = t * a00
    t = b04
    t = fma(-a01, b14, t)
    t = fma(-a02, b24, t)
    t = fma(-a03, b34, t)
    t = fma(-a04, b44, t)
    b04 = t * a00
    t = v0
    t = fma(-a01, v1, t)
    t = fma(-a02, v2, t)
    t = fma(-a03, v3, t)
    t = fma(-a04, v4, t)
    v0 = t * a00
    b[0, 0], b[0, 1], b[0, 2], b[0, 3], b[0, 4] = b00, b01, b02, b03, b04
    b[1, 0], b[1, 1], b[1, 2], b[1, 3], b[1, 4] = b10, b11, b12, b13, b14
    b[2, 0], b[2, 1], b[2, 2], b[2, 3], b[2, 4] = b20, b21, b22, b23, b24
    b[3, 0], b[3, 1], b[3, 2], b[3, 3], b[3, 4] = b30, b31, b32, b33, b34
    b[4, 0], b[4, 1], b[4, 2], b[4, 3], b[4, 4] = b40, b41, b42, b43, b44
    v[0], v[1], v[2], v[3], v[4] = v0, v1, v2, v3, v4
    return True


@nb.njit(cache=True, inline="always")
def info_step_lane(info, info_vec, f, q, xp, xf, bad, l):
    """Lane l of the backward information filter's step from node k to k−1
    (`pkf.fit.kalman._backward_information_filter`): with F = f, Q = q (node k's
    transport) and a = F·(xp − xf) (node k−1's forward prediction and filtered state),
    y ← y − Y·a, M = (I + Y·Q)⁻¹ (the pivoting solve of `solve5`, its row swaps as
    selects), Y ← Fᵀ·(M·Y)·F symmetrised, y ← Fᵀ·M·y: the same operations in the same
    order as the scalar step with dense products (`matvec5`, `matmul55` for
    `matmul_noise`, `transport_info`, `symmetrise`, `matvec5_t`): bitwise its Y and y for
    finite inputs. A lane whose solve meets a zero or non-finite pivot gets bad[l] = 1
    (Y, y then undefined). Straight-line (`pkf.physics.lanes_codegen`); compile the
    caller with error_model="numpy"."""
    y00, y01, y02, y03, y04 = info[0, 0, l], info[0, 1, l], info[0, 2, l], info[0, 3, l], info[0, 4, l]
    y10, y11, y12, y13, y14 = info[1, 0, l], info[1, 1, l], info[1, 2, l], info[1, 3, l], info[1, 4, l]
    y20, y21, y22, y23, y24 = info[2, 0, l], info[2, 1, l], info[2, 2, l], info[2, 3, l], info[2, 4, l]
    y30, y31, y32, y33, y34 = info[3, 0, l], info[3, 1, l], info[3, 2, l], info[3, 3, l], info[3, 4, l]
    y40, y41, y42, y43, y44 = info[4, 0, l], info[4, 1, l], info[4, 2, l], info[4, 3, l], info[4, 4, l]
    f00, f01, f02, f03, f04 = f[0, 0, l], f[0, 1, l], f[0, 2, l], f[0, 3, l], f[0, 4, l]
    f10, f11, f12, f13, f14 = f[1, 0, l], f[1, 1, l], f[1, 2, l], f[1, 3, l], f[1, 4, l]
    f20, f21, f22, f23, f24 = f[2, 0, l], f[2, 1, l], f[2, 2, l], f[2, 3, l], f[2, 4, l]
    f30, f31, f32, f33, f34 = f[3, 0, l], f[3, 1, l], f[3, 2, l], f[3, 3, l], f[3, 4, l]
    f40, f41, f42, f43, f44 = f[4, 0, l], f[4, 1, l], f[4, 2, l], f[4, 3, l], f[4, 4, l]
    q00, q01, q02, q03, q04 = q[0, 0, l], q[0, 1, l], q[0, 2, l], q[0, 3, l], q[0, 4, l]
    q10, q11, q12, q13, q14 = q[1, 0, l], q[1, 1, l], q[1, 2, l], q[1, 3, l], q[1, 4, l]
    q20, q21, q22, q23, q24 = q[2, 0, l], q[2, 1, l], q[2, 2, l], q[2, 3, l], q[2, 4, l]
    q30, q31, q32, q33, q34 = q[3, 0, l], q[3, 1, l], q[3, 2, l], q[3, 3, l], q[3, 4, l]
    q40, q41, q42, q43, q44 = q[4, 0, l], q[4, 1, l], q[4, 2, l], q[4, 3, l], q[4, 4, l]
    w0, w1, w2, w3, w4 = info_vec[0, l], info_vec[1, l], info_vec[2, l], info_vec[3, l], info_vec[4, l]
    d0 = xp[0, l] - xf[0, l]
    d1 = xp[1, l] - xf[1, l]
    d2 = xp[2, l] - xf[2, l]
    d3 = xp[3, l] - xf[3, l]
    d4 = xp[4, l] - xf[4, l]
    s = 0.0
    s = fma(f00, d0, s)
    s = fma(f01, d1, s)
    s = fma(f02, d2, s)
    s = fma(f03, d3, s)
    s = fma(f04, d4, s)
    g0 = s
    s = 0.0
    s = fma(f10, d0, s)
    s = fma(f11, d1, s)
    s = fma(f12, d2, s)
    s = fma(f13, d3, s)
    s = fma(f14, d4, s)
    g1 = s
    s = 0.0
    s = fma(f20, d0, s)
    s = fma(f21, d1, s)
    s = fma(f22, d2, s)
    s = fma(f23, d3, s)
    s = fma(f24, d4, s)
    g2 = s
    s = 0.0
    s = fma(f30, d0, s)
    s = fma(f31, d1, s)
    s = fma(f32, d2, s)
    s = fma(f33, d3, s)
    s = fma(f34, d4, s)
    g3 = s
    s = 0.0
    s = fma(f40, d0, s)
    s = fma(f41, d1, s)
    s = fma(f42, d2, s)
    s = fma(f43, d3, s)
    s = fma(f44, d4, s)
    g4 = s
    s = 0.0
    s = fma(y00, q00, s)
    s = fma(y01, q10, s)
    s = fma(y02, q20, s)
    s = fma(y03, q30, s)
    s = fma(y04, q40, s)
    a00 = s + 1.0
    s = 0.0
    s = fma(y00, q01, s)
    s = fma(y01, q11, s)
    s = fma(y02, q21, s)
    s = fma(y03, q31, s)
    s = fma(y04, q41, s)
    a01 = s
    s = 0.0
    s = fma(y00, q02, s)
    s = fma(y01, q12, s)
    s = fma(y02, q22, s)
    s = fma(y03, q32, s)
    s = fma(y04, q42, s)
    a02 = s
    s = 0.0
    s = fma(y00, q03, s)
    s = fma(y01, q13, s)
    s = fma(y02, q23, s)
    s = fma(y03, q33, s)
    s = fma(y04, q43, s)
    a03 = s
    s = 0.0
    s = fma(y00, q04, s)
    s = fma(y01, q14, s)
    s = fma(y02, q24, s)
    s = fma(y03, q34, s)
    s = fma(y04, q44, s)
    a04 = s
    s = 0.0
    s = fma(y10, q00, s)
    s = fma(y11, q10, s)
    s = fma(y12, q20, s)
    s = fma(y13, q30, s)
    s = fma(y14, q40, s)
    a10 = s
    s = 0.0
    s = fma(y10, q01, s)
    s = fma(y11, q11, s)
    s = fma(y12, q21, s)
    s = fma(y13, q31, s)
    s = fma(y14, q41, s)
    a11 = s + 1.0
    s = 0.0
    s = fma(y10, q02, s)
    s = fma(y11, q12, s)
    s = fma(y12, q22, s)
    s = fma(y13, q32, s)
    s = fma(y14, q42, s)
    a12 = s
    s = 0.0
    s = fma(y10, q03, s)
    s = fma(y11, q13, s)
    s = fma(y12, q23, s)
    s = fma(y13, q33, s)
    s = fma(y14, q43, s)
    a13 = s
    s = 0.0
    s = fma(y10, q04, s)
    s = fma(y11, q14, s)
    s = fma(y12, q24, s)
    s = fma(y13, q34, s)
    s = fma(y14, q44, s)
    a14 = s
    s = 0.0
    s = fma(y20, q00, s)
    s = fma(y21, q10, s)
    s = fma(y22, q20, s)
    s = fma(y23, q30, s)
    s = fma(y24, q40, s)
    a20 = s
    s = 0.0
    s = fma(y20, q01, s)
    s = fma(y21, q11, s)
    s = fma(y22, q21, s)
    s = fma(y23, q31, s)
    s = fma(y24, q41, s)
    a21 = s
    s = 0.0
    s = fma(y20, q02, s)
    s = fma(y21, q12, s)
    s = fma(y22, q22, s)
    s = fma(y23, q32, s)
    s = fma(y24, q42, s)
    a22 = s + 1.0
    s = 0.0
    s = fma(y20, q03, s)
    s = fma(y21, q13, s)
    s = fma(y22, q23, s)
    s = fma(y23, q33, s)
    s = fma(y24, q43, s)
    a23 = s
    s = 0.0
    s = fma(y20, q04, s)
    s = fma(y21, q14, s)
    s = fma(y22, q24, s)
    s = fma(y23, q34, s)
    s = fma(y24, q44, s)
    a24 = s
    s = 0.0
    s = fma(y30, q00, s)
    s = fma(y31, q10, s)
    s = fma(y32, q20, s)
    s = fma(y33, q30, s)
    s = fma(y34, q40, s)
    a30 = s
    s = 0.0
    s = fma(y30, q01, s)
    s = fma(y31, q11, s)
    s = fma(y32, q21, s)
    s = fma(y33, q31, s)
    s = fma(y34, q41, s)
    a31 = s
    s = 0.0
    s = fma(y30, q02, s)
    s = fma(y31, q12, s)
    s = fma(y32, q22, s)
    s = fma(y33, q32, s)
    s = fma(y34, q42, s)
    a32 = s
    s = 0.0
    s = fma(y30, q03, s)
    s = fma(y31, q13, s)
    s = fma(y32, q23, s)
    s = fma(y33, q33, s)
    s = fma(y34, q43, s)
    a33 = s + 1.0
    s = 0.0
    s = fma(y30, q04, s)
    s = fma(y31, q14, s)
    s = fma(y32, q24, s)
    s = fma(y33, q34, s)
    s = fma(y34, q44, s)
    a34 = s
    s = 0.0
    s = fma(y40, q00, s)
    s = fma(y41, q10, s)
    s = fma(y42, q20, s)
    s = fma(y43, q30, s)
    s = fma(y44, q40, s)
    a40 = s
    s = 0.0
    s = fma(y40, q01, s)
    s = fma(y41, q11, s)
    s = fma(y42, q21, s)
    s = fma(y43, q31, s)
    s = fma(y44, q41, s)
    a41 = s
    s = 0.0
    s = fma(y40, q02, s)
    s = fma(y41, q12, s)
    s = fma(y42, q22, s)
    s = fma(y43, q32, s)
    s = fma(y44, q42, s)
    a42 = s
    s = 0.0
    s = fma(y40, q03, s)
    s = fma(y41, q13, s)
    s = fma(y42, q23, s)
    s = fma(y43, q33, s)
    s = fma(y44, q43, s)
    a43 = s
    s = 0.0
    s = fma(y40, q04, s)
    s = fma(y41, q14, s)
    s = fma(y42, q24, s)
    s = fma(y43, q34, s)
    s = fma(y44, q44, s)
    a44 = s + 1.0
    s = w0
    s = fma(-y00, g0, s)
    s = fma(-y01, g1, s)
    s = fma(-y02, g2, s)
    s = fma(-y03, g3, s)
    s = fma(-y04, g4, s)
    v0 = s
    s = w1
    s = fma(-y10, g0, s)
    s = fma(-y11, g1, s)
    s = fma(-y12, g2, s)
    s = fma(-y13, g3, s)
    s = fma(-y14, g4, s)
    v1 = s
    s = w2
    s = fma(-y20, g0, s)
    s = fma(-y21, g1, s)
    s = fma(-y22, g2, s)
    s = fma(-y23, g3, s)
    s = fma(-y24, g4, s)
    v2 = s
    s = w3
    s = fma(-y30, g0, s)
    s = fma(-y31, g1, s)
    s = fma(-y32, g2, s)
    s = fma(-y33, g3, s)
    s = fma(-y34, g4, s)
    v3 = s
    s = w4
    s = fma(-y40, g0, s)
    s = fma(-y41, g1, s)
    s = fma(-y42, g2, s)
    s = fma(-y43, g3, s)
    s = fma(-y44, g4, s)
    v4 = s
    b00 = y00
    b01 = y01
    b02 = y02
    b03 = y03
    b04 = y04
    b10 = y10
    b11 = y11
    b12 = y12
    b13 = y13
    b14 = y14
    b20 = y20
    b21 = y21
    b22 = y22
    b23 = y23
    b24 = y24
    b30 = y30
    b31 = y31
    b32 = y32
    b33 = y33
    b34 = y34
    b40 = y40
    b41 = y41
    b42 = y42
    b43 = y43
    b44 = y44
    bad_l = bad[l]
    best = abs(a00)
    pivot = 0
    cnd = abs(a10) > best
    best = abs(a10) if cnd else best
    pivot = 1 if cnd else pivot
    cnd = abs(a20) > best
    best = abs(a20) if cnd else best
    pivot = 2 if cnd else pivot
    cnd = abs(a30) > best
    best = abs(a30) if cnd else best
    pivot = 3 if cnd else pivot
    cnd = abs(a40) > best
    best = abs(a40) if cnd else best
    pivot = 4 if cnd else pivot
    bad_l = bad_l if (best > 0.0 and best < math.inf) else 1.0
    sw = pivot == 1
    a00, a10 = (a10 if sw else a00), (a00 if sw else a10)
    a01, a11 = (a11 if sw else a01), (a01 if sw else a11)
    a02, a12 = (a12 if sw else a02), (a02 if sw else a12)
    a03, a13 = (a13 if sw else a03), (a03 if sw else a13)
    a04, a14 = (a14 if sw else a04), (a04 if sw else a14)
    b00, b10 = (b10 if sw else b00), (b00 if sw else b10)
    b01, b11 = (b11 if sw else b01), (b01 if sw else b11)
    b02, b12 = (b12 if sw else b02), (b02 if sw else b12)
    b03, b13 = (b13 if sw else b03), (b03 if sw else b13)
    b04, b14 = (b14 if sw else b04), (b04 if sw else b14)
    v0, v1 = (v1 if sw else v0), (v0 if sw else v1)
    sw = pivot == 2
    a00, a20 = (a20 if sw else a00), (a00 if sw else a20)
    a01, a21 = (a21 if sw else a01), (a01 if sw else a21)
    a02, a22 = (a22 if sw else a02), (a02 if sw else a22)
    a03, a23 = (a23 if sw else a03), (a03 if sw else a23)
    a04, a24 = (a24 if sw else a04), (a04 if sw else a24)
    b00, b20 = (b20 if sw else b00), (b00 if sw else b20)
    b01, b21 = (b21 if sw else b01), (b01 if sw else b21)
    b02, b22 = (b22 if sw else b02), (b02 if sw else b22)
    b03, b23 = (b23 if sw else b03), (b03 if sw else b23)
    b04, b24 = (b24 if sw else b04), (b04 if sw else b24)
    v0, v2 = (v2 if sw else v0), (v0 if sw else v2)
    sw = pivot == 3
    a00, a30 = (a30 if sw else a00), (a00 if sw else a30)
    a01, a31 = (a31 if sw else a01), (a01 if sw else a31)
    a02, a32 = (a32 if sw else a02), (a02 if sw else a32)
    a03, a33 = (a33 if sw else a03), (a03 if sw else a33)
    a04, a34 = (a34 if sw else a04), (a04 if sw else a34)
    b00, b30 = (b30 if sw else b00), (b00 if sw else b30)
    b01, b31 = (b31 if sw else b01), (b01 if sw else b31)
    b02, b32 = (b32 if sw else b02), (b02 if sw else b32)
    b03, b33 = (b33 if sw else b03), (b03 if sw else b33)
    b04, b34 = (b34 if sw else b04), (b04 if sw else b34)
    v0, v3 = (v3 if sw else v0), (v0 if sw else v3)
    sw = pivot == 4
    a00, a40 = (a40 if sw else a00), (a00 if sw else a40)
    a01, a41 = (a41 if sw else a01), (a01 if sw else a41)
    a02, a42 = (a42 if sw else a02), (a02 if sw else a42)
    a03, a43 = (a43 if sw else a03), (a03 if sw else a43)
    a04, a44 = (a44 if sw else a04), (a04 if sw else a44)
    b00, b40 = (b40 if sw else b00), (b00 if sw else b40)
    b01, b41 = (b41 if sw else b01), (b01 if sw else b41)
    b02, b42 = (b42 if sw else b02), (b02 if sw else b42)
    b03, b43 = (b43 if sw else b03), (b03 if sw else b43)
    b04, b44 = (b44 if sw else b04), (b04 if sw else b44)
    v0, v4 = (v4 if sw else v0), (v0 if sw else v4)
    a00 = 1.0 / a00
    e = a10 * a00
    a11 = fma(-e, a01, a11)
    a12 = fma(-e, a02, a12)
    a13 = fma(-e, a03, a13)
    a14 = fma(-e, a04, a14)
    b10 = fma(-e, b00, b10)
    b11 = fma(-e, b01, b11)
    b12 = fma(-e, b02, b12)
    b13 = fma(-e, b03, b13)
    b14 = fma(-e, b04, b14)
    v1 = fma(-e, v0, v1)
    e = a20 * a00
    a21 = fma(-e, a01, a21)
    a22 = fma(-e, a02, a22)
    a23 = fma(-e, a03, a23)
    a24 = fma(-e, a04, a24)
    b20 = fma(-e, b00, b20)
    b21 = fma(-e, b01, b21)
    b22 = fma(-e, b02, b22)
    b23 = fma(-e, b03, b23)
    b24 = fma(-e, b04, b24)
    v2 = fma(-e, v0, v2)
    e = a30 * a00
    a31 = fma(-e, a01, a31)
    a32 = fma(-e, a02, a32)
    a33 = fma(-e, a03, a33)
    a34 = fma(-e, a04, a34)
    b30 = fma(-e, b00, b30)
    b31 = fma(-e, b01, b31)
    b32 = fma(-e, b02, b32)
    b33 = fma(-e, b03, b33)
    b34 = fma(-e, b04, b34)
    v3 = fma(-e, v0, v3)
    e = a40 * a00
    a41 = fma(-e, a01, a41)
    a42 = fma(-e, a02, a42)
    a43 = fma(-e, a03, a43)
    a44 = fma(-e, a04, a44)
    b40 = fma(-e, b00, b40)
    b41 = fma(-e, b01, b41)
    b42 = fma(-e, b02, b42)
    b43 = fma(-e, b03, b43)
    b44 = fma(-e, b04, b44)
    v4 = fma(-e, v0, v4)
    best = abs(a11)
    pivot = 1
    cnd = abs(a21) > best
    best = abs(a21) if cnd else best
    pivot = 2 if cnd else pivot
    cnd = abs(a31) > best
    best = abs(a31) if cnd else best
    pivot = 3 if cnd else pivot
    cnd = abs(a41) > best
    best = abs(a41) if cnd else best
    pivot = 4 if cnd else pivot
    bad_l = bad_l if (best > 0.0 and best < math.inf) else 1.0
    sw = pivot == 2
    a11, a21 = (a21 if sw else a11), (a11 if sw else a21)
    a12, a22 = (a22 if sw else a12), (a12 if sw else a22)
    a13, a23 = (a23 if sw else a13), (a13 if sw else a23)
    a14, a24 = (a24 if sw else a14), (a14 if sw else a24)
    b10, b20 = (b20 if sw else b10), (b10 if sw else b20)
    b11, b21 = (b21 if sw else b11), (b11 if sw else b21)
    b12, b22 = (b22 if sw else b12), (b12 if sw else b22)
    b13, b23 = (b23 if sw else b13), (b13 if sw else b23)
    b14, b24 = (b24 if sw else b14), (b14 if sw else b24)
    v1, v2 = (v2 if sw else v1), (v1 if sw else v2)
    sw = pivot == 3
    a11, a31 = (a31 if sw else a11), (a11 if sw else a31)
    a12, a32 = (a32 if sw else a12), (a12 if sw else a32)
    a13, a33 = (a33 if sw else a13), (a13 if sw else a33)
    a14, a34 = (a34 if sw else a14), (a14 if sw else a34)
    b10, b30 = (b30 if sw else b10), (b10 if sw else b30)
    b11, b31 = (b31 if sw else b11), (b11 if sw else b31)
    b12, b32 = (b32 if sw else b12), (b12 if sw else b32)
    b13, b33 = (b33 if sw else b13), (b13 if sw else b33)
    b14, b34 = (b34 if sw else b14), (b14 if sw else b34)
    v1, v3 = (v3 if sw else v1), (v1 if sw else v3)
    sw = pivot == 4
    a11, a41 = (a41 if sw else a11), (a11 if sw else a41)
    a12, a42 = (a42 if sw else a12), (a12 if sw else a42)
    a13, a43 = (a43 if sw else a13), (a13 if sw else a43)
    a14, a44 = (a44 if sw else a14), (a14 if sw else a44)
    b10, b40 = (b40 if sw else b10), (b10 if sw else b40)
    b11, b41 = (b41 if sw else b11), (b11 if sw else b41)
    b12, b42 = (b42 if sw else b12), (b12 if sw else b42)
    b13, b43 = (b43 if sw else b13), (b13 if sw else b43)
    b14, b44 = (b44 if sw else b14), (b14 if sw else b44)
    v1, v4 = (v4 if sw else v1), (v1 if sw else v4)
    a11 = 1.0 / a11
    e = a21 * a11
    a22 = fma(-e, a12, a22)
    a23 = fma(-e, a13, a23)
    a24 = fma(-e, a14, a24)
    b20 = fma(-e, b10, b20)
    b21 = fma(-e, b11, b21)
    b22 = fma(-e, b12, b22)
    b23 = fma(-e, b13, b23)
    b24 = fma(-e, b14, b24)
    v2 = fma(-e, v1, v2)
    e = a31 * a11
    a32 = fma(-e, a12, a32)
    a33 = fma(-e, a13, a33)
    a34 = fma(-e, a14, a34)
    b30 = fma(-e, b10, b30)
    b31 = fma(-e, b11, b31)
    b32 = fma(-e, b12, b32)
    b33 = fma(-e, b13, b33)
    b34 = fma(-e, b14, b34)
    v3 = fma(-e, v1, v3)
    e = a41 * a11
    a42 = fma(-e, a12, a42)
    a43 = fma(-e, a13, a43)
    a44 = fma(-e, a14, a44)
    b40 = fma(-e, b10, b40)
    b41 = fma(-e, b11, b41)
    b42 = fma(-e, b12, b42)
    b43 = fma(-e, b13, b43)
    b44 = fma(-e, b14, b44)
    v4 = fma(-e, v1, v4)
    best = abs(a22)
    pivot = 2
    cnd = abs(a32) > best
    best = abs(a32) if cnd else best
    pivot = 3 if cnd else pivot
    cnd = abs(a42) > best
    best = abs(a42) if cnd else best
    pivot = 4 if cnd else pivot
    bad_l = bad_l if (best > 0.0 and best < math.inf) else 1.0
    sw = pivot == 3
    a22, a32 = (a32 if sw else a22), (a22 if sw else a32)
    a23, a33 = (a33 if sw else a23), (a23 if sw else a33)
    a24, a34 = (a34 if sw else a24), (a24 if sw else a34)
    b20, b30 = (b30 if sw else b20), (b20 if sw else b30)
    b21, b31 = (b31 if sw else b21), (b21 if sw else b31)
    b22, b32 = (b32 if sw else b22), (b22 if sw else b32)
    b23, b33 = (b33 if sw else b23), (b23 if sw else b33)
    b24, b34 = (b34 if sw else b24), (b24 if sw else b34)
    v2, v3 = (v3 if sw else v2), (v2 if sw else v3)
    sw = pivot == 4
    a22, a42 = (a42 if sw else a22), (a22 if sw else a42)
    a23, a43 = (a43 if sw else a23), (a23 if sw else a43)
    a24, a44 = (a44 if sw else a24), (a24 if sw else a44)
    b20, b40 = (b40 if sw else b20), (b20 if sw else b40)
    b21, b41 = (b41 if sw else b21), (b21 if sw else b41)
    b22, b42 = (b42 if sw else b22), (b22 if sw else b42)
    b23, b43 = (b43 if sw else b23), (b23 if sw else b43)
    b24, b44 = (b44 if sw else b24), (b24 if sw else b44)
    v2, v4 = (v4 if sw else v2), (v2 if sw else v4)
    a22 = 1.0 / a22
    e = a32 * a22
    a33 = fma(-e, a23, a33)
    a34 = fma(-e, a24, a34)
    b30 = fma(-e, b20, b30)
    b31 = fma(-e, b21, b31)
    b32 = fma(-e, b22, b32)
    b33 = fma(-e, b23, b33)
    b34 = fma(-e, b24, b34)
    v3 = fma(-e, v2, v3)
    e = a42 * a22
    a43 = fma(-e, a23, a43)
    a44 = fma(-e, a24, a44)
    b40 = fma(-e, b20, b40)
    b41 = fma(-e, b21, b41)
    b42 = fma(-e, b22, b42)
    b43 = fma(-e, b23, b43)
    b44 = fma(-e, b24, b44)
    v4 = fma(-e, v2, v4)
    best = abs(a33)
    pivot = 3
    cnd = abs(a43) > best
    best = abs(a43) if cnd else best
    pivot = 4 if cnd else pivot
    bad_l = bad_l if (best > 0.0 and best < math.inf) else 1.0
    sw = pivot == 4
    a33, a43 = (a43 if sw else a33), (a33 if sw else a43)
    a34, a44 = (a44 if sw else a34), (a34 if sw else a44)
    b30, b40 = (b40 if sw else b30), (b30 if sw else b40)
    b31, b41 = (b41 if sw else b31), (b31 if sw else b41)
    b32, b42 = (b42 if sw else b32), (b32 if sw else b42)
    b33, b43 = (b43 if sw else b33), (b33 if sw else b43)
    b34, b44 = (b44 if sw else b34), (b34 if sw else b44)
    v3, v4 = (v4 if sw else v3), (v3 if sw else v4)
    a33 = 1.0 / a33
    e = a43 * a33
    a44 = fma(-e, a34, a44)
    b40 = fma(-e, b30, b40)
    b41 = fma(-e, b31, b41)
    b42 = fma(-e, b32, b42)
    b43 = fma(-e, b33, b43)
    b44 = fma(-e, b34, b44)
    v4 = fma(-e, v3, v4)
    best = abs(a44)
    pivot = 4
    bad_l = bad_l if (best > 0.0 and best < math.inf) else 1.0
    a44 = 1.0 / a44
    t = b40
    b40 = t * a44
    t = b41
    b41 = t * a44
    t = b42
    b42 = t * a44
    t = b43
    b43 = t * a44
    t = b44
    b44 = t * a44
    t = v4
    v4 = t * a44
    t = b30
    t = fma(-a34, b40, t)
    b30 = t * a33
    t = b31
    t = fma(-a34, b41, t)
    b31 = t * a33
    t = b32
    t = fma(-a34, b42, t)
    b32 = t * a33
    t = b33
    t = fma(-a34, b43, t)
    b33 = t * a33
    t = b34
    t = fma(-a34, b44, t)
    b34 = t * a33
    t = v3
    t = fma(-a34, v4, t)
    v3 = t * a33
    t = b20
    t = fma(-a23, b30, t)
    t = fma(-a24, b40, t)
    b20 = t * a22
    t = b21
    t = fma(-a23, b31, t)
    t = fma(-a24, b41, t)
    b21 = t * a22
    t = b22
    t = fma(-a23, b32, t)
    t = fma(-a24, b42, t)
    b22 = t * a22
    t = b23
    t = fma(-a23, b33, t)
    t = fma(-a24, b43, t)
    b23 = t * a22
    t = b24
    t = fma(-a23, b34, t)
    t = fma(-a24, b44, t)
    b24 = t * a22
    t = v2
    t = fma(-a23, v3, t)
    t = fma(-a24, v4, t)
    v2 = t * a22
    t = b10
    t = fma(-a12, b20, t)
    t = fma(-a13, b30, t)
    t = fma(-a14, b40, t)
    b10 = t * a11
    t = b11
    t = fma(-a12, b21, t)
    t = fma(-a13, b31, t)
    t = fma(-a14, b41, t)
    b11 = t * a11
    t = b12
    t = fma(-a12, b22, t)
    t = fma(-a13, b32, t)
    t = fma(-a14, b42, t)
    b12 = t * a11
    t = b13
    t = fma(-a12, b23, t)
    t = fma(-a13, b33, t)
    t = fma(-a14, b43, t)
    b13 = t * a11
    t = b14
    t = fma(-a12, b24, t)
    t = fma(-a13, b34, t)
    t = fma(-a14, b44, t)
    b14 = t * a11
    t = v1
    t = fma(-a12, v2, t)
    t = fma(-a13, v3, t)
    t = fma(-a14, v4, t)
    v1 = t * a11
    t = b00
    t = fma(-a01, b10, t)
    t = fma(-a02, b20, t)
    t = fma(-a03, b30, t)
    t = fma(-a04, b40, t)
    b00 = t * a00
    t = b01
    t = fma(-a01, b11, t)
    t = fma(-a02, b21, t)
    t = fma(-a03, b31, t)
    t = fma(-a04, b41, t)
    b01 = t * a00
    t = b02
    t = fma(-a01, b12, t)
    t = fma(-a02, b22, t)
    t = fma(-a03, b32, t)
    t = fma(-a04, b42, t)
    b02 = t * a00
    t = b03
    t = fma(-a01, b13, t)
    t = fma(-a02, b23, t)
    t = fma(-a03, b33, t)
    t = fma(-a04, b43, t)
    b03 = t * a00
    t = b04
    t = fma(-a01, b14, t)
    t = fma(-a02, b24, t)
    t = fma(-a03, b34, t)
    t = fma(-a04, b44, t)
    b04 = t * a00
    t = v0
    t = fma(-a01, v1, t)
    t = fma(-a02, v2, t)
    t = fma(-a03, v3, t)
    t = fma(-a04, v4, t)
    v0 = t * a00
    bad[l] = bad_l
    s = 0.0
    s = fma(b00, f00, s)
    s = fma(b01, f10, s)
    s = fma(b02, f20, s)
    s = fma(b03, f30, s)
    s = fma(b04, f40, s)
    t00 = s
    s = 0.0
    s = fma(b00, f01, s)
    s = fma(b01, f11, s)
    s = fma(b02, f21, s)
    s = fma(b03, f31, s)
    s = fma(b04, f41, s)
    t01 = s
    s = 0.0
    s = fma(b00, f02, s)
    s = fma(b01, f12, s)
    s = fma(b02, f22, s)
    s = fma(b03, f32, s)
    s = fma(b04, f42, s)
    t02 = s
    s = 0.0
    s = fma(b00, f03, s)
    s = fma(b01, f13, s)
    s = fma(b02, f23, s)
    s = fma(b03, f33, s)
    s = fma(b04, f43, s)
    t03 = s
    s = 0.0
    s = fma(b00, f04, s)
    s = fma(b01, f14, s)
    s = fma(b02, f24, s)
    s = fma(b03, f34, s)
    s = fma(b04, f44, s)
    t04 = s
    s = 0.0
    s = fma(b10, f00, s)
    s = fma(b11, f10, s)
    s = fma(b12, f20, s)
    s = fma(b13, f30, s)
    s = fma(b14, f40, s)
    t10 = s
    s = 0.0
    s = fma(b10, f01, s)
    s = fma(b11, f11, s)
    s = fma(b12, f21, s)
    s = fma(b13, f31, s)
    s = fma(b14, f41, s)
    t11 = s
    s = 0.0
    s = fma(b10, f02, s)
    s = fma(b11, f12, s)
    s = fma(b12, f22, s)
    s = fma(b13, f32, s)
    s = fma(b14, f42, s)
    t12 = s
    s = 0.0
    s = fma(b10, f03, s)
    s = fma(b11, f13, s)
    s = fma(b12, f23, s)
    s = fma(b13, f33, s)
    s = fma(b14, f43, s)
    t13 = s
    s = 0.0
    s = fma(b10, f04, s)
    s = fma(b11, f14, s)
    s = fma(b12, f24, s)
    s = fma(b13, f34, s)
    s = fma(b14, f44, s)
    t14 = s
    s = 0.0
    s = fma(b20, f00, s)
    s = fma(b21, f10, s)
    s = fma(b22, f20, s)
    s = fma(b23, f30, s)
    s = fma(b24, f40, s)
    t20 = s
    s = 0.0
    s = fma(b20, f01, s)
    s = fma(b21, f11, s)
    s = fma(b22, f21, s)
    s = fma(b23, f31, s)
    s = fma(b24, f41, s)
    t21 = s
    s = 0.0
    s = fma(b20, f02, s)
    s = fma(b21, f12, s)
    s = fma(b22, f22, s)
    s = fma(b23, f32, s)
    s = fma(b24, f42, s)
    t22 = s
    s = 0.0
    s = fma(b20, f03, s)
    s = fma(b21, f13, s)
    s = fma(b22, f23, s)
    s = fma(b23, f33, s)
    s = fma(b24, f43, s)
    t23 = s
    s = 0.0
    s = fma(b20, f04, s)
    s = fma(b21, f14, s)
    s = fma(b22, f24, s)
    s = fma(b23, f34, s)
    s = fma(b24, f44, s)
    t24 = s
    s = 0.0
    s = fma(b30, f00, s)
    s = fma(b31, f10, s)
    s = fma(b32, f20, s)
    s = fma(b33, f30, s)
    s = fma(b34, f40, s)
    t30 = s
    s = 0.0
    s = fma(b30, f01, s)
    s = fma(b31, f11, s)
    s = fma(b32, f21, s)
    s = fma(b33, f31, s)
    s = fma(b34, f41, s)
    t31 = s
    s = 0.0
    s = fma(b30, f02, s)
    s = fma(b31, f12, s)
    s = fma(b32, f22, s)
    s = fma(b33, f32, s)
    s = fma(b34, f42, s)
    t32 = s
    s = 0.0
    s = fma(b30, f03, s)
    s = fma(b31, f13, s)
    s = fma(b32, f23, s)
    s = fma(b33, f33, s)
    s = fma(b34, f43, s)
    t33 = s
    s = 0.0
    s = fma(b30, f04, s)
    s = fma(b31, f14, s)
    s = fma(b32, f24, s)
    s = fma(b33, f34, s)
    s = fma(b34, f44, s)
    t34 = s
    s = 0.0
    s = fma(b40, f00, s)
    s = fma(b41, f10, s)
    s = fma(b42, f20, s)
    s = fma(b43, f30, s)
    s = fma(b44, f40, s)
    t40 = s
    s = 0.0
    s = fma(b40, f01, s)
    s = fma(b41, f11, s)
    s = fma(b42, f21, s)
    s = fma(b43, f31, s)
    s = fma(b44, f41, s)
    t41 = s
    s = 0.0
    s = fma(b40, f02, s)
    s = fma(b41, f12, s)
    s = fma(b42, f22, s)
    s = fma(b43, f32, s)
    s = fma(b44, f42, s)
    t42 = s
    s = 0.0
    s = fma(b40, f03, s)
    s = fma(b41, f13, s)
    s = fma(b42, f23, s)
    s = fma(b43, f33, s)
    s = fma(b44, f43, s)
    t43 = s
    s = 0.0
    s = fma(b40, f04, s)
    s = fma(b41, f14, s)
    s = fma(b42, f24, s)
    s = fma(b43, f34, s)
    s = fma(b44, f44, s)
    t44 = s
    s = 0.0
    s = fma(f00, t00, s)
    s = fma(f10, t10, s)
    s = fma(f20, t20, s)
    s = fma(f30, t30, s)
    s = fma(f40, t40, s)
    o00 = s
    s = 0.0
    s = fma(f00, t01, s)
    s = fma(f10, t11, s)
    s = fma(f20, t21, s)
    s = fma(f30, t31, s)
    s = fma(f40, t41, s)
    o01 = s
    s = 0.0
    s = fma(f00, t02, s)
    s = fma(f10, t12, s)
    s = fma(f20, t22, s)
    s = fma(f30, t32, s)
    s = fma(f40, t42, s)
    o02 = s
    s = 0.0
    s = fma(f00, t03, s)
    s = fma(f10, t13, s)
    s = fma(f20, t23, s)
    s = fma(f30, t33, s)
    s = fma(f40, t43, s)
    o03 = s
    s = 0.0
    s = fma(f00, t04, s)
    s = fma(f10, t14, s)
    s = fma(f20, t24, s)
    s = fma(f30, t34, s)
    s = fma(f40, t44, s)
    o04 = s
    s = 0.0
    s = fma(f01, t00, s)
    s = fma(f11, t10, s)
    s = fma(f21, t20, s)
    s = fma(f31, t30, s)
    s = fma(f41, t40, s)
    o10 = s
    s = 0.0
    s = fma(f01, t01, s)
    s = fma(f11, t11, s)
    s = fma(f21, t21, s)
    s = fma(f31, t31, s)
    s = fma(f41, t41, s)
    o11 = s
    s = 0.0
    s = fma(f01, t02, s)
    s = fma(f11, t12, s)
    s = fma(f21, t22, s)
    s = fma(f31, t32, s)
    s = fma(f41, t42, s)
    o12 = s
    s = 0.0
    s = fma(f01, t03, s)
    s = fma(f11, t13, s)
    s = fma(f21, t23, s)
    s = fma(f31, t33, s)
    s = fma(f41, t43, s)
    o13 = s
    s = 0.0
    s = fma(f01, t04, s)
    s = fma(f11, t14, s)
    s = fma(f21, t24, s)
    s = fma(f31, t34, s)
    s = fma(f41, t44, s)
    o14 = s
    s = 0.0
    s = fma(f02, t00, s)
    s = fma(f12, t10, s)
    s = fma(f22, t20, s)
    s = fma(f32, t30, s)
    s = fma(f42, t40, s)
    o20 = s
    s = 0.0
    s = fma(f02, t01, s)
    s = fma(f12, t11, s)
    s = fma(f22, t21, s)
    s = fma(f32, t31, s)
    s = fma(f42, t41, s)
    o21 = s
    s = 0.0
    s = fma(f02, t02, s)
    s = fma(f12, t12, s)
    s = fma(f22, t22, s)
    s = fma(f32, t32, s)
    s = fma(f42, t42, s)
    o22 = s
    s = 0.0
    s = fma(f02, t03, s)
    s = fma(f12, t13, s)
    s = fma(f22, t23, s)
    s = fma(f32, t33, s)
    s = fma(f42, t43, s)
    o23 = s
    s = 0.0
    s = fma(f02, t04, s)
    s = fma(f12, t14, s)
    s = fma(f22, t24, s)
    s = fma(f32, t34, s)
    s = fma(f42, t44, s)
    o24 = s
    s = 0.0
    s = fma(f03, t00, s)
    s = fma(f13, t10, s)
    s = fma(f23, t20, s)
    s = fma(f33, t30, s)
    s = fma(f43, t40, s)
    o30 = s
    s = 0.0
    s = fma(f03, t01, s)
    s = fma(f13, t11, s)
    s = fma(f23, t21, s)
    s = fma(f33, t31, s)
    s = fma(f43, t41, s)
    o31 = s
    s = 0.0
    s = fma(f03, t02, s)
    s = fma(f13, t12, s)
    s = fma(f23, t22, s)
    s = fma(f33, t32, s)
    s = fma(f43, t42, s)
    o32 = s
    s = 0.0
    s = fma(f03, t03, s)
    s = fma(f13, t13, s)
    s = fma(f23, t23, s)
    s = fma(f33, t33, s)
    s = fma(f43, t43, s)
    o33 = s
    s = 0.0
    s = fma(f03, t04, s)
    s = fma(f13, t14, s)
    s = fma(f23, t24, s)
    s = fma(f33, t34, s)
    s = fma(f43, t44, s)
    o34 = s
    s = 0.0
    s = fma(f04, t00, s)
    s = fma(f14, t10, s)
    s = fma(f24, t20, s)
    s = fma(f34, t30, s)
    s = fma(f44, t40, s)
    o40 = s
    s = 0.0
    s = fma(f04, t01, s)
    s = fma(f14, t11, s)
    s = fma(f24, t21, s)
    s = fma(f34, t31, s)
    s = fma(f44, t41, s)
    o41 = s
    s = 0.0
    s = fma(f04, t02, s)
    s = fma(f14, t12, s)
    s = fma(f24, t22, s)
    s = fma(f34, t32, s)
    s = fma(f44, t42, s)
    o42 = s
    s = 0.0
    s = fma(f04, t03, s)
    s = fma(f14, t13, s)
    s = fma(f24, t23, s)
    s = fma(f34, t33, s)
    s = fma(f44, t43, s)
    o43 = s
    s = 0.0
    s = fma(f04, t04, s)
    s = fma(f14, t14, s)
    s = fma(f24, t24, s)
    s = fma(f34, t34, s)
    s = fma(f44, t44, s)
    o44 = s
    info[0, 0, l] = o00
    s = 0.5 * (o01 + o10)
    info[0, 1, l] = s
    info[1, 0, l] = s
    s = 0.5 * (o02 + o20)
    info[0, 2, l] = s
    info[2, 0, l] = s
    s = 0.5 * (o03 + o30)
    info[0, 3, l] = s
    info[3, 0, l] = s
    s = 0.5 * (o04 + o40)
    info[0, 4, l] = s
    info[4, 0, l] = s
    info[1, 1, l] = o11
    s = 0.5 * (o12 + o21)
    info[1, 2, l] = s
    info[2, 1, l] = s
    s = 0.5 * (o13 + o31)
    info[1, 3, l] = s
    info[3, 1, l] = s
    s = 0.5 * (o14 + o41)
    info[1, 4, l] = s
    info[4, 1, l] = s
    info[2, 2, l] = o22
    s = 0.5 * (o23 + o32)
    info[2, 3, l] = s
    info[3, 2, l] = s
    s = 0.5 * (o24 + o42)
    info[2, 4, l] = s
    info[4, 2, l] = s
    info[3, 3, l] = o33
    s = 0.5 * (o34 + o43)
    info[3, 4, l] = s
    info[4, 3, l] = s
    info[4, 4, l] = o44
    s = 0.0
    s = fma(f00, v0, s)
    s = fma(f10, v1, s)
    s = fma(f20, v2, s)
    s = fma(f30, v3, s)
    s = fma(f40, v4, s)
    info_vec[0, l] = s
    s = 0.0
    s = fma(f01, v0, s)
    s = fma(f11, v1, s)
    s = fma(f21, v2, s)
    s = fma(f31, v3, s)
    s = fma(f41, v4, s)
    info_vec[1, l] = s
    s = 0.0
    s = fma(f02, v0, s)
    s = fma(f12, v1, s)
    s = fma(f22, v2, s)
    s = fma(f32, v3, s)
    s = fma(f42, v4, s)
    info_vec[2, l] = s
    s = 0.0
    s = fma(f03, v0, s)
    s = fma(f13, v1, s)
    s = fma(f23, v2, s)
    s = fma(f33, v3, s)
    s = fma(f43, v4, s)
    info_vec[3, l] = s
    s = 0.0
    s = fma(f04, v0, s)
    s = fma(f14, v1, s)
    s = fma(f24, v2, s)
    s = fma(f34, v3, s)
    s = fma(f44, v4, s)
    info_vec[4, l] = s


# ---- end of generated code ----


@nb.njit(cache=True, **NO_REFCOUNT)
def is_positive_definite_diag(a):
    """True if every diagonal element of a 5×5 matrix is positive and finite."""
    for i in range(5):
        if not (a[i, i] > 0.0 and math.isfinite(a[i, i])):
            return False
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def search_sorted(values, x, right):
    """np.searchsorted(values, x, side='right' if right else 'left') by bisection.

    numba's np.searchsorted costs ~200 ns on arrays held in a NamedTuple context;
    this costs ~25 ns for the ~70 planes of a detector.
    """
    lo = 0
    hi = values.size
    while lo < hi:
        mid = (lo + hi) >> 1
        if values[mid] < x or (right and values[mid] == x):
            lo = mid + 1
        else:
            hi = mid
    return lo
