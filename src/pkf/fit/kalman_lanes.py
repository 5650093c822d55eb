"""The Kalman core's track loop with the backward filter over GROUP tracks in SIMD lanes (issue 18.1).

`pkf.fit.kalman` fits one track at a time; both of its filters are chains of dependent
steps (the update's division, the solve's five pivots), so one track is latency-bound.
Here a group of GROUP tracks runs together in the structure-of-arrays layout of CMS
mkFit's Matriplex: the backward information filter's step (`info_step_lane`:
F·(x_p − x_f), I + Y·Q, the pivoting solve with its row swaps as selects, Fᵀ·(M·Y)·F,
Fᵀ·M·y) and the weighted-mean combination (`_combine_lane`, `invert_spd_ldl_lane`) work
on (5, 5, GROUP) stack arrays, lane l the matrix of track l, in loops over the lanes
whose body is straight-line code (`pkf.physics.lanes_codegen`), which LLVM issues as
SIMD over the tracks. The forward filter of each track is `_fit_once`'s own, one track
at a time (SMOOTHER_DEFERRED: it keeps F, Q, x_p, P_p, x_f in the track's rows of the
lane scratch, track-major, as it writes them); the backward filter gathers node k of the
lanes onto the stack (`_gather_node`).

Every lane performs the floating-point operations of the scalar core in the same order
(the multiply–adds are `pkf.jit.fma`, one rounding, on both sides), with dense products
where the scalar core leaves out exact zeros (`matmul_noise`, `transport_info`: bitwise
the same for finite inputs, hence only tracks with a finite seed and seed covariance
take the lanes): states, covariances, χ², node χ², active flags, status, ndf are bitwise those
of the scalar loop `pkf.fit.driver.fit_tracks_no_refcount` (tests/fit/
test_kalman_lanes.py: telescope tracks of unequal lengths, failing and NaN seeds; and,
checked by hashing every output, the 8,907 minimum-bias long tracks of
benchmarks/fit_core.py with the parametrized and the reference fitter, 1 and 2 passes,
max_outliers 0 and 3, weighted mean and forward only, two seeds broken on purpose).

Tracks of unequal lengths: sorted by number of nodes within windows of SORT_WINDOW
tracks (`lane_order`), so a group's lengths are close; each lane's (Y, y) starts empty
at its own last node, and a lane past its track's end computes on what is there and is
discarded. The outlier loop stays the shared one: after a group's lane fit (all
`n_iterations` passes), each track's node χ² (`find_outlier`); a track with an outlier
to remove continues in the shared loop from there (`pkf.fit.driver.refit_track`, with
the fitter's reference set as its first fit leaves it); one that failed anywhere, has
too few hits or a non-finite seed is fitted again from its start by
`pkf.fit.driver.fit_one_track`, which writes all its outputs. `pkf.fit.driver.track_loop` gives this loop (`fit_tracks_in_lanes`) to
`KalmanFitter`s with the weighted mean that keep no node stages (`fit_batch`, so `pkf
reconstruct`, and benchmarks/fit_core.py's full fit); forward only, RTS and
`track_states` keep the scalar loop.

Measured (fit_core's loop, minimum bias, 257,055 nodes, one pass, no outlier removal,
CPU time, min of 5, the scalar loop and this one alternating in one process, 3 rounds):
parametrized full fit 373–386 → 355–363 ns/node (×0.93–0.96; GROUP = 4: ×0.92–0.93);
reference ×0.99–1.01 (its RK4 dominates). `fit_batch` as `pkf reconstruct` runs it
(parametrized, 2 passes, outlier removal; main and this code alternating, 2 rounds):
863/890 → 790/784 ns/node (×0.88–0.92). The backward filter + combination alone went
from 160–190 to 50–70 ns/node when its inputs were already in (5, 5, GROUP) rows; what
the lanes gain there the forward side gives back: gathering or writing a node's 85
numbers into lanes (each a different cache line of the (…, 5, 5, GROUP) rows) measured
37 (node by node) to 107 (track by track) ns/node alone, and sorting the whole batch by
length costs the forward filter ~50 ns/node in cache misses (windows of 128: ~20).
The output rows (state and covariance, 240 bytes per node in arrays of tens of MB) are
prefetched for writing one node before the backward filter writes them
(`_prefetch_outputs`), as `pkf.fit.kalman._combine_nodes` does for its blocks: their
write-allocate misses had stalled the stores. Measured (`fit_tracks_in_lanes` alone,
parametrized, one pass, old and new code interleaved in one process, 16 rounds):
minimum bias (fit_core's 257,055 nodes) 341 → 319 ns/node, ×0.936 (quartiles
0.927–0.945; the same A/B with identical code on both sides: 1.004 and 1.010); the
telescope of benchmarks/vs_acts.py ×0.96 and ×0.95 in the two allocation orders,
relative to that null A/B (there, placement in memory alone moves the time by up to
±15 % between the two sides: 1.156 one way, 0.882 the other). Outputs bitwise the same.
Tried (all bitwise identical, none faster; branch fit19's history): the forward filter in
lanes too (F·P·Fᵀ + Q dense and the update with selects, SIMD over the tracks:
forward-only 235 → 379 ns/node), the scalar forward writing straight into the lanes
track by track (→ 434) or node by node over the lanes (→ 380), `_fit_once` then a copy
into lanes (→ 366), and the backward step reading F, Q in place from the track-major rows
instead of gathering them (no change), and (2026-12) the backward step without the exact
zeros and ones of F and Q where every lane's step has them (generated like
`info_step_lane`: VELO steps 123 instead of 460 products around the solve, layer steps
that keep q/p 315), chosen node by node: minimum bias ×1.002 (VELO steps only) and
×0.990 (both; quartiles 0.95–1.05) — the step waits on its chain of pivots, not on its
products; and (2026-12-06, branch exp) the lanes' rows made by 8×8 transposes in registers
(shufflevector: 8 vector loads, 24 shuffles) instead of the AVX2 gathers LLVM makes (znver3) of
`_gather_node` (perf put 43 % of this loop's samples on those gathers), with a read
prefetch of the next node's records and the outputs transposed likewise: bitwise the same,
fit_core minimum bias 287–290 → 294–312 ns/node (4 rounds, alternating processes) — the
samples on the gathers were the loop waiting there, not the gathers' own cost; a read
prefetch of the next group's node data (z, measurements, seed; the tracks of a group lie
scattered in the batch) 285–290 → 287–292; the forward step's state, F and Q on the stack,
copied to the node's rows after (`_fit_once`; branch exp2) forward 189–195 → 195–206. In a
separate kernel the forward filter alone (step, F·P·Fᵀ + Q, updates) takes 120–123 ns/node
in batch order with its outputs on the stack, 130–132 in `lane_order`, 138–140 with the
step's outputs in the node rows and 142–143 with the P_k|k−1 and x_k|k copies too, where the
lane loop's forward takes ~166: the remaining ~23 ns/node are the loop around it. Also
tried (2026-12-06, fit_core minimum bias, 4 rounds alternating with main, bitwise the same
outputs): the combination at node k and the step to k − 1 in one lane loop, one basic block
in which the step's chain of pivots could overlap the combination's inverses (branch
fuse): 286–294 → 295–297 ns/node, so this loop does not wait on that chain; a read
prefetch of the next track's UT→SciFi table cells (its seed carried straight to the
table's z, the 3 × 3 cells around, 144 lines) before each track's forward filter (branch
tpf): 285–302 → 288–299, within the noise (of the table step's ~500 ns its reads are
~100, the rest arithmetic: `pkf.params.ut_to_scifi._six_columns`); a read prefetch, one node ahead,
of the rows the backward filter gathers (x_p, P_p, x_f, F, Q: 40 streams per group, more
than the hardware prefetcher follows; branch bpf): 289–291 → 294–306; GROUP = 4 (256-bit
lanes, the same sort window of 128 tracks; branch g4): 287–293 → 287–302. So neither the
step's latency nor the rows' reads bound the backward loop; by a count of its source (not
of events: this VM has no hardware counters), a node of a group is ~1,000 8-wide
arithmetic operations and ~15 divisions, ~1,200–1,500 cycles where the core issues one
8-wide multiply–add per cycle, about half of the ~800 ns (~2,400 cycles at 3 GHz) it
takes. Next: fewer operations per
node — a forward filter whose F·P·Fᵀ uses the parametrized steps' structure in lanes (the
dense one costs more than the latency it hides), fewer numbers per node to move (F and Q
of a parametrized step have ~10 non-trivial entries each), a smoother of fewer products
that keeps the weighted mean's precision (`benchmarks/smoother_precision.py`).
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.driver import (
    count_ndf,
    finish_track,
    fit_one_track,
    fit_tracks_no_refcount,
    max_nodes,
    refit_track,
    register_track_loop,
    track_outlier,
)
from pkf.fit.kalman import SMOOTHER_DEFERRED, SMOOTHER_NONE, SMOOTHER_WEIGHTED_MEAN, KalmanFitter, _fit_once
from pkf.fit.status import STATUS_OK
from pkf.io.row_order import insertion_sort
from pkf.jit import NO_REFCOUNT, fma, prefetch_write_rows, stack_array
from pkf.physics.linalg import LANES, copy5, info_step_lane, invert_spd_ldl_lane

#: Tracks fitted together, one per SIMD lane (the lanes of `invert_spd_ldl_lane`).
GROUP = LANES


class LaneScratch(NamedTuple):
    """Per-node scratch of a group, node k of lane l at [l, k]: the transport F and noise
    Q into node k, the forward prediction and its covariance, the filtered state (track
    by track, as `_fit_once` writes them: no copy; the backward filter gathers node k of
    the lanes); per lane: the track, its first node, its number of nodes, alive (1.0: no
    failure so far), χ²; work: the extrapolator's (6, 5, 5) scratch."""

    jac: np.ndarray
    noise: np.ndarray
    pred: np.ndarray
    pred_cov: np.ndarray
    filt: np.ndarray
    track: np.ndarray
    first: np.ndarray
    n: np.ndarray
    alive: np.ndarray
    chi2: np.ndarray
    work: np.ndarray


