"""Options and status codes of the forward extension (`pkf.seeding.forward`).

`ForwardOptions` holds the user's options; `ForwardOptions.vectors` packs them into the
float and integer vectors the kernels read, indexed by the `O_*` and `I_*` constants.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pkf.seeding.forward.records import MAX_CHILDREN

#: Track status codes of `ForwardTracks.status`.
STATUS_OK = 0  # UT and SciFi hits added
STATUS_NO_UT = 1  # SciFi hits added, no UT hits (q/p from VELO + SciFi)
STATUS_NO_SCIFI = 2  # no SciFi extension; the UT candidate (if any) is kept ("upstream track")
STATUS_NOT_FOUND = 3  # nothing found
STATUS_INVALID = 4  # the VELO state could not be extrapolated (NaN, no VELO layer, |slope| too large)
STATUS_NAMES = ("ok", "no UT hits", "no SciFi extension", "not found", "invalid VELO state")

# Per-kernel integer/float option vectors (see ForwardOptions.vectors)
(O_QMAX, O_VSX, O_VMSX, O_VSTX, O_VMSTX, O_UT_QPRIOR, O_WEAK_QPRIOR, O_UT_NSIG,
 O_HOUGH_NSIG, O_TAU0, O_TAU1, O_NODE_DW, O_NSIG, O_PM_FLOOR, O_LINE_SIG, O_LINE_MS,
 O_LINE_CHI2, O_CONFIRM_NSIG, O_MISS, O_SLOPE_MS, O_MODEL, O_UT_OUTLIER, O_UT_SWAP, O_UT_AMBIGUOUS,
 O_UPSTREAM_AMBIGUOUS) = range(25)
N_FOPT = 25
(I_UT_MIN, I_UT_FIRST, I_BRANCH, I_MIN_X, I_MAX_CLUSTERS, I_SF_MIN, I_FALLBACK,
 I_CONFIRM_MIN, I_MAX_NODES, I_QUAD, I_STATION_X, I_UT_CANDIDATES, I_STEREO_CANDIDATES,
 I_NOUT_MIN, I_UT_REFITS, I_UT_BRANCH, I_WINDOW_BINS, I_TAKE_HITS, I_STEREO_MIN) = range(19)
N_IOPT = 19


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
    max_clusters [2]           (3) clusters followed by the combinatorial KF per scan. ν = 7.6,
                               200 minimum-bias events (triplet pattern): 3 → 2 changes
                               the long efficiency by +0.01/+0.01 points (> 5 / 2–5 GeV),
                               ghosts 2.02 → 2.00 %, forward time −1–4 %
    pseudo_floor [0.3]         (3) added in quadrature to the pseudo-measurement σ [mm]
    window_sigmas [5]          (3, 4) SciFi windows and Δχ² cut [σ]
    max_branch [3]             (3, 4) hits kept per layer and branch (best Δχ²)
    scifi_min_hits [10]        (3, 4) SciFi hits (of 12)
    miss_penalty [9]           (3, 4) ranking: χ² − miss_penalty·hits, lowest first
    scifi_model_noise [3000]   (3, 4) noise of the SciFi layer steps × (1 + (this·q/p)²) [MeV]
    ut_confirm_min_hits [2]    (4) UT hits re-collected with the SciFi q/p (0: keep the start's)
    confirm_window_sigmas [3]  (4) UT confirmation windows [σ]
    ut_outlier_chi2 [9]        (4) a UT hit of the final fit whose χ² against the rest of the
                               track (VELO, SciFi, other UT hits) exceeds this is replaced by
                               the best untaken hit of its layer under the cut, or dropped
                               (`pkf.seeding.forward.outliers`; inf: never). ν = 7.6, truth
                               VELO seeds: 0.2 % of the true and 4 % of the foreign UT hits
    ut_swap_margin [1]         (4) … a UT hit is replaced by another of its layer whose χ² is
                               lower by more than this (inf: never)
    ut_ambiguous_chi2 [9]      (4) … a UT hit is dropped if another hit of its layer (taken or
                               not) has a χ² below this: close tracks in the u-only UT share
                               and swap hits (0: keep). ν = 7.6: correct extensions with a
                               foreign UT hit 24 % → 4.5 % (cut 4), UT hits per track 3.55 →
                               2.93. 600 events, triplet pattern, cut 4 → 9 → 16: real long
                               candidates with a foreign UT hit 6,132 → 2,567 → 1,758 (of
                               142k; their q/p pulls are ≈ 2 wide), reference first-hit q/p
                               pull core at 1.5–3 GeV 1.053 → 1.042 → 1.039 (3–5 GeV 1.050 →
                               1.039 → 1.036), δp/p core 0.204 → 0.207 %, long efficiency
                               95.75 → 95.65 → 95.52 %, ghosts 2.04 → 2.01 → 2.02 %
    upstream_ambiguous_chi2 [4] (5) ut_ambiguous_chi2 for upstream tracks (their check is
                               against the VELO + UT fit). ν = 7.6, 60 events, triplet
                               pattern: 9 instead of 4 costs 13 % of the real upstream tracks
                               for a foreign-hit share 3.2 → 1.4 %
    upstream_pvalue [0]        (5) p-value cut on an upstream track's VELO + UT χ² (ndf = hits
                               − 1; 0: none). 0.01 costs 1.5 % of them, foreign share 3.2 → 2.8 %
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
    max_clusters: int = 2
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
    ut_outlier_chi2: float = 9.0
    ut_swap_margin: float = 1.0
    ut_ambiguous_chi2: float = 9.0
    upstream_ambiguous_chi2: float = 4.0
    upstream_pvalue: float = 0.0
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
            (1 <= self.max_branch <= MAX_CHILDREN - 1 and 1 <= self.ut_first_branches <= MAX_CHILDREN - 1,
             f"branches must be in 1..{MAX_CHILDREN - 1}"),
            (self.scifi_min_hits >= 1 and self.no_ut_min_hits >= 1, "minimum hit counts must be ≥ 1"),
            (1 <= self.ut_branch <= MAX_CHILDREN - 1, f"ut_branch must be in 1..{MAX_CHILDREN - 1}"),
            (self.ut_candidates >= 1 and self.stereo_candidates >= 1 and self.window_bins >= 1
             and self.ut_refits >= 1, "candidate counts, window_bins and ut_refits must be ≥ 1"),
            (0.0 <= self.no_ut_pvalue < 1.0 and 0.0 <= self.good_pvalue < 1.0, "p-values must be in [0, 1)"),
            (self.ut_confirm_min_hits >= 0, "ut_confirm_min_hits must be ≥ 0"),
            (self.max_nodes >= 16, "max_nodes must be ≥ 16"),
            (self.ut_outlier_chi2 > 0, "ut_outlier_chi2 must be > 0"),
            (self.ut_swap_margin >= 0 and self.ut_ambiguous_chi2 >= 0 and self.upstream_ambiguous_chi2 >= 0,
             "ut_swap_margin, ut_ambiguous_chi2 and upstream_ambiguous_chi2 must be ≥ 0"),
            (0.0 <= self.upstream_pvalue < 1.0, "upstream_pvalue must be in [0, 1)"),
        )
        for ok, message in checks:
            if not ok:
                raise ValueError(message)

    def vectors(self, p_table: float) -> tuple[np.ndarray, np.ndarray]:
        """The float and integer option vectors of the kernels (indices O_*, I_*); p_table:
        the UT→SciFi table's p_min [MeV] (the q/p node spacing is in its units)."""
        f = np.zeros(N_FOPT)
        for index, name in _FLOAT_OPTIONS:
            f[index] = getattr(self, name)
        f[O_QMAX] = 1.0 / self.p_min
        f[O_UT_QPRIOR] = self.ut_q_prior / self.p_min
        f[O_WEAK_QPRIOR] = 10.0 / self.p_min
        f[O_NODE_DW] = self.node_spacing / p_table
        i = np.zeros(N_IOPT, dtype=np.int64)
        for index, name in _INT_OPTIONS:
            i[index] = int(getattr(self, name))
        return f, i


