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
   fitted q/p over the UT and SciFi hits (hits beyond ``window_sigmas`` are dropped), then
   the UT outlier check (`outliers`: each UT hit against the smoothed VELO + SciFi + other
   UT track without it; outliers replaced or dropped, hits with an ambiguous neighbour
   dropped, refit) gives χ², ndf = hits − 1, q/p and its variance. Accepted if ≥ ``scifi_min_hits`` SciFi hits
   with the station requirement and p-value ≥ ``pvalue``; without UT hits (also tried when
   the fit with them fails) ≥ ``no_ut_min_hits`` and p-value ≥ ``no_ut_pvalue`` (the
   VELO–SciFi match alone must convince: most ghosts had no UT hit). The best accepted
   extension (χ² − miss_penalty·hits) is kept; the search ends at one with p-value ≥
   ``good_pvalue`` and ≥ 11 SciFi hits.
5. **Upstream tracks** (a third pass, `upstream`, after step 6): every long track with UT
   hits takes them; a track without an extension gets the UT search of step 1 again on the
   hits left, and its best UT candidate is returned as an upstream track (STATUS_NO_SCIFI,
   q/p from the kink) after the UT outlier check of step 4 against its VELO + UT fit
   (`ut.clean_upstream`, neighbour cut ``upstream_ambiguous_chi2``); with fewer than 4 UT
   hits left (`upstream.UPSTREAM_MIN_UT_HITS`) or a p-value below ``upstream_pvalue`` it
   stays a VELO track (STATUS_NO_SCIFI, n_ut = 0). A UT hit held by two upstream tracks
   goes to the one with the lower χ²; the other searches again without it.
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

