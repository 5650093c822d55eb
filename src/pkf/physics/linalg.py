"""Allocation-free 5×5 linear algebra for the compiled Kalman kernels.

Plain loops over small float64 arrays (numba unrolls them); every function writes into
arrays the caller owns, so the per-node work allocates nothing. Inverses of symmetric
positive-definite matrices go through a Cholesky factorisation and report failure
instead of returning garbage for a non-positive-definite matrix.

Structured variants (`transport_cov`, `transport_info`, `matmul_noise`) leave out the
terms that are exact zeros of a known Jacobian or noise structure and are bitwise the
dense products. `invert_spd_ldl_lane` is `invert_spd_ldl` for one lane of a stack of
matrices, written out for SIMD loops over the lanes (`pkf.physics.lanes_codegen`).
"""

from __future__ import annotations

import math

import numba as nb

from pkf.jit import NO_REFCOUNT


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
                s += a[i, k] * b[k, j]
            out[i, j] = s


@nb.njit(cache=True, inline="always")
def matmul52(a, b, out):
    """out = a·b for a 5×5 a and a 5×2 b; out (5×2) must not alias a or b."""
    for i in range(5):
        for j in range(2):
            s = 0.0
            for k in range(5):
                s += a[i, k] * b[k, j]
            out[i, j] = s


@nb.njit(cache=True, inline="always")
def matmul55_tn(a, b, out):
    """out = aᵀ·b (5×5); out must not alias a or b."""
    for i in range(5):
        for j in range(5):
            s = 0.0
            for k in range(5):
                s += a[k, i] * b[k, j]
            out[i, j] = s


@nb.njit(cache=True, inline="always")
def matvec5(a, v, out):
    """out = a·v (5×5 times 5-vector)."""
    for i in range(5):
        s = 0.0
        for k in range(5):
            s += a[i, k] * v[k]
        out[i] = s


@nb.njit(cache=True, inline="always")
def matvec5_t(a, v, out):
    """out = aᵀ·v (5×5 transposed times 5-vector)."""
    for i in range(5):
        s = 0.0
        for k in range(5):
            s += a[k, i] * v[k]
        out[i] = s


@nb.njit(cache=True, inline="always")
def add_matvec5(x, a, v, out):
    """out = x + a·v (5-vectors, a 5×5), summed from x[i] upwards; out may be x."""
    for i in range(5):
        s = x[i]
        for k in range(5):
            s += a[i, k] * v[k]
        out[i] = s