#: options copied as they are into the float and integer vectors
_FLOAT_OPTIONS = (
    (O_VSX, "velo_sigma_x"), (O_VMSX, "velo_ms_x"), (O_VSTX, "velo_sigma_tx"), (O_VMSTX, "velo_ms_tx"),
    (O_UT_NSIG, "ut_window_sigmas"), (O_HOUGH_NSIG, "hough_sigmas"), (O_TAU0, "hough_tol_abs"),
    (O_TAU1, "hough_tol_rel"), (O_NSIG, "window_sigmas"), (O_PM_FLOOR, "pseudo_floor"),
    (O_LINE_SIG, "line_sigma"), (O_LINE_MS, "line_ms"), (O_LINE_CHI2, "line_chi2"), (O_MISS, "miss_penalty"),
    (O_SLOPE_MS, "slope_ms"), (O_MODEL, "scifi_model_noise"), (O_CONFIRM_NSIG, "confirm_window_sigmas"),
    (O_UT_OUTLIER, "ut_outlier_chi2"), (O_UT_SWAP, "ut_swap_margin"),
    (O_UT_AMBIGUOUS, "ut_ambiguous_chi2"), (O_UPSTREAM_AMBIGUOUS, "upstream_ambiguous_chi2"),
)
_INT_OPTIONS = (
    (I_UT_MIN, "ut_min_hits"), (I_UT_FIRST, "ut_first_branches"), (I_BRANCH, "max_branch"),
    (I_MIN_X, "hough_min_x_layers"), (I_MAX_CLUSTERS, "max_clusters"), (I_SF_MIN, "scifi_min_hits"),
    (I_FALLBACK, "no_ut_fallback"), (I_CONFIRM_MIN, "ut_confirm_min_hits"), (I_MAX_NODES, "max_nodes"),
    (I_QUAD, "quadratic_continuation"), (I_STATION_X, "station_x_and_stereo"), (I_UT_CANDIDATES, "ut_candidates"),
    (I_STEREO_CANDIDATES, "stereo_candidates"), (I_NOUT_MIN, "no_ut_min_hits"), (I_UT_REFITS, "ut_refits"),
    (I_UT_BRANCH, "ut_branch"), (I_WINDOW_BINS, "window_bins"), (I_TAKE_HITS, "take_hits"),
    (I_STEREO_MIN, "stereo_min_layers"),
)
