"""The Kalman core: forward filter, backward filter, optimal states, χ², outliers (docs/physics.md#the-kalman-core).

One compiled core for every Kalman fitter; the extrapolator is passed in (a NamedTuple
context, see `pkf.fit.extrapolator`). Tracks come in batches as CSR arrays: the nodes
(measurements, sorted by z, at most one per layer) of track t are
``offsets[t]:offsets[t+1]``. Each node holds one or two scalar measurements
m_j = hx_j·x + hy_j·y + noise(σ_j) (pixel: x and y; strip: u = x·cos α + y·sin α).

Per iteration:

1. Forward filter (paper eqs. 1–8) from the seed at the first node: extrapolate
   (x_k|k−1 = f(x_k−1|k−1), P_k|k−1 = F·P·Fᵀ + Q) and update with each active node.
2. Backward filter, downstream → upstream, in information form (Y, y) starting from
   *no* information at the last node, so it is independent of the forward filter. It
   uses the same linearised model x_k = a_k + F_k·x_k−1 + w_k (a_k = f(r) − F_k·r at the
   forward linearisation point r), hence no second pass of extrapolations. y is the
   information vector of δ_k = x_k − x_p,k, the offset from the forward prediction, so
   that it carries residuals, not the measured values themselves (in absolute form the
   large terms h·m/σ² and Y·x cancel: against a 40-digit evaluation of the same filter
   on 268 nodes the optimal states were off by 5e-9 σ (median; worst 7e-7 σ), relative
   to x_p by 4e-11 σ (worst 4.5e-9 σ); what remains is the conditioning of I + Y·Q,
   up to 3e11): update Y += h·hᵀ/σ², y += h·(m − h·x_p)/σ²;
   propagate Y ← Fᵀ(I + Y·Q)⁻¹·Y·F, y ← Fᵀ(I + Y·Q)⁻¹·(y − Y·a′) with
   a′ = a_k + F·x_p,k−1 − x_p,k = F·(x_p,k−1 − x_f,k−1) (x_p,k = a_k + F·x_f,k−1).
3. Optimal state at every node = weighted mean of the forward prediction and the
   backward filtered state (paper §3): C = (P⁻¹ + Y)⁻¹, x = x_p + C·y (y on δ), with
   L·D·Lᵀ inverses; the backward filter keeps each node's (Y, y), and the weighted means
   are formed afterwards, LANES = 8 nodes at a time in SIMD lanes (`_combine_nodes`,
   `invert_spd_ldl_lane`: lane by lane bitwise `invert_spd_ldl`); the filters write its
   inputs straight into lanes (`_to_lanes55`). The backward step's M·Y and M·(y − Y·a)
   come from one solve with I + Y·Q (`_solve_general`, run as its straight-line form
   `pkf.physics.linalg.solve5`).
   `SMOOTHER_RTS` computes the same states with the Rauch–Tung–Striebel smoother
   instead; a test checks they agree.
4. Track χ² = the sum of the forward filter's increments r_k|k−1ᵀ S_k⁻¹ r_k|k−1 (paper
   eq. 9), which for a linear Gaussian model equals the smoothed measurement residuals'
   χ² plus the χ² of the fitted scattering kinks and follows χ²(ndf), ndf = Σ
   measurement dimensions − 5. docs/physics.md#the-kalman-core wrote Σ r_kᵀ R_k⁻¹ r_k with the smoothed
   residuals and R = V − H·C·Hᵀ: that sum has mean Σ dimensions, not ndf (measured:
   χ²/ndf = 1.34 on telescope tracks), so it serves only as each node's standardised
   χ² for the outlier test.

The first iteration of a track linearises each step at the forward filtered state
(extended Kalman filter); later iterations, and refits after an outlier was removed,
linearise around the previous optimal states (a reference trajectory). Outlier removal: the active node whose
standardised χ² exceeds its cut by the largest factor is deactivated and the track
refitted, at most `max_outliers` times (the loop every fitter shares, `pkf.fit.driver`,
which runs the core as `KalmanFitter`); the cut for 2-D (pixel) nodes is the one with
the same false-removal probability as `--outlier-chi2` for 1-D nodes (9 → 11.83). An
outlier node gets no update (its filtered state is the prediction) but still receives
an optimal state.

Speed (parametrized, one pass, no outlier removal, the compiled track loop alone, CPU
time, min of 7 repeats, 3 rounds alternating with the checkout before issue 18's changes,
on the shared 2-core machine under load, `benchmarks/fit_core.py`). Minimum-bias long
tracks (``--sample minbias``: 8,907 tracks / 257,055 nodes): full fit 660–758 ns/node
(before: 925–1,149; ×0.66–0.74 in each round), forward filter 408–440 (544–640), backward
filter + combination 252–339 (343–509). π-gun long tracks (3,390 / 86,806 nodes): full
523–559 (675–907; ×0.58–0.81), forward 282–397 (314–402), backward + combination
126–277 (353–505). Every output is bitwise what it was. What did it: the combination as
one SIMD loop over 8 nodes (119 → 50 ns/node alone; the ~20 ns of it that remain are the
gathers into lanes), the state and covariance being filtered and the backward filter's
Y on the stack (`pkf.jit.stack_array`: kept in registers, no aliasing with the node
arrays; the forward filter ×0.93, the backward ×0.9), Y·Q and Fᵀ·A·F without their
exact zeros (`matmul_noise`, `transport_info`). Where the rest goes (minimum bias, per
node): the extrapolation ~130 ns (`pkf.params.transport`), the forward update ~110, the
backward step ~200, the combination ~50; and the 12 % of long tracks below the UT→SciFi
table's p_min of 3 GeV take its RK4 fallback through the field map, ~2,000 ns/node on
those tracks, ~165 ns/node averaged over all (a table down to 1.5 GeV, LHCb's p_min,
would remove it). Both filters are chains of dependent steps, each waiting for the last
(the update's division, the elimination's five pivots): one track at a time is
latency-bound, and the backward step in SIMD lanes over the columns of its products
gained only 5 % (not kept). The next step was several tracks in SIMD lanes at once
(below).

Issue 18.1 (same protocol, `fit_core`'s loop in two long-lived processes, main cc35fa3
and this code alternating, 4 rounds of min-of-5, the machine under load 4–5 on 2 cores),
minimum bias: full fit 475 → 406 ns/node (×0.84–0.86 in each round), forward filter
254 → 241 (×0.94–0.97), backward + combination 226 → 166; the reference fitter 3,614 →
3,117 (×0.85–0.87; reference/parametrized 7.6 → 7.7). The telescope of
benchmarks/vs_acts.py (2,000 tracks of 10 nodes): `fit_batch` 5.06 → 4.45 µs per track,
the kernel alone 4.37 → 3.75. Every output (states, covariances, node and track χ²,
status; parametrized and reference) bitwise what it was. What did it: the solve with
I + Y·Q as straight-line code on scalars (`solve5`; the rolled loops kept the matrices
in memory, each pivot's elimination waiting on the stores of the last: backward +
combination −25 ns/node), the combination's inputs written into lanes by the filters
instead of gathered (−20 ns/node with the next), the UT→SciFi table stored cell-major
(`ParameterSet.extrapolator`: its share of the CPU samples 10.3 → 7.6 %), the forward
filter's per-node covariance copies skipped when nothing reads them (−2 %), and a
write prefetch of the next block's output rows in `_combine_nodes` (−2 to −3 %). Where
the ~400 ns/node go now (perf, samples mapped to the compiled functions): backward
filter 30 %, forward filter 18–20 %, combination 15–18 % (of which ~6 points are the
stores of the output covariances: 200 bytes per node into a 51 MB array, write-allocate
misses; in the forward-only loop the same copy is 11 %), extrapolation 27 %
(parametrized_step 10 %, layer steps 6 %, the UT→SciFi table 7.6 %, its RK4 fallback
3 %). Tried, measured, not kept: a branch-free bisection in `search_sorted` (nothing);
prefetching the UT→SciFi cells when a track leaves the VELO (forward filter 3–4 %
slower).

Tracks in SIMD lanes (issue 18.1, `pkf.fit.kalman_lanes`): the track loop of the fitters
with the weighted mean (`fit_batch`, `pkf reconstruct`) runs each track's forward filter
here (`SMOOTHER_DEFERRED`) and the backward filter and combination of 8 tracks at once in
SIMD lanes, the outlier refits through the scalar loop; every output bitwise that of the
scalar loop. `benchmarks/fit_core.py --sample minbias --fitters parametrized,reference
--repeat 5`, main and this code alternating, 2 rounds: parametrized full 390/403 →
365/374 ns/node (×0.93), backward + combination 160/167 → 134/138; reference 2,884/2,942
→ 2,906/2,908 (unchanged; reference/parametrized 7.3–7.4 → 7.8–8.0). As `pkf reconstruct`
runs it (`fit_batch`, 2 passes, outlier removal: a track with an outlier continues in
the scalar loop from its lane fit), parametrized on the same tracks: 863/890 → 790/784
ns/node (×0.88–0.92), outputs and locations bitwise main's (parametrized and reference).
Far from the issue's 200 ns/node: moving a node's numbers into lanes costs about what the
lanes gain (that module records what was tried and measured).

Per-node track states (ACTS's predicted / filtered / smoothed, seeds/002): the forward
filter's predicted and filtered states of the last fit are scratch of `KalmanFitter`;
given a `NodeStages` record with rows (`node_stages`), the fitter copies them there
after each track's last fit (`_kalman_end`); a fit that does not ask for them does the
same arithmetic as before they existed, plus one test per track (measured: no change). The smoothed states are the driver's
output states (`SMOOTHER_NONE`: none; the output states are then the filtered ones).

Helpers the GX2F and the GSF call rather than copy: `scalar_update` (the measurement
update), `add_node_information` and `transport_information` (measurements in
information form and their transport upstream).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.driver import register_fitter
from pkf.fit.extrapolator import extrapolate
from pkf.physics.linalg import (
    LANES,
    add_matvec5,
    copy5,
    copy55,
    invert_spd_ldl_lane,
    invert_spd_triangular,
    matmul55,
    matmul_noise,
    transport_info,
    matvec5,
    matvec5_t,
    sandwich,
    solve5,
    symmetrise,
    transport_cov,
    zero5,
    zero55,
)
from pkf.fit.status import STATUS_NOT_POSITIVE_DEFINITE, STATUS_OK
from pkf.jit import NO_REFCOUNT, fma, prefetch_write_rows, stack_array

SMOOTHER_WEIGHTED_MEAN = 0
SMOOTHER_RTS = 1
SMOOTHER_NONE = 2  # forward filter only (filtered states as output): for timing studies
SMOOTHER_DEFERRED = 3  # forward filter only, P_k|k−1 kept, no outputs: the caller combines (`pkf.fit.kalman_lanes`)


class NodeStages(NamedTuple):
    """Track states at every node of a batch (rows: the batch's nodes) from each track's
    last fit: the predicted, filtered and smoothed states (x, y [mm], tx, ty, q/p [1/MeV])
    and their 5×5 covariances; an outlier's filtered state is its predicted one. Zero
    rows: not kept (the smoothed rows only for fitters whose output is not the smoothed
    state itself, e.g. the GSF's mixture means)."""

    predicted: np.ndarray
    predicted_cov: np.ndarray
    filtered: np.ndarray
    filtered_cov: np.ndarray
    smoothed: np.ndarray
    smoothed_cov: np.ndarray


def node_stages(n_nodes: int, smoothed: bool = False) -> NodeStages:
    """A `NodeStages` record for `n_nodes` nodes (NaN until a fit writes them; 0: not kept),
    with smoothed rows if `smoothed`."""
    n_smoothed = n_nodes if smoothed else 0
    return NodeStages(
        np.full((n_nodes, 5), np.nan),
        np.full((n_nodes, 5, 5), np.nan),
        np.full((n_nodes, 5), np.nan),
        np.full((n_nodes, 5, 5), np.nan),
        np.full((n_smoothed, 5), np.nan),
        np.full((n_smoothed, 5, 5), np.nan),
    )


@nb.njit(cache=True, inline="always")
def _solve_general(a, b, v):
    """b ← a⁻¹·b (5×5) and v ← a⁻¹·v (5) for a general 5×5 matrix a (destroyed): Gaussian
    elimination with partial pivoting on the augmented matrix [a | b | v], then back
    substitution; one pass instead of an LU inverse and two products
    (~180 multiply–adds instead of ~440). False if a is singular."""
    for c in range(5):
        pivot = c
        best = abs(a[c, c])
        for r in range(c + 1, 5):
            if abs(a[r, c]) > best:
                best = abs(a[r, c])
                pivot = r
        if not best > 0.0 or not math.isfinite(best):
            return False
        if pivot != c:
            for j in range(5):
                t = a[c, j]
                a[c, j] = a[pivot, j]
                a[pivot, j] = t
                t = b[c, j]
                b[c, j] = b[pivot, j]
                b[pivot, j] = t
            t = v[c]
            v[c] = v[pivot]
            v[pivot] = t
        inv_p = 1.0 / a[c, c]
        a[c, c] = inv_p
        for r in range(c + 1, 5):
            f = a[r, c] * inv_p
            for j in range(c + 1, 5):
                a[r, j] = fma(-f, a[c, j], a[r, j])
            for j in range(5):
                b[r, j] = fma(-f, b[c, j], b[r, j])
            v[r] = fma(-f, v[c], v[r])
    for i in range(4, -1, -1):
        for j in range(5):
            t = b[i, j]
            for k in range(i + 1, 5):
                t = fma(-a[i, k], b[k, j], t)
            b[i, j] = t * a[i, i]
        t = v[i]
        for k in range(i + 1, 5):
            t = fma(-a[i, k], v[k], t)
        v[i] = t * a[i, i]
    return True


@nb.njit(cache=True, inline="always")
def scalar_update(x, p, hx, hy, m, var):
    """Kalman update of (x, P) in place with one scalar measurement m = hx·x + hy·y of
    variance var [mm²] (paper eqs. 4–8). Returns (r²/S, S): the χ² increment of the
    predicted residual r and its variance S = var + h·P·hᵀ; S ≤ 0 (nothing updated)
    if P is not positive definite along h. Every fitter's measurement update. One
    division (1/S, then products) instead of 21; the results differ from those of the
    divisions by rounding only."""
    r = m - fma(hy, x[1], hx * x[0])
    # P·h only involves the first two columns
    s = var
    ph0 = fma(hy, p[0, 1], hx * p[0, 0])
    ph1 = fma(hy, p[1, 1], hx * p[1, 0])
    s += fma(hy, ph1, hx * ph0)
    if not s > 0.0:
        return 0.0, s
    ph = (
        ph0,
        ph1,
        fma(hy, p[2, 1], hx * p[2, 0]),
        fma(hy, p[3, 1], hx * p[3, 0]),
        fma(hy, p[4, 1], hx * p[4, 0]),
    )
    inv_s = 1.0 / s  # one division, not 21: the gain K = P·h/S, then P −= K·(P·h)ᵀ
    for i in range(5):
        x[i] = fma(ph[i] * inv_s, r, x[i])
    for i in range(5):
        k = ph[i] * inv_s
        for j in range(i, 5):
            v = fma(-k, ph[j], p[i, j])
            p[i, j] = v
            p[j, i] = v
    return r * r * inv_s, s


@nb.njit(cache=True, inline="always")
def add_node_information(info, info_vec, n_meas, hx, hy, m, sigma, state):
    """Add one node's measurements in information form: Y += Σ_j h_jᵀh_j/σ_j²,
    y += Σ_j h_jᵀ(m_j − h_j·state)/σ_j² (state = 0: the measured values themselves; the
    current trajectory: its residuals). Y 5×5, y 5-vector, h_j = (hx_j, hy_j, 0, 0, 0)."""
    for j in range(n_meas):
        w = 1.0 / (sigma[j] * sigma[j])
        h0 = hx[j]
        h1 = hy[j]
        r = m[j] - fma(h1, state[1], h0 * state[0])
        info[0, 0] = fma(h0 * h0, w, info[0, 0])
        info[0, 1] = fma(h0 * h1, w, info[0, 1])
        info[1, 0] = fma(h0 * h1, w, info[1, 0])
        info[1, 1] = fma(h1 * h1, w, info[1, 1])
        info_vec[0] = fma(h0 * r, w, info_vec[0])
        info_vec[1] = fma(h1 * r, w, info_vec[1])


@nb.njit(cache=True, inline="always")
def transport_information(f, a, vec, out, tmp, tmp_vec):
    """Information of the state downstream of a step x′ = F·x, carried to upstream of it:
    out = Fᵀ·a·F (5×5, symmetrised; out may be a; `transport_info`) and vec ← Fᵀ·vec.
    tmp (5×5) and tmp_vec (5) are scratch."""
    transport_info(f, a, tmp, out)
    symmetrise(out)
    matvec5_t(f, vec, tmp_vec)
    copy5(tmp_vec, vec)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _fit_once(
    ext,
    z,
    n_meas,
    hx,
    hy,
    m,
    sigma,
    active,
    seed,
    seed_cov,
    use_reference,
    ref,
    pred,
    pred_cov,
    filt,
    filt_cov,
    jac,
    noise,
    smoother,
    out_state,
    out_cov,
    mats,
    vec5,
    perm,
    info_at,
    info_vec_at,
    pred_lanes,
    pred_cov_lanes,
    keep_covs,
):
    """One forward + backward + combination pass over the n nodes of one track.

    Arrays pred…noise/ref are per-node scratch (first n rows used), info_at/info_vec_at/
    pred_lanes/pred_cov_lanes per-node scratch in lanes (`_combine_nodes`); out_state/out_cov
    receive the optimal states. pred_cov/filt_cov are written only if keep_covs or the
    smoother needs them (the weighted mean does not: it takes pred_cov_lanes; with
    SMOOTHER_DEFERRED pred_cov only, and nothing else after the forward filter). Returns
    (status code, track χ²).
    """
    n = z.size
    lanes = smoother == SMOOTHER_WEIGHTED_MEAN
    deferred = smoother == SMOOTHER_DEFERRED
    keep_covs = keep_covs or not (lanes or deferred)
    lin = stack_array((5,))  # scratch on the stack (see `_backward_information_filter`)
    chi2 = 0.0
    tmp = stack_array((5, 5))
    step_work = stack_array((6, 5, 5))
    # ---- forward filter
    # The seed prior: at the pattern estimate, or, once a previous fit exists, at its
    # optimal first state, so that the prior biases nothing at convergence.
    # The state and covariance being filtered stay on the stack from node to node
    # (`state`, `cov`); each node's prediction and filtered state are copied out.
    state = stack_array((5,))
    cov = stack_array((5, 5))
    copy5(ref[0] if use_reference else seed, state)
    copy55(seed_cov, cov)
    for k in range(n):
        if k > 0:
            if use_reference:
                copy5(ref[k - 1], lin)
            else:
                copy5(state, lin)
            status = extrapolate(ext, lin, z[k - 1], z[k], pred[k], jac[k], noise[k], step_work)
            if status != STATUS_OK:
                return status, chi2
            if use_reference:
                for i in range(5):
                    s = 0.0
                    for j in range(5):
                        s = fma(jac[k, i, j], state[j] - lin[j], s)
                    pred[k, i] += s
            transport_cov(jac[k], cov, tmp, cov)
            for i in range(5):
                for j in range(5):
                    cov[i, j] += noise[k, i, j]
            copy5(pred[k], state)
        else:
            copy5(state, pred[0])
        if keep_covs or deferred:
            copy55(cov, pred_cov[k])
        if lanes:  # the combination's inputs, already in lanes
            _to_lanes5(state, pred_lanes, k)
            _to_lanes55(cov, pred_cov_lanes, k)
        if active[k]:
            for j in range(n_meas[k]):
                increment, s = scalar_update(state, cov, hx[k, j], hy[k, j], m[k, j], sigma[k, j] ** 2)
                if not s > 0.0:
                    copy5(state, filt[k])
                    copy55(cov, filt_cov[k])
                    return STATUS_NOT_POSITIVE_DEFINITE, chi2
                chi2 += increment
        copy5(state, filt[k])
        if keep_covs:
            copy55(cov, filt_cov[k])
    if deferred:
        return STATUS_OK, chi2
    if smoother == SMOOTHER_NONE:
        for k in range(n):
            copy5(filt[k], out_state[k])
            copy55(filt_cov[k], out_cov[k])
        return STATUS_OK, chi2
    if smoother == SMOOTHER_RTS:
        status = _rts_smoother(n, pred, pred_cov, filt, filt_cov, jac, out_state, out_cov, mats, vec5, perm)
    else:
        status = _backward_information_filter(
            n,
            n_meas,
            hx,
            hy,
            m,
            sigma,
            active,
            pred,
            pred_lanes,
            pred_cov_lanes,
            filt,
            jac,
            noise,
            out_state,
            out_cov,
            info_at,
            info_vec_at,
        )
    return status, chi2


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _backward_information_filter(
    n,
    n_meas,
    hx,
    hy,
    m,
    sigma,
    active,
    pred,
    pred_lanes,
    pred_cov_lanes,
    filt,
    jac,
    noise,
    out_state,
    out_cov,
    info_at,
    info_vec_at,
):
    """Backward information filter and weighted-mean combination (see module docstring),
    with y relative to the forward prediction at each node (δ = x − x_p).

    Two passes: the filter, downstream → upstream, keeps each node's (Y, y) in
    info_at/info_vec_at (in lanes, `_to_lanes55`); then `_combine_nodes` forms the weighted
    means of them and the forward predictions (pred_lanes, pred_cov_lanes), LANES nodes at a
    time. Bitwise the states of one pass that combines at each node before moving on (the
    same operations on the same numbers), and the same outputs on failure: the nodes
    downstream of the first failure (in the filter's order) are written, no others."""
    # scratch on the stack: no array of the caller's aliases it, so LLVM keeps it in registers
    info = stack_array((5, 5))  # Y
    info_vec = stack_array((5,))  # y of δ_k = x_k − x_p,k
    shift = stack_array((5,))
    vec5 = stack_array((5,))
    a = stack_array((5, 5))
    tmp = stack_array((5, 5))
    tmp2 = stack_array((5, 5))
    zero5(info_vec)
    zero55(info)
    status = STATUS_OK
    lowest = 0  # the lowest node whose (Y, y) is known
    for k in range(n - 1, -1, -1):
        if active[k]:  # the residuals m − h·x_p enter
            add_node_information(info, info_vec, n_meas[k], hx[k], hy[k], m[k], sigma[k], pred[k])
        _to_lanes55(info, info_at, k)
        _to_lanes5(info_vec, info_vec_at, k)
        if k == 0:
            break
        # propagate to node k−1: δ_k = F·δ_k−1 + a + w with a = F·(x_p,k−1 − x_f,k−1) (as
        # x_p,k = f(r) + F·(x_f,k−1 − r)); M = (I + Y·Q)⁻¹; Y ← Fᵀ·M·Y·F; y ← Fᵀ·M·(y − Y·a)
        for i in range(5):
            vec5[i] = pred[k - 1, i] - filt[k - 1, i]
        matvec5(jac[k], vec5, shift)
        matmul_noise(info, noise[k], a)
        for i in range(5):
            a[i, i] += 1.0
        for i in range(5):
            s = info_vec[i]
            for j in range(5):
                s = fma(-info[i, j], shift[j], s)
            info_vec[i] = s
        copy55(info, tmp)
        if not solve5(a, tmp, info_vec):  # M·Y, M·(y − Y·a) (`_solve_general` written out)
            status = STATUS_NOT_POSITIVE_DEFINITE
            lowest = k
            break
        # Y ← Fᵀ·(M·Y)·F, y ← Fᵀ·M·(y − Y·a)
        transport_information(jac[k], tmp, info_vec, info, tmp2, vec5)
    if not _combine_nodes(lowest, n, pred_lanes, pred_cov_lanes, info_at, info_vec_at, out_state, out_cov):
        return STATUS_NOT_POSITIVE_DEFINITE
    return status


@nb.njit(cache=True, inline="always")
def _to_lanes5(v, lanes, k):
    """Node k's 5-vector v into lanes (blocks, 5, LANES): block k // LANES, lane k % LANES."""
    blk = k // LANES
    lane = k - blk * LANES
    for i in range(5):
        lanes[blk, i, lane] = v[i]


@nb.njit(cache=True, inline="always")
def _to_lanes55(a, lanes, k):
    """Node k's 5×5 matrix a into lanes (blocks, 5, 5, LANES): block k // LANES, lane k % LANES."""
    blk = k // LANES
    lane = k - blk * LANES
    for i in range(5):
        for j in range(5):
            lanes[blk, i, j, lane] = a[i, j]


def lanes_scratch(n_nodes: int, matrix: bool) -> np.ndarray:
    """Zeroed per-node scratch in lanes for `n_nodes` nodes: (blocks, 5, 5, LANES) for
    matrices, (blocks, 5, LANES) for vectors (`_to_lanes5`, `_to_lanes55`). Zeroed, so that
    the lanes of a block past a track's nodes hold numbers (`_combine_nodes` computes
    them and discards them)."""
    blocks = max(1, -(-n_nodes // LANES))
    return np.zeros((blocks, 5, 5, LANES) if matrix else (blocks, 5, LANES))


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _combine_nodes(lo, hi, x_p, p, info, info_vec, out_state, out_cov):
    """The weighted mean of the forward prediction (x_p, P) and the backward filtered
    information (Y, y) on δ = x − x_p at nodes hi−1 … lo (paper §3, in information form):
    C = (P⁻¹ + Y)⁻¹ and x = x_p + C·y. The inputs are in lanes (`_to_lanes5`,
    `_to_lanes55`: node k in block k // LANES, lane k % LANES), written there by the
    filters, so a block's LANES nodes go through the vectorised L·D·Lᵀ inverses
    (`invert_spd_ldl_lane`, each lane bitwise what `invert_spd_ldl` gives) without
    gathering them first (the gathers were ~20 ns per node); every lane of a block is
    computed (a full SIMD loop), those outside lo…hi−1 discarded. Writes out_state/out_cov
    downstream → upstream, and stops at the first node where P or P⁻¹ + Y is not positive
    definite (nothing written there) or C has a diagonal element ≤ 0 (written there):
    returns False then."""
    a_lanes = stack_array((5, 5, LANES))
    c_lanes = stack_array((5, 5, LANES))
    x_lanes = stack_array((5, LANES))
    bad_pivot = stack_array((LANES,))
    bad_diag = stack_array((LANES,))
    top = hi
    while top > lo:
        blk = (top - 1) // LANES
        base = blk * LANES
        p_blk = p[blk]
        y_blk = info[blk]
        x_blk = x_p[blk]
        v_blk = info_vec[blk]
        # the next block's output rows (nodes max(lo, base − LANES) … base − 1), for writing
        nxt = max(lo, base - LANES)
        prefetch_write_rows(out_cov, nxt, base)
        prefetch_write_rows(out_state, nxt, base)
        for l in range(LANES):  # one SIMD loop over the lanes
            bad_pivot[l] = 0.0
            invert_spd_ldl_lane(p_blk, c_lanes, bad_pivot, l)  # P⁻¹
            for i in range(5):
                for j in range(5):
                    a_lanes[i, j, l] = c_lanes[i, j, l] + y_blk[i, j, l]
            invert_spd_ldl_lane(a_lanes, c_lanes, bad_pivot, l)  # C = (P⁻¹ + Y)⁻¹
            bad = 0.0
            for i in range(5):  # x = x_p + C·y (`add_matvec5`); diag(C) > 0
                s = x_blk[i, l]
                for k in range(5):
                    s = fma(c_lanes[i, k, l], v_blk[k, l], s)
                x_lanes[i, l] = s
                bad = bad if c_lanes[i, i, l] > 0.0 else 1.0
            bad_diag[l] = bad
        for k in range(top - 1, max(lo, base) - 1, -1):
            l = k - base
            if bad_pivot[l] != 0.0:
                return False
            for i in range(5):
                out_state[k, i] = x_lanes[i, l]
                for j in range(5):
                    out_cov[k, i, j] = c_lanes[i, j, l]
            if bad_diag[l] != 0.0:
                return False
        top = base
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def _rts_smoother(n, pred, pred_cov, filt, filt_cov, jac, out_state, out_cov, mats, vec, perm):
    """Rauch–Tung–Striebel smoother over the forward pass (the alternative combination)."""
    vec5 = vec[:5]
    spd_vec = vec[10:20]
    gain = mats[2]
    inv = mats[3]
    tmp = mats[0]
    tmp2 = mats[1]
    lu = mats[5]
    copy5(filt[n - 1], out_state[n - 1])
    copy55(filt_cov[n - 1], out_cov[n - 1])
    for k in range(n - 2, -1, -1):
        # A = P_k|k · F_k+1ᵀ · P_k+1|k⁻¹
        if not invert_spd_triangular(pred_cov[k + 1], inv, lu, spd_vec):
            return STATUS_NOT_POSITIVE_DEFINITE
        for i in range(5):
            for j in range(5):
                s = 0.0
                for l in range(5):
                    s = fma(filt_cov[k, i, l], jac[k + 1, j, l], s)
                tmp[i, j] = s
        matmul55(tmp, inv, gain)
        for i in range(5):
            vec5[i] = out_state[k + 1, i] - pred[k + 1, i]
        add_matvec5(filt[k], gain, vec5, out_state[k])
        for i in range(5):
            for j in range(5):
                tmp2[i, j] = out_cov[k + 1, i, j] - pred_cov[k + 1, i, j]
        sandwich(gain, tmp2, tmp, out_cov[k])
        for i in range(5):
            for j in range(5):
                out_cov[k, i, j] += filt_cov[k, i, j]
        symmetrise(out_cov[k])
        for i in range(5):
            if not out_cov[k, i, i] > 0.0:
                return STATUS_NOT_POSITIVE_DEFINITE
    return STATUS_OK


class KalmanFitter(NamedTuple):
    """The Kalman core as a fitter of `pkf.fit.driver.fit_tracks`: the extrapolator
    context, the number of passes (the 2nd and later linearise around the previous
    optimal states), the combination (SMOOTHER_*), per-node scratch for the batch's
    longest track (`kalman_fitter` allocates it; info/info_vec: the backward filter's
    (Y, y) at each node, pred_lanes/pred_cov_lanes the forward predictions, all in lanes
    for `_combine_nodes`), and `stages`, where each track's predicted and filtered states
    go after its last fit (zero rows: nowhere)."""

    ext: tuple
    n_iterations: int
    smoother: int
    measurement_only_fallback: bool
    have_reference: np.ndarray
    ref: np.ndarray
    pred: np.ndarray
    pred_cov: np.ndarray
    filt: np.ndarray
    filt_cov: np.ndarray
    jac: np.ndarray
    noise: np.ndarray
    mats: np.ndarray
    vec5: np.ndarray
    perm: np.ndarray
    stages: NodeStages
    info: np.ndarray
    info_vec: np.ndarray
    pred_lanes: np.ndarray
    pred_cov_lanes: np.ndarray


def kalman_fitter(
    ext, n_nodes: int, n_iterations: int = 1, smoother: int = SMOOTHER_WEIGHTED_MEAN, stages: NodeStages | None = None
) -> KalmanFitter:
    """The Kalman fitter of extrapolator context `ext` with scratch for tracks of up to
    `n_nodes` nodes; it keeps the predicted and filtered states in `stages` if given."""
    return KalmanFitter(
        ext,
        int(n_iterations),
        int(smoother),
        False,
        np.zeros(1, dtype=np.bool_),
        np.empty((n_nodes, 5)),
        np.empty((n_nodes, 5)),
        np.empty((n_nodes, 5, 5)),
        np.empty((n_nodes, 5)),
        np.empty((n_nodes, 5, 5)),
        np.empty((n_nodes, 5, 5)),
        np.empty((n_nodes, 5, 5)),
        np.empty((6, 5, 5)),
        np.empty(25),
        np.empty(5, dtype=np.int64),
        node_stages(0) if stages is None else stages,
        lanes_scratch(n_nodes, True),
        lanes_scratch(n_nodes, False),
        lanes_scratch(n_nodes, False),
        lanes_scratch(n_nodes, True),
    )


@nb.njit(cache=True, inline="always")
def _kalman_begin(f, t, seed):
    """A new track: the first pass linearises at the forward filtered states."""
    f.have_reference[0] = False
    return STATUS_OK


@nb.njit(cache=True, inline="always")
def _kalman_fit(f, t, lo, hi, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, out_state, out_cov):
    """`n_iterations` passes of `_fit_once`; each later pass (and a refit after an
    outlier) linearises around the previous pass's optimal states."""
    status = STATUS_OK
    chi2 = 0.0
    for it in range(max(1, f.n_iterations)):
        status, chi2 = _fit_once(
            f.ext,
            z,
            n_meas,
            hx,
            hy,
            m,
            sigma,
            active,
            seed,
            seed_cov,
            f.have_reference[0],
            f.ref,
            f.pred,
            f.pred_cov,
            f.filt,
            f.filt_cov,
            f.jac,
            f.noise,
            f.smoother,
            out_state,
            out_cov,
            f.mats,
            f.vec5,
            f.perm,
            f.info,
            f.info_vec,
            f.pred_lanes,
            f.pred_cov_lanes,
            f.stages.predicted.shape[0] > 0,
        )
        if status != STATUS_OK:
            break
        for k in range(z.size):
            copy5(out_state[k], f.ref[k])
        f.have_reference[0] = True
    return status, chi2


@nb.njit(cache=True, **NO_REFCOUNT)
def _keep_stages(f, lo, hi):
    """Copy the forward filter's scratch of nodes 0…hi−lo−1 into rows lo:hi of f.stages."""
    s = f.stages
    for k in range(hi - lo):
        copy5(f.pred[k], s.predicted[lo + k])
        copy55(f.pred_cov[k], s.predicted_cov[lo + k])
        copy5(f.filt[k], s.filtered[lo + k])
        copy55(f.filt_cov[k], s.filtered_cov[lo + k])


@nb.njit(cache=True, inline="always")
def _kalman_end(f, t, lo, hi, status, out_state, out_cov):
    """Keep the last fit's predicted and filtered states in `f.stages` (if it has rows)."""
    if f.stages.predicted.shape[0] > 0:
        _keep_stages(f, lo, hi)


register_fitter(KalmanFitter, _kalman_begin, _kalman_fit, _kalman_end, allocates=False)
