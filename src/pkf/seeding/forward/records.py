"""Records of the forward extension's kernels: typed NamedTuples of arrays and numbers.

numba compiles a `typing.NamedTuple` of arrays as a struct; the kernels take these records
instead of dozens of loose arrays and unpack the fields they use into locals at the top
(the compiled code is the same as with separate arguments). Index j runs over the forward
layers (the UT layers, then the SciFi layers); units are mm and 1/MeV (q/p).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: children per search depth (branches + the skip)
MAX_CHILDREN = 17
#: entries per SciFi x layer considered in a cluster (nearest to the trajectory)
MAX_PER_LAYER = 6

#: how `search` treats a forward layer (`Filter.mode`)
MODE_SEARCH = 0  # hits in the window, best by Δχ²
MODE_FIXED = 1  # the hit Filter.fixed[j] if compatible
MODE_OFF = 2  # transport only


class Layout(NamedTuple):
    """The forward layers (`pkf.seeding.forward.prepare.layout`).

    layer (n_fwd): geometry layer index; cos, sin: strip direction (u = x·cos α + y·sin α);
    sigma: strip resolution [mm]; acceptance (n_fwd, 5): half_x, half_y, hole radius,
    hole half_x, hole half_y [mm]; bit: station requirement bit of the layer (0: none);
    group_end/need_end: at the last layer of a station, the bits the station needs;
    scifi_need: all of them; x_layers/x_fwd: geometry and forward index of the SciFi x
    layers; x_station_bit/x_station_need: their station bits; n_ut: number of UT layers.
    """

    layer: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    sigma: np.ndarray
    acceptance: np.ndarray
    bit: np.ndarray
    group_end: np.ndarray
    need_end: np.ndarray
    scifi_need: int
    x_layers: np.ndarray
    x_fwd: np.ndarray
    x_station_bit: np.ndarray
    x_station_need: int
    n_ut: int


class Hits(NamedTuple):
    """The forward hits of one event, sorted by (layer, u).

    offsets (n_fwd + 1): the rows of layer j are offsets[j] … offsets[j+1]−1 of u (strip
    coordinate [mm]) and sigma [mm]; used: taken by a good extension (step 6).
    """

    offsets: np.ndarray
    u: np.ndarray
    sigma: np.ndarray
    used: np.ndarray


class Cuts(NamedTuple):
    """χ² cuts per number of measurements (`prepare.chi2_table`): pruning of the UT and
    SciFi searches, the final fit, the fit without UT hits, a good extension, a UT candidate,
    an upstream track after its UT outlier check."""

    ut_prune: np.ndarray
    sf_prune: np.ndarray
    final: np.ndarray
    no_ut: np.ndarray
    good: np.ndarray
    ut: np.ndarray
    upstream: np.ndarray


class Hough(NamedTuple):
    """The Hough coordinate t(q/p) of the q/p scan (`hough.hough_grid`): breakpoints
    (2, n) (row 0 |q/p|, row 1 t), cell tables of the breakpoint interval for |q| and |t|."""

    grid: np.ndarray
    lut_q: np.ndarray
    inv_cell_q: float
    lut_t: np.ndarray
    inv_cell_t: float


class Config(NamedTuple):
    """Options of one kernel call: float and integer option vectors (`options.O_*`,
    `options.I_*`), the χ² cuts and the Hough grid."""

    opt: np.ndarray
    iopt: np.ndarray
    cuts: Cuts
    hough: Hough


class Transport(NamedTuple):
    """What a reference trajectory needs: the parametrized extrapolator's context, the
    UT→SciFi table localised per track (poly, table_ref), the quadratic continuation
    below the table's p_min, scratch (6, 5, 5) and the SciFi model-noise momentum [MeV]."""

    ext: object
    poly: np.ndarray
    table_ref: np.ndarray
    quadratic: bool
    work: np.ndarray
    model_noise: float


class Reference(NamedTuple):
    """A reference trajectory: state s (n_fwd, 5) on each forward layer, the Jacobian F and
    the process noise Q (n_fwd, 5, 5) of the step onto it."""

    s: np.ndarray
    F: np.ndarray
    Q: np.ndarray


