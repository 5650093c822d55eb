"""Forward extension of VELO tracks through the UT and the magnet into the SciFi (docs/physics.md#pattern-recognition).

The triplet paper's "extrapolation technique": a VELO track (event, straight-line state
(x, y, tx, ty) at a VELO layer, q/p unknown) is extended with the *parametrized*
extrapolations of docs/physics.md#the-parametrized-fitter (no field map): VELO→UT (paper eqs. 15–20), UT and SciFi
layer steps (eq. 14), the UT→SciFi table (eqs. 21–23) and the parametrized noise (eq. 11),
through `pkf.seeding.forward_steps`. Every search step is a linearised Kalman filter (KF)
around a *reference trajectory* (the transport of the VELO state at a q/p hypothesis with
its Jacobians, and its noise evaluated at that q/p), so windows scale with the q/p
uncertainty and with the scattering of the hypothesis, and candidates are ranked by a χ²
that contains the VELO–UT–SciFi consistency.

Algorithm, per VELO track (one compiled kernel over all tracks of a batch of events; no
Python loop per track or hit; hits are looked up by bisection in u-sorted arrays per
(event, layer))
----------------------------------------------------------------------------------------
0. **Prior.** The VELO state with covariance diag(σx², σy², σtx², σty², σq²): σx² = a² +
   (b·q/p)², σtx² = a′² + (b′·q/p)² (hit resolution ⊕ scattering in the VELO, measured on
   lhcb-like minimum bias: ``velo_*`` options), σq = 10/p_min. Carried through the UT
   without hits it gives the state at the last UT layer *given q/p* (its conditional mean
   is linear in q/p: the VELO→UT kink) and its conditional covariance.
1. **UT search.** A depth-first combinatorial KF over the 4 UT layers around q/p = 0 with
   the noise of 1/p_min (in the weak UT field the predicted u is linear in q/p to ≲ 20 µm
   down to 1.5 GeV): until a first hit is attached every hit in the window (best
   ``ut_first_branches`` by Δχ², the q/p prior σ = ``ut_q_prior``/p_min spans the range)
   opens a branch, later layers keep ``ut_branch``; ≥ ``ut_min_hits`` of 4. The
   ``ut_candidates`` best leaves (most hits, then χ²) are re-fitted around their own q/p
   with the noise at that q/p; those passing ``ut_pvalue`` are the UT candidates: a q/p
   estimate from the kink (σ ≈ 10–25 %), a q/p range ± ``hough_sigmas``·σ and the fitted
   state at the last UT layer given q/p. In the dense core (UT strips measure u only) a
   random combination often looks as good as the true one: the UT only guides the SciFi
   search, and UT hits are attached at the end with the SciFi momentum (step 4).
2. **q/p scan of the SciFi x layers (Hough in q/p)** for each start — the UT candidates,
   best first; in the second pass (step 6) the VELO prior alone over |q/p| ≤ 1/p_min.
   The start state given q/p is transported to the SciFi layers at q/p nodes
   (``node_spacing``/3 GeV apart, cubic Hermite in between: ≤ 0.3 mm); each x-layer hit in
   the covered range gets its implied q/p (inverse Hermite, hits visited in x order) and a
   Hough coordinate t in units of the tolerance τ(q) = ``hough_tol_abs`` +
   ``hough_tol_rel``·|q/p| (piecewise linear in q/p between points where τ grows by 25 %).
   Windows of ``window_bins`` bins (counting sort: linear in the hits) with ≥
   ``hough_min_x_layers`` x layers, ≥ 1 per station and ≥ the fullest window's count − 1,
   not beaten by an overlapping window, are the clusters.
3. **Cluster ranking and SciFi search.** Each cluster's x residuals to the trajectory at
   its q/p are fitted with a straight line (offset and slope, the slope with the prior of
   the start state's direction given q/p: random coincidences of implied q/p have random
   directions), the line through one entry of the first and one of the last layer that
   best collects the others; the best ``stereo_candidates`` are checked on the stereo
   layers (nearest u = x·cos α + y·sin α with x from the line, y from the start state);
   key = χ²_x + Σ stereo Δχ² + window_sigmas² per missing layer; a cluster with a hit on
   fewer than ``stereo_min_layers`` stereo layers is dropped (a true track has 5–6; this
   removes most random x lines before the costly follow). The best ``max_clusters`` are
   followed: a reference trajectory at the cluster's q/p from the
   VELO, the KF from the VELO prior through the start's UT hits (Δχ²-checked), a
   pseudo-measurement of x at the first SciFi x layer from the cluster's line (narrows
   the windows, not counted in χ²), then a depth-first combinatorial KF over the 12 SciFi
   layers: windows of ``window_sigmas``·√(H·P·Hᵀ + σ²) (they scale with the q/p
   uncertainty), stereo hits resolved by the filter (a u/v hit constrains y through the
   stereo angle; wrong choices die on the next Δχ²), the ``max_branch`` best hits per
   layer, a skip only where no hit is compatible, ≥ ``scifi_min_hits``, and in every
   station ≥ 1 x and ≥ 1 stereo hit (the long-reconstructible definition, docs/physics.md#matching-and-metrics).
   Candidates are ranked by χ² − ``miss_penalty``·hits; following stops at a good, nearly
   complete one.
4. **UT confirmation and final fit**, candidates best first: the UT hits are searched
   again with the SciFi q/p (± its σ) as prior, in windows now set by the scattering at
   that momentum (``confirm_window_sigmas``, ≥ ``ut_confirm_min_hits``); a final KF at the
   fitted q/p over the UT and SciFi hits (hits beyond ``window_sigmas`` are dropped) gives
   χ², ndf = hits − 1, q/p and its variance. Accepted if ≥ ``scifi_min_hits`` SciFi hits
   with the station requirement and p-value ≥ ``pvalue``; without UT hits (also tried when
   the fit with them fails) ≥ ``no_ut_min_hits`` and p-value ≥ ``no_ut_pvalue`` (the
   VELO–SciFi match alone must convince: most ghosts had no UT hit). The best accepted
   extension (χ² − miss_penalty·hits) is kept; the search ends at one with p-value ≥
   ``good_pvalue`` and ≥ 11 SciFi hits.
5. Without an accepted extension the best UT candidate is returned as an upstream track
   (STATUS_NO_SCIFI, q/p from the kink).
6. **Two passes; good extensions take their hits.** The first pass runs steps 1–4 from
   the UT starts for every track of the batch, in order. An extension that ends its
   search (p-value ≥ ``good_pvalue``, ≥ 11 SciFi hits) takes its UT and SciFi hits: later
   searches of the same event do not see them (``take_hits``). The second pass runs the
   full-range scan for the tracks still without an extension, on the hits left. The
   scan sees every x-layer hit of the event in its window, and at ν = 7.6 most of them
   belong to tracks found in the first pass: taking them makes the scan several times
   cheaper and leaves fewer random lines to find (ν = 7.6, 100 events: forward time
   −35 %, ghost rate 3.3 → 1.9 %, efficiency +0.2 points for p > 5 GeV, +0.6 for
   2–5 GeV). Results depend on the order of the tracks within an event (the VELO
   search's, deterministic), not on how events are batched.

Momenta below the UT→SciFi table's p_min (3 GeV) are searched with the table's quadratic
continuation (`pkf.seeding.forward_steps`): the hits found are as good as any, the q/p
estimate is biased by ≲ 1–2 %, and ``below_table_p_min`` flags the track (the
parametrized Kalman fit returns status 4 there). Below that momentum the per-layer SciFi
steps also carry a model error beyond their scattering noise (largest across the T1→T2
gap), so the search inflates their noise by 1 + (``scifi_model_noise``·q/p)². With the
degree-4 SciFi steps of the shipped set, 3000 MeV (6450 with the earlier 15-term steps)
keeps the efficiency and halves the ghost rate at ν = 7.6.

Cost (`benchmarks/pattern_recognition.py`, lhcb-like minimum bias at ν = 7.6, ~340 VELO
tracks per event, one core): ≈ 15 ms per event, ≈ 45 µs per VELO track — in cycles per
track roughly 40 % the SciFi searches from UT starts, 30 % the second-pass scans, 13 % the
UT search, 10 % the final fits. What made it cheap, measured on the same events: the
unrolled layer step (`pkf.params.formulas`, 200 → 55 ns), the two passes with taken hits
(−35 %), fits through fixed hits as a straight loop (`_fit_fixed`, −8 %), the stereo
requirement before the follow (``stereo_min_layers``, −5 %) and compiling without numba's
reference counting (`pkf.jit.NO_REFCOUNT`, −22 %: the atomic reference-count updates of
array views and inlined helpers' array arguments were 40 % of the CPU samples).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba as nb
import numpy as np
from scipy.stats import chi2 as chi2_dist

from pkf.errors import InputError
from pkf.geometry.detector import SUBDETECTORS, Geometry
from pkf.jit import NO_REFCOUNT
from pkf.params.transport import STEP_SCIFI, STEP_UT, STEP_UT_TO_SCIFI, STEP_VELO_TO_UT
from pkf.params.ut_to_scifi import META_NX, META_NY, META_P_MIN, META_SIZE, localize_ut_to_scifi
from pkf.seeding.forward_steps import (
    TRANSPORT_FAILED,
    new_table_buffers,
    reference_trajectory,
    scan_states,
)

__all__ = [
    "STATUS_INVALID",
    "STATUS_NAMES",
    "STATUS_NOT_FOUND",
    "STATUS_NO_SCIFI",
    "STATUS_NO_UT",
    "STATUS_OK",
    "ForwardOptions",
    "ForwardTracks",
    "extend_velo_tracks",
]

#: Track status codes of `ForwardTracks.status`.
STATUS_OK = 0  # UT and SciFi hits added
STATUS_NO_UT = 1  # SciFi hits added, no UT hits (q/p from VELO + SciFi)
STATUS_NO_SCIFI = 2  # no SciFi extension; the UT candidate (if any) is kept ("upstream track")
STATUS_NOT_FOUND = 3  # nothing found
STATUS_INVALID = 4  # the VELO state could not be extrapolated (NaN, no VELO layer, |slope| too large)
STATUS_NAMES = ("ok", "no UT hits", "no SciFi extension", "not found", "invalid VELO state")

_MAX_CHILDREN = 17  # per search depth (branches + the skip)
_MODE_SEARCH = 0
_MODE_FIXED = 1
_MODE_OFF = 2

# Per-kernel integer/float option vectors (see ForwardOptions.vectors)
(_O_QMAX, _O_VSX, _O_VMSX, _O_VSTX, _O_VMSTX, _O_UT_QPRIOR, _O_WEAK_QPRIOR, _O_UT_NSIG,
 _O_HOUGH_NSIG, _O_TAU0, _O_TAU1, _O_NODE_DW, _O_NSIG, _O_PM_FLOOR, _O_LINE_SIG, _O_LINE_MS,
 _O_LINE_CHI2, _O_CONFIRM_NSIG, _O_MISS, _O_SLOPE_MS, _O_MODEL) = range(21)
_N_FOPT = 21
(_I_UT_MIN, _I_UT_FIRST, _I_BRANCH, _I_MIN_X, _I_MAX_CLUSTERS, _I_SF_MIN, _I_FALLBACK,
 _I_CONFIRM_MIN, _I_MAX_NODES, _I_QUAD, _I_STATION_X, _I_UT_CANDIDATES, _I_STEREO_CANDIDATES,
 _I_NOUT_MIN, _I_UT_REFITS, _I_UT_BRANCH, _I_WINDOW_BINS, _I_TAKE_HITS, _I_STEREO_MIN) = range(19)
_N_IOPT = 19


@dataclass(frozen=True)
class ForwardOptions:
    """Options of `extend_velo_tracks` (defaults in brackets; see the module docstring for
    the steps 0–5 they belong to). Units: MeV, mm.

    p_min [1500]               lowest momentum searched: |q/p| ≤ 1/p_min. At ν = 7.6 it finds
                               56 % of the long tracks below 2 GeV (2 % of all; 2000: 1 %) for
                               +2–10 % time and a ghost rate of 1.2 % instead of 1.2–1.4 %
    velo_sigma_x [0.01]        (0) VELO state position error at high momentum [mm]
    velo_ms_x [130]            … its scattering part: σx² = a² + (velo_ms_x·q/p)² [mm·MeV]
    velo_sigma_tx [3e-5]       (0) VELO slope error at high momentum
    velo_ms_tx [2.2]           … its scattering part: σtx² = a² + (velo_ms_tx·q/p)² [MeV]
    ut_q_prior [0.5]           (1) σ of the q/p prior of the UT search [1/p_min]
    ut_window_sigmas [4]       (1) UT search windows [σ]
    ut_min_hits [3]            (1) UT hits (of 4) of a UT candidate
    ut_first_branches [4]      (1) branches per layer until a first UT hit is attached
    ut_branch [2]              (1) branches per layer after it
    ut_candidates [2]          (1) UT leaves re-fitted and used as starts
    ut_refits [1]              (1) re-fits of a leaf around its own q/p
    ut_pvalue [1e-3]           (1) p-value cut of a re-fitted UT candidate
    hough_sigmas [4]           (2) q/p range around a UT estimate [σ]
    hough_tol_abs [1e-7]       (2) tolerance τ₀ of the q/p scan [1/MeV]
    hough_tol_rel [3e-3]       (2) … + τ₁·|q/p|
    window_bins [2]            (2) bins (of width τ) per cluster window
    hough_min_x_layers [4]     (2) x layers (of 6) in a cluster
    node_spacing [0.5]         (2) q/p node spacing [1/(3 GeV)]
    station_x_and_stereo [True] (2, 3) ≥ 1 x (and ≥ 1 stereo) hit in each SciFi station
    line_sigma [0.15]          (3) σ of an x hit about its cluster's line [mm]
    line_ms [1600]             (3) … ⊕ scattering in the SciFi: (line_ms·q/p) [mm·MeV]
    slope_ms [1.7]             (3) slope prior of the line: σ² = σtx²(start, given q/p) +
                               (slope_ms·q/p)² (scattering UT → SciFi) [MeV]
    line_chi2 [16]             (3) cut on the line χ²/ndf
    stereo_candidates [12]     (3) clusters checked on the stereo layers
    stereo_min_layers [4]      (3) … and followed only with a hit within window_sigmas on at
                               least this many stereo layers
    max_clusters [3]           (3) clusters followed by the combinatorial KF per scan
    pseudo_floor [0.3]         (3) added in quadrature to the pseudo-measurement σ [mm]
    window_sigmas [5]          (3, 4) SciFi windows and Δχ² cut [σ]
    max_branch [3]             (3, 4) hits kept per layer and branch (best Δχ²)
    scifi_min_hits [10]        (3, 4) SciFi hits (of 12)
    miss_penalty [9]           (3, 4) ranking: χ² − miss_penalty·hits, lowest first
    scifi_model_noise [3000]   (3, 4) noise of the SciFi layer steps × (1 + (this·q/p)²) [MeV]
    ut_confirm_min_hits [2]    (4) UT hits re-collected with the SciFi q/p (0: keep the start's)
    confirm_window_sigmas [3]  (4) UT confirmation windows [σ]
    pvalue [1e-4]              (4) p-value cut on the final χ² (ndf = hits − 1)
    no_ut_min_hits [11]        (4) SciFi hits of an extension without UT hits
    no_ut_pvalue [0.01]        (4) … and its p-value cut
    good_pvalue [0.01]         (4) an accepted extension with this p-value and ≥ 11 SciFi
                               hits ends the search of its track
    no_ut_fallback [True]      (6) scan with the VELO prior alone when the UT starts fail
    take_hits [True]           (6) a good extension takes its hits: later searches of the event
                               do not see them
    quadratic_continuation [True] continue the UT→SciFi table quadratically below its p_min
                               (False: linearly, as `pkf.params.ut_to_scifi`)
    max_nodes [4000]           visited KF nodes per combinatorial search (a safety cap)
    """

    p_min: float = 1500.0
    velo_sigma_x: float = 0.01
    velo_ms_x: float = 130.0
    velo_sigma_tx: float = 3e-5
    velo_ms_tx: float = 2.2
    ut_q_prior: float = 0.5
    ut_window_sigmas: float = 4.0
    ut_min_hits: int = 3
    ut_first_branches: int = 4
    ut_branch: int = 2
    ut_refits: int = 1
    ut_pvalue: float = 1e-3
    hough_sigmas: float = 4.0
    hough_tol_abs: float = 1e-7
    hough_tol_rel: float = 3e-3
    hough_min_x_layers: int = 4
    window_bins: int = 2
    node_spacing: float = 0.5
    max_clusters: int = 3
    window_sigmas: float = 5.0
    max_branch: int = 3
    scifi_min_hits: int = 10
    no_ut_min_hits: int = 11
    no_ut_pvalue: float = 0.01
    station_x_and_stereo: bool = True
    pseudo_floor: float = 0.3
    line_sigma: float = 0.15
    line_ms: float = 1600.0
    line_chi2: float = 16.0
    slope_ms: float = 1.7
    scifi_model_noise: float = 3000.0
    ut_candidates: int = 2
    stereo_candidates: int = 12
    stereo_min_layers: int = 4
    miss_penalty: float = 9.0
    good_pvalue: float = 0.01
    pvalue: float = 1e-4
    no_ut_fallback: bool = True
    take_hits: bool = True
    ut_confirm_min_hits: int = 2
    confirm_window_sigmas: float = 3.0
    quadratic_continuation: bool = True
    max_nodes: int = 4000

    def __post_init__(self):
        checks = (
            (self.p_min > 0, "p_min must be > 0 MeV"),
            (self.ut_q_prior > 0, "ut_q_prior must be > 0"),
            (self.ut_window_sigmas > 0 and self.window_sigmas > 0 and self.confirm_window_sigmas > 0,
             "window sigmas must be > 0"),
            (1 <= self.ut_min_hits <= 4, "ut_min_hits must be in 1..4"),
            (0.0 < self.ut_pvalue < 1.0 and 0.0 <= self.pvalue < 1.0, "p-values must be in (0, 1)"),
            (self.hough_tol_abs > 0 and self.hough_tol_rel >= 0, "hough tolerances must be > 0"),
            (1 <= self.hough_min_x_layers, "hough_min_x_layers must be ≥ 1"),
            (self.node_spacing > 0, "node_spacing must be > 0"),
            (self.max_clusters >= 1, "max_clusters must be ≥ 1"),
            (1 <= self.max_branch <= _MAX_CHILDREN - 1 and 1 <= self.ut_first_branches <= _MAX_CHILDREN - 1,
             f"branches must be in 1..{_MAX_CHILDREN - 1}"),
            (self.scifi_min_hits >= 1 and self.no_ut_min_hits >= 1, "minimum hit counts must be ≥ 1"),
            (1 <= self.ut_branch <= _MAX_CHILDREN - 1, f"ut_branch must be in 1..{_MAX_CHILDREN - 1}"),
            (self.ut_candidates >= 1 and self.stereo_candidates >= 1 and self.window_bins >= 1
             and self.ut_refits >= 1, "candidate counts, window_bins and ut_refits must be ≥ 1"),
            (0.0 <= self.no_ut_pvalue < 1.0 and 0.0 <= self.good_pvalue < 1.0, "p-values must be in [0, 1)"),
            (self.ut_confirm_min_hits >= 0, "ut_confirm_min_hits must be ≥ 0"),
            (self.max_nodes >= 16, "max_nodes must be ≥ 16"),
        )
        for ok, message in checks:
            if not ok:
                raise ValueError(message)

    def vectors(self, p_table: float) -> tuple[np.ndarray, np.ndarray]:
        f = np.zeros(_N_FOPT)
        f[_O_QMAX] = 1.0 / self.p_min
        f[_O_VSX] = self.velo_sigma_x
        f[_O_VMSX] = self.velo_ms_x
        f[_O_VSTX] = self.velo_sigma_tx
        f[_O_VMSTX] = self.velo_ms_tx
        f[_O_UT_QPRIOR] = self.ut_q_prior / self.p_min
        f[_O_WEAK_QPRIOR] = 10.0 / self.p_min
        f[_O_UT_NSIG] = self.ut_window_sigmas
        f[_O_HOUGH_NSIG] = self.hough_sigmas
        f[_O_TAU0] = self.hough_tol_abs
        f[_O_TAU1] = self.hough_tol_rel
        f[_O_NODE_DW] = self.node_spacing / p_table
        f[_O_NSIG] = self.window_sigmas
        f[_O_PM_FLOOR] = self.pseudo_floor
        f[_O_LINE_SIG] = self.line_sigma
        f[_O_LINE_MS] = self.line_ms
        f[_O_LINE_CHI2] = self.line_chi2
        f[_O_MISS] = self.miss_penalty
        f[_O_SLOPE_MS] = self.slope_ms
        f[_O_MODEL] = self.scifi_model_noise
        f[_O_CONFIRM_NSIG] = self.confirm_window_sigmas
        i = np.zeros(_N_IOPT, dtype=np.int64)
        i[_I_UT_MIN] = self.ut_min_hits
        i[_I_UT_FIRST] = self.ut_first_branches
        i[_I_BRANCH] = self.max_branch
        i[_I_MIN_X] = self.hough_min_x_layers
        i[_I_MAX_CLUSTERS] = self.max_clusters
        i[_I_SF_MIN] = self.scifi_min_hits
        i[_I_FALLBACK] = int(self.no_ut_fallback)
        i[_I_CONFIRM_MIN] = self.ut_confirm_min_hits
        i[_I_MAX_NODES] = self.max_nodes
        i[_I_QUAD] = int(self.quadratic_continuation)
        i[_I_STATION_X] = int(self.station_x_and_stereo)
        i[_I_UT_CANDIDATES] = self.ut_candidates
        i[_I_STEREO_CANDIDATES] = self.stereo_candidates
        i[_I_NOUT_MIN] = self.no_ut_min_hits
        i[_I_UT_REFITS] = self.ut_refits
        i[_I_UT_BRANCH] = self.ut_branch
        i[_I_WINDOW_BINS] = self.window_bins
        i[_I_TAKE_HITS] = int(self.take_hits)
        i[_I_STEREO_MIN] = self.stereo_min_layers
        return f, i


@dataclass
class ForwardTracks:
    """Result of `extend_velo_tracks`, one entry per input VELO track (same order).

    hit_rows[offsets[t]:offsets[t+1]]: rows of the input hit arrays added to track t
    (UT then SciFi, sorted by z); n_ut, n_scifi: how many of each. qop [1/MeV] and
    qop_var: the q/p estimate (at production, docs/physics.md#the-parametrized-fitter) and its variance (NaN if
    none); chi2/ndf of the extension fit (ndf = hits − 1, the VELO state as prior);
    status: STATUS_* (STATUS_NAMES); below_table_p_min: |q/p| > 1/p_min of the
    UT→SciFi table (the parametrized fit returns status 4 there); from_scan: the
    extension was found by the second pass's full-range scan (step 6), not from a UT start.
    """

    offsets: np.ndarray
    hit_rows: np.ndarray
    n_ut: np.ndarray
    n_scifi: np.ndarray
    qop: np.ndarray
    qop_var: np.ndarray
    chi2: np.ndarray
    ndf: np.ndarray
    status: np.ndarray
    below_table_p_min: np.ndarray
    from_scan: np.ndarray

    @property
    def n_tracks(self) -> int:
        return int(self.status.size)

    @property
    def n_hits(self) -> np.ndarray:
        return np.diff(self.offsets)

    @property
    def track_of_hit(self) -> np.ndarray:
        return np.repeat(np.arange(self.n_tracks, dtype=np.int64), self.n_hits)

    @property
    def found(self) -> np.ndarray:
        """Tracks extended into the SciFi (status ok or no UT)."""
        return (self.status == STATUS_OK) | (self.status == STATUS_NO_UT)


# ------------------------------------------------------------------------------------
# Kalman-filter pieces (deviation δ from a reference trajectory; H = [cos α, sin α, 0, 0, 0])
# ------------------------------------------------------------------------------------

@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _predict(F3, Q3, j, X, P3, a, X_out, P3_out, b, tmp):
    """X_out[b] = F·X[a], P3_out[b] = F·P3[a]·Fᵀ + Q with F = F3[j], Q = Q3[j], for the
    parametrized steps: q/p is transported unchanged (F row 4 = e₄) and has no noise
    (Q row/column 4 = 0). Indexed rather than sliced: a slice is an array view, and the
    views' reference counting cost more than the arithmetic in this loop."""
    for i in range(4):
        acc = 0.0
        for k in range(5):
            acc += F3[j, i, k] * X[a, k]
        X_out[b, i] = acc
    X_out[b, 4] = X[a, 4]
    for i in range(4):
        for k in range(5):
            acc = 0.0
            for m in range(5):
                acc += F3[j, i, m] * P3[a, m, k]
            tmp[i, k] = acc
    for k in range(5):
        tmp[4, k] = P3[a, 4, k]
    for i in range(4):
        for k in range(i, 4):
            acc = Q3[j, i, k]
            for m in range(5):
                acc += tmp[i, m] * F3[j, k, m]
            P3_out[b, i, k] = acc
            P3_out[b, k, i] = acc
        acc = tmp[i, 4]  # (F·P)[i, 4] · F[4, 4] = 1
        P3_out[b, i, 4] = acc
        P3_out[b, 4, i] = acc
    P3_out[b, 4, 4] = P3[a, 4, 4]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _update(X, P3, d, c, s, r, var, X_out, P3_out, pht):
    """Strip update of state d with residual r and residual variance var = H·P·Hᵀ + σ²."""
    for i in range(5):
        pht[i] = c * P3[d, i, 0] + s * P3[d, i, 1]
    for i in range(5):
        k = pht[i] / var
        X_out[d, i] = X[d, i] + k * r
        for m in range(5):
            P3_out[d, i, m] = P3[d, i, m] - k * pht[m]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _velo_prior(opt, q_noise, sigma_q, P):
    for i in range(5):
        for k in range(5):
            P[i, k] = 0.0
    vx = opt[_O_VSX] ** 2 + (opt[_O_VMSX] * q_noise) ** 2
    vt = opt[_O_VSTX] ** 2 + (opt[_O_VMSTX] * q_noise) ** 2
    P[0, 0] = vx
    P[1, 1] = vx
    P[2, 2] = vt
    P[3, 3] = vt
    P[4, 4] = sigma_q * sigma_q


@nb.njit(cache=True, **NO_REFCOUNT)
def _reference(ext, poly, ref, quad, a, f_layer, n_ut, j_end, s_v, q, q_noise, ref_s, ref_F, ref_Q,
               work, opt_model):
    """Reference trajectory from VELO layer a through forward layers 0 … j_end−1 at
    q/p = q; noise at q_noise. Returns the worst transport status."""
    s_in = work[0, 0]
    for i in range(4):
        s_in[i] = s_v[i]
    s_in[4] = q
    st = reference_trajectory(ext, poly, ref, quad, a, f_layer, n_ut, j_end, s_in, q_noise, ref_s,
                              ref_F, ref_Q, work[0, 1])
    # model error of the SciFi layer steps at low momentum (see ForwardOptions.scifi_model_noise)
    f = 1.0 + (opt_model * q_noise) ** 2
    for j in range(n_ut + 1, j_end):
        for i in range(5):
            for k in range(5):
                ref_Q[j, i, k] *= f
    return st


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _maybe_crossed(x, y, vx, vy, acc, j):
    """False if (x, y) with variances (vx, vy) is outside the active area acc[j] (half_x,
    half_y, hole radius, hole half_x, hole half_y) by more than 3σ."""
    sx = 3.0 * math.sqrt(max(vx, 0.0))
    sy = 3.0 * math.sqrt(max(vy, 0.0))
    if abs(x) - sx > acc[j, 0] or abs(y) - sy > acc[j, 1]:
        return False
    if acc[j, 2] > 0.0:
        r = math.sqrt(x * x + y * y)
        if r + math.sqrt(sx * sx + sy * sy) < acc[j, 2]:
            return False
    if acc[j, 3] > 0.0 and abs(x) + sx < acc[j, 3] and abs(y) + sy < acc[j, 4]:
        return False
    return True


@nb.njit(cache=True, **NO_REFCOUNT)
def _search(j0, j1, mode, fixed, lay_off_e, hu, hsig, used, f_cos, f_sin, f_sig, f_acc, f_bit, f_group_end,
            f_need_end, ref_s, ref_F, ref_Q, x0, P0, pm_depth, pm_value, pm_var,
            nsig, first_branches, max_branch, max_skip, min_hits, skip_first, need, chi2_prune,
            max_nodes, ws, best_path, best_x, best_P, top, miss_penalty):
    """Depth-first combinatorial Kalman filter over forward layers j0 … j1−1.

    mode[j]: _MODE_SEARCH (hits in the window that are not used[h] — taken by a good
    extension, step 6 — up to first_branches / max_branch by Δχ²), _MODE_FIXED (the hit
    fixed[j] if Δχ² < nsig², sorted-hit index, −1 none), _MODE_OFF (transport only).
    Search layers without an accepted hit are skips (at most max_skip); before the first
    search hit is attached the skip branch is always tried if skip_first. The
    pseudo-measurement (x = pm_value, variance pm_var) is applied at depth pm_depth (−1:
    none) before the hits, outside χ².
    f_bit[j]: requirement bit of layer j (0: none); f_group_end[j]: the bits needed by
    the group ending at j must be present (f_need_end[j] mask). need: bits required at
    the end. Returns (n_search_hits, n_fixed_hits, chi2) of the best leaf (most search
    hits, then lowest χ²) with best_path[j] (sorted-hit index or −1) and the deviation
    state/covariance at layer j1−1 in best_x/best_P; n = −1 if none. top = (paths (K, ·),
    n (K), chi2 (K), q-deviation (K), its variance (K), count (1)): the K best leaves
    (K = 0: not collected), ranked like the best. Ranking: χ² − miss_penalty·(search hits),
    lowest first (a large penalty: most hits first, then χ²).
    """
    nd = j1 - j0
    top_paths, top_n, top_chi, top_dq, top_var, top_count = top
    n_top_max = top_n.shape[0]
    top_count[0] = 0
    (pred_x, post_x, pred_P, post_P, tmp, pht, upred, sbase, post_chi, ch_chi, n_ch, it, post_n,
     post_nf, post_skip, post_mask, post_att, path, ch_hit, x_init, P_init) = ws
    for i in range(5):
        x_init[0, i] = x0[i]
        for k in range(5):
            P_init[0, i, k] = P0[i, k]
    best_n = -1
    best_nf = 0
    best_chi = 1e300
    nodes = 0
    d = 0
    expand = True
    while d >= 0:
        if expand:
            expand = False
            j = j0 + d
            if d == 0:
                _predict(ref_F, ref_Q, j, x_init, P_init, 0, pred_x, pred_P, d, tmp)
                prev_chi = 0.0
                prev_n = 0
                prev_nf = 0
                prev_att = 0
            else:
                _predict(ref_F, ref_Q, j, post_x, post_P, d - 1, pred_x, pred_P, d, tmp)
                prev_chi = post_chi[d - 1]
                prev_n = post_n[d - 1]
                prev_nf = post_nf[d - 1]
                prev_att = post_att[d - 1]
            nodes += 1
            c = f_cos[j]
            s = f_sin[j]
            if d == pm_depth:
                for i in range(5):
                    pht[i] = pred_P[d, i, 0]
                var = pred_P[d, 0, 0] + pm_var
                r = pm_value - (ref_s[j, 0] + pred_x[d, 0])
                for i in range(5):
                    kk = pht[i] / var
                    pred_x[d, i] += kk * r
                for i in range(5):
                    for m in range(5):
                        post_P[d, i, m] = pred_P[d, i, m] - pht[i] * pht[m] / var
                for i in range(5):
                    for m in range(5):
                        pred_P[d, i, m] = post_P[d, i, m]
            up = c * (ref_s[j, 0] + pred_x[d, 0]) + s * (ref_s[j, 1] + pred_x[d, 1])
            sb = c * c * pred_P[d, 0, 0] + 2.0 * c * s * pred_P[d, 0, 1] + s * s * pred_P[d, 1, 1]
            upred[d] = up
            sbase[d] = sb
            nc = 0
            md = mode[j]
            if md != _MODE_OFF and not _maybe_crossed(ref_s[j, 0] + pred_x[d, 0], ref_s[j, 1] + pred_x[d, 1],
                                                      pred_P[d, 0, 0], pred_P[d, 1, 1], f_acc, j):
                md = _MODE_OFF  # certainly outside the active area: no hit, not a missing one
            lo = lay_off_e[j]
            hi = lay_off_e[j + 1]
            if md == _MODE_FIXED:
                h = fixed[j]
                if h >= 0:
                    r = hu[h] - up
                    c2 = r * r / (sb + hsig[h] * hsig[h])
                    if c2 < nsig * nsig:
                        ch_hit[d, 0] = h
                        ch_chi[d, 0] = c2
                        nc = 1
                if nc == 0:
                    ch_hit[d, 0] = -1
                    ch_chi[d, 0] = 0.0
                    nc = 1
            elif md == _MODE_SEARCH:
                kmax = first_branches if prev_att == 0 else max_branch
                hw = nsig * math.sqrt(sb + f_sig[j] * f_sig[j])
                # first hit with u >= up − hw (bisection)
                a_ = lo
                b_ = hi
                while a_ < b_:
                    mid = (a_ + b_) >> 1
                    if hu[mid] < up - hw:
                        a_ = mid + 1
                    else:
                        b_ = mid
                h = a_
                while h < hi and hu[h] <= up + hw:
                    r = hu[h] - up
                    c2 = r * r / (sb + hsig[h] * hsig[h])
                    if c2 < nsig * nsig and not used[h]:
                        # insertion into the sorted top-kmax list
                        if nc < kmax:
                            pos = nc
                            nc += 1
                        elif c2 < ch_chi[d, nc - 1]:
                            pos = nc - 1
                        else:
                            pos = -1
                        if pos >= 0:
                            while pos > 0 and ch_chi[d, pos - 1] > c2:
                                ch_chi[d, pos] = ch_chi[d, pos - 1]
                                ch_hit[d, pos] = ch_hit[d, pos - 1]
                                pos -= 1
                            ch_chi[d, pos] = c2
                            ch_hit[d, pos] = h
                    h += 1
                skips_so_far = 0 if d == 0 else post_skip[d - 1]
                if (nc == 0 or (skip_first and prev_att == 0)) and skips_so_far < max_skip:
                    ch_hit[d, nc] = -2  # skip
                    ch_chi[d, nc] = 0.0
                    nc += 1
            else:
                ch_hit[d, 0] = -1
                ch_chi[d, 0] = 0.0
                nc = 1
            n_ch[d] = nc
            it[d] = 0
            if nodes > max_nodes:
                break
        if it[d] >= n_ch[d]:
            d -= 1
            continue
        ci = it[d]
        it[d] += 1
        j = j0 + d
        h = ch_hit[d, ci]
        if d == 0:
            prev_chi = 0.0
            prev_n = 0
            prev_nf = 0
            prev_skip = 0
            prev_mask = 0
            prev_att = 0
        else:
            prev_chi = post_chi[d - 1]
            prev_n = post_n[d - 1]
            prev_nf = post_nf[d - 1]
            prev_skip = post_skip[d - 1]
            prev_mask = post_mask[d - 1]
            prev_att = post_att[d - 1]
        if h >= 0:
            c = f_cos[j]
            s = f_sin[j]
            var = sbase[d] + hsig[h] * hsig[h]
            r = hu[h] - upred[d]
            _update(pred_x, pred_P, d, c, s, r, var, post_x, post_P, pht)
            post_chi[d] = prev_chi + r * r / var
            if mode[j] == _MODE_SEARCH:
                post_n[d] = prev_n + 1
                post_nf[d] = prev_nf
                post_mask[d] = prev_mask | f_bit[j]
                post_att[d] = 1
            else:
                post_n[d] = prev_n
                post_nf[d] = prev_nf + 1
                post_mask[d] = prev_mask | f_bit[j]
                post_att[d] = prev_att
            post_skip[d] = prev_skip
        else:
            for i in range(5):
                post_x[d, i] = pred_x[d, i]
                for m in range(5):
                    post_P[d, i, m] = pred_P[d, i, m]
            post_chi[d] = prev_chi
            post_n[d] = prev_n
            post_nf[d] = prev_nf
            post_mask[d] = prev_mask
            post_att[d] = prev_att
            post_skip[d] = prev_skip + (1 if h == -2 else 0)
        path[d] = h if h >= 0 else -1
        # pruning
        ntot = post_n[d] + post_nf[d]
        if post_chi[d] > chi2_prune[min(ntot, chi2_prune.shape[0] - 1)]:
            continue
        if f_group_end[j] and (post_mask[d] & f_need_end[j]) != f_need_end[j]:
            continue
        if d == nd - 1:
            if post_n[d] >= min_hits and (post_mask[d] & need) == need:
                key = post_chi[d] - miss_penalty * post_n[d]
                better = best_n < 0 or key < best_chi - miss_penalty * best_n
                if better:
                    best_n = post_n[d]
                    best_nf = post_nf[d]
                    best_chi = post_chi[d]
                    for k in range(nd):
                        best_path[j0 + k] = path[k]
                    for i in range(5):
                        best_x[i] = post_x[d, i]
                        for m in range(5):
                            best_P[i, m] = post_P[d, i, m]
                if n_top_max > 0:
                    nt = top_count[0]
                    pos = nt
                    while pos > 0 and key < top_chi[pos - 1] - miss_penalty * top_n[pos - 1]:
                        pos -= 1
                    if pos < n_top_max:
                        last = min(nt, n_top_max - 1)
                        for q_ in range(last, pos, -1):
                            top_n[q_] = top_n[q_ - 1]
                            top_chi[q_] = top_chi[q_ - 1]
                            top_dq[q_] = top_dq[q_ - 1]
                            top_var[q_] = top_var[q_ - 1]
                            for k in range(nd):
                                top_paths[q_, j0 + k] = top_paths[q_ - 1, j0 + k]
                        top_n[pos] = post_n[d]
                        top_chi[pos] = post_chi[d]
                        top_dq[pos] = post_x[d, 4]
                        top_var[pos] = post_P[d, 4, 4]
                        for k in range(nd):
                            top_paths[pos, j0 + k] = path[k]
                        if nt < n_top_max:
                            top_count[0] = nt + 1
            continue
        d += 1
        expand = True
    return best_n, best_nf, best_chi


@nb.njit(cache=True, **NO_REFCOUNT)
def _fit_fixed(j0, j1, fixed, hu, hsig, f_cos, f_sin, f_acc, f_bit, f_group_end, f_need_end, ref_s, ref_F,
               ref_Q, x0, P0, nsig, chi2_prune, ws, best_path, best_x, best_P):
    """The Kalman filter through layers j0 … j1−1 with the hits fixed[j] (sorted-hit index,
    −1: none): `_search` with every layer _MODE_FIXED (a hit beyond nsig σ or certainly
    outside the active area is not attached), as one straight loop — the refits, fits and
    transports of the extension call it ~5 times per track, and the combinatorial search's
    set-up costs more than such a fit. Returns (hits attached, χ²), −1 hits if the χ² or
    a station requirement fails (the same pruning as `_search`); best_path[j] (hit or −1)
    and the deviation state/covariance at layer j1−1 in best_x/best_P."""
    pred_x, post_x, pred_P, post_P, tmp, pht = ws[0], ws[1], ws[2], ws[3], ws[4], ws[5]
    x_init, P_init = ws[19], ws[20]
    for i in range(5):
        x_init[0, i] = x0[i]
        for k in range(5):
            P_init[0, i, k] = P0[i, k]
    chi2 = 0.0
    n_hits = 0
    mask = 0
    for d in range(j1 - j0):
        j = j0 + d
        if d == 0:
            _predict(ref_F, ref_Q, j, x_init, P_init, 0, pred_x, pred_P, d, tmp)
        else:
            _predict(ref_F, ref_Q, j, post_x, post_P, d - 1, pred_x, pred_P, d, tmp)
        c = f_cos[j]
        s = f_sin[j]
        h = fixed[j]
        if h >= 0 and not _maybe_crossed(ref_s[j, 0] + pred_x[d, 0], ref_s[j, 1] + pred_x[d, 1],
                                         pred_P[d, 0, 0], pred_P[d, 1, 1], f_acc, j):
            h = -1
        if h >= 0:
            up = c * (ref_s[j, 0] + pred_x[d, 0]) + s * (ref_s[j, 1] + pred_x[d, 1])
            sb = c * c * pred_P[d, 0, 0] + 2.0 * c * s * pred_P[d, 0, 1] + s * s * pred_P[d, 1, 1]
            var = sb + hsig[h] * hsig[h]
            r = hu[h] - up
            if r * r / var >= nsig * nsig:
                h = -1
        if h >= 0:
            _update(pred_x, pred_P, d, c, s, r, var, post_x, post_P, pht)
            chi2 += r * r / var
            n_hits += 1
            mask |= f_bit[j]
        else:
            for i in range(5):
                post_x[d, i] = pred_x[d, i]
                for m in range(5):
                    post_P[d, i, m] = pred_P[d, i, m]
        best_path[j] = h
        if chi2 > chi2_prune[min(n_hits, chi2_prune.shape[0] - 1)]:
            return -1, chi2
        if f_group_end[j] and (mask & f_need_end[j]) != f_need_end[j]:
            return -1, chi2
    d = j1 - j0 - 1
    for i in range(5):
        best_x[i] = post_x[d, i]
        for m in range(5):
            best_P[i, m] = post_P[d, i, m]
    return n_hits, chi2


def _hough_grid(tau0: float, tau1: float, q_max: float, ratio: float = 1.25) -> tuple:
    """Breakpoints of the Hough coordinate t(q) (see `_t_of_q`): |q| = 0 and then every
    point where the tolerance τ(q) = τ0 + τ1·|q| has grown by `ratio`, up to 2·q_max;
    grid row 0: |q|, row 1: t = ln(1 + τ1·|q|/τ0)/τ1 (exact at the breakpoints). With
    look-up tables of the breakpoint interval on uniform cells of |q| and of |t| (cells
    half the shortest interval wide: the interval is the cell's or the next), so that a
    conversion costs a table read instead of a bisection (the q/p scan converts every
    hit). Returns (grid (2, n), q table, 1/q cell, t table, 1/t cell)."""
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
    return (grid, *tables)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _interval(a, row, lut, inv_cell):
    """Index lo of the breakpoint interval [row[lo], row[lo+1]) holding a ≥ 0 (the last
    interval beyond the end), from the cell table of `_hough_grid`."""
    c = int(a * inv_cell)
    last = row.shape[0] - 2
    if c >= lut.shape[0]:
        return last
    lo = lut[c]
    while lo < last and row[lo + 1] <= a:
        lo += 1
    return lo


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _t_of_q(q, hough):
    """Hough coordinate of q/p in units of the local tolerance τ(q): piecewise linear
    through the breakpoints (each interval's bin width lies between τ at its ends; a
    logarithm per hit would cost more than the rest of the scan)."""
    tg, lut_q, inv_q, _, _ = hough
    a = abs(q)
    lo = _interval(a, tg[0], lut_q, inv_q)
    hi = lo + 1
    t = tg[1, lo] + (a - tg[0, lo]) * (tg[1, hi] - tg[1, lo]) / (tg[0, hi] - tg[0, lo])
    return t if q >= 0.0 else -t


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _q_of_t(t, hough):
    tg, _, _, lut_t, inv_t = hough
    a = abs(t)
    lo = _interval(a, tg[1], lut_t, inv_t)
    hi = lo + 1
    q = tg[0, lo] + (a - tg[1, lo]) * (tg[0, hi] - tg[0, lo]) / (tg[1, hi] - tg[1, lo])
    return q if t >= 0.0 else -q


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _hermite(x0, x1, d0, d1, h, u):
    """Cubic Hermite interpolation on [x0, x1] (length h, derivatives d0, d1) at u ∈ [0, 1]."""
    u2 = u * u
    u3 = u2 * u
    return ((2 * u3 - 3 * u2 + 1) * x0 + (u3 - 2 * u2 + u) * h * d0 + (-2 * u3 + 3 * u2) * x1
            + (u3 - u2) * h * d1)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _node_interp(qn, n_nodes, vals, ders, col, q):
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
    v = _hermite(vals[k, col], vals[k + 1, col], ders[k, col], ders[k + 1, col], h, u)
    return v, ders[k, col] + u * (ders[k + 1, col] - ders[k, col])


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _pvalue_ok(chi2, n_meas, cut):
    return chi2 <= cut[min(n_meas, cut.shape[0] - 1)]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _popcount(m):
    n = 0
    while m:
        m &= m - 1
        n += 1
    return n


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _conditional(P, pc, k):
    """Covariance of (x, tx) and (y, ty) given q/p: pc[k … k+5] = xx, x·tx, tx·tx, yy, y·ty, ty·ty."""
    pc[k] = P[0, 0] - P[0, 4] ** 2 / P[4, 4]
    pc[k + 1] = P[0, 2] - P[0, 4] * P[2, 4] / P[4, 4]
    pc[k + 2] = P[2, 2] - P[2, 4] ** 2 / P[4, 4]
    pc[k + 3] = P[1, 1] - P[1, 4] ** 2 / P[4, 4]
    pc[k + 4] = P[1, 3] - P[1, 4] * P[3, 4] / P[4, 4]
    pc[k + 5] = P[3, 3] - P[3, 4] ** 2 / P[4, 4]


@nb.njit(cache=True, **NO_REFCOUNT)
def _stereo_score(loe, hu, hsig, used, n_ut, n_fwd, f_cos, f_sin, f_sig, f_z, qn, n_nodes, sxs, sdxs,
                  sys_, sdys, q_c, alpha, beta, z0, sig2, pc, z_ut, nsig):
    """Stereo confirmation of a q/p cluster: on every SciFi stereo layer the nearest hit
    to u = x·cos α + y·sin α, with x from the cluster's line and y from the VELO prior
    given q/p (σ_y: the conditional covariance pc carried by a straight line). Returns
    (Σ min(Δχ², nsig²) over the stereo layers, number of layers with a hit within nsig σ)."""
    score = 0.0
    n_found = 0
    q2 = q_c * q_c
    for j in range(n_ut, n_fwd):
        c = f_cos[j]
        s = f_sin[j]
        if abs(s) < 1e-6:
            continue
        col = j - n_ut
        x_ref, _ = _node_interp(qn, n_nodes, sxs, sdxs, col, q_c)
        y_ref, _ = _node_interp(qn, n_nodes, sys_, sdys, col, q_c)
        x = x_ref + alpha + beta * (f_z[j] - z0)
        dz = f_z[j] - z_ut
        vy = (pc[3] + pc[9] * q2) + 2.0 * dz * (pc[4] + pc[10] * q2) + dz * dz * (pc[5] + pc[11] * q2)
        var = s * s * max(vy, 0.0) + c * c * sig2 + f_sig[j] * f_sig[j]
        up = c * x + s * y_ref
        hw = nsig * math.sqrt(var)
        lo = loe[j]
        hi = loe[j + 1]
        while lo < hi:
            mid = (lo + hi) >> 1
            if hu[mid] < up - hw:
                lo = mid + 1
            else:
                hi = mid
        best = nsig * nsig
        h = lo
        while h < loe[j + 1] and hu[h] <= up + hw:
            if not used[h]:
                best = min(best, (hu[h] - up) ** 2 / var)
            h += 1
        if best < nsig * nsig:
            n_found += 1
        score += best
    return score, n_found


_MAX_PER_LAYER = 6  # entries per x layer considered in a cluster (nearest to the trajectory)


@nb.njit(cache=True, **NO_REFCOUNT)
def _line_fit(n_x, chosen, rx, x_z, sig2, w_beta):
    """Least-squares line rx = α + β·(z − z_0) through the chosen layers with the prior
    β ~ N(0, 1/w_beta). Returns (n, χ², α, β)."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    r0 = 0.0
    r1 = 0.0
    n = 0
    for li in range(n_x):
        if chosen[li] < 0:
            continue
        dz = x_z[li] - x_z[0]
        s0 += 1.0
        s1 += dz
        s2 += dz * dz
        r0 += rx[li]
        r1 += rx[li] * dz
        n += 1
    if n == 0:
        return 0, 0.0, 0.0, 0.0
    s2 += w_beta * sig2
    det = s0 * s2 - s1 * s1
    if det <= 0.0:
        return n, 0.0, r0 / s0, 0.0
    alpha = (s2 * r0 - s1 * r1) / det
    beta = (s0 * r1 - s1 * r0) / det
    chi2 = beta * beta * w_beta
    for li in range(n_x):
        if chosen[li] >= 0:
            res = rx[li] - alpha - beta * (x_z[li] - x_z[0])
            chi2 += res * res / sig2
    return n, chi2, alpha, beta


@nb.njit(cache=True, **NO_REFCOUNT)
def _cluster_fit(kb, ke, e_hit, e_t, e_li, e_order, hu, n_x, x_c, lin, t_c, x_z, sig2, w_beta, chosen,
                 rx, cand_e, cand_r, cand_n):
    """Straight-line test of a q/p cluster in the SciFi x layers.

    The entries kb … ke−1 (in e_order) are hits (e_hit) on x layer e_li; their x residual
    to the trajectory at the cluster's q/p is r = u − x_c[layer] (lin=False, x_c: the
    interpolated trajectory) or, to first order, (t − t_c)·x_c[layer] (lin=True, x_c:
    τ(q_c)·dx/dq; cheaper, for ranking). Lines through one entry of the first and one of
    the last layer (the _MAX_PER_LAYER nearest to the trajectory on each) pick the nearest
    entry on every other layer; the best line by χ² is refitted with β ~ N(0, 1/w_beta):
    given q/p the VELO state predicts the direction in the SciFi, random coincidences of
    implied q/p have random directions and do not line up. Returns (n_layers, χ², α, β);
    chosen[li] (entry or −1) and rx[li] its residual.
    """
    for li in range(n_x):
        cand_n[li] = 0
    for kk in range(kb, ke):
        ent = e_order[kk]
        li = e_li[ent]
        r = (e_t[ent] - t_c) * x_c[li] if lin else hu[e_hit[ent]] - x_c[li]
        m = cand_n[li]
        if m < _MAX_PER_LAYER:
            cand_n[li] = m + 1
        elif abs(r) < abs(cand_r[li, m - 1]):
            m = m - 1
        else:
            continue
        while m > 0 and abs(cand_r[li, m - 1]) > abs(r):  # keep sorted by |r|
            cand_r[li, m] = cand_r[li, m - 1]
            cand_e[li, m] = cand_e[li, m - 1]
            m -= 1
        cand_r[li, m] = r
        cand_e[li, m] = ent
    lf = -1
    ll = -1
    for li in range(n_x):
        if cand_n[li] > 0:
            if lf < 0:
                lf = li
            ll = li
    if lf < 0:
        for li in range(n_x):
            chosen[li] = -1
        return 0, 0.0, 0.0, 0.0
    best_chi = 1e300
    best_a = 0.0
    best_b = 0.0
    for i1 in range(cand_n[lf]):
        for i2 in range(cand_n[ll] if ll != lf else 1):
            r1 = cand_r[lf, i1]
            if ll != lf:
                b_ = (cand_r[ll, i2] - r1) / (x_z[ll] - x_z[lf])
            else:
                b_ = 0.0
            a_ = r1 - b_ * (x_z[lf] - x_z[0])
            chi = b_ * b_ * w_beta
            for li in range(n_x):
                if cand_n[li] == 0:
                    continue
                pred = a_ + b_ * (x_z[li] - x_z[0])
                bd = 1e300
                for m in range(cand_n[li]):
                    dd = abs(cand_r[li, m] - pred)
                    bd = min(bd, dd)
                chi += bd * bd / sig2
            if chi < best_chi:
                best_chi = chi
                best_a = a_
                best_b = b_
    for li in range(n_x):
        chosen[li] = -1
        if cand_n[li] == 0:
            continue
        pred = best_a + best_b * (x_z[li] - x_z[0])
        bd = 1e300
        for m in range(cand_n[li]):
            dd = abs(cand_r[li, m] - pred)
            if dd < bd:
                bd = dd
                chosen[li] = cand_e[li, m]
                rx[li] = cand_r[li, m]
    return _line_fit(n_x, chosen, rx, x_z, sig2, w_beta)


@nb.njit(cache=True, **NO_REFCOUNT)
def _scifi_search(ext, poly, tref, quad, geo, a, s_v, loe, hu, hsig, used, opt, iopt, cuts, tgrid, s0, ds0, pc,
                  q_lo, q_hi, ut_hits, W, cand):
    """Steps 2–3: q/p scan of the SciFi x layers over [q_lo, q_hi], then the combinatorial
    KF from the best clusters (through the UT hits ut_hits, −1: none, then the SciFi
    layers). s0/ds0: state at the last UT layer given q/p (conditional
    mean, s0[4] its q/p) and its derivative; pc = (σx², σxtx, σtx² at q/p = 0, the same
    ∝ (q/p)² per (1/MeV)²): the conditional covariance at the last UT layer.

    cand = (paths (M, n_fwd), n_sf (M), χ² (M), q (M), var (M), count (1)): the SciFi
    candidates, best first (χ² − miss_penalty·hits).
    """
    (f_layer, f_cos, f_sin, f_sig, f_acc, f_bit, f_group_end, f_need_end, sf_need, x_layers, x_fwd,
     x_station_bit, x_station_need, n_ut) = geo
    ut_prune, sf_prune, final_cut, noutcut, good_cut = cuts
    (ref_s, ref_F, ref_Q, work, ws, path, mode, fixed, x0, P0, bx, bP, qn, sxs, sdxs, sys_, sdys,
     nx_x, nx_q, nx_dq, e_t, e_bin, e_li, e_hit, e_order, bin_count, bin_start, cl_bin, cl_npop,
     cl_key, chosen, rx, x_z, d_l, x_z_all, mask_pop, cand_e, cand_r, cand_n, top) = W
    c_paths, c_n, c_chi, c_q, c_var, c_count = cand
    c_count[0] = 0
    n_fwd = f_layer.shape[0]
    n_x = x_layers.shape[0]
    tau0 = opt[_O_TAU0]
    tau1 = opt[_O_TAU1]
    nsig = opt[_O_NSIG]
    miss = opt[_O_MISS]
    n_win = iopt[_I_WINDOW_BINS]
    max_entries = e_t.shape[0]
    max_bins = bin_count.shape[0] - 1
    if not q_hi > q_lo:
        return 0
    localize_ut_to_scifi(ext.uts_meta, ext.uts_coef, s0[0], s0[1], poly, tref)
    n_nodes = int(math.ceil((q_hi - q_lo) / opt[_O_NODE_DW])) + 1
    n_nodes = min(max(n_nodes, 2), qn.shape[0])
    for k in range(n_nodes):
        qn[k] = q_lo + (q_hi - q_lo) * k / (n_nodes - 1)
    st = scan_states(ext, poly, tref, quad, f_layer[n_ut - 1], f_layer[n_ut:], s0, ds0, qn[:n_nodes],
                     sxs, sdxs, sys_, sdys, work)
    if st == TRANSPORT_FAILED:
        return 0
    # ---- Hough coordinate t of every x-layer hit in the covered range: its implied q/p by
    # cubic Hermite interpolation of q(x) between the nodes (x is monotone in q/p; the hits
    # are visited in order of x, so the node interval only moves forward)
    t_lo = _t_of_q(q_lo, tgrid)
    n_bins = min(int(_t_of_q(q_hi, tgrid) - t_lo) + 1, max_bins)
    q_rms = max(abs(q_lo), abs(q_hi))
    pcxx = pc[0] + pc[6] * q_rms * q_rms
    pcxt = pc[1] + pc[7] * q_rms * q_rms
    pctt = pc[2] + pc[8] * q_rms * q_rms
    z_ut = ext.layer_z[f_layer[n_ut - 1]]
    f_z = x_z_all
    for j in range(n_fwd):
        f_z[j] = ext.layer_z[f_layer[j]]
    n_e = 0
    for li in range(n_x):
        col = x_fwd[li] - n_ut
        x_z[li] = ext.layer_z[x_layers[li]]
        inc = sxs[n_nodes - 1, col] >= sxs[0, col]
        for k in range(n_nodes):
            kk = k if inc else n_nodes - 1 - k
            nx_x[li, k] = sxs[kk, col]
            nx_q[li, k] = qn[kk]
            dxdq = sdxs[kk, col]
            nx_dq[li, k] = 1.0 / dxdq if dxdq != 0.0 else 0.0
        dz = x_z[li] - z_ut
        var = max(pcxx + 2.0 * dz * pcxt + dz * dz * pctt, 0.0) + f_sig[x_fwd[li]] ** 2
        margin = nsig * math.sqrt(var) + 1.0
        x_min = nx_x[li, 0] - margin
        x_max = nx_x[li, n_nodes - 1] + margin
        lo = loe[x_fwd[li]]
        hi = loe[x_fwd[li] + 1]
        while lo < hi:
            mid = (lo + hi) >> 1
            if hu[mid] < x_min:
                lo = mid + 1
            else:
                hi = mid
        h = lo
        hi = loe[x_fwd[li] + 1]
        seg = 0
        while h < hi and hu[h] <= x_max and n_e < max_entries:
            if used[h]:
                h += 1
                continue
            x = hu[h]
            while seg < n_nodes - 2 and x > nx_x[li, seg + 1]:
                seg += 1
            if x <= nx_x[li, 0]:
                q = nx_q[li, 0] + nx_dq[li, 0] * (x - nx_x[li, 0])
            elif x >= nx_x[li, n_nodes - 1]:
                q = nx_q[li, n_nodes - 1] + nx_dq[li, n_nodes - 1] * (x - nx_x[li, n_nodes - 1])
            else:
                hx = nx_x[li, seg + 1] - nx_x[li, seg]
                q = _hermite(nx_q[li, seg], nx_q[li, seg + 1], nx_dq[li, seg], nx_dq[li, seg + 1], hx,
                             (x - nx_x[li, seg]) / hx) if hx > 0.0 else nx_q[li, seg]
            t = _t_of_q(q, tgrid)
            tb = t - t_lo
            if 0.0 <= tb < n_bins:
                e_t[n_e] = t
                e_bin[n_e] = int(tb)
                e_li[n_e] = li
                e_hit[n_e] = h
                n_e += 1
            h += 1
    # ---- counting sort of the entries by bin
    for k in range(n_e):
        bin_count[e_bin[k]] += 1
    bin_start[0] = 0
    for b in range(n_bins):
        bin_start[b + 1] = bin_start[b] + bin_count[b]
    for k in range(n_e):
        bin_count[e_bin[k]] = 0
    for k in range(n_e):
        b = e_bin[k]
        e_order[bin_start[b] + bin_count[b]] = k
        bin_count[b] += 1
    for k in range(n_e):  # bin_count now holds the x-layer mask of each bin
        bin_count[e_bin[k]] = 0
    for k in range(n_e):
        bin_count[e_bin[k]] |= 1 << e_li[k]
    for m in range(1 << n_x):  # x layers in a mask, 0 if a station has none
        npop = _popcount(m)
        if iopt[_I_STATION_X] != 0:
            smask = 0
            for li in range(n_x):
                if m & (1 << li):
                    smask |= x_station_bit[li]
            if smask != x_station_need:
                npop = 0
        mask_pop[m] = npop
    # ---- clusters: windows of two bins starting at every occupied bin; kept if they have
    # enough x layers (≥ 1 per station, ≥ the fullest window's count − 1) and no
    # overlapping window has more
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
    min_pop = max(iopt[_I_MIN_X], max_pop - 1)
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
    n_cl = n_keep
    # ---- straight-line test of every cluster (key: its χ², nsig² per missing x layer), then
    # the stereo confirmation of the best few (key += Σ stereo Δχ²; lower is better)
    ms = opt[_O_LINE_MS]
    for c_ in range(n_cl):
        b = cl_bin[c_]
        t_c = t_lo + b + 0.5 * n_win
        q_c = _q_of_t(t_c, tgrid)
        tau_c = tau0 + tau1 * abs(q_c)
        k = 0
        while k < n_nodes - 2 and qn[k + 1] <= q_c:
            k += 1
        u = min(max((q_c - qn[k]) / (qn[k + 1] - qn[k]), 0.0), 1.0)
        for li in range(n_x):
            col = x_fwd[li] - n_ut
            d_l[li] = tau_c * (sdxs[k, col] + u * (sdxs[k + 1, col] - sdxs[k, col]))
        sig2 = opt[_O_LINE_SIG] ** 2 + (ms * q_c) ** 2
        w_beta = 1.0 / (pc[2] + (pc[8] + opt[_O_SLOPE_MS] ** 2) * q_c * q_c)
        nl_, chi2l, alpha, beta = _cluster_fit(bin_start[b], bin_start[min(b + n_win, n_bins)], e_hit, e_t,
                                               e_li, e_order, hu, n_x, d_l, True, t_c, x_z, sig2, w_beta,
                                               chosen, rx, cand_e, cand_r, cand_n)
        if nl_ < iopt[_I_MIN_X] or chi2l > opt[_O_LINE_CHI2] * max(nl_ - 1, 1):
            cl_key[c_] = 1e300
        else:
            cl_key[c_] = chi2l + nsig * nsig * (n_x - nl_)
    n_conf = 0
    while n_conf < iopt[_I_STEREO_CANDIDATES]:
        best = -1
        for c_ in range(n_cl):
            if cl_key[c_] < 1e299 and cl_npop[c_] >= 0 and (best < 0 or cl_key[c_] < cl_key[best]):
                best = c_
        if best < 0:
            break
        n_conf += 1
        cl_npop[best] = -cl_npop[best] - 1  # mark as confirmed
        b = cl_bin[best]
        q_c = _q_of_t(t_lo + b + 0.5 * n_win, tgrid)
        for li in range(n_x):
            d_l[li], _ = _node_interp(qn, n_nodes, sxs, sdxs, x_fwd[li] - n_ut, q_c)
        sig2 = opt[_O_LINE_SIG] ** 2 + (ms * q_c) ** 2
        w_beta = 1.0 / (pc[2] + (pc[8] + opt[_O_SLOPE_MS] ** 2) * q_c * q_c)
        nl_, chi2l, alpha, beta = _cluster_fit(bin_start[b], bin_start[min(b + n_win, n_bins)], e_hit, e_t,
                                               e_li, e_order, hu, n_x, d_l, False, 0.0, x_z, sig2, w_beta,
                                               chosen, rx, cand_e, cand_r, cand_n)
        sscore, n_stereo = _stereo_score(loe, hu, hsig, used, n_ut, n_fwd, f_cos, f_sin, f_sig, f_z, qn,
                                         n_nodes, sxs, sdxs, sys_, sdys, q_c, alpha, beta, x_z[0], sig2, pc,
                                         z_ut, nsig)
        cl_key[best] = cl_key[best] + sscore if n_stereo >= iopt[_I_STEREO_MIN] else 1e300
    for c_ in range(n_cl):
        if cl_npop[c_] >= 0:
            cl_key[c_] = 1e300  # not confirmed: not followed
    for k in range(n_e):
        bin_count[e_bin[k]] = 0
    # ---- follow the best clusters with the combinatorial KF (VELO prior, UT layers off)
    pm_depth = x_fwd[0]
    n_follow = 0
    while n_follow < iopt[_I_MAX_CLUSTERS]:
        best = -1
        for c_ in range(n_cl):
            if cl_key[c_] < 1e299 and (best < 0 or cl_key[c_] < cl_key[best]):
                best = c_
        if best < 0:
            break
        cl_key[best] = 1e300
        n_follow += 1
        b = cl_bin[best]
        kb = bin_start[b]
        ke = bin_start[min(b + n_win, n_bins)]
        t_c = t_lo + b + 0.5 * n_win
        q_c = _q_of_t(t_c, tgrid)
        tau_c = tau0 + tau1 * abs(q_c)
        for li in range(n_x):
            d_l[li], _ = _node_interp(qn, n_nodes, sxs, sdxs, x_fwd[li] - n_ut, q_c)
        sig2 = opt[_O_LINE_SIG] ** 2 + (ms * q_c) ** 2
        w_beta = 1.0 / (pc[2] + (pc[8] + opt[_O_SLOPE_MS] ** 2) * q_c * q_c)
        nl_, chi2l, alpha, beta = _cluster_fit(kb, ke, e_hit, e_t, e_li, e_order, hu, n_x, d_l, False,
                                               0.0, x_z, sig2, w_beta, chosen, rx, cand_e, cand_r,
                                               cand_n)
        # refined q/p: mean Hough coordinate of the chosen entries
        ts = 0.0
        for li in range(n_x):
            if chosen[li] >= 0:
                ts += e_t[chosen[li]]
        q_c = _q_of_t(ts / nl_, tgrid)
        # pseudo-measurement at the first x layer: the cluster's straight line there, fitted
        # without the slope prior (which may pull it by more than the hit spacing)
        _, _, alpha, _ = _line_fit(n_x, chosen, rx, x_z, sig2, 0.0)
        x_first, _ = _node_interp(qn, n_nodes, sxs, sdxs, x_fwd[0] - n_ut, q_c)
        xpm = x_first + alpha
        pm_var = sig2 + opt[_O_PM_FLOOR] ** 2
        st = _reference(ext, poly, tref, quad, a, f_layer, n_ut, n_fwd, s_v, q_c, abs(q_c), ref_s,
                        ref_F, ref_Q, work, opt[_O_MODEL])
        if st == TRANSPORT_FAILED:
            continue
        for j in range(n_fwd):
            if j < n_ut:
                mode[j] = _MODE_FIXED if ut_hits[j] >= 0 else _MODE_OFF
                fixed[j] = ut_hits[j]
            else:
                mode[j] = _MODE_SEARCH
        for i in range(4):
            x0[i] = 0.0
        x0[4] = -q_c
        _velo_prior(opt, abs(q_c), opt[_O_WEAK_QPRIOR], P0)
        n_sf, _, chi_c = _search(
            0, n_fwd, mode, fixed, loe, hu, hsig, used, f_cos, f_sin, f_sig, f_acc, f_bit, f_group_end,
            f_need_end, ref_s, ref_F, ref_Q, x0, P0, pm_depth, xpm, pm_var,
            nsig, iopt[_I_BRANCH], iopt[_I_BRANCH], n_fwd - n_ut - iopt[_I_SF_MIN],
            iopt[_I_SF_MIN], False, sf_need, sf_prune, iopt[_I_MAX_NODES], ws, path, bx, bP, top, miss)
        if n_sf < 0:
            continue
        # insert into the candidate list (best first), dropping duplicates
        key = chi_c - miss * n_sf
        dup = False
        for c2 in range(c_count[0]):
            same = True
            for j in range(n_ut, n_fwd):
                if c_paths[c2, j] != path[j]:
                    same = False
                    break
            if same:
                dup = True
                break
        if dup:
            continue
        nc = c_count[0]
        pos = nc
        while pos > 0 and key < c_chi[pos - 1] - miss * c_n[pos - 1]:
            pos -= 1
        if pos >= c_n.shape[0]:
            continue
        for q_ in range(min(nc, c_n.shape[0] - 1), pos, -1):
            c_n[q_] = c_n[q_ - 1]
            c_chi[q_] = c_chi[q_ - 1]
            c_q[q_] = c_q[q_ - 1]
            c_var[q_] = c_var[q_ - 1]
            for j in range(n_fwd):
                c_paths[q_, j] = c_paths[q_ - 1, j]
        c_n[pos] = n_sf
        c_chi[pos] = chi_c
        c_q[pos] = ref_s[n_fwd - 1, 4] + bx[4]
        c_var[pos] = bP[4, 4]
        for j in range(n_fwd):
            c_paths[pos, j] = path[j]
        if nc < c_n.shape[0]:
            c_count[0] = nc + 1
        if n_sf >= n_fwd - n_ut - 1 and _pvalue_ok(chi_c, n_sf, good_cut):
            break  # a good, (nearly) complete candidate: the next clusters are worse
    return c_count[0]


@nb.njit(cache=True)
def _workspace(n_fwd, n_sf, n_x, max_nodes_q, max_entries, max_bins, n_cand):
    """Scratch arrays of one kernel call (reused by every track)."""
    top_none = (np.zeros((0, n_fwd), dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0),
                np.zeros(0), np.zeros(0), np.zeros(1, dtype=np.int64))
    ws = (np.zeros((n_fwd, 5)), np.zeros((n_fwd, 5)), np.zeros((n_fwd, 5, 5)),
          np.zeros((n_fwd, 5, 5)), np.zeros((5, 5)), np.zeros(5), np.zeros(n_fwd), np.zeros(n_fwd),
          np.zeros(n_fwd), np.zeros((n_fwd, _MAX_CHILDREN)), np.zeros(n_fwd, dtype=np.int64),
          np.zeros(n_fwd, dtype=np.int64), np.zeros(n_fwd, dtype=np.int64),
          np.zeros(n_fwd, dtype=np.int64), np.zeros(n_fwd, dtype=np.int64),
          np.zeros(n_fwd, dtype=np.int64), np.zeros(n_fwd, dtype=np.int64),
          np.zeros(n_fwd, dtype=np.int64), np.zeros((n_fwd, _MAX_CHILDREN), dtype=np.int64),
          np.zeros((1, 5)), np.zeros((1, 5, 5)))
    W = (np.zeros((n_fwd, 5)), np.zeros((n_fwd, 5, 5)), np.zeros((n_fwd, 5, 5)), np.zeros((6, 5, 5)),
         ws, np.full(n_fwd, -1, dtype=np.int64), np.zeros(n_fwd, dtype=np.int64),
         np.full(n_fwd, -1, dtype=np.int64), np.zeros(5), np.zeros((5, 5)), np.zeros(5),
         np.zeros((5, 5)), np.zeros(max_nodes_q), np.zeros((max_nodes_q, n_sf)),
         np.zeros((max_nodes_q, n_sf)), np.zeros((max_nodes_q, n_sf)), np.zeros((max_nodes_q, n_sf)),
         np.zeros((n_x, max_nodes_q)), np.zeros((n_x, max_nodes_q)), np.zeros((n_x, max_nodes_q)),
         np.zeros(max_entries), np.zeros(max_entries, dtype=np.int64),
         np.zeros(max_entries, dtype=np.int64), np.zeros(max_entries, dtype=np.int64),
         np.zeros(max_entries, dtype=np.int64),
         np.zeros(max_bins + 1, dtype=np.int64), np.zeros(max_bins + 2, dtype=np.int64),
         np.zeros(max_entries + 1, dtype=np.int64), np.zeros(max_entries + 1, dtype=np.int64),
         np.zeros(max_entries + 1),
         np.full(n_x, -1, dtype=np.int64), np.zeros(n_x), np.zeros(n_x), np.zeros(n_x),
         np.zeros(n_fwd), np.zeros(1 << n_x, dtype=np.int64),
         np.zeros((n_x, _MAX_PER_LAYER), dtype=np.int64), np.zeros((n_x, _MAX_PER_LAYER)),
         np.zeros(n_x, dtype=np.int64), top_none)
    cand = (np.full((n_cand, n_fwd), -1, dtype=np.int64), np.zeros(n_cand, dtype=np.int64),
            np.zeros(n_cand), np.zeros(n_cand), np.zeros(n_cand), np.zeros(1, dtype=np.int64))
    return W, top_none, cand


@nb.njit(cache=True)
def _extend_kernel(ext, poly, tref, geo, t_ev, t_state, t_layer, lay_off, hu, hsig, opt, iopt, cuts,
                   good_cut, tgrid, max_entries, max_bins, out):
    (f_layer, f_cos, f_sin, f_sig, f_acc, f_bit, f_group_end, f_need_end, sf_need, x_layers, x_fwd,
     x_station_bit, x_station_need, n_ut) = geo
    ut_prune, sf_prune, final_cut, noutcut, good_cut_ = cuts
    out_hits, out_q, out_qvar, out_chi2, out_ndf, out_status, out_nut, out_nsf, out_scan = out
    ut_cut = good_cut[1]
    good_cut = good_cut[0]
    n_fwd = f_layer.shape[0]
    n_x = x_layers.shape[0]
    quad = iopt[_I_QUAD] != 0
    qmax = opt[_O_QMAX]
    n_utc_max = iopt[_I_UT_CANDIDATES]
    max_nodes_q = int(math.ceil(2.0 * qmax / opt[_O_NODE_DW])) + 2
    W, top_none, cand = _workspace(n_fwd, n_fwd - n_ut, n_x, max_nodes_q, max_entries, max_bins,
                                   iopt[_I_MAX_CLUSTERS])
    ref_s = W[0]
    ref_F = W[1]
    ref_Q = W[2]
    work = W[3]
    ws = W[4]
    path = W[5]
    mode = W[6]
    fixed = W[7]
    x0 = W[8]
    P0 = W[9]
    bx = W[10]
    bP = W[11]
    c_paths, c_n, c_chi, c_q, c_var, c_count = cand
    top_ut = (np.zeros((n_utc_max, n_fwd), dtype=np.int64), np.zeros(n_utc_max, dtype=np.int64),
              np.zeros(n_utc_max), np.zeros(n_utc_max), np.zeros(n_utc_max), np.zeros(1, dtype=np.int64))
    s_v = np.zeros(5)
    s0 = np.zeros(5)
    ds0 = np.zeros(5)
    pc = np.zeros(12)
    ut_best = np.full(n_fwd, -1, dtype=np.int64)
    cx = np.zeros(5)
    cP = np.zeros((5, 5))
    best_key = np.zeros(1)
    r_lo = np.zeros(n_utc_max)
    r_hi = np.zeros(n_utc_max)
    u_q = np.zeros(n_utc_max)
    u_var = np.zeros(n_utc_max)
    u_chi = np.zeros(n_utc_max)
    u_n = np.zeros(n_utc_max, dtype=np.int64)
    u_leaf = np.zeros(n_utc_max, dtype=np.int64)
    u_pc = np.zeros((n_utc_max, 12))
    u_s0 = np.zeros((n_utc_max, 5))
    u_ds0 = np.zeros((n_utc_max, 5))
    ut_hits = np.full(n_fwd, -1, dtype=np.int64)
    no_hits = np.full(n_fwd, -1, dtype=np.int64)
    # Two passes (module docstring, step 6): the UT starts of every track, then the full-range
    # scan for the tracks without an extension, on the SciFi hits no good extension took
    n_tracks = t_ev.shape[0]
    used = np.zeros(hu.shape[0], dtype=np.bool_)
    need_scan = np.zeros(n_tracks, dtype=np.bool_)
    keep_s0 = np.zeros((n_tracks, 5))
    keep_ds0 = np.zeros((n_tracks, 5))
    keep_pc = np.zeros((n_tracks, 12))
    keep_ut = np.zeros((n_tracks, n_ut), dtype=np.int64)
    keep_u = np.zeros((n_tracks, 4))  # q/p, its variance, χ², hits of the best UT candidate
    keep_nutc = np.zeros(n_tracks, dtype=np.int64)
    for step in range(2 * n_tracks):
        second_pass = step >= n_tracks
        t = step - n_tracks if second_pass else step
        if second_pass and not need_scan[t]:
            continue
        e = t_ev[t]
        a = t_layer[t]
        loe = lay_off[e]
        if second_pass:
            for i in range(4):
                s_v[i] = t_state[t, i]
            s_v[4] = 0.0
            for i in range(5):
                s0[i] = keep_s0[t, i]
                ds0[i] = keep_ds0[t, i]
            for i in range(12):
                pc[i] = keep_pc[t, i]
            for j in range(n_ut):
                ut_best[j] = keep_ut[t, j]
            n_utc = keep_nutc[t]
            u_q[0] = keep_u[t, 0]
            u_var[0] = keep_u[t, 1]
            u_chi[0] = keep_u[t, 2]
            u_n[0] = int(keep_u[t, 3])
        else:
            for i in range(4):
                s_v[i] = t_state[t, i]
            s_v[4] = 0.0
            out_status[t] = STATUS_NOT_FOUND
            for j in range(n_fwd):
                out_hits[t, j] = -1
            ok_state = a >= 0
            for i in range(4):
                if not np.isfinite(s_v[i]):
                    ok_state = False
            if not ok_state:
                out_status[t] = STATUS_INVALID
                continue
            # ---- the VELO prior carried through the UT without hits, at the noise of 1/p_min and
            # without noise: the state at the last UT layer given q/p and its covariance
            st = _reference(ext, poly, tref, quad, a, f_layer, n_ut, n_ut, s_v, 0.0, 0.0, ref_s, ref_F,
                            ref_Q, work, opt[_O_MODEL])
            if st == TRANSPORT_FAILED:
                out_status[t] = STATUS_INVALID
                continue
            for i in range(5):
                x0[i] = 0.0
            _velo_prior(opt, 0.0, opt[_O_WEAK_QPRIOR], P0)
            _fit_fixed(0, n_ut, no_hits, hu, hsig, f_cos, f_sin, f_acc, f_bit, f_group_end, f_need_end, ref_s,
                       ref_F, ref_Q, x0, P0, 1.0, ut_prune, ws, path, cx, cP)
            for i in range(5):
                s0[i] = ref_s[n_ut - 1, i] + cx[i]
                ds0[i] = cP[i, 4] / cP[4, 4]
            _conditional(cP, pc, 0)
            _reference(ext, poly, tref, quad, a, f_layer, n_ut, n_ut, s_v, 0.0, qmax, ref_s, ref_F, ref_Q,
                       work, opt[_O_MODEL])
            _velo_prior(opt, qmax, opt[_O_WEAK_QPRIOR], P0)
            _fit_fixed(0, n_ut, no_hits, hu, hsig, f_cos, f_sin, f_acc, f_bit, f_group_end, f_need_end, ref_s,
                       ref_F, ref_Q, x0, P0, 1.0, ut_prune, ws, path, cx, cP)
            _conditional(cP, pc, 6)
            for i in range(6):
                pc[6 + i] = (pc[6 + i] - pc[i]) / (qmax * qmax)
            # ---- 1. UT search around q/p = 0 (noise of 1/p_min): q/p ranges of its best leaves
            for j in range(n_fwd):
                mode[j] = _MODE_SEARCH if j < n_ut else _MODE_OFF
            _velo_prior(opt, qmax, opt[_O_UT_QPRIOR], P0)
            nb_ut, _, _ = _search(
                0, n_ut, mode, fixed, loe, hu, hsig, used, f_cos, f_sin, f_sig, f_acc, f_bit, f_group_end,
                f_need_end, ref_s, ref_F, ref_Q, x0, P0, -1, 0.0, 1.0,
                opt[_O_UT_NSIG], iopt[_I_UT_FIRST], iopt[_I_UT_BRANCH], n_ut - iopt[_I_UT_MIN],
                iopt[_I_UT_MIN], True, 0, ut_prune, iopt[_I_MAX_NODES], ws, path, bx, bP, top_ut, 1e6)
            n_leaves = top_ut[5][0]
            q0_ref = ref_s[n_ut - 1, 4]
            for j in range(n_fwd):
                ut_best[j] = top_ut[0][0, j] if (n_leaves > 0 and j < n_ut) else -1
            # re-fit each leaf around its own q/p with the noise at that q/p (the search used the
            # noise of 1/p_min): its q/p range for the SciFi scan
            n_utc = 0
            for c in range(n_leaves):
                q_c = q0_ref + top_ut[3][c]
                v_c = top_ut[4][c]
                chi_c = 1e300
                n_c = 0
                for iteration in range(iopt[_I_UT_REFITS]):
                    q_noise = min(math.sqrt(q_c * q_c + v_c), qmax)
                    st = _reference(ext, poly, tref, quad, a, f_layer, n_ut, n_ut, s_v, q_c, q_noise, ref_s,
                                    ref_F, ref_Q, work, opt[_O_MODEL])
                    if st == TRANSPORT_FAILED:
                        n_c = 0
                        break
                    for j in range(n_ut):
                        fixed[j] = top_ut[0][c, j]
                    for i in range(4):
                        x0[i] = 0.0
                    x0[4] = -q_c
                    _velo_prior(opt, q_noise, opt[_O_WEAK_QPRIOR], P0)
                    n_c, chi_c = _fit_fixed(0, n_ut, fixed, hu, hsig, f_cos, f_sin, f_acc, f_bit, f_group_end,
                                            f_need_end, ref_s, ref_F, ref_Q, x0, P0, opt[_O_UT_NSIG], ut_prune,
                                            ws, path, cx, cP)
                    if n_c < iopt[_I_UT_MIN]:
                        break
                    q_c = ref_s[n_ut - 1, 4] + cx[4]
                    v_c = cP[4, 4]
                if n_c < iopt[_I_UT_MIN] or chi_c > ut_cut[min(n_c, ut_cut.shape[0] - 1)]:
                    continue
                w_ = opt[_O_HOUGH_NSIG] * math.sqrt(v_c)
                # insert by (hits, χ²)
                pos = n_utc
                while pos > 0 and (n_c > u_n[pos - 1] or (n_c == u_n[pos - 1] and chi_c < u_chi[pos - 1])):
                    pos -= 1
                for k in range(n_utc, pos, -1):
                    r_lo[k] = r_lo[k - 1]
                    r_hi[k] = r_hi[k - 1]
                    u_q[k] = u_q[k - 1]
                    u_var[k] = u_var[k - 1]
                    u_chi[k] = u_chi[k - 1]
                    u_n[k] = u_n[k - 1]
                    u_leaf[k] = u_leaf[k - 1]
                    for i in range(12):
                        u_pc[k, i] = u_pc[k - 1, i]
                    for i in range(5):
                        u_s0[k, i] = u_s0[k - 1, i]
                        u_ds0[k, i] = u_ds0[k - 1, i]
                r_lo[pos] = max(q_c - w_, -qmax)
                r_hi[pos] = min(q_c + w_, qmax)
                u_q[pos] = q_c
                u_var[pos] = v_c
                u_chi[pos] = chi_c
                u_n[pos] = n_c
                u_leaf[pos] = c
                _conditional(cP, u_pc[pos], 0)
                for i in range(6, 12):
                    u_pc[pos, i] = 0.0
                for i in range(5):
                    u_s0[pos, i] = ref_s[n_ut - 1, i] + cx[i]
                    u_ds0[pos, i] = cP[i, 4] / cP[4, 4]
                n_utc += 1
            if n_utc > 0:
                for j in range(n_ut):
                    ut_best[j] = top_ut[0][u_leaf[0], j]
        # ---- 2–5. SciFi from each UT candidate (its fitted state, its q/p range, its hits in
        # the KF), best first; in the second pass the VELO prior alone over the whole range
        best_key[0] = 1e300
        final_ok = False
        done = False
        for attempt in range(n_utc, n_utc + 1) if second_pass else range(n_utc):
            if done:
                break
            if attempt < n_utc:
                q_lo = r_lo[attempt]
                q_hi = r_hi[attempt]
                for j in range(n_fwd):
                    ut_hits[j] = top_ut[0][u_leaf[attempt], j] if j < n_ut else -1
                c_s0 = u_s0[attempt]
                c_ds0 = u_ds0[attempt]
                c_pc = u_pc[attempt]
            else:
                if iopt[_I_FALLBACK] == 0:
                    break
                q_lo = -qmax
                q_hi = qmax
                for j in range(n_fwd):
                    ut_hits[j] = -1
                c_s0 = s0
                c_ds0 = ds0
                c_pc = pc
            n_c = _scifi_search(ext, poly, tref, quad, geo, a, s_v, loe, hu, hsig, used, opt, iopt, cuts, tgrid,
                                c_s0, c_ds0, c_pc, q_lo, q_hi, ut_hits, W, cand)
            for c in range(n_c):
                ok_c = _finalize(ext, poly, tref, quad, a, f_layer, n_ut, n_fwd, s_v, c_q[c], c_var[c],
                                 c_paths[c], ut_best, n_utc > 0, mode, fixed,
                                 loe, hu, hsig, used, f_cos, f_sin, f_sig, f_acc, f_bit, f_group_end, f_need_end,
                                 ref_s, ref_F, ref_Q, work, x0, P0, opt, iopt, ut_prune, final_cut,
                                 noutcut, sf_prune, ws, path, cx, cP, bx, bP, t, out_hits, out_q, out_qvar,
                                 out_chi2,
                                 out_ndf, out_status, out_nut, out_nsf, top_none, best_key)
                final_ok = final_ok or ok_c
                if final_ok and _pvalue_ok(out_chi2[t], out_ndf[t] + 1, good_cut) \
                        and out_nsf[t] >= n_fwd - n_ut - 1:
                    done = True  # a good, (nearly) complete extension: no need to look further
                    break
        if not second_pass:
            if final_ok and done and iopt[_I_TAKE_HITS] != 0:
                for j in range(n_fwd):  # a good extension takes its UT and SciFi hits
                    if out_hits[t, j] >= 0:
                        used[out_hits[t, j]] = True
            elif not final_ok:
                need_scan[t] = True
                for i in range(5):
                    keep_s0[t, i] = s0[i]
                    keep_ds0[t, i] = ds0[i]
                for i in range(12):
                    keep_pc[t, i] = pc[i]
                for j in range(n_ut):
                    keep_ut[t, j] = ut_best[j]
                keep_nutc[t] = n_utc
                keep_u[t, 0] = u_q[0]
                keep_u[t, 1] = u_var[0]
                keep_u[t, 2] = u_chi[0]
                keep_u[t, 3] = u_n[0]
            continue
        out_scan[t] = final_ok
        if not final_ok and n_utc > 0:
            # an upstream track: the best UT leaf, its q/p from the kink
            out_status[t] = STATUS_NO_SCIFI
            out_q[t] = u_q[0]
            out_qvar[t] = u_var[0]
            out_chi2[t] = u_chi[0]
            out_ndf[t] = u_n[0] - 1
            n_h = 0
            for j in range(n_ut):
                out_hits[t, j] = ut_best[j]
                if ut_best[j] >= 0:
                    n_h += 1
            out_nut[t] = n_h


@nb.njit(cache=True, **NO_REFCOUNT)
def _finalize(ext, poly, tref, quad, a, f_layer, n_ut, n_fwd, s_v, q_best, var_best, sf_path,
              ut_hits, use_ut_hits, mode, fixed, loe, hu, hsig, used, f_cos, f_sin, f_sig, f_acc, f_bit,
              f_group_end, f_need_end, ref_s, ref_F, ref_Q, work, x0, P0, opt, iopt, ut_prune,
              final_cut, noutcut, sf_prune, ws, path, cx, cP, bx, bP, t, out_hits, out_q, out_qvar,
              out_chi2, out_ndf, out_status, out_nut, out_nsf, top_none, best_key):
    """UT confirmation with the SciFi q/p as prior, then the final fit (step 5); if the fit
    with the UT hits fails its χ² cut, once more without UT hits."""
    st = _reference(ext, poly, tref, quad, a, f_layer, n_ut, n_fwd, s_v, q_best, abs(q_best), ref_s,
                    ref_F, ref_Q, work, opt[_O_MODEL])
    if st == TRANSPORT_FAILED:
        return False
    confirm_min = iopt[_I_CONFIRM_MIN]
    for attempt in range(2):
        if attempt == 0:
            if confirm_min > 0:
                for j in range(n_fwd):
                    mode[j] = _MODE_SEARCH if j < n_ut else _MODE_OFF
                for i in range(5):
                    x0[i] = 0.0
                _velo_prior(opt, abs(q_best), 0.0, P0)
                P0[4, 4] = var_best
                nb_c, _, _ = _search(
                    0, n_ut, mode, fixed, loe, hu, hsig, used, f_cos, f_sin, f_sig, f_acc, f_bit, f_group_end,
                    f_need_end, ref_s, ref_F, ref_Q, x0, P0, -1, 0.0, 1.0,
                    opt[_O_CONFIRM_NSIG], iopt[_I_BRANCH], iopt[_I_BRANCH], n_ut - confirm_min,
                    confirm_min, True, 0, ut_prune, iopt[_I_MAX_NODES], ws, path, cx, cP, top_none, 1e6)
                n_conf = 0
                for j in range(n_ut):
                    fixed[j] = path[j] if nb_c >= confirm_min else -1
                    if fixed[j] >= 0:
                        n_conf += 1
            else:
                n_conf = 0
                for j in range(n_ut):
                    fixed[j] = ut_hits[j] if use_ut_hits else -1
                    if fixed[j] >= 0:
                        n_conf += 1
            if n_conf == 0:
                continue  # identical to attempt 1
        else:
            for j in range(n_ut):
                fixed[j] = -1
        for j in range(n_ut, n_fwd):
            fixed[j] = sf_path[j]
        for i in range(4):
            x0[i] = 0.0
        x0[4] = -q_best
        _velo_prior(opt, abs(q_best), opt[_O_WEAK_QPRIOR], P0)
        n_fit, chi_f = _fit_fixed(0, n_fwd, fixed, hu, hsig, f_cos, f_sin, f_acc, f_bit, f_group_end, f_need_end,
                                  ref_s, ref_F, ref_Q, x0, P0, opt[_O_NSIG], sf_prune, ws, path, bx, bP)
        if n_fit < 1:
            continue
        n_u = 0
        n_s = 0
        for j in range(n_fwd):
            if path[j] >= 0:
                if j < n_ut:
                    n_u += 1
                else:
                    n_s += 1
        if n_s < iopt[_I_SF_MIN] or chi_f > final_cut[min(n_u + n_s, final_cut.shape[0] - 1)]:
            continue
        if n_u == 0 and (n_s < iopt[_I_NOUT_MIN] or chi_f > noutcut[min(n_s, noutcut.shape[0] - 1)]):
            continue  # without UT hits the VELO–SciFi match alone must be convincing
        key = chi_f - opt[_O_MISS] * (n_u + n_s)
        if key >= best_key[0]:
            return True
        best_key[0] = key
        for j in range(n_fwd):
            out_hits[t, j] = path[j]
        out_q[t] = ref_s[n_fwd - 1, 4] + bx[4]
        out_qvar[t] = bP[4, 4]
        out_chi2[t] = chi_f
        out_ndf[t] = n_u + n_s - 1
        out_nut[t] = n_u
        out_nsf[t] = n_s
        out_status[t] = STATUS_OK if n_u > 0 else STATUS_NO_UT
        return True
    return False


# ------------------------------------------------------------------------------------
# Python interface
# ------------------------------------------------------------------------------------

def _layout(geometry: Geometry):
    """Forward layers (UT then SciFi) and their requirement bits."""
    sub = geometry.layer_subdetector
    ut = np.flatnonzero(sub == SUBDETECTORS.index("ut"))
    sf = np.flatnonzero(sub == SUBDETECTORS.index("scifi"))
    velo = np.flatnonzero(sub == SUBDETECTORS.index("velo"))
    if ut.size == 0 or sf.size == 0 or velo.size == 0:
        raise InputError(f"geometry {geometry.name!r}: the forward extension needs VELO, UT and SciFi layers")
    if np.any(geometry.layer_kind[np.concatenate([ut, sf])] != 1):
        raise InputError(f"geometry {geometry.name!r}: UT and SciFi layers must be strip layers")
    f_layer = np.concatenate([ut, sf]).astype(np.int64)
    if np.any(np.diff(f_layer) != 1) or velo[-1] >= ut[0]:
        raise InputError(f"geometry {geometry.name!r}: the forward extension needs the VELO, UT and SciFi "
                         "layers in this order, each contiguous")
    n_fwd = f_layer.size
    stations = np.unique(geometry.layer_station[sf])
    if stations.size > 15:
        raise InputError(f"geometry {geometry.name!r}: too many SciFi stations")
    is_x = np.abs(geometry.layer_stereo[f_layer]) < 1e-9
    f_bit = np.zeros(n_fwd, dtype=np.int64)
    f_group_end = np.zeros(n_fwd, dtype=np.bool_)
    f_need_end = np.zeros(n_fwd, dtype=np.int64)
    sf_need = 0
    for s_i, station in enumerate(stations):
        members = np.flatnonzero((geometry.layer_station[f_layer] == station)
                                 & (geometry.layer_subdetector[f_layer] == SUBDETECTORS.index("scifi")))
        for j in members:
            f_bit[j] = 1 << (2 * s_i + (0 if is_x[j] else 1))
        need = 0
        if np.any(is_x[members]):
            need |= 1 << (2 * s_i)
        if np.any(~is_x[members]):
            need |= 1 << (2 * s_i + 1)
        f_group_end[members[-1]] = True
        f_need_end[members[-1]] = need
        sf_need |= need
    x_fwd = np.flatnonzero(is_x & (np.arange(n_fwd) >= ut.size))
    if x_fwd.size == 0 or x_fwd.size > 30:
        raise InputError(f"geometry {geometry.name!r}: the SciFi needs 1–30 x layers")
    x_layers = f_layer[x_fwd]
    x_station_bit = np.array([1 << int(np.searchsorted(stations, geometry.layer_station[lay]))
                              for lay in x_layers], dtype=np.int64)
    x_station_need = int(np.bitwise_or.reduce(x_station_bit))
    return dict(
        velo=velo, n_ut=int(ut.size), f_layer=f_layer,
        f_cos=geometry.layer_cos[f_layer].astype(np.float64),
        f_sin=geometry.layer_sin[f_layer].astype(np.float64),
        f_sig=geometry.layer_sigma[f_layer].astype(np.float64),
        f_acc=_acceptance(geometry, f_layer),
        f_bit=f_bit, f_group_end=f_group_end, f_need_end=f_need_end, sf_need=int(sf_need),
        x_layers=x_layers.astype(np.int64), x_fwd=x_fwd.astype(np.int64), x_station_bit=x_station_bit,
        x_station_need=x_station_need,
    )


def _acceptance(geometry: Geometry, f_layer: np.ndarray) -> np.ndarray:
    """Active area of the forward layers: (half_x, half_y, hole radius, hole half_x, hole
    half_y) per layer [mm] (docs/geometry.md)."""
    planes = geometry.planes
    acc = np.zeros((f_layer.size, 5))
    for j, lay in enumerate(f_layer):
        i = int(np.flatnonzero(planes.layer == lay)[0])
        acc[j] = (planes.half_x[i], planes.half_y[i], planes.hole_radius[i], planes.hole_half_x[i],
                  planes.hole_half_y[i])
    return acc


def _check_extrapolator(ext, geometry: Geometry) -> None:
    """The reference trajectories use one paper step per layer pair (`forward_steps`):
    VELO→UT from any VELO layer, layer steps in the UT and the SciFi, the UT→SciFi table."""
    v, u, t = (SUBDETECTORS.index(n) for n in ("velo", "ut", "scifi"))
    ok = (ext.layer_z.size == geometry.layer_z.size
          and ext.between_type[v] == STEP_VELO_TO_UT and ext.within_type[u] == STEP_UT
          and ext.between_type[u] == STEP_UT_TO_SCIFI and ext.within_type[t] == STEP_SCIFI)
    if not ok:
        raise InputError(f"geometry {geometry.name!r}: the forward extension needs the step types "
                         "velo_to_ut, ut, ut_to_scifi and scifi (docs/physics.md#the-parametrized-fitter)")
    meta, coef = ext.uts_meta, ext.uts_coef
    if (meta.size < META_SIZE or meta[META_NX] < 3 or meta[META_NY] < 3 or meta[META_P_MIN] <= 0
            or coef.ndim != 4 or coef.shape[1] != int(meta[META_NX]) or coef.shape[2] != int(meta[META_NY])):
        raise InputError("the parameter set has no valid UT→SciFi table (eqs. 21–23): run `pkf tune`")


def _chi2_table(pvalue: float, n: int, offset: int) -> np.ndarray:
    """χ² upper cut per number of measurements m (index), ndf = max(m − offset, 1)."""
    m = np.arange(n)
    ndf = np.maximum(m - offset, 1)
    if pvalue <= 0.0:
        return np.full(n, np.inf)
    return chi2_dist.isf(pvalue, ndf)


@nb.njit(cache=True)
def _bucket_order(key, u, n_keys):
    """The order of np.lexsort((u, key)) for integer keys in [0, n_keys): a counting sort by
    key, then a stable sort by u within each key (an (event, layer) holds tens to hundreds
    of hits; a lexsort of all hits cost half of the extension's set-up). Returns (order,
    bounds): the rows of key b are order[bounds[b]:bounds[b + 1]]."""
    bounds = np.zeros(n_keys + 1, dtype=np.int64)
    for k in key:
        bounds[k + 1] += 1
    for b in range(n_keys):
        bounds[b + 1] += bounds[b]
    fill = bounds[:-1].copy()
    order = np.empty(key.size, dtype=np.int64)
    for i in range(key.size):
        order[fill[key[i]]] = i
        fill[key[i]] += 1
    for b in range(n_keys):
        lo = bounds[b]
        hi = bounds[b + 1]
        if hi - lo > 1:
            seg = order[lo:hi].copy()
            order[lo:hi] = seg[np.argsort(u[seg], kind="mergesort")]
    return order, bounds


def _prepare(track_event, velo_state, z_state, hit_event, hit_layer, hit_u, hit_sigma, geometry, ext,
             options):
    """Arrays for the kernel: hits of the forward layers sorted by (event, layer, u) with
    their (event, layer) offsets, tracks moved to their VELO layer, option vectors."""
    lay = _layout(geometry)
    _check_extrapolator(ext, geometry)
    track_event = np.ascontiguousarray(track_event, dtype=np.int64)
    velo_state = np.ascontiguousarray(velo_state, dtype=np.float64).reshape(-1, 4)
    z_state = np.ascontiguousarray(z_state, dtype=np.float64)
    n = track_event.size
    if velo_state.shape[0] != n or z_state.shape != (n,):
        raise ValueError("track_event, velo_state (n, 4) and z_state (n,) must describe the same tracks")
    hit_event = np.asarray(hit_event, dtype=np.int64)
    hit_layer = np.asarray(hit_layer, dtype=np.int64)
    hit_u = np.asarray(hit_u, dtype=np.float64)
    hit_sigma = np.asarray(hit_sigma, dtype=np.float64)
    if not (hit_event.shape == hit_layer.shape == hit_u.shape == hit_sigma.shape):
        raise ValueError("hit columns must have the same length")
    f_layer = lay["f_layer"]
    n_fwd = f_layer.size
    # forward index of every hit (−1 for VELO/other)
    fwd_of_layer = np.full(geometry.layer_z.size, -1, dtype=np.int64)
    fwd_of_layer[f_layer] = np.arange(n_fwd)
    valid_layer = (hit_layer >= 0) & (hit_layer < fwd_of_layer.size)
    hf = np.where(valid_layer, fwd_of_layer[np.clip(hit_layer, 0, fwd_of_layer.size - 1)], -1)
    use = np.flatnonzero((hf >= 0) & np.isfinite(hit_u) & (hit_sigma > 0))
    events = np.unique(track_event)
    ev_index = np.searchsorted(events, hit_event[use])
    if events.size:
        known = (ev_index < events.size) & (events[np.minimum(ev_index, events.size - 1)] == hit_event[use])
    else:
        known = np.zeros(use.size, dtype=bool)
    use = use[known]
    ev_index = ev_index[known]
    n_ev = events.size
    order, bounds = _bucket_order(ev_index * n_fwd + hf[use], hit_u[use], n_ev * n_fwd)
    rows = use[order]
    lay_off = bounds[np.arange(n_ev)[:, None] * n_fwd + np.arange(n_fwd + 1)[None, :]].astype(np.int64)
    hu = np.ascontiguousarray(hit_u[rows])
    hsig = np.ascontiguousarray(hit_sigma[rows])
    # tracks: event index, VELO layer, state moved to it
    t_ev = np.searchsorted(events, track_event).astype(np.int64)
    velo = lay["velo"]
    vz = geometry.layer_z[velo]
    nearest = np.clip(np.searchsorted(vz, z_state), 1, max(vz.size - 1, 1))
    pick = np.where(np.abs(vz[nearest - 1] - z_state) <= np.abs(vz[np.minimum(nearest, vz.size - 1)] - z_state),
                    nearest - 1, np.minimum(nearest, vz.size - 1)) if vz.size > 1 else np.zeros(n, dtype=np.int64)
    t_layer = velo[pick].astype(np.int64)
    dz = geometry.layer_z[t_layer] - z_state
    state = velo_state.copy()
    state[:, 0] += velo_state[:, 2] * dz
    state[:, 1] += velo_state[:, 3] * dz
    bad = ~np.isfinite(z_state) | (z_state < vz[0] - 50.0) | (z_state > vz[-1] + 50.0)
    t_layer[bad] = -1
    # options, tables, buffers
    p_table = float(ext.uts_meta[META_P_MIN])
    fopt, iopt = options.vectors(p_table)
    n_meas = n_fwd + 2
    ut_prune = _chi2_table(1e-6, n_meas, 1) + 10.0
    sf_prune = _chi2_table(1e-7, n_meas, 1) + 10.0
    final_cut = _chi2_table(options.pvalue, n_meas, 1)
    x_fwd = np.isin(f_layer, lay["x_layers"])
    per_event_x = np.diff(lay_off, axis=1)[:, x_fwd].sum(axis=1) if n_ev else np.zeros(0)
    max_entries = int(per_event_x.max()) + 1 if n_ev else 1
    qmax = 1.0 / options.p_min
    t_max = (math.log1p(options.hough_tol_rel * qmax / options.hough_tol_abs) / options.hough_tol_rel
             if options.hough_tol_rel > 0 else qmax / options.hough_tol_abs)
    max_bins = int(2.0 * t_max) + 4
    poly, tref = new_table_buffers(ext)
    geo = (f_layer, lay["f_cos"], lay["f_sin"], lay["f_sig"], lay["f_acc"], lay["f_bit"], lay["f_group_end"],
           lay["f_need_end"], lay["sf_need"], lay["x_layers"], lay["x_fwd"], lay["x_station_bit"],
           lay["x_station_need"], lay["n_ut"])
    return dict(n=n, n_events=n_ev, geo=geo, t_ev=t_ev, state=state, t_layer=t_layer, lay_off=lay_off,
                hu=hu, hsig=hsig, rows=rows, fopt=fopt, iopt=iopt,
                cuts=(ut_prune, sf_prune, final_cut, _chi2_table(options.no_ut_pvalue, n_meas, 1),
                      _chi2_table(options.good_pvalue, n_meas, 1)),
                good_cut=_chi2_table(options.good_pvalue, n_meas, 1),
                ut_cut=_chi2_table(options.ut_pvalue, n_meas, 1),
                tgrid=_hough_grid(options.hough_tol_abs, options.hough_tol_rel, 1.0 / options.p_min),
                max_entries=max_entries, max_bins=max_bins, poly=poly, tref=tref, p_table=p_table,
                events=events)


def extend_velo_tracks(track_event, velo_state, z_state, hit_event, hit_layer, hit_u, hit_sigma,
                       geometry: Geometry, ext, options: ForwardOptions | None = None,
                       **overrides) -> ForwardTracks:
    """Extend VELO tracks through the UT and the SciFi (docs/physics.md#pattern-recognition).

    track_event (n,): event id of each VELO track; velo_state (n, 4): (x, y, tx, ty) [mm]
    at z_state (n,) [mm], a z inside the VELO (the state is moved along its straight line
    to the nearest VELO layer: the VELO is straight to the parametrization's precision);
    hit_event, hit_layer, hit_u, hit_sigma: hit columns of the same events (any order;
    only UT and SciFi rows are used; u = x·cos α + y·sin α, σ_u [mm]); ext: the context
    of the parametrized extrapolator (`ParameterSet.extrapolator(geometry)`); options:
    `ForwardOptions` or keyword overrides. Returns `ForwardTracks` (hit rows index the
    input hit arrays).
    """
    if options is None:
        options = ForwardOptions(**overrides)
    elif overrides:
        options = ForwardOptions(**(asdict(options) | overrides))
    prep = _prepare(track_event, velo_state, z_state, hit_event, hit_layer, hit_u, hit_sigma, geometry,
                    ext, options)
    n = prep["n"]
    n_fwd = prep["geo"][0].size
    out_hits = np.full((n, n_fwd), -1, dtype=np.int64)
    out_q = np.full(n, np.nan)
    out_qvar = np.full(n, np.nan)
    out_chi2 = np.full(n, np.nan)
    out_ndf = np.zeros(n, dtype=np.int64)
    out_status = np.full(n, STATUS_NOT_FOUND, dtype=np.int64)
    out_nut = np.zeros(n, dtype=np.int64)
    out_nsf = np.zeros(n, dtype=np.int64)
    out_scan = np.zeros(n, dtype=np.bool_)
    if n and prep["n_events"]:
        _extend_kernel(ext, prep["poly"], prep["tref"], prep["geo"], prep["t_ev"], prep["state"],
                       prep["t_layer"], prep["lay_off"], prep["hu"], prep["hsig"], prep["fopt"],
                       prep["iopt"], prep["cuts"], (prep["good_cut"], prep["ut_cut"]), prep["tgrid"],
                       prep["max_entries"], prep["max_bins"],
                       (out_hits, out_q, out_qvar, out_chi2, out_ndf, out_status, out_nut, out_nsf,
                        out_scan))
    rows = prep["rows"]
    p_table = prep["p_table"]
    found = out_hits >= 0
    counts = found.sum(axis=1)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    hit_rows = rows[out_hits[found]] if found.any() else np.zeros(0, dtype=np.int64)
    p_table_q = 1.0 / p_table
    return ForwardTracks(
        offsets=offsets, hit_rows=hit_rows.astype(np.int64), n_ut=out_nut, n_scifi=out_nsf,
        qop=out_q, qop_var=out_qvar, chi2=out_chi2, ndf=out_ndf, status=out_status,
        below_table_p_min=np.abs(out_q) > p_table_q, from_scan=out_scan,
    )
