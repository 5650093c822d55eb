"""The q/p scan of the SciFi x layers as a Hough transform in q/p (step 2).

Every x-layer hit in the covered range gets its implied q/p (inverse cubic Hermite
interpolation of the trajectory at the q/p nodes) and a Hough coordinate t in units of
the tolerance τ(q) = τ₀ + τ₁·|q/p| (`hough_grid`, `t_of_q`); a counting sort orders the
entries by bin (`sort_entries`) and windows of bins with enough x layers are the
clusters (`find_clusters`). Units: mm, 1/MeV.

The fill (`hough_entries`) is ~16 % of the pattern recognition's CPU at ν = 7.6 (calling it
twice per scan: ×1.16, `benchmarks/side_by_side.py --workload pattern`, 50 events, 6 rounds),
~150k conversions per event (pass 1: 349 scans of ~204 entries, pass 2: 121 of ~638).
Tried and not kept (2026-12-08, branch hough): an anchored fill, exact because a cluster
needs an x layer of every station — one station's x layers converted first, the others' hits
only in the x ranges of the runs of bins within window_bins − 1 of an anchor entry (each run's
q/p ends carried to the layer by `node_interp`, ± 1 bin and 2 mm): outputs bitwise the same
(truth and searched VELO tracks, ν = 1, 4, 7.6), but slower, ×1.13 at ν = 7.6 with runs merged
over gaps < 4 bins, ×1.06–1.12 < 16, ×1.20 < 64 (the anchor station the last one or the one
with the fewest hits in range). A conversion costs ~45 ns (16 % of 43 ms per event over ~150k;
a slow machine state), about what locating a run on a layer (two `q_of_t`, two `node_interp`,
a bisection) and the bins' bookkeeping cost, and the runs are nearly as many as the anchor
entries; what the fill's time is made of (the conversion's two divisions and table reads, the
taken hits' links) is the next question.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT
from pkf.seeding.forward.kalman import first_at_least
from pkf.seeding.forward.records import Hough


def hough_grid(tau0: float, tau1: float, q_max: float, ratio: float = 1.25) -> Hough:
    """Breakpoints of the Hough coordinate t(q) (see `t_of_q`): |q| = 0 and then every
    point where the tolerance τ(q) = τ0 + τ1·|q| has grown by `ratio`, up to 2·q_max;
    grid row 0: |q|, row 1: t = ln(1 + τ1·|q|/τ0)/τ1 (exact at the breakpoints). With
    look-up tables of the breakpoint interval on uniform cells of |q| and of |t| (cells
    half the shortest interval wide: the interval is the cell's or the next), so that a
    conversion costs a table read instead of a bisection (the q/p scan converts every
    hit). Returns the `Hough` record."""
    qs = [0.0]
    while qs[-1] < 2.0 * q_max and tau1 > 0:
        qs.append((ratio * (tau0 + tau1 * qs[-1]) - tau0) / tau1)
    if tau1 <= 0:
        qs.append(2.0 * q_max)
    q = np.array(qs)
    t = np.log1p(tau1 * q / tau0) / tau1 if tau1 > 0 else q / tau0
    grid = np.ascontiguousarray(np.vstack([q, t]))
    tables = []
    for row in grid:
        cell = 0.5 * float(np.min(np.diff(row)))
        edges = np.arange(int(row[-1] / cell) + 2) * cell
        lut = np.clip(np.searchsorted(row, edges, side="right") - 1, 0, row.size - 2).astype(np.int64)
        tables += [lut, 1.0 / cell]
    return Hough(grid, *tables)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _interval(a, row, lut, inv_cell):
    """Index lo of the breakpoint interval [row[lo], row[lo+1]) holding a ≥ 0, from the cell
    table of `hough_grid`; the last interval beyond the table's end and for a NaN (a cell is
    looked up only for a number below the end: a NaN's integer conversion is undefined, and
    its cell was read out of bounds)."""
    cell = a * inv_cell
    last = row.shape[0] - 2
    if not cell < lut.shape[0]:
        return last
    lo = lut[int(cell)]
    while lo < last and row[lo + 1] <= a:
        lo += 1
    return lo


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _convert(v, x, y, lut, inv_cell):
    """y(v) for the breakpoint rows x → y, odd in v: linear between the breakpoints."""
    a = abs(v)
    lo = _interval(a, x, lut, inv_cell)
    hi = lo + 1
    w = y[lo] + (a - x[lo]) * (y[hi] - y[lo]) / (x[hi] - x[lo])
    return w if v >= 0.0 else -w


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def t_of_q(q, hough):
    """Hough coordinate of q/p in units of the local tolerance τ(q): piecewise linear
    through the breakpoints (each interval's bin width lies between τ at its ends; a
    logarithm per hit would cost more than the rest of the scan)."""
    return _convert(q, hough.grid[0], hough.grid[1], hough.lut_q, hough.inv_cell_q)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def q_of_t(t, hough):
    """The inverse of `t_of_q`."""
    return _convert(t, hough.grid[1], hough.grid[0], hough.lut_t, hough.inv_cell_t)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def hermite(x0, x1, d0, d1, h, u):
    """Cubic Hermite interpolation on [x0, x1] (length h, derivatives d0, d1) at u ∈ [0, 1]."""
    u2 = u * u
    u3 = u2 * u
    return ((2 * u3 - 3 * u2 + 1) * x0 + (u3 - 2 * u2 + u) * h * d0 + (-2 * u3 + 3 * u2) * x1
            + (u3 - u2) * h * d1)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def node_interp(qn, n_nodes, vals, ders, col, q):
    """x(q) on SciFi layer `col` by cubic Hermite interpolation of the nodes (linear
    outside) and dx/dq by linear interpolation of the node derivatives."""
    if q <= qn[0]:
        return vals[0, col] + ders[0, col] * (q - qn[0]), ders[0, col]
    k_last = n_nodes - 1
    if q >= qn[k_last]:
        return vals[k_last, col] + ders[k_last, col] * (q - qn[k_last]), ders[k_last, col]
    k = 0
    while k < k_last - 1 and qn[k + 1] <= q:
        k += 1
    h = qn[k + 1] - qn[k]
    u = (q - qn[k]) / h
    v = hermite(vals[k, col], vals[k + 1, col], ders[k, col], ders[k + 1, col], h, u)
    return v, ders[k, col] + u * (ders[k + 1, col] - ders[k, col])



@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def next_free(free_next, h):
    """The first hit ≥ h not taken (`Scan.free_next`: a taken hit links to the next row;
    the links are halved on the way, as in a union–find). The q/p scans skip runs of
    taken hits without reading them: at ν = 7.6 most hits in a scan's window belong to
    tracks the first pass found, and converting them too (a branch-free variant) cost
    +16 % of the forward time."""
    while free_next[h] != h:
        free_next[h] = free_next[free_next[h]]
        h = free_next[h]
    return h


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _popcount(m):
    n = 0
    while m:
        m &= m - 1
        n += 1
    return n


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _implied_q(li, x, seg, n_nodes, inv_x, inv_q, inv_dq):
    """q/p implied by x on x layer li: cubic Hermite interpolation of q(x) between the
    nodes (segment seg), linear beyond the end nodes."""
    if x <= inv_x[li, 0]:
        return inv_q[li, 0] + inv_dq[li, 0] * (x - inv_x[li, 0])
    if x >= inv_x[li, n_nodes - 1]:
        return inv_q[li, n_nodes - 1] + inv_dq[li, n_nodes - 1] * (x - inv_x[li, n_nodes - 1])
    hx = inv_x[li, seg + 1] - inv_x[li, seg]
    return hermite(inv_q[li, seg], inv_q[li, seg + 1], inv_dq[li, seg], inv_dq[li, seg + 1], hx,
                   (x - inv_x[li, seg]) / hx) if hx > 0.0 else inv_q[li, seg]


@nb.njit(cache=True, **NO_REFCOUNT)
def hough_entries(lay, hits, hough, scan, n_nodes, pc, q_rms, z_ut, nsig, t_lo, n_bins):
    """The Hough entries of every untaken x-layer hit (scan.free_next) in the range covered by the node
    states (± nsig σ of the start's conditional covariance pc at |q/p| = q_rms, + 1 mm),
    in bins 0 … n_bins−1 of t − t_lo: scan.entries (`Entries`) t, bin, layer, hit. The
    x layers' z must be in scan.line.x_z. Returns the number of entries."""
    nodes = scan.nodes
    qn, sxs, sdxs = nodes.q, nodes.x, nodes.dx
    inv_x, inv_q, inv_dq = scan.inv_x, scan.inv_q, scan.inv_dq
    e = scan.entries
    e_t, e_bin, e_li, e_hit = e.t, e.bin, e.layer, e.hit
    x_z = scan.line.x_z
    loe, hu, _, _ = hits
    free_next = scan.free_next
    x_fwd, n_ut, f_sig = lay.x_fwd, lay.n_ut, lay.sigma
    max_entries = e_t.shape[0]
    pcxx = pc[0] + pc[6] * q_rms * q_rms
    pcxt = pc[1] + pc[7] * q_rms * q_rms
    pctt = pc[2] + pc[8] * q_rms * q_rms
    n_e = 0
    for li in range(x_fwd.shape[0]):
        col = x_fwd[li] - n_ut
        inc = sxs[n_nodes - 1, col] >= sxs[0, col]
        for k in range(n_nodes):
            kk = k if inc else n_nodes - 1 - k
            inv_x[li, k] = sxs[kk, col]
            inv_q[li, k] = qn[kk]
            dxdq = sdxs[kk, col]
            inv_dq[li, k] = 1.0 / dxdq if dxdq != 0.0 else 0.0
        dz = x_z[li] - z_ut
        var = max(pcxx + 2.0 * dz * pcxt + dz * dz * pctt, 0.0) + f_sig[x_fwd[li]] ** 2
        margin = nsig * math.sqrt(var) + 1.0
        x_min = inv_x[li, 0] - margin
        x_max = inv_x[li, n_nodes - 1] + margin
        hi = loe[x_fwd[li] + 1]
        h = next_free(free_next, first_at_least(hu, loe[x_fwd[li]], hi, x_min))
        seg = 0
        while h < hi and hu[h] <= x_max and n_e < max_entries:
            x = hu[h]
            while seg < n_nodes - 2 and x > inv_x[li, seg + 1]:
                seg += 1
            t = t_of_q(_implied_q(li, x, seg, n_nodes, inv_x, inv_q, inv_dq), hough)
            tb = t - t_lo
            if 0.0 <= tb < n_bins:
                e_t[n_e] = t
                e_bin[n_e] = int(tb)
                e_li[n_e] = li
                e_hit[n_e] = h
                n_e += 1
            h = next_free(free_next, h + 1)
    return n_e


@nb.njit(cache=True, **NO_REFCOUNT)
def sort_entries(n_e, n_bins, e):
    """Counting sort of the entries by bin: e.order, e.bin_start; e.bin_count then holds
    the x-layer mask of each bin (`Entries`)."""
    e_bin, e_li, e_order, bin_count, bin_start = e.bin, e.layer, e.order, e.bin_count, e.bin_start
    for k in range(n_e):
        bin_count[e_bin[k]] += 1
    bin_start[0] = 0
    for b in range(n_bins):
        bin_start[b + 1] = bin_start[b] + bin_count[b]
    for k in range(n_e - 1, -1, -1):  # backwards from each bin's end: stable, and the counts end at 0
        b = e_bin[k]
        bin_count[b] -= 1
        e_order[bin_start[b] + bin_count[b]] = k
    for k in range(n_e):  # bin_count now holds the x-layer mask of each bin
        bin_count[e_bin[k]] |= 1 << e_li[k]


@nb.njit(cache=True, **NO_REFCOUNT)
def x_layer_counts(lay, station_x, mask_pop):
    """mask_pop[m]: the number of x layers in mask m, 0 if station_x and a SciFi station
    has none of them."""
    n_x = lay.x_fwd.shape[0]
    x_station_bit = lay.x_station_bit
    for m in range(1 << n_x):  # x layers in a mask, 0 if a station has none
        npop = _popcount(m)
        if station_x:
            smask = 0
            for li in range(n_x):
                if m & (1 << li):
                    smask |= x_station_bit[li]
            if smask != lay.x_station_need:
                npop = 0
        mask_pop[m] = npop


@nb.njit(cache=True, **NO_REFCOUNT)
def find_clusters(n_e, n_bins, n_win, min_x, scan):
    """Clusters: windows of n_win bins starting at every occupied bin; kept if they have
    enough x layers (≥ 1 per station, ≥ min_x, ≥ the fullest window's count − 1) and no
    overlapping window has more. scan.cl_bin (first bin) and scan.cl_npop (x layers) of
    the kept clusters; returns their number."""
    e = scan.entries
    e_bin, e_order, bin_count, bin_start = e.bin, e.order, e.bin_count, e.bin_start
    cl_bin, cl_npop, mask_pop = scan.cl_bin, scan.cl_npop, scan.mask_pop
    n_cl = 0
    k = 0
    while k < n_e:
        b = e_bin[e_order[k]]
        mask = 0
        for bb in range(b, min(b + n_win, n_bins)):
            mask |= bin_count[bb]
        cl_bin[n_cl] = b
        cl_npop[n_cl] = mask_pop[mask]
        n_cl += 1
        k = bin_start[b + 1]
    max_pop = 0
    for c_ in range(n_cl):
        max_pop = max(max_pop, cl_npop[c_])
    min_pop = max(min_x, max_pop - 1)
    n_keep = 0
    for c_ in range(n_cl):
        npop = cl_npop[c_]
        if npop < min_pop:
            continue
        if c_ > 0 and cl_bin[c_ - 1] == cl_bin[c_] - 1 and cl_npop[c_ - 1] > npop:
            continue
        if c_ + 1 < n_cl and cl_bin[c_ + 1] == cl_bin[c_] + 1 and cl_npop[c_ + 1] > npop:
            continue
        cl_bin[n_keep] = cl_bin[c_]
        cl_npop[n_keep] = npop
        n_keep += 1
    return n_keep