Cost (`benchmarks/pattern_recognition.py`, lhcb-like minimum bias at ν = 7.6, ~330 VELO
tracks per event, one core, this machine): ≈ 20.5 ms per event, ≈ 63 µs per VELO track
(ν = 1: 2.3 ms, 34 µs; the scans' Hough entries and clusters grow with the hit density:
forward time ∝ hits^1.5). Where the cycles go at ν = 7.6 (read-time-stamp counters around
the stages, 50 events): first pass 67 %, second pass 33 %; the UT search with its start
and refits 17 %, the node-state transports of the scans 15 %, the Hough entries and their
sort 21 % (pass 1: 349 scans per event of 204 entries, pass 2: 121 full-range scans of
638), cluster finding and line ranking 9 %, stereo confirmation 9 %, the combinatorial
follow 15 %, the final fits (UT confirmation, fit, UT outlier check) 15 %. What made it
cheap, measured on the same events: the unrolled layer step (`pkf.params.formulas`,
200 → 55 ns), the two passes with taken hits (−35 %), fits through fixed hits as a
straight loop (`_fit_fixed`, −8 %), the stereo requirement before the follow
(``stereo_min_layers``, −5 %), compiling without numba's reference counting
(`pkf.jit.NO_REFCOUNT`, −22 %: the atomic reference-count updates of array views and
inlined helpers' array arguments were 40 % of the CPU samples) and the UT outlier
check's smoother without matrix inverses (`outliers.smooth_ut_chi2`, −11 %, the same
candidates bit for bit), the q/p scans skipping runs of taken hits through links
(`hough.next_free`) with branch-free bisections (`kalman.first_at_least`, the same
candidates) and ``max_clusters`` 3 → 2 (efficiency and ghosts within 0.02 points):
together −1.5 to −3 % of the forward time at ν = 7.6 (19.53 → 19.23 ms on 200 events,
19.70 → 19.16 on 100; interleaved against the previous code), none measurable at
ν = 1; a branch and bound in the combinatorial KF (`search.search`: a branch whose best
possible key cannot rank is not followed; the same candidates bit for bit): SciFi follow
nodes 27.6 → 19.5 per follow in the first pass at ν = 7.6, the pattern step ×0.970 (50
events, 8 rounds side by side against the previous code, every round faster). Issue 18.3's profile (perf with a symbol map of the compiled
kernels, ν = 7.6, 50 events, share of all CPU samples of the pattern step): the scan
driver with its inlined Hough entries 16 % (two thirds the entry loop: the implied q/p,
its Hough coordinate's division, the bin table), the combinatorial KF `search.search`
15 % (a quarter its window bisection and hit loop), the VELO triplet search 7 %, the
node transports (`scan_states` + the UT→SciFi step + its localisation) 10 %, the
stereo confirmation 4 %, `fit_fixed` 4 %, the reference trajectories 3.5 %, the UT
smoother 3 %, the entry sort 2.6 %, the line fits 3.8 %. A quarter of the extensions
at ν = 7.6 (13 % at ν = 1; median p 11 and 26 GeV) are found only by the second pass's
full-range scan, half of them with UT hits in the end (without the second pass the
long efficiency above 5 GeV falls from 96.9 to 74.6 % at ν = 7.6): better UT starts
would move them to the cheap first pass.

The stages live in modules of this package: `options` (options and status codes),
`prepare` (layout, sorted hits, cut tables), `records` (the kernels' NamedTuples),
`kalman` (the filter pieces and the fit through fixed hits), `search` (the combinatorial
KF), `hough` and `lines` (the q/p scan, its clusters and their line and stereo tests),
`scifi` (steps 2–3), `ut` (steps 1 and 4), `outliers` (the UT outlier check of step 4),
`kernel` (the two passes, step 6) and `upstream` (the third pass, step 5).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from pkf.geometry.detector import Geometry
from pkf.params.ut_to_scifi import without_soft_range
from pkf.seeding.csr import CsrTracks
from pkf.seeding.forward.kernel import extend_kernel, new_pass_work, new_work
from pkf.seeding.forward.options import (
    I_QUAD,
    I_UT_CANDIDATES,
    O_MODEL,
    STATUS_INVALID,
    STATUS_NAMES,
    STATUS_NO_SCIFI,
    STATUS_NO_UT,
    STATUS_NOT_FOUND,
    STATUS_OK,
    ForwardOptions,
)
from pkf.seeding.forward.prepare import prepare
from pkf.seeding.forward.records import Inputs, Output, Transport
from pkf.seeding.forward.upstream import upstream_pass

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


@dataclass
class ForwardTracks(CsrTracks):
    """Result of `extend_velo_tracks`, one entry per input VELO track (same order).

    hit_rows[offsets[t]:offsets[t+1]]: rows of the input hit arrays added to track t
    (UT then SciFi, sorted by z); n_ut, n_scifi: how many of each. qop [1/MeV] and
    qop_var: the q/p estimate (at production, docs/physics.md#the-parametrized-fitter) and its variance (NaN if
    none); chi2/ndf of the extension fit (ndf = hits − 1, the VELO state as prior);
    status: STATUS_* (STATUS_NAMES); below_table_p_min: |q/p| > 1/p_min of the
    UT→SciFi table (the parametrized fit returns status 4 there); from_scan: the
    extension was found by the second pass's full-range scan (step 6), not from a UT start;
    ut_chi2 (n, UT layers): the χ² of each UT hit of the extension against the track of
    the VELO, the SciFi and the other UT hits (step 4, `pkf.seeding.forward.outliers`; NaN
    where the layer has no hit).
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
    ut_chi2: np.ndarray

    @property
    def found(self) -> np.ndarray:
        """Tracks extended into the SciFi (status ok or no UT)."""
        return (self.status == STATUS_OK) | (self.status == STATUS_NO_UT)

    @property
    def upstream(self) -> np.ndarray:
        """Tracks without a SciFi extension that keep their best UT candidate (step 5): upstream
        tracks, VELO + ≥ 4 UT hits that passed the UT outlier check, q/p from the VELO→UT kink."""
        return (self.status == STATUS_NO_SCIFI) & (self.n_ut > 0)


def _new_output(n: int, n_fwd: int, n_ut: int) -> Output:
    return Output(
        hits=np.full((n, n_fwd), -1, dtype=np.int64),
        q=np.full(n, np.nan),
        qvar=np.full(n, np.nan),
        chi2=np.full(n, np.nan),
        ndf=np.zeros(n, dtype=np.int64),
        status=np.full(n, STATUS_NOT_FOUND, dtype=np.int64),
        n_ut=np.zeros(n, dtype=np.int64),
        n_scifi=np.zeros(n, dtype=np.int64),
        from_scan=np.zeros(n, dtype=np.bool_),
        ut_chi2=np.full((n, n_ut), np.nan),
    )


def kernel_setup(track_event, velo_state, z_state, hit_event, hit_layer, hit_u, hit_sigma, geometry: Geometry, ext,
                 options: ForwardOptions):
    """The inputs of the forward extension's kernels (arguments as `extend_velo_tracks`):
    the prepared layout, hits and cut tables (`prepare`), and (tr, lay, cfg, w, pw, inputs):
    `Transport`, `Layout`, the option vectors, `Work`, `PassWork` and `Inputs`, or None
    without tracks or events."""
    # The search reads the UT→SciFi table as one of p ≥ p_min (3 GeV) continued below it,
    # as it was tuned: with the soft range 1.5–3 GeV its 2–5 GeV long efficiency at ν = 7.6
    # fell from 95.2 to 93.6 % (benchmarks/pattern_recognition.py, 100 events). The fits
    # use the whole table.
    ext = ext._replace(uts_meta=without_soft_range(ext.uts_meta))
    prep = prepare(track_event, velo_state, z_state, hit_event, hit_layer, hit_u, hit_sigma, geometry, ext, options)
    n = prep.n_tracks
    if not (n and prep.n_events):
        return prep, None
    cfg = prep.cfg
    tr = Transport(
        ext, prep.poly, prep.table_ref, bool(cfg.iopt[I_QUAD] != 0), np.zeros((6, 5, 5)), float(cfg.opt[O_MODEL])
    )
    lay = prep.lay
    pw = new_pass_work(lay.layer.size, lay.n_ut, int(cfg.iopt[I_UT_CANDIDATES]), n, prep.hit_u.size)
    inputs = Inputs(prep.t_ev, prep.state, prep.t_layer, prep.lay_off, prep.hit_u, prep.hit_sigma)
    w = new_work(lay, cfg, prep.max_entries, prep.max_bins, prep.hit_u.size)
    return prep, (tr, lay, cfg, w, pw, inputs)


def extend_velo_tracks(
    track_event,
    velo_state,
    z_state,
    hit_event,
    hit_layer,
    hit_u,
    hit_sigma,
    geometry: Geometry,
    ext,
    options: ForwardOptions | None = None,
    **overrides,
) -> ForwardTracks:
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
    prep, args = kernel_setup(track_event, velo_state, z_state, hit_event, hit_layer, hit_u, hit_sigma, geometry, ext,
                              options)
    n = prep.n_tracks
    out = _new_output(n, prep.lay.layer.size, prep.lay.n_ut)
    if args is not None:
        extend_kernel(*args, out)
        upstream_pass(*args, out, np.full(prep.hit_u.size, -1, dtype=np.int64))
    found = out.hits >= 0
    counts = found.sum(axis=1)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    hit_rows = prep.rows[out.hits[found]] if found.any() else np.zeros(0, dtype=np.int64)
    return ForwardTracks(
        offsets=offsets,
        hit_rows=hit_rows.astype(np.int64),
        n_ut=out.n_ut,
        n_scifi=out.n_scifi,
        qop=out.q,
        qop_var=out.qvar,
        chi2=out.chi2,
        ndf=out.ndf,
        status=out.status,
        below_table_p_min=np.abs(out.q) > 1.0 / prep.p_table,
        from_scan=out.from_scan,
        ut_chi2=out.ut_chi2,
    )