def lane_scratch(n_nodes: int) -> LaneScratch:
    """`LaneScratch` for tracks of up to `n_nodes` nodes."""
    n_nodes = max(1, n_nodes)
    return LaneScratch(
        np.zeros((GROUP, n_nodes, 5, 5)),
        np.zeros((GROUP, n_nodes, 5, 5)),
        np.zeros((GROUP, n_nodes, 5)),
        np.zeros((GROUP, n_nodes, 5, 5)),
        np.zeros((GROUP, n_nodes, 5)),
        np.zeros(GROUP, dtype=np.int64),
        np.zeros(GROUP, dtype=np.int64),
        np.zeros(GROUP, dtype=np.int64),
        np.zeros(GROUP),
        np.zeros(GROUP),
        np.zeros((6, 5, 5)),
    )


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _forward_scalar(f, sc, l, use_reference, nodes, out):
    """The forward filter of lane l's track by `_fit_once` itself, writing its per-node
    results into sc[l] (SMOOTHER_DEFERRED; with SMOOTHER_NONE also the filtered states
    into out.state/out.cov). False if it failed."""
    t = sc.track[l]
    lo = nodes.offsets[t]
    hi = nodes.offsets[t + 1]
    n = hi - lo
    if use_reference:
        for k in range(n):
            copy5(out.state[lo + k], f.ref[k])
    status, chi2 = _fit_once(
        f.ext,
        nodes.z[lo:hi],
        nodes.n_meas[lo:hi],
        nodes.hx[lo:hi],
        nodes.hy[lo:hi],
        nodes.m[lo:hi],
        nodes.sigma[lo:hi],
        out.active[lo:hi],
        nodes.seeds[t],
        nodes.seed_covs[t],
        use_reference,
        f.ref,
        sc.pred[l],
        sc.pred_cov[l],
        sc.filt[l],
        f.filt_cov,
        sc.jac[l],
        sc.noise[l],
        SMOOTHER_NONE if f.smoother == SMOOTHER_NONE else SMOOTHER_DEFERRED,
        out.state[lo:hi],
        out.cov[lo:hi],
        f.mats,
        f.vec5,
        f.perm,
        f.info,
        f.info_vec,
        f.pred_lanes,
        f.pred_cov_lanes,
        False,
    )
    if status != STATUS_OK:
        return False
    sc.chi2[l] = chi2
    return True


