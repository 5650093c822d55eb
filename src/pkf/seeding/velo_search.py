"""VELO pattern recognition: triplet search, merging and arbitration (docs/physics.md#pattern-recognition).

``find_velo_tracks`` takes the hits of many events (per-hit arrays, sorted by event) and
returns VELO track candidates in CSR form with a straight-line first state. All work is
done in compiled kernels (numba) over arrays: no Python loop over events, hits or
tracks. Units: mm, MeV, tesla, rad.

Algorithm (per event)
---------------------
1. **Lookup.** The VELO hits of each module are sorted by φ = atan2(y, x) and binned in
   ``N_PHI_BINS`` φ bins; a φ window is an index range read from the bin table (O(1)
   plus the hits in the window), never a scan of a module.

2. **Triplets on one VELO half** (docs/physics.md#pattern-recognition). The modules alternate between the left
   (x ≤ +5 mm) and the right (x ≥ −5 mm) half. A triplet uses three modules of the same
   half, i < j < k, with at most ``max_missing`` (1) module of that half between
   consecutive hits that the straight line through them certainly crosses (inside its
   active area shrunk by ``edge_margin``) without a hit there. Modules the line misses
   (beyond an edge, inside the beam hole) are not "missing" hits.

3. **Doublets** (first hit a, middle hit b). For each hit b the earlier modules of its
   half are searched, nearest first, until max_missing + 1 modules that certainly
   contain b's (x, y) were searched. Tracks from the luminous region are straight in
   the VELO: φ is constant along a track and r ∝ (z − z0) for a vertex
   |z0| ≤ ``z_luminous``. So a must satisfy |Δφ|·min(r_a, r_b) ≤ tol (a transverse
   mismatch: beam spot, scattering upstream, resolution, displaced decay vertices),
   tol = ``doublet_tolerance`` + ``doublet_tolerance_slope``·r_b (0.3 mm + 0.005·r_b),
   and r_b·(z_a − z0max)/(z_b − z0max) − tol ≤ r_a ≤ r_b·(z_a + z_luminous)/(z_b +
   z_luminous) + tol, z0max = min(z_luminous, z_a); the φ window is tan(asin(tol/r_min))
   (≥ asin(tol/r_min): a wider window only adds hits that fail the cuts).

4. **Third hit and triplet fit.** The line a → b is extrapolated to the following
   modules of the half; hits within ``window_sigmas`` standard deviations (hit errors
   propagated along the line; Highland scattering at p_min at b and at every crossed
   module) are fitted with the triplet fit (``triplet_fit.fit_triplet_kinks``, curvature
   form at the middle hit: the VELO field, a few mT, is below ``b_threshold``, so σ_MS
   is Highland at ``p_min`` = 1 GeV and, with ``straight`` (default), κ ≡ 0 and
   ndf = 2). A triplet is kept if its χ² p-value exceeds ``pvalue`` (1e-3). The search
   stops at the first module that gives a triplet: a module is skipped only if it gave
   none. With ``keep_best`` only the best third hit of a doublet is kept, ranked by the
   χ² of the four hits (a, b, c, d) with the best continuation (b, c, d) when there is
   one; this separates nearly parallel tracks (0.1–0.4 mm apart near the beam) that a
   single triplet cannot. A doublet that skips a module is used only if no doublet of
   the same middle hit without a skip gave a triplet (``all_skips``: always; ~1.7× the
   fits for < 0.01 % efficiency). A track thus makes about one triplet per hit and the
   number of fits grows linearly with the number of hits.

5. **Merging.** Conjoined triplets (a, b, c) → (b, c, d) share two hits. Triplets are
   built from the last module backwards, so all continuations of a new triplet exist
   when it is made, and each triplet is linked to its best continuation (longest chain,
   then lowest combined χ²) by dynamic programming, linear in the number of triplets.
   A link needs the combined χ² of the pair (paper eqs. 5–6 in the curvature h3D = κ,
   as ``combine_triplet_chain(..., mode=COMBINE_CURVATURE)``) to pass the p-value cut.
   A chain's χ² is eqs. 5–6 over its triplets; with ``straight`` (κ ≡ 0) the
   κ-consistency term is identically zero and carries no degrees of freedom, so its
   ndf is Σ ndf_i (``combine_triplet_chain`` counts n_triplets − 1 more).
   ``chain_pvalue`` optionally cuts on the whole chain's χ².

6. **Arbitration.** Chains that are nobody's continuation are the candidates, ranked by
   number of hits, then χ²/ndf, and accepted greedily; a hit belongs to at most one
   accepted track. A candidate some of whose hits are taken keeps its free hits if at
   least ``min_hits`` and at least (1 − ``max_shared``) of its hits are free. The
   minimum track length is 3 hits (one triplet): large-angle tracks leave the VELO
   after a few modules, and a 3-hit VELO track is still a useful seed.

7. **Both halves: gap filling and extension.** The halves overlap in the strip
   |x| < 5 mm, where a track crosses every module; near the beam this strip is a large
   part of the acceptance, and ~60 % of the particles with ≥ 3 VELO hits have hits on
   both halves (minimum bias). Such a track makes one chain per half. As soon as a
   track is accepted, (``fill_gaps``) every module crossed between two consecutive hits
   is searched for a free hit at the interpolated point, kept if the triplet
   (before, hit, after) passes the χ² cut (best χ²): this adds the other half's hits
   (and hits a chain skipped). Then (``extend``) the track is followed downstream from
   its last two hits and upstream from its first two, with up to ``extend_missing`` (2)
   crossed modules without a hit and scattering down to ``extend_p_min`` (500 MeV),
   adding the best free hit passing the triplet χ² cut, repeatedly; upstream it stops
   at the beam hole and where the line moves away from the beam (past its origin).
   The other half's chain and the pieces of a track broken by two missing modules or
   by a scattering kink above the p_min hypothesis then find their hits used and are
   dropped, instead of becoming clones. (``same_side=False`` instead lets triplets use
   modules of both halves where the track is in the overlap strip: one chain per
   track there, but 12.5 mm instead of 25 mm lever arms; measured worse on every
   metric.) A short track in the overlap strip may have fewer than three hits on
   either half (a large-angle track leaving the VELO after four modules, or one
   entering its acceptance near the end): with ``second_pass`` steps 3–7 are run again
   on the hits still unused, with triplets across both halves, keeping only candidates
   with hits on both halves (one-half pieces there are low-momentum fragments).

8. **First state.** (x, y, tx, ty) at the first (most upstream) hit from a weighted
   least-squares straight line through all the track's hits (x–z and y–z separately,
   weights 1/σ², scattering ignored): the seed of the Kalman fit and of the forward
   extension (docs/physics.md#pattern-recognition).

A track's χ²/ndf is that of its chain plus the triplets that added hits in step 7.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple
from dataclasses import asdict, dataclass, field

import numba as nb
import numpy as np
from scipy.special import chdtri

from pkf.geometry.detector import KIND_PIXEL, SIDE_LEFT, SIDE_RIGHT, SUBDETECTORS, Geometry
from pkf.jit import NO_REFCOUNT
from pkf.seeding.csr import CsrTracks
from pkf.seeding.triplet_fit import (
    DEFAULT_B_THRESHOLD,
    DEFAULT_P_MIN,
    FORM_CURVATURE,
    MASS_PION,
    N_GEOMETRY_COLUMNS,
    STATUS_INVALID,
    fit_triplet_kinks,
    highland_sigma,
    triplet_geometry_row,
)

__all__ = [
    "N_PHI_BINS",
    "VeloSearchOptions",
    "VeloTracks",
    "find_velo_tracks",
    "find_velo_tracks_in_hits",
    "options_dict",
    "velo_layer_table",
    "STAT_NAMES",
]

#: Counters returned in ``VeloTracks.stats`` (summed over events).
STAT_NAMES = ("hits", "doublets", "fits", "triplets", "candidates", "tracks")
_N_STATS = len(STAT_NAMES)

# columns of the per-layer table given to the kernel
(_L_Z, _L_HALF_X, _L_HALF_Y, _L_HOLE_R, _L_HOLE_HX, _L_HOLE_HY, _L_SIDE, _L_OVERLAP,
 _L_X0, _L_BX, _L_BY, _L_BZ, _L_SIGMA_MS) = range(13)
_N_LAYER_COLUMNS = 13

_SIDE_LEFT = SIDE_LEFT
_SIDE_RIGHT = SIDE_RIGHT

# float columns of the triplet table
(_T_CHI2, _T_KAPPA, _T_VARK, _T_NDF, _T_CC, _T_CS0, _T_CS1, _T_CS2, _T_CNDF) = range(9)
_N_TF = 9
# int columns of the triplet table
(_T_NEXT, _T_LEN, _T_LINK, _T_POINTED) = range(4)
_N_TI = 4

_MAX_NDF_TABLE = 1024  # χ² cut table length (ndf index)


class VeloConfig(NamedTuple):
    """The options of one kernel call (`VeloSearchOptions`, as the kernels read them):
    χ² cuts per ndf for triplets and pairs (chi2_cut) and for whole chains (chain_cut,
    empty: none), the Highland mass and momenta [MeV], the field threshold [T], the
    luminous region z_lo … z_hi [mm], the doublet tolerance tol0 + tol1·r [mm], the
    extension's σ_MS momentum and its ratio ms_scale to p_min's, and the switches."""

    chi2_cut: np.ndarray
    chain_cut: np.ndarray
    mass: float
    b_threshold: float
    p_min: float
    straight: bool
    max_missing: int
    z_lo: float
    z_hi: float
    tol0: float
    tol1: float
    window_sigmas: float
    margin: float
    min_hits: int
    max_shared: float
    keep_best: bool
    all_skips: bool
    extend: bool
    extend_missing: int
    extend_p_min: float
    ms_scale: float
    same_side: bool
    fill_gaps: bool
    second_pass: bool


class EventHits(NamedTuple):
    """The sorted VELO hits of all events: lay_off[e·nl + l] first row of module l of event
    e; hit (n, _N_H) table; hlay module of each row; lt (nl, _N_LAYER_COLUMNS) module
    table; bin_off the φ-bin table of the current event (`_fill_bins`); used: taken by
    an accepted track; nl: number of modules."""

    lay_off: np.ndarray
    hit: np.ndarray
    hlay: np.ndarray
    lt: np.ndarray
    bin_off: np.ndarray
    used: np.ndarray
    nl: int


class FitBuffers(NamedTuple):
    """Scratch of one triplet fit (`triplet_geometry_row`): hits (3, 3), variances (3, 3),
    field (3), geometry row."""

    hbuf: np.ndarray
    vbuf: np.ndarray
    bbuf: np.ndarray
    gbuf: np.ndarray


class Triplets(NamedTuple):
    """The triplet tables of an event: hits th (·, 3), floats tf (·, _N_TF), ints ti
    (·, _N_TI) and per hit the first triplet starting there (head_first, linked lists)."""

    th: np.ndarray
    tf: np.ndarray
    ti: np.ndarray
    head_first: np.ndarray


class TrackOut(NamedTuple):
    """The growing output: event index per track, CSR offsets, first states and χ²
    (·, _N_OUT), hit rows."""

    event: np.ndarray
    off: np.ndarray
    f: np.ndarray
    hits: np.ndarray


@dataclass(frozen=True)
class VeloSearchOptions:
    """Options of `find_velo_tracks` (defaults in brackets); see the module docstring.

    pvalue [1e-3]            p-value cut on the χ² of triplets and of linked pairs
    chain_pvalue [0]         p-value cut on a whole chain's combined χ² (0: no cut)
    p_min [1000 MeV]         seeding momentum: σ_MS (Highland) of the triplet fit
    mass [m_π]               mass hypothesis for Highland [MeV]
    b_threshold [0.05 T]     below it the curvature is not fitted (docs/physics.md#pattern-recognition)
    straight [True]          κ ≡ 0 below b_threshold (ndf 2 per triplet); else κ fitted
    max_missing [1]          crossed modules without a hit between consecutive hits
    z_luminous [200 mm]      |z0| of the luminous region (σ_z = 45 mm) for doublets
    doublet_tolerance [0.3]  transverse tolerance [mm] of a doublet's φ alignment, plus
    doublet_tolerance_slope [0.005] × r_b (scattering upstream grows with r)
    window_sigmas [4]        half-width of the third-hit window in standard deviations
    edge_margin [1.0 mm]     margin on module edges when deciding if a line crosses one
    min_hits [3]             minimum number of hits of a track
    max_shared [0.3]         largest fraction of a candidate's hits that may already be
                             used by accepted tracks (it then keeps its free hits)
    keep_best [True]         one third hit per doublet and module (best 4-hit χ²)
    all_skips [False]        also form module-skipping triplets when not needed
    same_side [True]         triplets on modules of one half only (docs/physics.md#pattern-recognition);
                             False: also across halves in the overlap strip
    fill_gaps [True]         add free hits on modules crossed between a track's hits
    second_pass [True]       with same_side: a second search across both halves on the
                             hits left (short tracks in the overlap strip)
    extend [True]            extend accepted tracks at both ends
    extend_missing [2]       crossed modules without a hit allowed when extending
    extend_p_min [500 MeV]   σ_MS momentum of the extension (None: p_min)
    field [None]             FieldModel of the VELO field (default: the geometry's
                             analytic field), evaluated on the beam axis per module
    """

    pvalue: float = 1e-3
    chain_pvalue: float = 0.0
    p_min: float = DEFAULT_P_MIN
    mass: float = MASS_PION
    b_threshold: float = DEFAULT_B_THRESHOLD
    straight: bool = True
    max_missing: int = 1
    z_luminous: float = 200.0
    doublet_tolerance: float = 0.3
    doublet_tolerance_slope: float = 0.005
    window_sigmas: float = 4.0
    edge_margin: float = 1.0
    min_hits: int = 3
    max_shared: float = 0.3
    keep_best: bool = True
    all_skips: bool = False
    same_side: bool = True
    fill_gaps: bool = True
    second_pass: bool = True
    extend: bool = True
    extend_missing: int = 2
    extend_p_min: float | None = 500.0
    field: object = field(default=None, compare=False)

    def __post_init__(self):
        if not 0.0 < self.pvalue < 1.0:
            raise ValueError(f"pvalue must be in (0, 1), got {self.pvalue}")
        if not 0.0 <= self.chain_pvalue < 1.0:
            raise ValueError(f"chain_pvalue must be in [0, 1), got {self.chain_pvalue}")
        if not self.p_min > 0.0:
            raise ValueError(f"p_min must be > 0 MeV, got {self.p_min}")
        if self.max_missing < 0:
            raise ValueError(f"max_missing must be >= 0, got {self.max_missing}")
        if self.min_hits < 3:
            raise ValueError(f"min_hits must be >= 3 (one triplet), got {self.min_hits}")
        if not 0.0 <= self.max_shared < 1.0:
            raise ValueError(f"max_shared must be in [0, 1), got {self.max_shared}")
        if self.extend_missing < 0:
            raise ValueError(f"extend_missing must be >= 0, got {self.extend_missing}")
        if self.extend_p_min is not None and not self.extend_p_min > 0.0:
            raise ValueError(f"extend_p_min must be > 0 MeV or None, got {self.extend_p_min}")
        if self.doublet_tolerance_slope < 0.0:
            raise ValueError("doublet_tolerance_slope must be >= 0")
        for name in ("z_luminous", "doublet_tolerance", "window_sigmas"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")


@dataclass
class VeloTracks(CsrTracks):
    """VELO track candidates (CSR), output of `find_velo_tracks`.

    Track t has hits ``hit_rows[offsets[t]:offsets[t+1]]`` (rows of the input arrays,
    sorted by z) and belongs to event ``event_id[t]``. Tracks are sorted by event, and
    within an event in the order arbitration accepted them (longest, best χ²/ndf first).
    First state at the first hit: ``z`` [mm], ``x``, ``y`` [mm], ``tx``, ``ty`` from a
    straight-line fit. ``chi2``/``ndf``: combined triplet χ² of the chain (eqs. 5–6)
    plus the χ² of the triplets that added hits when filling gaps and extending.
    ``stats``: counters summed over events (STAT_NAMES: VELO hits, doublets tried,
    triplet fits, triplets kept, candidates, tracks).
    """

    event_id: np.ndarray
    offsets: np.ndarray
    hit_rows: np.ndarray
    z: np.ndarray
    x: np.ndarray
    y: np.ndarray
    tx: np.ndarray
    ty: np.ndarray
    chi2: np.ndarray
    ndf: np.ndarray
    stats: dict

    def state_array(self) -> np.ndarray:
        """First states as an (n_tracks, 4) array of (x, y, tx, ty)."""
        return np.column_stack([self.x, self.y, self.tx, self.ty])


# ------------------------------------------------------------------------------------
# Compiled kernels. Hot helpers take scalars only (array arguments of non-inlined calls
# cost atomic reference-count updates in numba).
# ------------------------------------------------------------------------------------


@nb.njit(cache=True, **NO_REFCOUNT)
def _inside(x, y, margin, half_x, half_y, hole_r, hole_hx, hole_hy, side, overlap):
    """True if (x, y) lies on a module's active area shrunk by `margin` [mm] (negative:
    enlarged); the rules of geometry.acceptance.in_active_area."""
    if abs(x) > half_x - margin or abs(y) > half_y - margin:
        return False
    if hole_r > 0.0:
        rr = hole_r + margin
        if rr > 0.0 and x * x + y * y < rr * rr:
            return False
    if hole_hx > 0.0 and abs(x) < hole_hx + margin and abs(y) < hole_hy + margin:
        return False
    if side == _SIDE_LEFT and x > overlap - margin:
        return False
    if side == _SIDE_RIGHT and x < -overlap + margin:
        return False
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def _window(v0x, v0y, v1x, v1y, rho, ms, tx, ty, nsig):
    """Half-widths (x, y) [mm] of the search window for a hit extrapolated along the line
    from hit 0 through hit 1 (variances v0, v1 [mm²]) by rho = Δz/(z1 − z0): the line's
    error v1(1 + ρ)² + v0ρ², the new hit's own error (≈ v1) and the scattering `ms`
    [mm²] (Σσ²_MS·Δz², per unit (1 + t²) projection)."""
    vx = v1x * (1.0 + rho) ** 2 + v0x * rho * rho + v1x + ms * (1.0 + tx * tx)
    vy = v1y * (1.0 + rho) ** 2 + v0y * rho * rho + v1y + ms * (1.0 + ty * ty)
    return nsig * math.sqrt(vx), nsig * math.sqrt(vy)


#: φ bins per module and event for the candidate lookup (hits are sorted by φ inside
#: a module, so a bin range is an index range)
N_PHI_BINS = 256


@nb.njit(cache=True, **NO_REFCOUNT)
def _bin_ranges(bin_off, k, phi, w):
    """Index ranges [a0, a1) and [b0, b1) of the hits of module k of the current event
    in the φ bins overlapping [φ − w, φ + w], wrapping at ±π (the second range is empty
    unless the window wraps); hits near the window edges must still be checked.
    bin_off[k·(N_PHI_BINS + 1) + b]: first row of bin b of module k (`_fill_bins`). A window
    whose width or centre is not a finite number (a prediction that is not) is the whole
    module: its bins would be undefined integer conversions, read out of bounds."""
    base = k * (N_PHI_BINS + 1)
    if not (w < math.pi and math.isfinite(phi)):
        return bin_off[base], bin_off[base + N_PHI_BINS], 0, 0
    scale = N_PHI_BINS / (2.0 * math.pi)
    b0 = int(math.floor((phi - w + math.pi) * scale))
    b1 = int(math.floor((phi + w + math.pi) * scale))
    if b0 < 0:
        a0 = bin_off[base + b0 + N_PHI_BINS]
        e1 = bin_off[base + min(b1, N_PHI_BINS - 1) + 1]
        return a0, bin_off[base + N_PHI_BINS], bin_off[base], min(e1, a0)
    if b1 >= N_PHI_BINS:
        a0 = bin_off[base + b0]
        e1 = bin_off[base + min(b1 - N_PHI_BINS, N_PHI_BINS - 1) + 1]
        return a0, bin_off[base + N_PHI_BINS], bin_off[base], min(e1, a0)
    return bin_off[base + b0], bin_off[base + b1 + 1], 0, 0


@nb.njit(cache=True, **NO_REFCOUNT)
def _fill_bins(bin_off, lay_off, hit, e, nl):
    """φ-bin table of event e: bin_off[k·(N_PHI_BINS + 1) + b] is the first row of module
    k with a φ bin ≥ b (rows are sorted by φ inside a module), the last entry its end."""
    scale = N_PHI_BINS / (2.0 * math.pi)
    for k in range(nl):
        lo = lay_off[e * nl + k]
        hi = lay_off[e * nl + k + 1]
        base = k * (N_PHI_BINS + 1)
        p = lo
        for b in range(N_PHI_BINS):
            while p < hi and min(int(math.floor((hit[p, _H_PHI] + math.pi) * scale)),
                                 N_PHI_BINS - 1) < b:
                p += 1
            bin_off[base + b] = p
        bin_off[base + N_PHI_BINS] = hi


@nb.njit(cache=True, **NO_REFCOUNT)
def _other_side(side_a, side_b):
    """True if two modules cover opposite VELO halves (SIDE_LEFT vs SIDE_RIGHT)."""
    return side_a != side_b and side_a != 0.0 and side_b != 0.0


@nb.njit(cache=True)
def _stable_order(key):
    """Indices that sort `key` ascending, ties in index order (a Shell sort: compiles in
    a fraction of the time of np.argsort and is fast for the few hundred candidates of
    an event)."""
    n = key.shape[0]
    idx = np.arange(n)
    gap = n // 2
    while gap > 0:
        for i in range(gap, n):
            t = idx[i]
            j = i
            while j >= gap and (key[idx[j - gap]] > key[t]
                                or (key[idx[j - gap]] == key[t] and idx[j - gap] > t)):
                idx[j] = idx[j - gap]
                j -= gap
            idx[j] = t
        gap //= 2
    return idx


@nb.njit(cache=True, **NO_REFCOUNT)
def _wrap(a):
    if a > math.pi:
        return a - 2.0 * math.pi
    if a < -math.pi:
        return a + 2.0 * math.pi
    return a


@nb.njit("Tuple((int64[:, ::1], float64[:, ::1], int64[:, ::1]))"
          "(int64[:, ::1], float64[:, ::1], int64[:, ::1], int64)", cache=True)
def _grow_triplets(th, tf, ti, need):
    """Triplet tables with room for at least `need` rows (twice the capacity or more;
    rows copied)."""
    cap = th.shape[0]
    new = max(2 * cap, need)
    th2 = np.empty((new, th.shape[1]), dtype=np.int64)
    tf2 = np.empty((new, tf.shape[1]))
    ti2 = np.empty((new, ti.shape[1]), dtype=np.int64)
    for r in range(cap):
        for u in range(th.shape[1]):
            th2[r, u] = th[r, u]
        for u in range(tf.shape[1]):
            tf2[r, u] = tf[r, u]
        for u in range(ti.shape[1]):
            ti2[r, u] = ti[r, u]
    return th2, tf2, ti2


@nb.njit("Tuple((int64[::1], int64[::1], float64[:, ::1]))"
         "(int64[::1], int64[::1], float64[:, ::1], int64)", cache=True)
def _grow_tracks(o_event, o_off, o_f, n_out):
    """Track output arrays with twice the capacity (first n_out tracks copied)."""
    cap = 2 * o_event.shape[0]
    ne = np.empty(cap, dtype=np.int64)
    no = np.zeros(cap + 1, dtype=np.int64)
    nf = np.empty((cap, o_f.shape[1]))
    for r in range(n_out):
        ne[r] = o_event[r]
        no[r] = o_off[r]
        for u in range(o_f.shape[1]):
            nf[r, u] = o_f[r, u]
    no[n_out] = o_off[n_out]
    return ne, no, nf


@nb.njit(cache=True, **NO_REFCOUNT)
def _chain_chi2(cc, cs0, cs1, cs2, straight):
    """Combined χ² of a chain from its running sums (paper eqs. 5–6 in κ):
    Σχ²_i + Σκ_i²/σ_i² − (Σκ_i/σ_i²)²/Σ1/σ_i²."""
    if straight or not cs0 > 0.0:
        return cc
    return cc + max(cs2 - cs1 * cs1 / cs0, 0.0)


@nb.njit(cache=True, **NO_REFCOUNT)
def _best_continuation_chi2(th, tf, ti, head_first, b, c, default):
    """Lowest χ² of the triplets (b, c, ·) already built, or `default` if none."""
    best = np.inf
    s = head_first[b]
    while s >= 0:
        if th[s, 1] == c and tf[s, _T_CHI2] < best:
            best = tf[s, _T_CHI2]
        s = ti[s, _T_LINK]
    return best if best < np.inf else float(default)


@nb.njit("int64(int64[:, ::1], float64[:, ::1], int64[:, ::1], int64, int64[::1], int64,"
         " int64, int64, float64, float64, float64, int64, float64[::1], boolean)", cache=True)
def _add_triplet(th, tf, ti, nt, head_first, a, b, c, c2, kap, vk, nd, chi2_cut, straight):
    """Store triplet (a, b, c) as row nt (the caller made room) and link it to its best
    continuation (b, c, ·) by dynamic programming: longest chain, then lowest combined χ²
    (eqs. 5–6); a link needs the pair's combined χ² below the cut. Returns nt + 1."""
    t = nt
    th[t, 0] = a
    th[t, 1] = b
    th[t, 2] = c
    w_k = 1.0 / vk if (vk > 0.0 and vk < np.inf) else 0.0
    tf[t, _T_CHI2] = c2
    tf[t, _T_KAPPA] = kap
    tf[t, _T_VARK] = vk
    tf[t, _T_NDF] = nd
    best = -1
    best_len = 0
    best_c2 = np.inf
    s = head_first[b]
    while s >= 0:
        if th[s, 1] == c:
            vs = tf[s, _T_VARK]
            ws = 1.0 / vs if (vs > 0.0 and vs < np.inf) else 0.0
            ks = tf[s, _T_KAPPA]
            pc2 = _chain_chi2(c2 + tf[s, _T_CHI2], w_k + ws, w_k * kap + ws * ks,
                              w_k * kap * kap + ws * ks * ks, straight)
            pnd = nd + int(tf[s, _T_NDF]) + (0 if straight else 1)
            if pc2 <= chi2_cut[min(pnd, chi2_cut.shape[0] - 1)]:
                ln = ti[s, _T_LEN]
                cc = _chain_chi2(c2 + tf[s, _T_CC], w_k + tf[s, _T_CS0],
                                 w_k * kap + tf[s, _T_CS1], w_k * kap * kap + tf[s, _T_CS2],
                                 straight)
                if ln > best_len or (ln == best_len and cc < best_c2):
                    best = s
                    best_len = ln
                    best_c2 = cc
        s = ti[s, _T_LINK]
    ti[t, _T_POINTED] = 0
    tf[t, _T_CC] = c2
    tf[t, _T_CS0] = w_k
    tf[t, _T_CS1] = w_k * kap
    tf[t, _T_CS2] = w_k * kap * kap
    tf[t, _T_CNDF] = nd
    if best >= 0:
        ti[t, _T_NEXT] = best
        ti[t, _T_LEN] = best_len + 1
        ti[best, _T_POINTED] = 1
        tf[t, _T_CC] += tf[best, _T_CC]
        tf[t, _T_CS0] += tf[best, _T_CS0]
        tf[t, _T_CS1] += tf[best, _T_CS1]
        tf[t, _T_CS2] += tf[best, _T_CS2]
        tf[t, _T_CNDF] += tf[best, _T_CNDF] + (0 if straight else 1)
    else:
        ti[t, _T_NEXT] = -1
        ti[t, _T_LEN] = 1
    ti[t, _T_LINK] = head_first[a]
    head_first[a] = t
    return nt + 1


#: bound on |fast_atan2 − math.atan2| [rad] by which the φ windows are widened (the
#: polynomial's error is ≤ 4.1e-8 rad; tests/seeding/test_velo_phi_window.py measures it)
FAST_ATAN2_ERROR = 1e-6


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def fast_atan2(y, x):
    """atan2(y, x) [rad] within `FAST_ATAN2_ERROR`: an odd degree-15 polynomial (least
    squares on [0, 1]) in min(|x|, |y|)/max(|x|, |y|), unfolded to the octant; cheaper
    than libm's atan2. Only for window centres, never for a stored φ."""
    ax = abs(x)
    ay = abs(y)
    big = max(ax, ay)
    if big == 0.0:
        return 0.0
    a = min(ax, ay) / big
    s = a * a
    r = a * (0.9999994368089473 + s * (-0.3333010651496397 + s * (0.19948506907809624 + s * (
        -0.13915790947967252 + s * (0.09656225487513842 + s * (-0.05606272859318783 + s * (
            0.02194628436349235 - 0.004073214991437468 * s)))))))
    if ay > ax:
        r = 0.5 * math.pi - r
    if x < 0.0:
        r = math.pi - r
    return -r if y < 0.0 else r


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _angular_half_width(w, r):
    """An upper bound [rad] of asin(w/r), the angle under which a disc of radius w [mm] at
    distance r [mm] from the origin is seen: tan(asin(w/r)) = w/√(r² − w²) (≥ the angle;
    one square root instead of an arcsine), at most π/2 (≥ any arcsine: a window below
    π, as with the arcsine); 4 (> π: the whole module) if w ≥ r."""
    if w >= r:
        return 4.0
    return min(w / math.sqrt((r - w) * (r + w)), 0.5 * math.pi)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _window_ranges(bin_off, k, xp, yp, wx, wy):
    """Index ranges (`_bin_ranges`) of the hits of module k in a φ window that holds the
    box ±(wx, wy) [mm] around (xp, yp) (a superset of the box: every hit of the box is in
    the ranges, in φ order, whatever the window's exact width)."""
    w = 1.4143 * max(wx, wy)
    rp = math.sqrt(xp * xp + yp * yp)
    wphi = 1.0001 * _angular_half_width(w, rp) + FAST_ATAN2_ERROR
    return _bin_ranges(bin_off, k, fast_atan2(yp, xp), wphi)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _best_free_hit(ev, k, box, first, middle, last, m_fit, p_min, cfg, buf):
    """The free hit c of module k in the box (xp, yp, wx, wy) [mm] whose triplet (first,
    middle, last) — c in the place marked −1 — has the lowest χ² within the cut, fitted
    with the field and x/X0 of module m_fit and σ_MS at p_min [MeV]. Returns (c or −1,
    χ², ndf, fits)."""
    _, hit, _, lt, bin_off, used, _ = ev
    hbuf, vbuf, bbuf, gbuf = buf
    xp, yp, wx, wy = box
    a0, a1, c0, c1 = _window_ranges(bin_off, k, xp, yp, wx, wy)
    best_c = -1
    best_c2 = np.inf
    best_nd = 0
    n_fits = 0
    for rng in range(2):
        s0 = a0 if rng == 0 else c0
        s1 = a1 if rng == 0 else c1
        for c in range(s0, s1):
            if used[c] or abs(hit[c, _H_X] - xp) > wx or abs(hit[c, _H_Y] - yp) > wy:
                continue
            for u in range(3):
                h = first if u == 0 else (middle if u == 1 else last)
                if h < 0:
                    h = c
                hbuf[u, 0] = hit[h, _H_X]
                hbuf[u, 1] = hit[h, _H_Y]
                hbuf[u, 2] = hit[h, _H_Z]
                vbuf[u, 0] = hit[h, _H_VX]
                vbuf[u, 1] = hit[h, _H_VY]
            bbuf[0] = lt[m_fit, _L_BX]
            bbuf[1] = lt[m_fit, _L_BY]
            bbuf[2] = lt[m_fit, _L_BZ]
            triplet_geometry_row(hbuf, bbuf, vbuf, cfg.b_threshold, gbuf)
            _k, _vk, c2, nd, _s, _kp, _kt, st = fit_triplet_kinks(
                gbuf, lt[m_fit, _L_X0], cfg.mass, cfg.b_threshold, p_min, FORM_CURVATURE, cfg.straight)
            n_fits += 1
            ok = (st & STATUS_INVALID) == 0
            if ok and c2 <= cfg.chi2_cut[nd] and c2 < best_c2:
                best_c = c
                best_c2 = c2
                best_nd = nd
    return best_c, best_c2, best_nd, n_fits


@nb.njit(cache=True, **NO_REFCOUNT)
def _extend_track(trk, lo, hi, ev, e, cfg, buf):
    """Extend an accepted track trk[lo:hi] (hit rows in z order) downstream, then
    upstream: from its last (first) two hits, the line is followed through the next
    modules, allowing up to `max_missing` crossed modules without a hit; the free hit
    with the best triplet χ² below the cut (triplet fit at the inner hit) is added and
    the search continues from the new last two hits (σ_MS at cfg.extend_p_min, up to
    cfg.extend_missing crossed modules without a hit). Returns (lo, hi, Σχ², Σndf, fits)."""
    lay_off, hit, hlay, lt, _, used, nl = ev
    p_min, ms_scale, max_missing = cfg.extend_p_min, cfg.ms_scale, cfg.extend_missing
    window_sigmas, margin = cfg.window_sigmas, cfg.margin
    c2_sum = 0.0
    nd_sum = 0
    n_fits = 0
    for direction in (1, -1):
        while hi - lo >= 2:
            if direction == 1:
                p0 = trk[hi - 2]
                p1 = trk[hi - 1]
            else:
                p0 = trk[lo + 1]
                p1 = trk[lo]
            x0 = hit[p0, _H_X]
            y0 = hit[p0, _H_Y]
            z0 = hit[p0, _H_Z]
            x1 = hit[p1, _H_X]
            y1 = hit[p1, _H_Y]
            z1 = hit[p1, _H_Z]
            tx = (x1 - x0) / (z1 - z0)
            ty = (y1 - y0) / (z1 - z0)
            n2 = 1.0 + tx * tx + ty * ty
            j = hlay[p1]
            s1 = lt[j, _L_SIGMA_MS] * ms_scale
            m0 = s1 * s1 * n2
            m1 = m0 * z1
            m2 = m1 * z1
            count = 0
            best_c = -1
            best_c2 = np.inf
            best_nd = 0
            r1 = math.sqrt(x1 * x1 + y1 * y1)
            k = j + direction
            while 0 <= k < nl and count <= max_missing:
                zk = lt[k, _L_Z]
                dz = zk - z1
                xp = x1 + tx * dz
                yp = y1 + ty * dz
                if abs(xp) > lt[k, _L_HALF_X] + margin or abs(yp) > lt[k, _L_HALF_Y] + margin:
                    break
                if direction == -1:
                    # upstream, tracks from the beam line approach it: stop at the beam
                    # hole or once the line moves away again (past its origin)
                    rk = math.sqrt(xp * xp + yp * yp)
                    if rk < lt[k, _L_HOLE_R] - margin or rk > r1 + margin:
                        break
                if _inside(xp, yp, -margin, lt[k, _L_HALF_X], lt[k, _L_HALF_Y],
                           lt[k, _L_HOLE_R], lt[k, _L_HOLE_HX], lt[k, _L_HOLE_HY],
                           lt[k, _L_SIDE], lt[k, _L_OVERLAP]):
                    lo_k = lay_off[e * nl + k]
                    hi_k = lay_off[e * nl + k + 1]
                    if hi_k > lo_k:
                        rho = dz / (z1 - z0)
                        ms = m0 * zk * zk - 2.0 * zk * m1 + m2
                        v1x = hit[p1, _H_VX]
                        v1y = hit[p1, _H_VY]
                        wx, wy = _window(hit[p0, _H_VX], hit[p0, _H_VY], v1x, v1y, rho, ms,
                                         tx, ty, window_sigmas)
                        # along the motion: (p0, p1, c) downstream, (c, p1, p0) upstream
                        best_c, best_c2, best_nd, nf = _best_free_hit(
                            ev, k, (xp, yp, wx, wy), p0 if direction == 1 else -1, p1,
                            -1 if direction == 1 else p0, j, p_min, cfg, buf)
                        n_fits += nf
                    if best_c >= 0:
                        break
                    if _inside(xp, yp, margin, lt[k, _L_HALF_X], lt[k, _L_HALF_Y],
                               lt[k, _L_HOLE_R], lt[k, _L_HOLE_HX], lt[k, _L_HOLE_HY],
                               lt[k, _L_SIDE], lt[k, _L_OVERLAP]):
                        count += 1
                    sk = lt[k, _L_SIGMA_MS] * ms_scale
                    qk = sk * sk * n2
                    m0 += qk
                    m1 += qk * zk
                    m2 += qk * zk * zk
                k += direction
            if best_c < 0:
                break
            used[best_c] = True
            c2_sum += best_c2
            nd_sum += best_nd
            if direction == 1:
                trk[hi] = best_c
                hi += 1
            else:
                lo -= 1
                trk[lo] = best_c
    return lo, hi, c2_sum, nd_sum, n_fits


@nb.njit(cache=True, **NO_REFCOUNT)
def _fill_gaps(trk, lo, hi, tmp, ev, e, cfg, buf):
    """Add free hits on the modules crossed between consecutive hits of trk[lo:hi] (the
    other VELO half in the overlap strip, or hits the chain skipped): the point is
    interpolated between the two hits and the free hit with the best χ² of the triplet
    (before, hit, after) below the cut is taken. Returns (hi, Σχ², Σndf, fits)."""
    lay_off, hit, hlay, lt, _, used, nl = ev
    window_sigmas, margin = cfg.window_sigmas, cfg.margin
    n = 0
    c2_sum = 0.0
    nd_sum = 0
    n_fits = 0
    for q in range(lo, hi):
        tmp[n] = trk[q]
        n += 1
        if q + 1 >= hi:
            break
        h0 = trk[q]
        h1 = trk[q + 1]
        x0 = hit[h0, _H_X]
        y0 = hit[h0, _H_Y]
        z0 = hit[h0, _H_Z]
        dz01 = hit[h1, _H_Z] - z0
        tx = (hit[h1, _H_X] - x0) / dz01
        ty = (hit[h1, _H_Y] - y0) / dz01
        n2 = 1.0 + tx * tx + ty * ty
        for k in range(hlay[h0] + 1, hlay[h1]):
            dz = lt[k, _L_Z] - z0
            xp = x0 + tx * dz
            yp = y0 + ty * dz
            if not _inside(xp, yp, -margin, lt[k, _L_HALF_X], lt[k, _L_HALF_Y],
                           lt[k, _L_HOLE_R], lt[k, _L_HOLE_HX], lt[k, _L_HOLE_HY],
                           lt[k, _L_SIDE], lt[k, _L_OVERLAP]):
                continue
            lo_k = lay_off[e * nl + k]
            hi_k = lay_off[e * nl + k + 1]
            if hi_k <= lo_k:
                continue
            f = dz / dz01
            # interpolation error, the hit's own error, one kink (σ_MS at the larger
            # neighbour's module) over the shorter lever arm
            sms = max(lt[hlay[h0], _L_SIGMA_MS], lt[hlay[h1], _L_SIGMA_MS])
            arm = min(dz, dz01 - dz)
            ms = sms * sms * n2 * arm * arm
            vx = hit[h0, _H_VX] * (1 - f) ** 2 + hit[h1, _H_VX] * f * f + hit[h0, _H_VX]
            vy = hit[h0, _H_VY] * (1 - f) ** 2 + hit[h1, _H_VY] * f * f + hit[h0, _H_VY]
            wx = window_sigmas * math.sqrt(vx + ms * (1.0 + tx * tx))
            wy = window_sigmas * math.sqrt(vy + ms * (1.0 + ty * ty))
            best_c, best_c2, best_nd, nf = _best_free_hit(ev, k, (xp, yp, wx, wy), h0, -1, h1, k, cfg.p_min,
                                                          cfg, buf)
            n_fits += nf
            if best_c >= 0:
                used[best_c] = True
                tmp[n] = best_c
                n += 1
                c2_sum += best_c2
                nd_sum += best_nd
    for q in range(n):
        trk[lo + q] = tmp[q]
    return lo + n, c2_sum, nd_sum, n_fits


@nb.njit(cache=True, **NO_REFCOUNT)
def _line_state(trk, lo, hi, hit):
    """Weighted least-squares straight line through the hits trk[lo:hi] (x–z and y–z
    independently, weights 1/σ²): (z, x, y, tx, ty) at the first hit."""
    z0 = hit[trk[lo], _H_Z]
    sw = swz = swzz = swx = swzx = 0.0
    vw = vwz = vwzz = vwy = vwzy = 0.0
    for u in range(lo, hi):
        h = trk[u]
        dz = hit[h, _H_Z] - z0
        wgt = 1.0 / hit[h, _H_VX]
        sw += wgt
        swz += wgt * dz
        swzz += wgt * dz * dz
        swx += wgt * hit[h, _H_X]
        swzx += wgt * dz * hit[h, _H_X]
        wgt = 1.0 / hit[h, _H_VY]
        vw += wgt
        vwz += wgt * dz
        vwzz += wgt * dz * dz
        vwy += wgt * hit[h, _H_Y]
        vwzy += wgt * dz * hit[h, _H_Y]
    slx = (sw * swzx - swz * swx) / (sw * swzz - swz * swz)
    sly = (vw * vwzy - vwz * vwy) / (vw * vwzz - vwz * vwz)
    return z0, (swx - slx * swz) / sw, (vwy - sly * vwz) / vw, slx, sly


# per-hit columns of the kernel's hit table
(_H_X, _H_Y, _H_Z, _H_PHI, _H_R, _H_VX, _H_VY) = range(7)
_N_H = 7
# output columns per track
(_O_Z, _O_X, _O_Y, _O_TX, _O_TY, _O_CHI2, _O_NDF) = range(7)
_N_OUT = 7


#: runs of this many elements are sorted by insertion before merging
_INSERTION_RUN = 16


@nb.njit(cache=True, **NO_REFCOUNT)
def _stable_sort_by_key(key, val, lo, hi, key_tmp, val_tmp):
    """Sort key[lo:hi] ascending, carrying val[lo:hi] along, stably (equal keys keep their
    order: the permutation of np.argsort(kind="mergesort")), in place: insertion sort of
    runs of `_INSERTION_RUN`, then bottom-up merges through key_tmp/val_tmp (scratch of at
    least hi elements)."""
    for start in range(lo, hi, _INSERTION_RUN):
        stop = min(start + _INSERTION_RUN, hi)
        for i in range(start + 1, stop):
            kk = key[i]
            vv = val[i]
            j = i
            while j > start and key[j - 1] > kk:
                key[j] = key[j - 1]
                val[j] = val[j - 1]
                j -= 1
            key[j] = kk
            val[j] = vv
    width = _INSERTION_RUN
    while width < hi - lo:
        for left in range(lo, hi, 2 * width):
            mid = min(left + width, hi)
            right = min(left + 2 * width, hi)
            if mid >= right or not key[mid] < key[mid - 1]:
                continue  # already in order
            for i in range(left, mid):
                key_tmp[i] = key[i]
                val_tmp[i] = val[i]
            i = left
            j = mid
            out = left
            while i < mid and j < right:
                if key[j] < key_tmp[i]:  # strictly less: ties take the left run first
                    key[out] = key[j]
                    val[out] = val[j]
                    j += 1
                else:
                    key[out] = key_tmp[i]
                    val[out] = val_tmp[i]
                    i += 1
                out += 1
            while i < mid:
                key[out] = key_tmp[i]
                val[out] = val_tmp[i]
                i += 1
                out += 1
        width *= 2


@nb.njit(cache=True)
def _prepare_hits(event_id, layer, x, y, z, sx, sy, lmap, nl):
    """Select the VELO hits, sort them by (event, module, φ) with a counting sort and
    build the kernel's tables. Returns (hit table, module, input row, lay_off, event
    ids, first bad row or −1). lay_off[e*nl + l] is the first sorted row of
    module l in event e (events: those with at least one VELO hit, in input order)."""
    n = event_id.shape[0]
    nlay = lmap.shape[0]
    m = 0
    n_events = 0
    last_event = 0
    for i in range(n):
        li = layer[i]
        if li < 0 or li >= nlay or lmap[li] < 0:
            continue
        if not (math.isfinite(x[i]) and math.isfinite(y[i]) and math.isfinite(z[i])
                and sx[i] > 0.0 and sy[i] > 0.0):
            return (np.empty((0, _N_H)), np.empty(0, dtype=np.int64),
                    np.empty(0, dtype=np.int64), np.zeros(1, dtype=np.int64),
                    np.empty(0, dtype=np.int64), i)
        if m == 0 or event_id[i] != last_event:
            n_events += 1
            last_event = event_id[i]
        m += 1
    events = np.empty(n_events, dtype=np.int64)
    bucket = np.empty(m, dtype=np.int64)
    src = np.empty(m, dtype=np.int64)
    counts = np.zeros(n_events * nl + 1, dtype=np.int64)
    q = 0
    e = -1
    for i in range(n):
        li = layer[i]
        if li < 0 or li >= nlay or lmap[li] < 0:
            continue
        if e < 0 or event_id[i] != events[e]:
            e += 1
            events[e] = event_id[i]
        k = e * nl + lmap[li]
        bucket[q] = k
        src[q] = i
        counts[k + 1] += 1
        q += 1
    lay_off = np.cumsum(counts)
    fill = lay_off[:-1].copy()
    rows = np.empty(m, dtype=np.int64)
    hlay = np.empty(m, dtype=np.int64)
    phi_tmp = np.empty(m)
    for q in range(m):
        k = bucket[q]
        p = fill[k]
        fill[k] += 1
        i = src[q]
        rows[p] = i
        hlay[p] = k % nl
        phi_tmp[p] = math.atan2(y[i], x[i])
    # φ order inside each (event, module) bucket: a stable merge sort (at ν = 7.6 a module
    # holds ~100 hits of an event, too many for an insertion sort alone) in one scratch
    # buffer, not an argsort and two gathers (three allocations) per bucket
    scratch_phi = np.empty(m)
    scratch_rows = np.empty(m, dtype=np.int64)
    for k in range(n_events * nl):
        _stable_sort_by_key(phi_tmp, rows, lay_off[k], lay_off[k + 1], scratch_phi, scratch_rows)
    hit = np.empty((m, _N_H))
    for p in range(m):
        i = rows[p]
        hit[p, _H_X] = x[i]
        hit[p, _H_Y] = y[i]
        hit[p, _H_Z] = z[i]
        hit[p, _H_PHI] = phi_tmp[p]
        hit[p, _H_R] = math.sqrt(x[i] * x[i] + y[i] * y[i])
        hit[p, _H_VX] = sx[i] * sx[i]
        hit[p, _H_VY] = sy[i] * sy[i]
    return hit, hlay, rows, lay_off, events, -1




@nb.njit(cache=True, **NO_REFCOUNT)
def _search_triplets(e, side_only, j_start, b_start, nt, ev, cfg, store, dbl_a, dbl_m, buf, counters):
    """Triplet search and merging of event e (module docstring, steps 3–5) on the unused
    hits: doublets, third hits, triplet fits, links to the best continuation.
    side_only: triplets on one VELO half. Starts at middle module j_start, at its row
    b_start (or its first row if b_start is below it), with nt triplets stored.

    The triplet tables th, tf, ti are never reassigned here (a loop-carried array
    variable costs reference-count updates in every iteration): before the third hits
    of a middle hit b the search checks that the tables have room for b's triplets, and
    if not it returns early, before any side effect of b, for the caller to grow them
    and resume at b. Returns (nt, j, b, need): need = 0 when the event is done, else the
    rows needed to resume at module j, row b. counters[0] += doublets tried,
    counters[1] += triplet fits. dbl_a, dbl_m: scratch of b's doublets (first hit, modules
    skipped)."""
    lay_off, hit, _, lt, bin_off, used, nl = ev
    th, tf, ti, head_first = store
    hbuf, vbuf, bbuf, gbuf = buf
    chi2_cut, mass, b_threshold, p_min, straight = cfg.chi2_cut, cfg.mass, cfg.b_threshold, cfg.p_min, cfg.straight
    max_missing, z_lo, z_hi, tol0, tol1 = cfg.max_missing, cfg.z_lo, cfg.z_hi, cfg.tol0, cfg.tol1
    window_sigmas, margin, keep_best, all_skips = cfg.window_sigmas, cfg.margin, cfg.keep_best, cfg.all_skips
    max_module_hits = 0
    for k in range(nl):
        max_module_hits = max(max_module_hits, lay_off[e * nl + k + 1] - lay_off[e * nl + k])
    # ---------------- triplet search: middle modules from the last backwards ----
    for j in range(j_start, 0, -1):
        zb_layer = lt[j, _L_Z]
        bx_j = lt[j, _L_BX]
        by_j = lt[j, _L_BY]
        bz_j = lt[j, _L_BZ]
        x0_j = lt[j, _L_X0]
        sms_j = lt[j, _L_SIGMA_MS]
        b_first = lay_off[e * nl + j]
        if j == j_start:
            b_first = max(b_first, b_start)
        for b in range(b_first, lay_off[e * nl + j + 1]):
            if used[b]:
                continue
            xb = hit[b, _H_X]
            yb = hit[b, _H_Y]
            zb = hit[b, _H_Z]
            rb = hit[b, _H_R]
            phib = hit[b, _H_PHI]
            # ---- doublets (a, b): earlier modules, nearest first, until
            # max_missing + 1 modules that certainly cover b's (x, y) were searched
            n_dbl = 0
            n_tried = 0
            count = 0
            for i in range(j - 1, -1, -1):
                if count > max_missing:
                    break
                if side_only and _other_side(lt[i, _L_SIDE], lt[j, _L_SIDE]):
                    continue
                if _inside(xb, yb, margin, lt[i, _L_HALF_X], lt[i, _L_HALF_Y],
                           lt[i, _L_HOLE_R], lt[i, _L_HOLE_HX], lt[i, _L_HOLE_HY],
                           lt[i, _L_SIDE], lt[i, _L_OVERLAP]):
                    count += 1
                za_layer = lt[i, _L_Z]
                lo = lay_off[e * nl + i]
                hi = lay_off[e * nl + i + 1]
                if hi <= lo or za_layer <= z_lo:
                    continue
                # r window for a vertex z0 in [z_lo, min(z_hi, z_a)]
                tol = tol0 + tol1 * rb
                r_hi = rb * (za_layer - z_lo) / (zb_layer - z_lo) + tol
                z0max = min(z_hi, za_layer)
                r_lo = rb * (za_layer - z0max) / (zb_layer - z0max) - tol
                r_min = max(r_lo, lt[i, _L_HOLE_R])
                wphi = 1.0001 * _angular_half_width(tol, r_min)
                a0, a1, c0, c1 = _bin_ranges(bin_off, i, phib, wphi)
                for rng in range(2):
                    s0 = a0 if rng == 0 else c0
                    s1 = a1 if rng == 0 else c1
                    for a in range(s0, s1):
                        ra = hit[a, _H_R]
                        if ra > r_hi or ra < r_lo or used[a]:
                            continue
                        if abs(_wrap(hit[a, _H_PHI] - phib)) * min(ra, rb) > tol:
                            continue
                        n_tried += 1
                        # modules between a and b that the line certainly crosses
                        # (the slopes are computed in the loop: with side_only most
                        # doublets have no module of their half in between)
                        xa = hit[a, _H_X]
                        ya = hit[a, _H_Y]
                        za = hit[a, _H_Z]
                        txd = (xb - xa) / (zb - za)
                        tyd = (yb - ya) / (zb - za)
                        m = 0
                        for u in range(i + 1, j):
                            if side_only and _other_side(lt[u, _L_SIDE], lt[j, _L_SIDE]):
                                continue
                            dzl = lt[u, _L_Z] - za
                            if _inside(xa + txd * dzl, ya + tyd * dzl, margin,
                                       lt[u, _L_HALF_X], lt[u, _L_HALF_Y],
                                       lt[u, _L_HOLE_R], lt[u, _L_HOLE_HX],
                                       lt[u, _L_HOLE_HY], lt[u, _L_SIDE],
                                       lt[u, _L_OVERLAP]):
                                m += 1
                        if m > max_missing or n_dbl >= dbl_a.shape[0]:
                            continue
                        dbl_a[n_dbl] = a
                        dbl_m[n_dbl] = m
                        n_dbl += 1
            # ---- third hits: doublets without a skipped module first; those with
            # a skip only if the former gave no triplet. Room for b's triplets first:
            # a doublet gives at most one (keep_best: the module loop stops at the first
            # module that gave one) or the hits of one module.
            need = nt + n_dbl * (1 if keep_best else max_module_hits)
            if need > th.shape[0]:
                return nt, j, b, need
            counters[0] += n_tried
            found_direct = False
            for q in range(2 * n_dbl):
                skip_pass = q >= n_dbl
                qq = q - n_dbl if skip_pass else q
                if skip_pass and found_direct and not all_skips:
                    break
                if (dbl_m[qq] > 0) != skip_pass:
                    continue
                a = dbl_a[qq]
                xa = hit[a, _H_X]
                ya = hit[a, _H_Y]
                za = hit[a, _H_Z]
                vxa = hit[a, _H_VX]
                vya = hit[a, _H_VY]
                vxb = hit[b, _H_VX]
                vyb = hit[b, _H_VY]
                dab = zb - za
                tx = (xb - xa) / dab
                ty = (yb - ya) / dab
                n2 = 1.0 + tx * tx + ty * ty
                # scattering moments Σσ², Σσ²z, Σσ²z² of the crossed modules from b
                m0 = sms_j * sms_j * n2
                m1 = m0 * zb
                m2 = m1 * zb
                count = 0
                nacc = 0
                for k in range(j + 1, nl):
                    if count > max_missing:
                        break
                    if side_only and _other_side(lt[k, _L_SIDE], lt[j, _L_SIDE]):
                        continue
                    zk = lt[k, _L_Z]
                    dz = zk - zb
                    xp = xb + tx * dz
                    yp = yb + ty * dz
                    if (abs(xp) > lt[k, _L_HALF_X] + margin
                            or abs(yp) > lt[k, _L_HALF_Y] + margin):
                        break  # the line leaves the VELO
                    possible = _inside(xp, yp, -margin, lt[k, _L_HALF_X], lt[k, _L_HALF_Y],
                                       lt[k, _L_HOLE_R], lt[k, _L_HOLE_HX],
                                       lt[k, _L_HOLE_HY], lt[k, _L_SIDE], lt[k, _L_OVERLAP])
                    if not possible:
                        continue
                    expected = _inside(xp, yp, margin, lt[k, _L_HALF_X], lt[k, _L_HALF_Y],
                                       lt[k, _L_HOLE_R], lt[k, _L_HOLE_HX],
                                       lt[k, _L_HOLE_HY], lt[k, _L_SIDE], lt[k, _L_OVERLAP])
                    lo = lay_off[e * nl + k]
                    hi = lay_off[e * nl + k + 1]
                    if hi > lo:
                        rho = dz / dab
                        ms = m0 * zk * zk - 2.0 * zk * m1 + m2
                        wx, wy = _window(vxa, vya, vxb, vyb, rho, ms, tx, ty,
                                         window_sigmas)
                        a0, a1, c0, c1 = _window_ranges(bin_off, k, xp, yp, wx, wy)
                        best_c = -1
                        best_c2 = np.inf
                        best_score = np.inf
                        best_kap = 0.0
                        best_vk = 0.0
                        best_nd = 0
                        for rng in range(2):
                            s0 = a0 if rng == 0 else c0
                            s1 = a1 if rng == 0 else c1
                            for c in range(s0, s1):
                                if (used[c] or abs(hit[c, _H_X] - xp) > wx
                                        or abs(hit[c, _H_Y] - yp) > wy):
                                    continue
                                # triplet fit (docs/physics.md#pattern-recognition) at the middle hit b
                                hbuf[0, 0] = xa
                                hbuf[0, 1] = ya
                                hbuf[0, 2] = za
                                hbuf[1, 0] = xb
                                hbuf[1, 1] = yb
                                hbuf[1, 2] = zb
                                hbuf[2, 0] = hit[c, _H_X]
                                hbuf[2, 1] = hit[c, _H_Y]
                                hbuf[2, 2] = hit[c, _H_Z]
                                vbuf[0, 0] = vxa
                                vbuf[0, 1] = vya
                                vbuf[1, 0] = vxb
                                vbuf[1, 1] = vyb
                                vbuf[2, 0] = hit[c, _H_VX]
                                vbuf[2, 1] = hit[c, _H_VY]
                                bbuf[0] = bx_j
                                bbuf[1] = by_j
                                bbuf[2] = bz_j
                                triplet_geometry_row(hbuf, bbuf, vbuf, b_threshold, gbuf)
                                kap, vk, c2, nd, _s, _kp, _kt, st = fit_triplet_kinks(
                                    gbuf, x0_j, mass, b_threshold, p_min, FORM_CURVATURE,
                                    straight)
                                counters[1] += 1
                                if (st & STATUS_INVALID) != 0 or not (c2 <= chi2_cut[nd]):
                                    continue
                                if keep_best:
                                    # rank by the χ² of the four hits (a, b, c, d) with
                                    # the best continuation (b, c, d) if there is one
                                    score = c2 + _best_continuation_chi2(
                                        th, tf, ti, head_first, b, c, nd)
                                    if score < best_score:
                                        best_score = score
                                        best_c = c
                                        best_c2 = c2
                                        best_kap = kap
                                        best_vk = vk
                                        best_nd = nd
                                    continue
                                nt = _add_triplet(
                                    th, tf, ti, nt, head_first, a, b, c, c2, kap, vk, nd,
                                    chi2_cut, straight)
                                nacc += 1
                        if best_c >= 0:
                            nt = _add_triplet(
                                th, tf, ti, nt, head_first, a, b, best_c, best_c2, best_kap,
                                best_vk, best_nd, chi2_cut, straight)
                            nacc += 1
                    if nacc > 0:
                        break  # third hit found on this module: no skip
                    if expected:
                        count += 1
                    # module k is crossed: its scattering adds to farther predictions
                    sk = lt[k, _L_SIGMA_MS]
                    qk = sk * sk * n2
                    m0 += qk
                    m1 += qk * zk
                    m2 += qk * zk * zk
                if nacc > 0 and not skip_pass:
                    found_direct = True
    return nt, 0, 0, 0


@nb.njit(cache=True)
def _arbitrate(e, nt, both_halves, ev, cfg, store, trk, tmp, buf, counters, out, n_out, n_out_hits):
    """Candidates (chains that are nobody's continuation), arbitration, gap filling,
    extension and first states of event e (module docstring, steps 6–8); appends the
    accepted tracks to the output arrays. both_halves: keep only candidates with free
    hits on both VELO halves (the second pass). Returns (out, n_out, n_out_hits), out
    (`TrackOut`) grown if needed. counters[1] += triplet fits, counters[3] += candidates."""
    _, _, hlay, lt, _, used, nl = ev
    th, tf, ti, _ = store
    o_event, o_off, o_f, o_hits = out
    straight, chain_cut, min_hits, max_shared = cfg.straight, cfg.chain_cut, cfg.min_hits, cfg.max_shared
    # ---------------- candidates: chains that are nobody's continuation ---------
    n_cand = 0
    for t in range(nt):
        if ti[t, _T_POINTED] == 0:
            n_cand += 1
    cand = np.empty(n_cand, dtype=np.int64)
    key = np.empty(n_cand)
    q = 0
    for t in range(nt):
        if ti[t, _T_POINTED] == 0:
            cand[q] = t
            c2 = _chain_chi2(tf[t, _T_CC], tf[t, _T_CS0], tf[t, _T_CS1], tf[t, _T_CS2],
                             straight)
            nd = tf[t, _T_CNDF]
            key[q] = -(ti[t, _T_LEN] + 2) * 1.0e9 + min(c2 / max(nd, 1.0), 1.0e8)
            q += 1
    counters[3] += n_cand
    order = _stable_order(key)
    # ---------------- arbitration: longest, then best χ²/ndf first ---------------
    for qq in range(n_cand):
        t = cand[order[qq]]
        c2 = _chain_chi2(tf[t, _T_CC], tf[t, _T_CS0], tf[t, _T_CS1], tf[t, _T_CS2],
                         straight)
        nd = tf[t, _T_CNDF]
        if chain_cut.shape[0] > 0 and c2 > chain_cut[min(int(nd), chain_cut.shape[0] - 1)]:
            continue
        # the chain's hits, stored from trk[nl + 2] on (room to extend upstream)
        lo = nl + 2
        trk[lo] = th[t, 0]
        trk[lo + 1] = th[t, 1]
        trk[lo + 2] = th[t, 2]
        nh = 3
        s = ti[t, _T_NEXT]
        while s >= 0:
            trk[lo + nh] = th[s, 2]
            nh += 1
            s = ti[s, _T_NEXT]
        n_free = 0
        n_left = 0
        n_right = 0
        for u in range(lo, lo + nh):
            if not used[trk[u]]:
                n_free += 1
                side = lt[hlay[trk[u]], _L_SIDE]
                if side == _SIDE_LEFT:
                    n_left += 1
                elif side == _SIDE_RIGHT:
                    n_right += 1
        if n_free < min_hits or n_free < (1.0 - max_shared) * nh - 1e-9:
            continue
        if both_halves and (n_left == 0 or n_right == 0):
            continue  # second pass: one-half tracks had their chance in the first
        # accept its free hits (in z order), then extend it
        hi = lo
        for u in range(lo, lo + nh):
            if not used[trk[u]]:
                used[trk[u]] = True
                trk[hi] = trk[u]
                hi += 1
        if cfg.fill_gaps:
            hi, c2x, ndx, nfx = _fill_gaps(trk, lo, hi, tmp, ev, e, cfg, buf)
            c2 += c2x
            nd += ndx
            counters[1] += nfx
        if cfg.extend:
            lo, hi, c2x, ndx, nfx = _extend_track(trk, lo, hi, ev, e, cfg, buf)
            c2 += c2x
            nd += ndx
            counters[1] += nfx
        if n_out >= o_event.shape[0]:
            o_event, o_off, o_f = _grow_tracks(o_event, o_off, o_f, n_out)
        if n_out_hits + (hi - lo) > o_hits.shape[0]:
            nhits = np.empty(2 * o_hits.shape[0] + hi - lo, dtype=np.int64)
            nhits[:n_out_hits] = o_hits[:n_out_hits]
            o_hits = nhits
        for u in range(lo, hi):
            o_hits[n_out_hits] = trk[u]
            n_out_hits += 1
        z0, x0, y0, slx, sly = _line_state(trk, lo, hi, ev.hit)
        o_event[n_out] = e
        o_f[n_out, _O_Z] = z0
        o_f[n_out, _O_X] = x0
        o_f[n_out, _O_Y] = y0
        o_f[n_out, _O_TX] = slx
        o_f[n_out, _O_TY] = sly
        o_f[n_out, _O_CHI2] = c2
        o_f[n_out, _O_NDF] = nd
        n_out += 1
        o_off[n_out] = n_out_hits
    return TrackOut(o_event, o_off, o_f, o_hits), n_out, n_out_hits


@nb.njit(cache=True)
def _velo_search_kernel(lay_off, n_events, nl, hit, hlay, lt, cfg):
    """All events: triplet search, merging, arbitration, first states (module docstring).

    lay_off[e*nl + l]: first row of module l of event e in `hit` (rows sorted by event,
    module, φ); hit: (n, _N_H) table; hlay: module of each row; lt: (nl,
    _N_LAYER_COLUMNS) module table; cfg: `VeloConfig`. Returns (track event index, CSR offsets, hit
    rows, (n_tracks, _N_OUT) first states and χ², stats).
    """
    n = hit.shape[0]
    head_first = np.full(n, -1, dtype=np.int64)  # triplets by first hit (linked lists)
    used = np.zeros(n, dtype=np.bool_)
    th = np.empty((1024, 3), dtype=np.int64)
    tf = np.empty((1024, _N_TF))
    ti = np.empty((1024, _N_TI), dtype=np.int64)
    hbuf = np.zeros((3, 3))
    vbuf = np.zeros((3, 3))
    bbuf = np.zeros(3)
    gbuf = np.zeros(N_GEOMETRY_COLUMNS)
    dbl_a = np.empty(4096, dtype=np.int64)
    dbl_m = np.empty(4096, dtype=np.int64)
    trk = np.empty(2 * nl + 4, dtype=np.int64)
    tmp = np.empty(2 * nl + 4, dtype=np.int64)
    bin_off = np.empty(nl * (N_PHI_BINS + 1), dtype=np.int64)
    o_event = np.empty(256, dtype=np.int64)
    o_off = np.zeros(257, dtype=np.int64)
    o_f = np.empty((256, _N_OUT))
    o_hits = np.empty(4096, dtype=np.int64)
    n_out = np.int64(0)  # typed, not a literal: one compilation of _arbitrate
    n_out_hits = np.int64(0)
    counters = np.zeros(4, dtype=np.int64)  # doublets, fits, triplets, candidates
    ev = EventHits(lay_off, hit, hlay, lt, bin_off, used, nl)
    buf = FitBuffers(hbuf, vbuf, bbuf, gbuf)
    out = TrackOut(o_event, o_off, o_f, o_hits)
    same_side = cfg.same_side
    for e in range(n_events):
        ev_lo = lay_off[e * nl]
        ev_hi = lay_off[(e + 1) * nl]
        if ev_hi - ev_lo < 3:
            continue
        _fill_bins(bin_off, lay_off, hit, e, nl)
        # pass 0: triplets on one VELO half (or on both, same_side=False); pass 1 (when
        # same_side and second_pass): both halves, on the hits left unused, for short
        # tracks in the overlap strip with fewer than three hits on either half
        for pass_ in range(2 if (same_side and cfg.second_pass) else 1):
            side_only = same_side and pass_ == 0
            both_halves = same_side and pass_ == 1
            nt = 0
            j = nl - 2
            b = -1
            while True:
                nt, j, b, need = _search_triplets(e, side_only, j, b, nt, ev, cfg,
                                                  Triplets(th, tf, ti, head_first), dbl_a, dbl_m, buf,
                                                  counters)
                if need == 0:
                    break
                th, tf, ti = _grow_triplets(th, tf, ti, need)
            counters[2] += nt
            out, n_out, n_out_hits = _arbitrate(e, nt, both_halves, ev, cfg, Triplets(th, tf, ti, head_first),
                                                trk, tmp, buf, counters, out, n_out, n_out_hits)
            for h in range(ev_lo, ev_hi):
                head_first[h] = -1
    stats = np.zeros(_N_STATS, dtype=np.int64)
    stats[0] = n
    stats[1:5] = counters
    stats[5] = n_out
    return (out.event[:n_out].copy(), out.off[:n_out + 1].copy(), out.hits[:n_out_hits].copy(),
            out.f[:n_out].copy(), stats)


# ------------------------------------------------------------------------------------
# Python interface
# ------------------------------------------------------------------------------------


def velo_layer_table(geometry: Geometry, options: VeloSearchOptions | None = None):
    """(velo layer indices, per-module table) used by the search.

    The VELO layers are the pixel layers of subdetector "velo", sorted by z. The table
    holds per module: z, outer half-widths, beam hole, covered side and overlap, x/X0,
    the field on the beam axis [T] and σ_MS [rad] at p_min for normal incidence.
    """
    options = options or VeloSearchOptions()
    velo = np.flatnonzero((geometry.layer_subdetector == SUBDETECTORS.index("velo"))
                          & (geometry.layer_kind == KIND_PIXEL))
    velo = velo[np.argsort(geometry.layer_z[velo], kind="stable")]
    planes = geometry.planes
    rows = geometry.layer_plane[velo]
    lt = np.zeros((velo.size, _N_LAYER_COLUMNS))
    lt[:, _L_Z] = geometry.layer_z[velo]
    lt[:, _L_HALF_X] = planes.half_x[rows]
    lt[:, _L_HALF_Y] = planes.half_y[rows]
    lt[:, _L_HOLE_R] = planes.hole_radius[rows]
    lt[:, _L_HOLE_HX] = planes.hole_half_x[rows]
    lt[:, _L_HOLE_HY] = planes.hole_half_y[rows]
    lt[:, _L_SIDE] = planes.side[rows]
    lt[:, _L_OVERLAP] = planes.side_overlap[rows]
    lt[:, _L_X0] = geometry.layer_x_over_x0[velo]
    fld = options.field if options.field is not None else geometry.field
    if velo.size:
        lt[:, _L_BX:_L_BZ + 1] = fld.evaluate(np.zeros(velo.size), np.zeros(velo.size),
                                              lt[:, _L_Z])
    lt[:, _L_SIGMA_MS] = [highland_sigma(options.p_min, options.mass, t) for t in lt[:, _L_X0]]
    return velo, lt


def _ms_ratio(p: float, p_ref: float, mass: float, lt: np.ndarray) -> float:
    """σ_MS(p)/σ_MS(p_ref) (Highland) for the typical module thickness."""
    t = float(np.median(lt[:, _L_X0])) if lt.shape[0] else 0.01
    ref = highland_sigma(p_ref, mass, t)
    return float(highland_sigma(p, mass, t) / ref) if ref > 0.0 else 1.0


def _chi2_table(pvalue: float, n: int) -> np.ndarray:
    """χ² cut for ndf = 0 … n−1 at the given p-value (ndf 0: 0)."""
    return np.array(_chi2_cuts(pvalue, n))


@functools.lru_cache(maxsize=16)
def _chi2_cuts(pvalue: float, n: int) -> tuple[float, ...]:
    """`_chi2_table`'s values, computed once per (pvalue, n): scipy's quantiles take 1 ms per
    table, 0.25 s of CPU on 1,000 minimum-bias events when made for every batch."""
    table = np.zeros(n)
    if pvalue > 0.0:
        table[1:] = chdtri(np.arange(1, n), pvalue)  # = scipy.stats.chi2.isf (scipy.stats costs ~2 s to import)
    return tuple(table.tolist())


def find_velo_tracks(event_id, layer, x, y, z, sigma, geometry: Geometry,
                     **options) -> VeloTracks:
    """Find VELO tracks in many events at once (docs/physics.md#pattern-recognition); see the module docstring.

    event_id, layer, x, y, z: per-hit arrays (rows of a hits table, sorted by event_id;
    any subdetector: only pixel hits on VELO layers are used; x = u, y = v [mm]);
    sigma: per-hit resolution [mm], shape (n,) (same in x and y) or (n, 2) (σx, σy);
    geometry: the detector (``pkf.geometry.load_geometry``); options: `VeloSearchOptions`.

    Returns `VeloTracks`: per track its event_id, its hits as rows of the input arrays
    (sorted by z) and the first state (x, y, tx, ty at the first hit, straight-line fit).
    """
    opts = VeloSearchOptions(**options)
    event_id = np.asarray(event_id)
    n = event_id.shape[0]
    layer = np.asarray(layer)
    cols = {"layer": layer, "x": np.asarray(x, dtype=np.float64),
            "y": np.asarray(y, dtype=np.float64), "z": np.asarray(z, dtype=np.float64)}
    for name, arr in cols.items():
        if arr.shape != (n,):
            raise ValueError(f"{name}: expected shape ({n},) like event_id, got {arr.shape}")
    sig = np.asarray(sigma, dtype=np.float64)
    if sig.shape == (n,):
        sx = sy = sig
    elif sig.shape == (n, 2):
        sx, sy = sig[:, 0], sig[:, 1]
    else:
        raise ValueError(f"sigma: expected shape ({n},) or ({n}, 2), got {sig.shape}")
    if n and np.any(np.diff(event_id) < 0):
        bad = int(np.flatnonzero(np.diff(event_id) < 0)[0]) + 1
        raise ValueError(f"event_id: hits must be sorted by event (row {bad} goes back)")
    velo, lt = velo_layer_table(geometry, opts)
    nl = velo.size
    lmap = np.full(max(geometry.n_layers, 1), -1, dtype=np.int64)
    lmap[velo] = np.arange(nl)
    hit, hlay, rows, lay_off, events, bad = _prepare_hits(
        event_id.astype(np.int64, copy=False), layer.astype(np.int64, copy=False),
        cols["x"], cols["y"], cols["z"], np.ascontiguousarray(sx), np.ascontiguousarray(sy),
        lmap, nl)
    if bad >= 0:
        raise ValueError(f"VELO hit at row {bad}: x, y, z must be finite and sigma > 0")
    ext_p = float(opts.extend_p_min if opts.extend_p_min is not None else opts.p_min)
    chi2_cut = _chi2_table(opts.pvalue, _MAX_NDF_TABLE)
    chain_cut = (_chi2_table(opts.chain_pvalue, _MAX_NDF_TABLE) if opts.chain_pvalue > 0
                 else np.zeros(0))
    cfg = VeloConfig(
        chi2_cut=chi2_cut, chain_cut=chain_cut, mass=float(opts.mass), b_threshold=float(opts.b_threshold),
        p_min=float(opts.p_min), straight=bool(opts.straight), max_missing=int(opts.max_missing),
        z_lo=-float(opts.z_luminous), z_hi=float(opts.z_luminous), tol0=float(opts.doublet_tolerance),
        tol1=float(opts.doublet_tolerance_slope), window_sigmas=float(opts.window_sigmas),
        margin=float(opts.edge_margin), min_hits=int(opts.min_hits), max_shared=float(opts.max_shared),
        keep_best=bool(opts.keep_best), all_skips=bool(opts.all_skips), extend=bool(opts.extend),
        extend_missing=int(opts.extend_missing), extend_p_min=ext_p,
        ms_scale=_ms_ratio(ext_p, opts.p_min, opts.mass, lt), same_side=bool(opts.same_side),
        fill_gaps=bool(opts.fill_gaps), second_pass=bool(opts.second_pass))
    o_event, o_off, o_hits, o_f, stats = _velo_search_kernel(lay_off, events.size, nl, hit, hlay, lt, cfg)
    hit_rows = rows[o_hits]
    return VeloTracks(
        event_id=events[o_event],
        offsets=o_off,
        hit_rows=hit_rows.astype(np.int64),
        z=o_f[:, _O_Z].copy(), x=o_f[:, _O_X].copy(), y=o_f[:, _O_Y].copy(),
        tx=o_f[:, _O_TX].copy(), ty=o_f[:, _O_TY].copy(),
        chi2=o_f[:, _O_CHI2].copy(), ndf=o_f[:, _O_NDF].astype(np.int64),
        stats=dict(zip(STAT_NAMES, (int(s) for s in stats), strict=True)),
    )


def find_velo_tracks_in_hits(hits, geometry: Geometry, **options) -> VeloTracks:
    """`find_velo_tracks` on a ``hits`` table (pyarrow Table with the docs/formats.md columns
    event_id, layer, z, u, v, sigma_u, sigma_v; sorted by event). Track hits are row
    indices of the table."""
    def col(name):
        return np.asarray(hits.column(name).to_numpy(zero_copy_only=False))

    sigma = np.column_stack([col("sigma_u"), col("sigma_v")])
    return find_velo_tracks(col("event_id"), col("layer"), col("u"), col("v"), col("z"),
                            sigma, geometry, **options)


def options_dict(options: VeloSearchOptions | None = None, **overrides) -> dict:
    """The options as plain values (for run metadata); the field model is left out."""
    opts = options if options is not None else VeloSearchOptions(**overrides)
    d = asdict(opts)
    d.pop("field", None)
    return d