class KFWork(NamedTuple):
    """Scratch of the combinatorial Kalman filter, per depth d (n_fwd rows): predicted and
    filtered deviation states and covariances, the predicted strip coordinate and its
    variance, the χ², hit counts, skips, requirement mask and attach flag of the branch,
    the children (hits and Δχ²) and the iterator, the path, the start state, and the number
    of search layers below each depth (the bound of `search.search`)."""

    pred_x: np.ndarray
    post_x: np.ndarray
    pred_P: np.ndarray
    post_P: np.ndarray
    tmp: np.ndarray
    pht: np.ndarray
    upred: np.ndarray
    sbase: np.ndarray
    post_chi: np.ndarray
    ch_chi: np.ndarray
    n_ch: np.ndarray
    it: np.ndarray
    post_n: np.ndarray
    post_nf: np.ndarray
    post_skip: np.ndarray
    post_mask: np.ndarray
    post_att: np.ndarray
    path: np.ndarray
    ch_hit: np.ndarray
    x_init: np.ndarray
    P_init: np.ndarray
    search_left: np.ndarray


class Filter(NamedTuple):
    """A Kalman filter around a reference trajectory: the trajectory, the scratch, the
    treatment of each layer (mode: MODE_*, fixed: its hit for MODE_FIXED, −1 none) and the
    start deviation x0 (5) with covariance P0 (5, 5) at the VELO layer."""

    ref: Reference
    ws: KFWork
    mode: np.ndarray
    fixed: np.ndarray
    x0: np.ndarray
    P0: np.ndarray


class Leaf(NamedTuple):
    """The best leaf of a search or the result of a fit: path (n_fwd) of sorted-hit indices
    (−1 none), deviation state x (5) and covariance P (5, 5) at the last layer."""

    path: np.ndarray
    x: np.ndarray
    P: np.ndarray


class Ranked(NamedTuple):
    """The K best leaves or candidates, best first: paths (K, n_fwd), search hits n (K),
    χ² (K), q/p or its deviation (K), its variance (K), how many are filled (1)."""

    paths: np.ndarray
    n: np.ndarray
    chi2: np.ndarray
    q: np.ndarray
    var: np.ndarray
    count: np.ndarray


class SearchRules(NamedTuple):
    """The rules of one combinatorial search (`search.search`): window and Δχ² cut nsig [σ];
    branches per layer before the first and after a hit; skips allowed; search hits needed;
    the skip always tried before the first hit (skip_first); requirement bits needed at
    the end; χ² pruning per hit count; node cap; ranking χ² − miss_penalty·hits; the
    pseudo-measurement of x (value [mm], variance [mm²]) at depth pm_depth (−1: none)."""

    nsig: float
    first_branches: int
    max_branch: int
    max_skip: int
    min_hits: int
    skip_first: bool
    need: int
    prune: np.ndarray
    max_nodes: int
    miss_penalty: float
    pm_depth: int
    pm_value: float
    pm_var: float


class Start(NamedTuple):
    """The state at the last UT layer given q/p: conditional mean s0 (5, s0[4] its q/p),
    its derivative ds0 (5) in q/p and the conditional covariance pc (12): xx, x·tx, tx·tx,
    yy, y·ty, ty·ty at q/p = 0, then the same per (q/p)² [per (1/MeV)²]."""

    s0: np.ndarray
    ds0: np.ndarray
    pc: np.ndarray


class NodeStates(NamedTuple):
    """The trajectory at the q/p nodes of a scan: q (N), x, dx/dq, y, dy/dq (N, n_scifi)."""

    q: np.ndarray
    x: np.ndarray
    dx: np.ndarray
    y: np.ndarray
    dy: np.ndarray


class Entries(NamedTuple):
    """Hough entries of a scan: per entry t, bin, x-layer index, hit; order (by bin);
    per bin the count (then the x-layer mask) and the start in order."""

    t: np.ndarray
    bin: np.ndarray
    layer: np.ndarray
    hit: np.ndarray
    order: np.ndarray
    bin_count: np.ndarray
    bin_start: np.ndarray


class LineWork(NamedTuple):
    """Scratch of the straight-line test of a cluster (`lines.cluster_fit`), per SciFi x
    layer: the chosen entry, its residual, z [mm], the trajectory (or its derivative) at
    the cluster's q/p, and the MAX_PER_LAYER nearest entries with their residuals."""

    chosen: np.ndarray
    rx: np.ndarray
    x_z: np.ndarray
    d_l: np.ndarray
    cand_e: np.ndarray
    cand_r: np.ndarray
    cand_n: np.ndarray


class Scan(NamedTuple):
    """Scratch of the q/p scan (`scifi`): node states, their inverse per x layer (x, q,
    dq/dx at the nodes in x order), the entries, the clusters (first bin, x layers,
    ranking key), the line scratch, z of every forward layer, the x layers of a mask and,
    per sorted hit, a link toward the next hit not taken (`hough.next_free`: hit h is
    free iff free_next[h] = h; n_hits + 1 rows, the last a sentinel)."""

    nodes: NodeStates
    inv_x: np.ndarray
    inv_q: np.ndarray
    inv_dq: np.ndarray
    entries: Entries
    cl_bin: np.ndarray
    cl_npop: np.ndarray
    cl_key: np.ndarray
    line: LineWork
    f_z: np.ndarray
    mask_pop: np.ndarray
    free_next: np.ndarray