@nb.njit(cache=True, inline="always")
def _gather_node(v, a, v_lanes, a_lanes, l):
    """A 5-vector and a 5×5 matrix of one lane's track into lane l of stack arrays
    (5, GROUP), (5, 5, GROUP): the gathers are ~85 stores per node into a few hot cache
    lines (into the (5, 5, GROUP) rows of the whole group's nodes they cost 37–107 ns/node,
    each a different cache line)."""
    for i in range(5):
        v_lanes[i, l] = v[i]
        for j in range(5):
            a_lanes[i, j, l] = a[i, j]


@nb.njit(cache=True, inline="always")
def _gather_measurement(sc, k, j, l, nodes, hx, hy, m, var, do, squared):
    """Measurement j of lane l's node k (of `nodes`, a `TrackNodes`) into the lane vectors
    (do[l] = 0: none); var[l] its σ² if `squared` (as `_fit_once` computes it), else σ."""
    node = sc.first[l] + k
    if k < sc.n[l] and sc.alive[l] != 0.0 and j < nodes.n_meas[node]:
        do[l] = 1.0
        hx[l] = nodes.hx[node, j]
        hy[l] = nodes.hy[node, j]
        m[l] = nodes.m[node, j]
        var[l] = nodes.sigma[node, j] ** 2 if squared else nodes.sigma[node, j]
    else:
        do[l] = 0.0
        hx[l] = 0.0
        hy[l] = 0.0
        m[l] = 0.0
        var[l] = 1.0