@nb.njit(cache=True, inline="always")
def sandwich(f, c, tmp, out):
    """out = f·c·fᵀ (5×5), symmetrised; tmp is 5×5 scratch. out may be c (c is read only
    into tmp), not f or tmp."""
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
            tmp[0, j] = 0.0 + c[0, j] + a * c[2, j] + b * c[4, j]
            tmp[1, j] = 0.0 + c[1, j] + d * c[3, j]
            tmp[2, j] = 0.0 + c[2, j] + e * c[4, j]
            tmp[3, j] = 0.0 + c[3, j]
            tmp[4, j] = 0.0 + c[4, j]
        for i in range(5):
            t0 = 0.0 + tmp[i, 0] + a * tmp[i, 2] + b * tmp[i, 4]
            t1 = 0.0 + tmp[i, 1] + d * tmp[i, 3]
            t2 = 0.0 + tmp[i, 2] + e * tmp[i, 4]
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
                    s += f[i, k] * c[k, j]
                tmp[i, j] = s
        for j in range(5):
            tmp[4, j] = 0.0 + c[4, j]
        for i in range(5):
            for j in range(i, 4):
                s = 0.0
                for k in range(5):
                    s += tmp[i, k] * f[j, k]
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
            tmp[i, 2] = 0.0 + a[i, 0] * p + a[i, 2]
            tmp[i, 3] = 0.0 + a[i, 1] * d + a[i, 3]
            tmp[i, 4] = 0.0 + a[i, 0] * b + a[i, 2] * e + a[i, 4]
        for j in range(5):
            out[0, j] = 0.0 + tmp[0, j]
            out[1, j] = 0.0 + tmp[1, j]
            out[2, j] = 0.0 + p * tmp[0, j] + tmp[2, j]
            out[3, j] = 0.0 + d * tmp[1, j] + tmp[3, j]
            out[4, j] = 0.0 + b * tmp[0, j] + e * tmp[2, j] + tmp[4, j]
        return
    if is_unit_last_row(f):  # the terms of f's last row (0, 0, 0, 0, 1) are exact zeros and ones
        for i in range(5):
            for j in range(4):
                s = 0.0
                for k in range(4):
                    s += a[i, k] * f[k, j]
                tmp[i, j] = s
            s = 0.0
            for k in range(4):
                s += a[i, k] * f[k, 4]
            tmp[i, 4] = s + a[i, 4]
        for j in range(5):
            for i in range(4):
                s = 0.0
                for k in range(4):
                    s += f[k, i] * tmp[k, j]
                out[i, j] = s
            s = 0.0
            for k in range(4):
                s += f[k, 4] * tmp[k, j]
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
            out[i, 0] = 0.0 + a[i, 0] * q[0, 0] + a[i, 2] * q[2, 0]
            out[i, 1] = 0.0 + a[i, 1] * q[1, 1] + a[i, 3] * q[3, 1]
            out[i, 2] = 0.0 + a[i, 0] * q[0, 2] + a[i, 2] * q[2, 2]
            out[i, 3] = 0.0 + a[i, 1] * q[1, 3] + a[i, 3] * q[3, 3]
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
            s -= work[j, k] * work[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        work[j, j] = d
        for i in range(j + 1, n):
            t = a[i, j] * scale[i] * scale[j]
            for k in range(j):
                t -= work[i, k] * work[j, k]
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
                t -= work[i, k] * col[k]
            col[i] = t / work[i, i]
        for i in range(n - 1, -1, -1):
            t = col[i]
            for k in range(i + 1, n):
                t -= work[k, i] * out[k, c]
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
                t += work[i, k] * work[k, j]
            work[i, j] = -t * inv_d
        work[j, j] = inv_d
    # a⁻¹ = D·(L⁻ᵀ·L⁻¹)·D, one triangle
    for i in range(n):
        for j in range(i, n):
            t = 0.0
            for k in range(j, n):
                t += work[k, i] * work[k, j]
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
            d -= work[j, k] * work[k, j]
        if not d > 0.0:
            return False
        r = 1.0 / d
        dinv[j] = r
        for i in range(j + 1, 5):
            t = a[i, j]
            for k in range(j):
                t -= work[i, k] * work[k, j]
            work[j, i] = t  # L[i, j]·D[j], read by the later columns
            work[i, j] = t * r
    # L⁻¹ (unit lower), stored transposed above the diagonal: work[j, i] = (L⁻¹)[i, j], i > j
    for j in range(4):
        for i in range(j + 1, 5):
            t = -work[i, j]
            for k in range(j + 1, i):
                t -= work[i, k] * work[j, k]
            work[j, i] = t
    # a⁻¹[i, j] = Σ_{k ≥ j} (L⁻¹)[k, i]·D⁻¹[k]·(L⁻¹)[k, j], i ≤ j, (L⁻¹)[k, k] = 1
    for i in range(5):
        for j in range(i, 5):
            t = dinv[j] * (work[i, j] if j > i else 1.0)
            for k in range(j + 1, 5):
                t += work[i, k] * dinv[k] * work[j, k]
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
    d -= w10 * u01
    bad[l] = bad[l] if d > 0.0 else 1.0
    r1 = 1.0 / d
    t = a[2, 1, l]
    t -= w20 * u01
    u12 = t
    w21 = t * r1
    t = a[3, 1, l]
    t -= w30 * u01
    u13 = t
    w31 = t * r1
    t = a[4, 1, l]
    t -= w40 * u01
    u14 = t
    w41 = t * r1
    d = a[2, 2, l]
    d -= w20 * u02
    d -= w21 * u12
    bad[l] = bad[l] if d > 0.0 else 1.0
    r2 = 1.0 / d
    t = a[3, 2, l]
    t -= w30 * u02
    t -= w31 * u12
    u23 = t
    w32 = t * r2
    t = a[4, 2, l]
    t -= w40 * u02
    t -= w41 * u12
    u24 = t
    w42 = t * r2
    d = a[3, 3, l]
    d -= w30 * u03
    d -= w31 * u13
    d -= w32 * u23
    bad[l] = bad[l] if d > 0.0 else 1.0
    r3 = 1.0 / d
    t = a[4, 3, l]
    t -= w40 * u03
    t -= w41 * u13
    t -= w42 * u23
    u34 = t
    w43 = t * r3
    d = a[4, 4, l]
    d -= w40 * u04
    d -= w41 * u14
    d -= w42 * u24
    d -= w43 * u34
    bad[l] = bad[l] if d > 0.0 else 1.0
    r4 = 1.0 / d
    t = -w10
    u01 = t
    t = -w20
    t -= w21 * u01
    u02 = t
    t = -w30
    t -= w31 * u01
    t -= w32 * u02
    u03 = t
    t = -w40
    t -= w41 * u01
    t -= w42 * u02
    t -= w43 * u03
    u04 = t
    t = -w21
    u12 = t
    t = -w31
    t -= w32 * u12
    u13 = t
    t = -w41
    t -= w42 * u12
    t -= w43 * u13
    u14 = t
    t = -w32
    u23 = t
    t = -w42
    t -= w43 * u23
    u24 = t
    t = -w43
    u34 = t
    t = r0 * 1.0
    t += u01 * r1 * u01
    t += u02 * r2 * u02
    t += u03 * r3 * u03
    t += u04 * r4 * u04
    out[0, 0, l] = t
    t = r1 * u01
    t += u02 * r2 * u12
    t += u03 * r3 * u13
    t += u04 * r4 * u14
    out[0, 1, l] = t
    out[1, 0, l] = t
    t = r2 * u02
    t += u03 * r3 * u23
    t += u04 * r4 * u24
    out[0, 2, l] = t
    out[2, 0, l] = t
    t = r3 * u03
    t += u04 * r4 * u34
    out[0, 3, l] = t
    out[3, 0, l] = t
    t = r4 * u04
    out[0, 4, l] = t
    out[4, 0, l] = t
    t = r1 * 1.0
    t += u12 * r2 * u12
    t += u13 * r3 * u13
    t += u14 * r4 * u14
    out[1, 1, l] = t
    t = r2 * u12
    t += u13 * r3 * u23
    t += u14 * r4 * u24
    out[1, 2, l] = t
    out[2, 1, l] = t
    t = r3 * u13
    t += u14 * r4 * u34
    out[1, 3, l] = t
    out[3, 1, l] = t
    t = r4 * u14
    out[1, 4, l] = t
    out[4, 1, l] = t
    t = r2 * 1.0
    t += u23 * r3 * u23
    t += u24 * r4 * u24
    out[2, 2, l] = t
    t = r3 * u23
    t += u24 * r4 * u34
    out[2, 3, l] = t
    out[3, 2, l] = t
    t = r4 * u24
    out[2, 4, l] = t
    out[4, 2, l] = t
    t = r3 * 1.0
    t += u34 * r4 * u34
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
    a11 -= f * a01
    a12 -= f * a02
    a13 -= f * a03
    a14 -= f * a04
    b10 -= f * b00
    b11 -= f * b01
    b12 -= f * b02
    b13 -= f * b03
    b14 -= f * b04
    v1 -= f * v0
    f = a20 * a00
    a21 -= f * a01
    a22 -= f * a02
    a23 -= f * a03
    a24 -= f * a04
    b20 -= f * b00
    b21 -= f * b01
    b22 -= f * b02
    b23 -= f * b03
    b24 -= f * b04
    v2 -= f * v0
    f = a30 * a00
    a31 -= f * a01
    a32 -= f * a02
    a33 -= f * a03
    a34 -= f * a04
    b30 -= f * b00
    b31 -= f * b01
    b32 -= f * b02
    b33 -= f * b03
    b34 -= f * b04
    v3 -= f * v0
    f = a40 * a00
    a41 -= f * a01
    a42 -= f * a02
    a43 -= f * a03
    a44 -= f * a04
    b40 -= f * b00
    b41 -= f * b01
    b42 -= f * b02
    b43 -= f * b03
    b44 -= f * b04
    v4 -= f * v0
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
    a22 -= f * a12
    a23 -= f * a13
    a24 -= f * a14
    b20 -= f * b10
    b21 -= f * b11
    b22 -= f * b12
    b23 -= f * b13
    b24 -= f * b14
    v2 -= f * v1
    f = a31 * a11
    a32 -= f * a12
    a33 -= f * a13
    a34 -= f * a14
    b30 -= f * b10
    b31 -= f * b11
    b32 -= f * b12
    b33 -= f * b13
    b34 -= f * b14
    v3 -= f * v1
    f = a41 * a11
    a42 -= f * a12
    a43 -= f * a13
    a44 -= f * a14
    b40 -= f * b10
    b41 -= f * b11
    b42 -= f * b12
    b43 -= f * b13
    b44 -= f * b14
    v4 -= f * v1
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
    a33 -= f * a23
    a34 -= f * a24
    b30 -= f * b20
    b31 -= f * b21
    b32 -= f * b22
    b33 -= f * b23
    b34 -= f * b24
    v3 -= f * v2
    f = a42 * a22
    a43 -= f * a23
    a44 -= f * a24
    b40 -= f * b20
    b41 -= f * b21
    b42 -= f * b22
    b43 -= f * b23
    b44 -= f * b24
    v4 -= f * v2
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
    a44 -= f * a34
    b40 -= f * b30
    b41 -= f * b31
    b42 -= f * b32
    b43 -= f * b33
    b44 -= f * b34
    v4 -= f * v3
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
    t -= a34 * b40
    b30 = t * a33
    t = b31
    t -= a34 * b41
    b31 = t * a33
    t = b32
    t -= a34 * b42
    b32 = t * a33
    t = b33
    t -= a34 * b43
    b33 = t * a33
    t = b34
    t -= a34 * b44
    b34 = t * a33
    t = v3
    t -= a34 * v4
    v3 = t * a33
    t = b20
    t -= a23 * b30
    t -= a24 * b40
    b20 = t * a22
    t = b21
    t -= a23 * b31
    t -= a24 * b41
    b21 = t * a22
    t = b22
    t -= a23 * b32
    t -= a24 * b42
    b22 = t * a22
    t = b23
    t -= a23 * b33
    t -= a24 * b43
    b23 = t * a22
    t = b24
    t -= a23 * b34
    t -= a24 * b44
    b24 = t * a22
    t = v2
    t -= a23 * v3
    t -= a24 * v4
    v2 = t * a22
    t = b10
    t -= a12 * b20
    t -= a13 * b30
    t -= a14 * b40
    b10 = t * a11
    t = b11
    t -= a12 * b21
    t -= a13 * b31
    t -= a14 * b41
    b11 = t * a11
    t = b12
    t -= a12 * b22
    t -= a13 * b32
    t -= a14 * b42
    b12 = t * a11
    t = b13
    t -= a12 * b23
    t -= a13 * b33
    t -= a14 * b43
    b13 = t * a11
    t = b14
    t -= a12 * b24
    t -= a13 * b34
    t -= a14 * b44
    b14 = t * a11
    t = v1
    t -= a12 * v2
    t -= a13 * v3
    t -= a14 * v4
    v1 = t * a11
    t = b00
    t -= a01 * b10
    t -= a02 * b20
    t -= a03 * b30
    t -= a04 * b40
    b00 = t * a00
    t = b01
    t -= a01 * b11
    t -= a02 * b21
    t -= a03 * b31
    t -= a04 * b41
    b01 = t * a00
    t = b02
    t -= a01 * b12
    t -= a02 * b22
    t -= a03 * b32
    t -= a04 * b42
    b02 = t * a00
    t = b03
    t -= a01 * b13
    t -= a02 * b23
    t -= a03 * b33
    t -= a04 * b43
    b03 = t * a00
    t = b04
    t -= a01 * b14
    t -= a02 * b24
    t -= a03 * b34
    t -= a04 * b44
    b04 = t * a00
    t = v0
    t -= a01 * v1
    t -= a02 * v2
    t -= a03 * v3
    t -= a04 * v4
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
    s += f00 * d0
    s += f01 * d1
    s += f02 * d2
    s += f03 * d3
    s += f04 * d4
    g0 = s
    s = 0.0
    s += f10 * d0
    s += f11 * d1
    s += f12 * d2
    s += f13 * d3
    s += f14 * d4
    g1 = s
    s = 0.0
    s += f20 * d0
    s += f21 * d1
    s += f22 * d2
    s += f23 * d3
    s += f24 * d4
    g2 = s
    s = 0.0
    s += f30 * d0
    s += f31 * d1
    s += f32 * d2
    s += f33 * d3
    s += f34 * d4
    g3 = s
    s = 0.0
    s += f40 * d0
    s += f41 * d1
    s += f42 * d2
    s += f43 * d3
    s += f44 * d4
    g4 = s
    s = 0.0
    s += y00 * q00
    s += y01 * q10
    s += y02 * q20
    s += y03 * q30
    s += y04 * q40
    a00 = s + 1.0
    s = 0.0
    s += y00 * q01
    s += y01 * q11
    s += y02 * q21
    s += y03 * q31
    s += y04 * q41
    a01 = s
    s = 0.0
    s += y00 * q02
    s += y01 * q12
    s += y02 * q22
    s += y03 * q32
    s += y04 * q42
    a02 = s
    s = 0.0
    s += y00 * q03
    s += y01 * q13
    s += y02 * q23
    s += y03 * q33
    s += y04 * q43
    a03 = s
    s = 0.0
    s += y00 * q04
    s += y01 * q14
    s += y02 * q24
    s += y03 * q34
    s += y04 * q44
    a04 = s
    s = 0.0
    s += y10 * q00
    s += y11 * q10
    s += y12 * q20
    s += y13 * q30
    s += y14 * q40
    a10 = s
    s = 0.0
    s += y10 * q01
    s += y11 * q11
    s += y12 * q21
    s += y13 * q31
    s += y14 * q41
    a11 = s + 1.0
    s = 0.0
    s += y10 * q02
    s += y11 * q12
    s += y12 * q22
    s += y13 * q32
    s += y14 * q42
    a12 = s
    s = 0.0
    s += y10 * q03
    s += y11 * q13
    s += y12 * q23
    s += y13 * q33
    s += y14 * q43
    a13 = s
    s = 0.0
    s += y10 * q04
    s += y11 * q14
    s += y12 * q24
    s += y13 * q34
    s += y14 * q44
    a14 = s
    s = 0.0
    s += y20 * q00
    s += y21 * q10
    s += y22 * q20
    s += y23 * q30
    s += y24 * q40
    a20 = s
    s = 0.0
    s += y20 * q01
    s += y21 * q11
    s += y22 * q21
    s += y23 * q31
    s += y24 * q41
    a21 = s
    s = 0.0
    s += y20 * q02
    s += y21 * q12
    s += y22 * q22
    s += y23 * q32
    s += y24 * q42
    a22 = s + 1.0
    s = 0.0
    s += y20 * q03
    s += y21 * q13
    s += y22 * q23
    s += y23 * q33
    s += y24 * q43
    a23 = s
    s = 0.0
    s += y20 * q04
    s += y21 * q14
    s += y22 * q24
    s += y23 * q34
    s += y24 * q44
    a24 = s
    s = 0.0
    s += y30 * q00
    s += y31 * q10
    s += y32 * q20
    s += y33 * q30
    s += y34 * q40
    a30 = s
    s = 0.0
    s += y30 * q01
    s += y31 * q11
    s += y32 * q21
    s += y33 * q31
    s += y34 * q41
    a31 = s
    s = 0.0
    s += y30 * q02
    s += y31 * q12
    s += y32 * q22
    s += y33 * q32
    s += y34 * q42
    a32 = s
    s = 0.0
    s += y30 * q03
    s += y31 * q13
    s += y32 * q23
    s += y33 * q33
    s += y34 * q43
    a33 = s + 1.0
    s = 0.0
    s += y30 * q04
    s += y31 * q14
    s += y32 * q24
    s += y33 * q34
    s += y34 * q44
    a34 = s
    s = 0.0
    s += y40 * q00
    s += y41 * q10
    s += y42 * q20
    s += y43 * q30
    s += y44 * q40
    a40 = s
    s = 0.0
    s += y40 * q01
    s += y41 * q11
    s += y42 * q21
    s += y43 * q31
    s += y44 * q41
    a41 = s
    s = 0.0
    s += y40 * q02
    s += y41 * q12
    s += y42 * q22
    s += y43 * q32
    s += y44 * q42
    a42 = s
    s = 0.0
    s += y40 * q03
    s += y41 * q13
    s += y42 * q23
    s += y43 * q33
    s += y44 * q43
    a43 = s
    s = 0.0
    s += y40 * q04
    s += y41 * q14
    s += y42 * q24
    s += y43 * q34
    s += y44 * q44
    a44 = s + 1.0
    s = w0
    s -= y00 * g0
    s -= y01 * g1
    s -= y02 * g2
    s -= y03 * g3
    s -= y04 * g4
    v0 = s
    s = w1
    s -= y10 * g0
    s -= y11 * g1
    s -= y12 * g2
    s -= y13 * g3
    s -= y14 * g4
    v1 = s
    s = w2
    s -= y20 * g0
    s -= y21 * g1
    s -= y22 * g2
    s -= y23 * g3
    s -= y24 * g4
    v2 = s
    s = w3
    s -= y30 * g0
    s -= y31 * g1
    s -= y32 * g2
    s -= y33 * g3
    s -= y34 * g4
    v3 = s
    s = w4
    s -= y40 * g0
    s -= y41 * g1
    s -= y42 * g2
    s -= y43 * g3
    s -= y44 * g4
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
    a11 -= e * a01
    a12 -= e * a02
    a13 -= e * a03
    a14 -= e * a04
    b10 -= e * b00
    b11 -= e * b01
    b12 -= e * b02
    b13 -= e * b03
    b14 -= e * b04
    v1 -= e * v0
    e = a20 * a00
    a21 -= e * a01
    a22 -= e * a02
    a23 -= e * a03
    a24 -= e * a04
    b20 -= e * b00
    b21 -= e * b01
    b22 -= e * b02
    b23 -= e * b03
    b24 -= e * b04
    v2 -= e * v0
    e = a30 * a00
    a31 -= e * a01
    a32 -= e * a02
    a33 -= e * a03
    a34 -= e * a04
    b30 -= e * b00
    b31 -= e * b01
    b32 -= e * b02
    b33 -= e * b03
    b34 -= e * b04
    v3 -= e * v0
    e = a40 * a00
    a41 -= e * a01
    a42 -= e * a02
    a43 -= e * a03
    a44 -= e * a04
    b40 -= e * b00
    b41 -= e * b01
    b42 -= e * b02
    b43 -= e * b03
    b44 -= e * b04
    v4 -= e * v0
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
    a22 -= e * a12
    a23 -= e * a13
    a24 -= e * a14
    b20 -= e * b10
    b21 -= e * b11
    b22 -= e * b12
    b23 -= e * b13
    b24 -= e * b14
    v2 -= e * v1
    e = a31 * a11
    a32 -= e * a12
    a33 -= e * a13
    a34 -= e * a14
    b30 -= e * b10
    b31 -= e * b11
    b32 -= e * b12
    b33 -= e * b13
    b34 -= e * b14
    v3 -= e * v1
    e = a41 * a11
    a42 -= e * a12
    a43 -= e * a13
    a44 -= e * a14
    b40 -= e * b10
    b41 -= e * b11
    b42 -= e * b12
    b43 -= e * b13
    b44 -= e * b14
    v4 -= e * v1
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
    a33 -= e * a23
    a34 -= e * a24
    b30 -= e * b20
    b31 -= e * b21
    b32 -= e * b22
    b33 -= e * b23
    b34 -= e * b24
    v3 -= e * v2
    e = a42 * a22
    a43 -= e * a23
    a44 -= e * a24
    b40 -= e * b20
    b41 -= e * b21
    b42 -= e * b22
    b43 -= e * b23
    b44 -= e * b24
    v4 -= e * v2
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
    a44 -= e * a34
    b40 -= e * b30
    b41 -= e * b31
    b42 -= e * b32
    b43 -= e * b33
    b44 -= e * b34
    v4 -= e * v3
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
    t -= a34 * b40
    b30 = t * a33
    t = b31
    t -= a34 * b41
    b31 = t * a33
    t = b32
    t -= a34 * b42
    b32 = t * a33
    t = b33
    t -= a34 * b43
    b33 = t * a33
    t = b34
    t -= a34 * b44
    b34 = t * a33
    t = v3
    t -= a34 * v4
    v3 = t * a33
    t = b20
    t -= a23 * b30
    t -= a24 * b40
    b20 = t * a22
    t = b21
    t -= a23 * b31
    t -= a24 * b41
    b21 = t * a22
    t = b22
    t -= a23 * b32
    t -= a24 * b42
    b22 = t * a22
    t = b23
    t -= a23 * b33
    t -= a24 * b43
    b23 = t * a22
    t = b24
    t -= a23 * b34
    t -= a24 * b44
    b24 = t * a22
    t = v2
    t -= a23 * v3
    t -= a24 * v4
    v2 = t * a22
    t = b10
    t -= a12 * b20
    t -= a13 * b30
    t -= a14 * b40
    b10 = t * a11
    t = b11
    t -= a12 * b21
    t -= a13 * b31
    t -= a14 * b41
    b11 = t * a11
    t = b12
    t -= a12 * b22
    t -= a13 * b32
    t -= a14 * b42
    b12 = t * a11
    t = b13
    t -= a12 * b23
    t -= a13 * b33
    t -= a14 * b43
    b13 = t * a11
    t = b14
    t -= a12 * b24
    t -= a13 * b34
    t -= a14 * b44
    b14 = t * a11
    t = v1
    t -= a12 * v2
    t -= a13 * v3
    t -= a14 * v4
    v1 = t * a11
    t = b00
    t -= a01 * b10
    t -= a02 * b20
    t -= a03 * b30
    t -= a04 * b40
    b00 = t * a00
    t = b01
    t -= a01 * b11
    t -= a02 * b21
    t -= a03 * b31
    t -= a04 * b41
    b01 = t * a00
    t = b02
    t -= a01 * b12
    t -= a02 * b22
    t -= a03 * b32
    t -= a04 * b42
    b02 = t * a00
    t = b03
    t -= a01 * b13
    t -= a02 * b23
    t -= a03 * b33
    t -= a04 * b43
    b03 = t * a00
    t = b04
    t -= a01 * b14
    t -= a02 * b24
    t -= a03 * b34
    t -= a04 * b44
    b04 = t * a00
    t = v0
    t -= a01 * v1
    t -= a02 * v2
    t -= a03 * v3
    t -= a04 * v4
    v0 = t * a00
    bad[l] = bad_l
    s = 0.0
    s += b00 * f00
    s += b01 * f10
    s += b02 * f20
    s += b03 * f30
    s += b04 * f40
    t00 = s
    s = 0.0
    s += b00 * f01
    s += b01 * f11
    s += b02 * f21
    s += b03 * f31
    s += b04 * f41
    t01 = s
    s = 0.0
    s += b00 * f02
    s += b01 * f12
    s += b02 * f22
    s += b03 * f32
    s += b04 * f42
    t02 = s
    s = 0.0
    s += b00 * f03
    s += b01 * f13
    s += b02 * f23
    s += b03 * f33
    s += b04 * f43
    t03 = s
    s = 0.0
    s += b00 * f04
    s += b01 * f14
    s += b02 * f24
    s += b03 * f34
    s += b04 * f44
    t04 = s
    s = 0.0
    s += b10 * f00
    s += b11 * f10
    s += b12 * f20
    s += b13 * f30
    s += b14 * f40
    t10 = s
    s = 0.0
    s += b10 * f01
    s += b11 * f11
    s += b12 * f21
    s += b13 * f31
    s += b14 * f41
    t11 = s
    s = 0.0
    s += b10 * f02
    s += b11 * f12
    s += b12 * f22
    s += b13 * f32
    s += b14 * f42
    t12 = s
    s = 0.0
    s += b10 * f03
    s += b11 * f13
    s += b12 * f23
    s += b13 * f33
    s += b14 * f43
    t13 = s
    s = 0.0
    s += b10 * f04
    s += b11 * f14
    s += b12 * f24
    s += b13 * f34
    s += b14 * f44
    t14 = s
    s = 0.0
    s += b20 * f00
    s += b21 * f10
    s += b22 * f20
    s += b23 * f30
    s += b24 * f40
    t20 = s
    s = 0.0
    s += b20 * f01
    s += b21 * f11
    s += b22 * f21
    s += b23 * f31
    s += b24 * f41
    t21 = s
    s = 0.0
    s += b20 * f02
    s += b21 * f12
    s += b22 * f22
    s += b23 * f32
    s += b24 * f42
    t22 = s
    s = 0.0
    s += b20 * f03
    s += b21 * f13
    s += b22 * f23
    s += b23 * f33
    s += b24 * f43
    t23 = s
    s = 0.0
    s += b20 * f04
    s += b21 * f14
    s += b22 * f24
    s += b23 * f34
    s += b24 * f44
    t24 = s
    s = 0.0
    s += b30 * f00
    s += b31 * f10
    s += b32 * f20
    s += b33 * f30
    s += b34 * f40
    t30 = s
    s = 0.0
    s += b30 * f01
    s += b31 * f11
    s += b32 * f21
    s += b33 * f31
    s += b34 * f41
    t31 = s
    s = 0.0
    s += b30 * f02
    s += b31 * f12
    s += b32 * f22
    s += b33 * f32
    s += b34 * f42
    t32 = s
    s = 0.0
    s += b30 * f03
    s += b31 * f13
    s += b32 * f23
    s += b33 * f33
    s += b34 * f43
    t33 = s
    s = 0.0
    s += b30 * f04
    s += b31 * f14
    s += b32 * f24
    s += b33 * f34
    s += b34 * f44
    t34 = s
    s = 0.0
    s += b40 * f00
    s += b41 * f10
    s += b42 * f20
    s += b43 * f30
    s += b44 * f40
    t40 = s
    s = 0.0
    s += b40 * f01
    s += b41 * f11
    s += b42 * f21
    s += b43 * f31
    s += b44 * f41
    t41 = s
    s = 0.0
    s += b40 * f02
    s += b41 * f12
    s += b42 * f22
    s += b43 * f32
    s += b44 * f42
    t42 = s
    s = 0.0
    s += b40 * f03
    s += b41 * f13
    s += b42 * f23
    s += b43 * f33
    s += b44 * f43
    t43 = s
    s = 0.0
    s += b40 * f04
    s += b41 * f14
    s += b42 * f24
    s += b43 * f34
    s += b44 * f44
    t44 = s
    s = 0.0
    s += f00 * t00
    s += f10 * t10
    s += f20 * t20
    s += f30 * t30
    s += f40 * t40
    o00 = s
    s = 0.0
    s += f00 * t01
    s += f10 * t11
    s += f20 * t21
    s += f30 * t31
    s += f40 * t41
    o01 = s
    s = 0.0
    s += f00 * t02
    s += f10 * t12
    s += f20 * t22
    s += f30 * t32
    s += f40 * t42
    o02 = s
    s = 0.0
    s += f00 * t03
    s += f10 * t13
    s += f20 * t23
    s += f30 * t33
    s += f40 * t43
    o03 = s
    s = 0.0
    s += f00 * t04
    s += f10 * t14
    s += f20 * t24
    s += f30 * t34
    s += f40 * t44
    o04 = s
    s = 0.0
    s += f01 * t00
    s += f11 * t10
    s += f21 * t20
    s += f31 * t30
    s += f41 * t40
    o10 = s
    s = 0.0
    s += f01 * t01
    s += f11 * t11
    s += f21 * t21
    s += f31 * t31
    s += f41 * t41
    o11 = s
    s = 0.0
    s += f01 * t02
    s += f11 * t12
    s += f21 * t22
    s += f31 * t32
    s += f41 * t42
    o12 = s
    s = 0.0
    s += f01 * t03
    s += f11 * t13
    s += f21 * t23
    s += f31 * t33
    s += f41 * t43
    o13 = s
    s = 0.0
    s += f01 * t04
    s += f11 * t14
    s += f21 * t24
    s += f31 * t34
    s += f41 * t44
    o14 = s
    s = 0.0
    s += f02 * t00
    s += f12 * t10
    s += f22 * t20
    s += f32 * t30
    s += f42 * t40
    o20 = s
    s = 0.0
    s += f02 * t01
    s += f12 * t11
    s += f22 * t21
    s += f32 * t31
    s += f42 * t41
    o21 = s
    s = 0.0
    s += f02 * t02
    s += f12 * t12
    s += f22 * t22
    s += f32 * t32
    s += f42 * t42
    o22 = s
    s = 0.0
    s += f02 * t03
    s += f12 * t13
    s += f22 * t23
    s += f32 * t33
    s += f42 * t43
    o23 = s
    s = 0.0
    s += f02 * t04
    s += f12 * t14
    s += f22 * t24
    s += f32 * t34
    s += f42 * t44
    o24 = s
    s = 0.0
    s += f03 * t00
    s += f13 * t10
    s += f23 * t20
    s += f33 * t30
    s += f43 * t40
    o30 = s
    s = 0.0
    s += f03 * t01
    s += f13 * t11
    s += f23 * t21
    s += f33 * t31
    s += f43 * t41
    o31 = s
    s = 0.0
    s += f03 * t02
    s += f13 * t12
    s += f23 * t22
    s += f33 * t32
    s += f43 * t42
    o32 = s
    s = 0.0
    s += f03 * t03
    s += f13 * t13
    s += f23 * t23
    s += f33 * t33
    s += f43 * t43
    o33 = s
    s = 0.0
    s += f03 * t04
    s += f13 * t14
    s += f23 * t24
    s += f33 * t34
    s += f43 * t44
    o34 = s
    s = 0.0
    s += f04 * t00
    s += f14 * t10
    s += f24 * t20
    s += f34 * t30
    s += f44 * t40
    o40 = s
    s = 0.0
    s += f04 * t01
    s += f14 * t11
    s += f24 * t21
    s += f34 * t31
    s += f44 * t41
    o41 = s
    s = 0.0
    s += f04 * t02
    s += f14 * t12
    s += f24 * t22
    s += f34 * t32
    s += f44 * t42
    o42 = s
    s = 0.0
    s += f04 * t03
    s += f14 * t13
    s += f24 * t23
    s += f34 * t33
    s += f44 * t43
    o43 = s
    s = 0.0
    s += f04 * t04
    s += f14 * t14
    s += f24 * t24
    s += f34 * t34
    s += f44 * t44
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
    s += f00 * v0
    s += f10 * v1
    s += f20 * v2
    s += f30 * v3
    s += f40 * v4
    info_vec[0, l] = s
    s = 0.0
    s += f01 * v0
    s += f11 * v1
    s += f21 * v2
    s += f31 * v3
    s += f41 * v4
    info_vec[1, l] = s
    s = 0.0
    s += f02 * v0
    s += f12 * v1
    s += f22 * v2
    s += f32 * v3
    s += f42 * v4
    info_vec[2, l] = s
    s = 0.0
    s += f03 * v0
    s += f13 * v1
    s += f23 * v2
    s += f33 * v3
    s += f43 * v4
    info_vec[3, l] = s
    s = 0.0
    s += f04 * v0
    s += f14 * v1
    s += f24 * v2
    s += f34 * v3
    s += f44 * v4
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