class Smoother(NamedTuple):
    """Scratch of the UT outlier check (`outliers`): the adjoint variables λ̂ (5) and Λ̂
    (5, 5) of the modified Bryson–Frazier smoother, a product (5, 5), two vectors (5), the
    smoothed deviation x (5) and covariance C (5, 5) of the current layer, per UT layer the
    smoothed x_ut (n_ut, 5) and C_ut (n_ut, 5, 5) and the χ² of its hit against the rest
    of the track (n_ut; NaN: no hit)."""

    lam: np.ndarray
    Lam: np.ndarray
    M: np.ndarray
    v: np.ndarray
    k: np.ndarray
    x: np.ndarray
    C: np.ndarray
    x_ut: np.ndarray
    C_ut: np.ndarray
    chi2: np.ndarray


class Work(NamedTuple):
    """All scratch of one kernel call (`kernel.workspace`), reused by every track: the
    filter, two leaves sharing one path (b: searches and fits, c: the UT side), the scan,
    an empty Ranked (no leaves collected), the SciFi candidates, the best key so far and
    the scratch of the UT outlier check."""

    filt: Filter
    leaf_b: Leaf
    leaf_c: Leaf
    scan: Scan
    top_none: Ranked
    cand: Ranked
    best_key: np.ndarray
    smooth: Smoother


class Track(NamedTuple):
    """The VELO track being extended: its output row t, VELO layer a and state s_v
    (x, y, tx, ty, 0) at that layer."""

    t: int
    a: int
    s_v: np.ndarray


class Output(NamedTuple):
    """Per track: hits (n, n_fwd) sorted-hit index per forward layer (−1 none), q/p
    [1/MeV] and its variance, χ², ndf, status (STATUS_*), UT and SciFi hit counts, found
    by the second pass's scan, and ut_chi2 (n, n_ut): the χ² of each UT hit against the
    rest of the extension (`outliers`; NaN: no hit or not checked)."""

    hits: np.ndarray
    q: np.ndarray
    qvar: np.ndarray
    chi2: np.ndarray
    ndf: np.ndarray
    status: np.ndarray
    n_ut: np.ndarray
    n_scifi: np.ndarray
    from_scan: np.ndarray
    ut_chi2: np.ndarray


class UtCandidates(NamedTuple):
    """The UT candidates of a track (step 1), best first (most hits, then χ²): the q/p
    range of the scan (lo, hi), q/p and its variance, χ², hits, the UT leaf, and the
    start at the last UT layer given q/p (pc (K, 12), s0 and ds0 (K, 5); `Start`)."""

    lo: np.ndarray
    hi: np.ndarray
    q: np.ndarray
    var: np.ndarray
    chi2: np.ndarray
    n: np.ndarray
    leaf: np.ndarray
    pc: np.ndarray
    s0: np.ndarray
    ds0: np.ndarray


class Kept(NamedTuple):
    """What the second pass needs of a track the first pass did not extend: need_scan
    (n_tracks), its `Start` (s0, ds0, pc per track), the UT hits of its best UT leaf (ut),
    the q/p, its variance, χ² and hits of its best UT candidate (u (n_tracks, 4)) and
    the number of UT candidates."""

    need_scan: np.ndarray
    s0: np.ndarray
    ds0: np.ndarray
    pc: np.ndarray
    ut: np.ndarray
    u: np.ndarray
    n_utc: np.ndarray


class PassWork(NamedTuple):
    """Per-track scratch of the two passes (`kernel`): the UT leaves (top_ut) and
    candidates (utc) of the track, its `Start`, VELO state s_v (5), the UT hits of its best
    UT leaf (ut_best) and of the current start (ut_hits), what the second pass keeps, and
    per hit whether a good extension took it (used)."""

    top_ut: Ranked
    utc: UtCandidates
    start: Start
    s_v: np.ndarray
    ut_best: np.ndarray
    ut_hits: np.ndarray
    kept: Kept
    used: np.ndarray


class Inputs(NamedTuple):
    """The kernel's input: per track the event index, the state (n, 4) (x, y, tx, ty) at
    its VELO layer and that layer (−1: invalid); the forward hits' u and σ [mm] sorted by
    (event, layer, u) with their offsets lay_off (events, n_fwd + 1)."""

    t_ev: np.ndarray
    t_state: np.ndarray
    t_layer: np.ndarray
    lay_off: np.ndarray
    hu: np.ndarray
    hsig: np.ndarray