@nb.njit(cache=True, inline="always")
def _add_information_lane(info, info_vec, hx, hy, m, sigma, x, do, l):
    """`pkf.fit.kalman.add_node_information` of one measurement on lane l (σ = sigma[l];
    residual against x, the forward prediction), where do[l] ≠ 0: the same operations."""
    d = do[l] != 0.0
    w = 1.0 / (sigma[l] * sigma[l])
    h0 = hx[l]
    h1 = hy[l]
    r = m[l] - fma(h1, x[1, l], h0 * x[0, l])
    i00 = info[0, 0, l]
    i01 = info[0, 1, l]
    i10 = info[1, 0, l]
    i11 = info[1, 1, l]
    v0 = info_vec[0, l]
    v1 = info_vec[1, l]
    info[0, 0, l] = fma(h0 * h0, w, i00) if d else i00
    info[0, 1, l] = fma(h0 * h1, w, i01) if d else i01
    info[1, 0, l] = fma(h0 * h1, w, i10) if d else i10
    info[1, 1, l] = fma(h1 * h1, w, i11) if d else i11
    info_vec[0, l] = fma(h0 * r, w, v0) if d else v0
    info_vec[1, l] = fma(h1 * r, w, v1) if d else v1


@nb.njit(cache=True, inline="always")
def _combine_lane(p, info, x_p, info_vec, a, c, x, bad_pivot, bad_diag, l):
    """`pkf.fit.kalman._combine_nodes`'s weighted mean for lane l: C = (P⁻¹ + Y)⁻¹ into c,
    x = x_p + C·y into x; bad_pivot[l]/bad_diag[l] = 1 where P or P⁻¹ + Y is not positive
    definite / C has a diagonal element ≤ 0."""
    bad_pivot[l] = 0.0
    invert_spd_ldl_lane(p, c, bad_pivot, l)  # P⁻¹
    for i in range(5):
        for j in range(5):
            a[i, j, l] = c[i, j, l] + info[i, j, l]
    invert_spd_ldl_lane(a, c, bad_pivot, l)  # C = (P⁻¹ + Y)⁻¹
    bad = 0.0
    for i in range(5):
        s = x_p[i, l]
        for k in range(5):
            s = fma(c[i, k, l], info_vec[k, l], s)
        x[i, l] = s
        bad = bad if c[i, i, l] > 0.0 else 1.0
    bad_diag[l] = bad


@nb.njit(cache=True, inline="always")
def _prefetch_outputs(sc, k, out):
    """Hint the cache to fetch, for writing, the output rows (state, covariance) of node k
    of the lanes that have one: the backward filter writes them one node later, so that
    their write-allocate misses (the rows of a batch's nodes, 240 bytes each, are tens of
    MB) overlap a node's arithmetic instead of stalling its stores."""
    for l in range(GROUP):
        if k < sc.n[l]:
            node = sc.first[l] + k
            prefetch_write_rows(out.cov, node, node + 1)
            prefetch_write_rows(out.state, node, node + 1)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def _backward_lanes(sc, n_max, nodes, out):
    """The backward information filter and the weighted-mean combination of
    `_backward_information_filter` for the group's lanes, node by node downstream →
    upstream, each lane's (Y, y) starting empty at its own last node; the optimal states
    into out.state/out.cov. A failing lane gets alive = 0."""
    info = stack_array((5, 5, GROUP))
    info_vec = stack_array((5, GROUP))
    a = stack_array((5, 5, GROUP))
    c = stack_array((5, 5, GROUP))
    x = stack_array((5, GROUP))
    hx = stack_array((GROUP,))
    hy = stack_array((GROUP,))
    m = stack_array((GROUP,))
    sigma = stack_array((GROUP,))
    do = stack_array((GROUP,))
    bad = stack_array((GROUP,))
    bad_diag = stack_array((GROUP,))
    pred_k = stack_array((5, GROUP))
    pcov_k = stack_array((5, 5, GROUP))
    jac_k = stack_array((5, 5, GROUP))
    noise_k = stack_array((5, 5, GROUP))
    pred_prev = stack_array((5, GROUP))
    filt_prev = stack_array((5, GROUP))
    for l in range(GROUP):
        bad[l] = 0.0
    for k in range(n_max - 1, -1, -1):
        for l in range(GROUP):
            if k >= sc.n[l] - 1:  # at or past the track's last node: no information yet
                for i in range(5):
                    info_vec[i, l] = 0.0
                    for j in range(5):
                        info[i, j, l] = 0.0
        for l in range(GROUP):
            _gather_node(sc.pred[l, k], sc.pred_cov[l, k], pred_k, pcov_k, l)
        for jm in range(2):
            for l in range(GROUP):
                _gather_measurement(sc, k, jm, l, nodes, hx, hy, m, sigma, do, False)
            for l in range(GROUP):
                _add_information_lane(info, info_vec, hx, hy, m, sigma, pred_k, do, l)
        for l in range(GROUP):  # the weighted mean at node k, SIMD over the lanes
            _combine_lane(pcov_k, info, pred_k, info_vec, a, c, x, bad, bad_diag, l)
        for l in range(GROUP):
            if k < sc.n[l] and sc.alive[l] != 0.0:
                if bad[l] != 0.0 or bad_diag[l] != 0.0:
                    sc.alive[l] = 0.0
                    continue
                node = sc.first[l] + k
                for i in range(5):
                    out.state[node, i] = x[i, l]
                    for j in range(5):
                        out.cov[node, i, j] = c[i, j, l]
        if k == 0:
            break
        _prefetch_outputs(sc, k - 1, out)
        for l in range(GROUP):
            _gather_node(sc.pred[l, k - 1], sc.jac[l, k], pred_prev, jac_k, l)
            _gather_node(sc.filt[l, k - 1], sc.noise[l, k], filt_prev, noise_k, l)
        for l in range(GROUP):  # (Y, y) from node k to k − 1, SIMD over the lanes
            bad[l] = 0.0
            info_step_lane(info, info_vec, jac_k, noise_k, pred_prev, filt_prev, bad, l)
        for l in range(GROUP):
            if bad[l] != 0.0 and k < sc.n[l]:
                sc.alive[l] = 0.0


@nb.njit(cache=True, inline="always")
def _start_group(sc, order, g0, n_grouped, offsets, out_active):
    """Lanes of the group starting at order[g0]; returns the group's largest track length."""
    n_max = 0
    for l in range(GROUP):
        idx = g0 + l
        if idx < n_grouped:
            t = order[idx]
            lo = offsets[t]
            hi = offsets[t + 1]
            sc.track[l] = t
            sc.first[l] = lo
            sc.n[l] = hi - lo
            sc.alive[l] = 1.0
            out_active[lo:hi] = True
            n_max = max(n_max, hi - lo)
        else:
            sc.track[l] = -1
            sc.first[l] = 0
            sc.n[l] = 0
            sc.alive[l] = 0.0
    return n_max


@nb.njit(cache=True, inline="always")
def _finish_lane(fitter, sc, l, nodes, rule, out):
    """After the lane fit of a group, lane l's track: its node χ² and outlier candidate
    (`track_outlier`); a candidate to remove → the shared loop's refits from the state of
    this first fit (`refit_track`); a failure → the shared loop from the start
    (`fit_one_track`); else the lane fit's outputs (`finish_track`)."""
    t = sc.track[l]
    lo = nodes.offsets[t]
    hi = nodes.offsets[t + 1]
    status = STATUS_OK
    worst = -1
    if sc.alive[l] != 0.0:
        status, worst = track_outlier(fitter, lo, hi, nodes, rule, out)
    if sc.alive[l] != 0.0 and status == STATUS_OK and rule.max_outliers > 0 and worst >= 0:
        # the scalar loop's state after this first fit, then its refits
        for k in range(hi - lo):
            copy5(out.state[lo + k], fitter.ref[k])
        fitter.have_reference[0] = True
        out.active[lo + worst] = False
        refit_track(fitter, t, nodes, rule, out, STATUS_OK, 1)
    elif sc.alive[l] == 0.0 or status != STATUS_OK:
        fit_one_track(fitter, t, nodes, rule, out)
    else:
        ndf = count_ndf(nodes.n_meas[lo:hi], out.active[lo:hi])
        finish_track(fitter, t, lo, hi, out, STATUS_OK, sc.chi2[l], ndf, 0)


@nb.njit(cache=True, error_model="numpy", **NO_REFCOUNT)
def fit_tracks_lanes(fitter, order, n_grouped, sc, nodes, rule, out):
    """`pkf.fit.driver._fit_tracks_loop` for a `KalmanFitter`, the first fits of the tracks
    order[:n_grouped] (sorted by length) GROUP at a time in lanes (all `n_iterations`
    passes), the others, and those whose lane fit failed or found an outlier to remove,
    through `fit_one_track`. Same arguments and outputs as `fit_tracks` (`TrackNodes`,
    `OutlierRule`, `FitOutputs`), plus order, n_grouped and the scratch sc (`lane_scratch`)."""
    for g0 in range(0, n_grouped, GROUP):
        n_max = _start_group(sc, order, g0, n_grouped, nodes.offsets, out.active)
        for it in range(max(1, fitter.n_iterations)):
            for l in range(GROUP):
                if sc.alive[l] != 0.0:
                    if not _forward_scalar(fitter, sc, l, it > 0, nodes, out):
                        sc.alive[l] = 0.0
            if fitter.smoother == SMOOTHER_WEIGHTED_MEAN:
                _backward_lanes(sc, n_max, nodes, out)
        for l in range(GROUP):
            if sc.track[l] >= 0:
                _finish_lane(fitter, sc, l, nodes, rule, out)
    for idx in range(n_grouped, order.size):
        fit_one_track(fitter, order[idx], nodes, rule, out)


#: Tracks sorted by length within windows of this many (not over the whole batch: tracks
#: far apart in memory cost cache misses in the forward filter).
SORT_WINDOW = 16 * GROUP


@nb.njit(cache=True)
def lane_order(nodes, window=SORT_WINDOW):
    """(order, n_grouped): the tracks of `nodes` (`TrackNodes`) that take the lanes (ndf > 0
    with every node active, finite seed and seed covariance), sorted by number of nodes
    within windows of `window` tracks (stable), then the others."""
    offsets, seeds, seed_covs = nodes.offsets, nodes.seeds, nodes.seed_covs
    n_tracks = offsets.size - 1
    lengths = offsets[1:] - offsets[:-1]
    order = np.empty(n_tracks, dtype=np.int64)
    n_grouped = 0
    n_other = 0
    for t in range(n_tracks):
        dims = -5
        for k in range(offsets[t], offsets[t + 1]):
            dims += nodes.n_meas[k]
        finite = True
        for i in range(5):
            finite = finite and np.isfinite(seeds[t, i])
            for j in range(5):
                finite = finite and np.isfinite(seed_covs[t, i, j])
        if dims > 0 and finite:
            order[n_grouped] = t
            n_grouped += 1
        else:
            n_other += 1
            order[n_tracks - n_other] = t
    order[n_grouped:] = order[n_grouped:][::-1].copy()
    for w0 in range(0, n_grouped, window):  # by insertion (a mergesort per window took 3× as long)
        insertion_sort(order, lengths, w0, min(n_grouped, w0 + window))
    return order, n_grouped


def fit_tracks_in_lanes(fitter, nodes, rule, out):
    """`fit_tracks`'s signature and outputs for a `KalmanFitter`, run by `fit_tracks_lanes`
    (the order of the tracks and the lane scratch made here) if it combines by weighted
    mean or not at all and keeps no node stages, else by `fit_tracks_no_refcount`."""
    if fitter.smoother not in (SMOOTHER_WEIGHTED_MEAN, SMOOTHER_NONE) or fitter.stages.predicted.shape[0] > 0:
        fit_tracks_no_refcount(fitter, nodes, rule, out)
        return
    # every argument given: called from Python with `window` left to its default, this call
    # measured 118 µs instead of 34 (numba's dispatcher; 2,000 telescope tracks)
    order, n_grouped = lane_order(nodes, SORT_WINDOW)
    fit_tracks_lanes(fitter, order, n_grouped, lane_scratch(max_nodes(nodes.offsets)), nodes, rule, out)


def _choose_loop(fitter: KalmanFitter):
    """The lane loop for the fitters whose track loop it is: weighted-mean combination,
    no node stages kept (forward only: measured slower in lanes, +10 %)."""
    if fitter.smoother != SMOOTHER_WEIGHTED_MEAN or fitter.stages.predicted.shape[0] > 0:
        return None
    return fit_tracks_in_lanes


register_track_loop(KalmanFitter, _choose_loop)

__all__ = ["GROUP", "fit_tracks_in_lanes", "fit_tracks_lanes", "lane_scratch"]
