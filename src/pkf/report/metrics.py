"""Report metrics (docs/physics.md#matching-and-metrics, paper Figs. 1–4): resolutions, pulls, χ²/ndf, B_s mass, efficiency, timing.

:func:`compute_report` takes validated runs (:func:`pkf.report.runs.load_runs`) and
returns a :class:`ReportData`: the machine-readable ``summary`` (written as
``summary.json``) and the per-fitter arrays the plots need.

Conventions
-----------
- Resolutions and pulls are taken at the **first hit** (the paper's "most upstream
  measurement"), for the **long** tracks in the run's ``pulls`` table (fit status ``ok``
  and matched to an MC particle), as in the paper's figures: a VELO-only track has no
  momentum measurement and would fill the δp/p RMS with its prior (:func:`track_types`).
  Pulls are also given per track type (``pulls.by_type``). Each entry uses its own tracks.
- ``rms`` is the root mean square of the values about zero, ``sqrt(mean(v²))``
  (paper Fig. 1: "root mean square of the residual distribution"); ``core_*`` /
  ``mean``, ``width`` come from :func:`pkf.params.gauss.gaussian_core` (iterative
  ±3σ truncated-Gaussian unbinned fits, 3 passes). Bins with fewer than 10 values
  have no core fit (``null``).
- δp/p = (p_fit − p_true)/p_true with p_fit = 1/|qop| of the fitted first-hit state
  (``states``) and p_true from ``pulls`` (the truth the pull was computed against).
- χ²/ndf uses tracks with fit status ``ok``; "real" = matched to an MC particle,
  "ghost" = ``is_ghost``. Cutting at c keeps χ²/ndf < c: real efficiency = kept real
  / real, ghost rejection = removed ghosts / ghosts.
- B_s⁰ → φφ (paper Fig. 4): the peak is built from **all kaon tracks of each event**
  (:mod:`pkf.report.combinatorics`: kaon identification from MC truth since no RICH is
  simulated, K⁺K⁻ pairs in the φ window, two φ with distinct kaons whose beamline points lie
  within a few mm in z), so it sits on combinatorial background; Gaussian + linear
  background, extended unbinned ML in the window (``fit``). Separately, the **truth-matched**
  signal decays: kaons with ``from_signal``, |pdg| = 321, parent φ (333), grand-parent B_s
  (531); each kaon takes the fitted **beamline** state of its matched track (fit ``ok``, not a
  ghost; among clones the highest match fraction, then the lowest track_id); decays whose four
  kaons are long reconstructible particles (paper §5 uses only tracks with measurements in
  every subdetector — a kaon seen in the VELO alone, or VELO + UT, has no usable momentum: 70%
  of those had p_fit < 0.8·p_true, measured on 2000 events). Fitters can lose different
  decays, so ``ratio_to_reference`` compares σ(m) on the *common* truth-matched candidates —
  the same decays with the same kaons — with a jackknife error on the ratio.
- Efficiency: reconstructible long particles of the dataset (docs/physics.md#matching-and-metrics, via
  :func:`pkf.pipeline.matching.reconstructible_particles`); a particle is found by
  a fitter if a track of that fitter with fit status ``ok`` is matched to it; at
  run level (``runs[i].pattern.recomputed``) if any candidate is matched to it
  (the definition of run.json ``pattern``). p and η are the production momentum's.
  Errors are Clopper–Pearson 68.3% intervals.
- Speed-up = tracks_per_s(entry) / tracks_per_s(reference entry), from run.json
  ``timing.fit``; benchmarks/ (docs/physics.md) asks for ratios from one process run on the same
  tracks, so ``same_run_as_reference`` says whether that holds.

Every float is written as a number, or ``null`` where undefined (NaN/inf).

summary.json keys
-----------------
Top level:

- ``kind``: ``"report"``; ``pkf_version``; ``reference``: the entry ``LABEL/FITTER`` that
  ratios and speed-ups compare with (``--reference``; default the first entry of the
  ``reference`` fitter, else the first entry).
- ``entry_order``: entry names ``LABEL/FITTER`` in the order of the runs given and, within a
  run, of run.json ``config.fitters``.
- ``warnings``: one line per problem a reader should know of (runs from different datasets,
  with both content hashes).
- ``settings``: ``resolution_location``, ``pull_location``, ``mass_location``,
  ``p_edges_mev`` (resolution and efficiency bins of p [MeV]), ``eta_edges``,
  ``chi2_ndf_cuts``, ``mass_window_mev`` [lo, hi], ``mass_fit`` (method, text).
- ``runs``: list, one per run directory given, each with ``path``, ``label``, ``dataset``,
  ``dataset_hash`` (run.json ``input.content_hash``),
  ``dataset_status`` (``"ok"`` or why dataset-based metrics are missing),
  ``geometry``, ``pattern_recognition`` (run.json config.pattern), ``fitters``,
  ``events``, ``has_mc``, ``timing`` (run.json timing per stage, without ``fit``),
  ``pattern`` = {``run_json``: run.json ``pattern`` or null, ``recomputed``:
  {``tracks``, ``reconstructible``, ``found``, ``efficiency``, ``ghost_rate``,
  ``clone_rate``} or null}.
- ``entries``: per entry name ``LABEL/FITTER``:

  - ``run``: index into ``runs``; ``label``, ``fitter``.
  - ``tracks``: ``total``, ``ok``, ``failed``, ``matched`` (ok and matched), ``ghost`` (ok and ghost).
  - ``resolution``: ``available``, ``note``, ``location``, ``track_type`` (``long``), ``p_edges_mev``,
    ``variables`` → for each of ``dp_over_p`` (dimensionless), ``x``, ``y`` [mm],
    ``tx``, ``ty`` [rad]: ``unit``, ``all`` = {``n``, ``rms``, ``core_mean``,
    ``core_sigma``, ``core_sigma_error``, ``core_valid``} over all p, and ``bins`` =
    the same keys as lists, one value per p bin; ``ratio_to_reference`` → per
    variable {``rms``, ``core_sigma``} lists (this fitter / reference, per p bin),
    null for the reference itself or without a reference.
  - ``pulls``: ``available``, ``note``, ``location``, ``track_type`` (``long``), ``by_type`` (per
    track type: ``n_tracks`` and the same per-parameter keys), ``parameters`` → for each of
    ``x``, ``y``, ``tx``, ``ty``, ``qop``: ``mean``, ``mean_error``, ``width``,
    ``width_error`` (Gaussian core), ``rms``, ``n`` (finite pulls), ``n_core``
    (within the final ±3σ window), ``fit_converged``, ``core_distance`` (Kolmogorov
    distance of the core from the fitted Gaussian), ``valid`` (converged and a Gaussian
    describes the core, :func:`gaussian_describes_core`).
  - ``chi2``: ``available``, ``note``, ``has_mc``, ``has_ghosts``, ``real``,
    ``ghost``, ``all`` = {``n``, ``mean``, ``median``, ``q90``, ``q99``} (``real`` and
    ``ghost`` null without MC, ``ghost`` null without ghosts), ``cut_scan`` =
    {``cuts``, ``real_efficiency``, ``ghost_rejection`` (null without ghosts); without
    MC instead ``all_efficiency`` (fraction of all tracks kept)}; ``by_type``: per track
    type present (``long``, ``upstream``, ``velo``) the same keys for that type's tracks.
  - ``mass``: ``available``, ``note``, ``location``, ``n_signal_decays`` (B_s in the
    dataset), ``n_long_decays`` (those whose four kaons are long reconstructible),
    ``n_truth_matched`` (long decays with all four kaons fitted), ``n_candidates`` (all-kaon
    candidates in the window), ``n_signal_candidates`` (those made of four signal kaons),
    ``selection`` (the cuts), ``fit`` (on the all-kaon candidates) =
    {``mean``, ``mean_error``, ``sigma``, ``sigma_error``, ``n_signal``,
    ``n_signal_error``, ``n_background``, ``n_background_error``, ``slope``,
    ``n_candidates`` (in the window), ``window``, ``valid``, ``status``} [MeV];
    ``ratio_to_reference``: null for the reference, without a reference or for another
    dataset, else {``candidates`` (what they are), ``n_candidates`` (decays with all four
    kaons fitted by both), ``fit`` and ``reference_fit`` (same keys as ``fit``, on those
    candidates), ``sigma_ratio`` (this σ / reference σ), ``sigma_ratio_error``
    (jackknife), ``error_method``}.
  - ``efficiency``: ``available``, ``note``, ``reconstructible``, ``found``,
    ``efficiency``, ``ghost_rate``, ``clone_rate`` (among this fitter's ok tracks),
    ``p_edges_mev``, ``vs_p`` and ``eta_edges``, ``vs_eta`` = {``reconstructible``,
    ``found``, ``efficiency``, ``error_low``, ``error_high``} lists per bin; ``by_type``:
    per track type (:data:`EFFICIENCY_TYPES`) ``reconstructible_as``, ``found_by``,
    ``reconstructible``, ``found``, ``efficiency``, ``vs_p``, ``vs_eta``.
  - ``timing``: ``available``, ``note``, ``wall_s``, ``cpu_s``, ``tracks``,
    ``tracks_per_s``, ``ns_per_node``, ``speed_up_vs_reference``,
    ``ns_per_node_ratio`` (reference ns/node ÷ this fitter's), ``same_run_as_reference``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import hist
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from scipy.special import ndtr
from scipy.stats import beta

import pkf
from pkf.errors import InputError
from pkf.io.schemas import particle_key
from pkf.params.gauss import gaussian_core
from pkf.report.combinatorics import KAON_PT_MIN, PHI_WINDOW, VERTEX_DZ, combinatorial_bs_masses
from pkf.report.massfit import (
    BS_MASS,
    KAON_MASS,
    MIN_CANDIDATES,
    MassFit,
    fit_mass_peak,
    four_momenta,
    invariant_mass,
)
from pkf.report.runs import REFERENCE_FITTER, RunInput, column, rows_of

__all__ = [
    "P_EDGES_MEV",
    "ETA_EDGES",
    "CHI2_NDF_CUTS",
    "MASS_WINDOW_MEV",
    "RESOLUTION_VARIABLES",
    "PULL_PARAMETERS",
    "FitterArrays",
    "ReportData",
    "compute_report",
    "resolution_summary",
    "pull_summary",
    "chi2_summary",
    "efficiency_in_bins",
    "delta_p_over_p",
]

#: Bins of true momentum [MeV] for resolutions and efficiencies (paper Fig. 1 spans 0–100 GeV).
P_EDGES_MEV = np.array([1, 2, 3, 5, 7, 10, 15, 20, 30, 50, 100], dtype=float) * 1e3
#: Bins of pseudorapidity for efficiencies (the LHCb acceptance, 2 < η < 5).
ETA_EDGES = np.array([2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0])
#: Upper cuts on χ²/ndf for the efficiency / rejection scan (paper Fig. 3).
CHI2_NDF_CUTS = np.round(np.arange(0.5, 10.0001, 0.5), 6)
#: B_s mass fit window [MeV].
MASS_WINDOW_MEV = (BS_MASS - 250.0, BS_MASS + 250.0)
#: Groups of the jackknife error of the σ(m) ratio on common candidates.
MASS_JACKKNIFE_GROUPS = 20

RESOLUTION_LOCATION = "first_hit"
PULL_LOCATION = "first_hit"
MASS_LOCATION = "beamline"
#: Resolution variables and their units.
RESOLUTION_VARIABLES = {"dp_over_p": "", "x": "mm", "y": "mm", "tx": "rad", "ty": "rad"}
PULL_PARAMETERS = ("x", "y", "tx", "ty", "qop")
_KEY = 1 << 32


#: Pull histograms of the plots: 50 bins over [-5, 5) (values outside go to the flow bins).
PULL_HISTOGRAM = (50, -5.0, 5.0)
#: χ²/ndf histograms of the plots: 50 bins over [0, 10), overflow clipped into the last bin.
CHI2_NDF_HISTOGRAM = (50, 0.0, 10.0)


def pull_histogram(values: np.ndarray) -> hist.Hist:
    """The finite pulls in :data:`PULL_HISTOGRAM` bins (what the pull figure draws)."""
    values = np.asarray(values)
    h = hist.Hist(hist.axis.Regular(*PULL_HISTOGRAM, name="pull"))
    h.fill(values[np.isfinite(values)])
    return h


def chi2_ndf_histogram(values: np.ndarray) -> hist.Hist:
    """χ²/ndf values (finite) in :data:`CHI2_NDF_HISTOGRAM` bins, overflow in the last bin."""
    n, lo, hi = CHI2_NDF_HISTOGRAM
    h = hist.Hist(hist.axis.Regular(n, lo, hi, name="chi2ndf"))
    h.fill(np.clip(values, lo, hi - 1e-9))
    return h


@dataclass
class FitterArrays:
    """Per-entry histograms and values the plots need (kept until the plots are drawn, so they
    are histograms, not per-track arrays, except for the few B_s candidates).

    ``pulls``: per pull parameter the histogram of the long tracks' finite first-hit pulls
    (:func:`pull_histogram`); ``pulls_outside``: how many of them have |pull| ≥ 5.
    ``chi2_ndf_real``, ``chi2_ndf_ghost``, ``chi2_ndf_all``: χ²/ndf histograms of the ok
    tracks (:func:`chi2_ndf_histogram`; None when there is no such track);
    ``chi2_ndf_by_type``: per track type present (real, ghost) histograms (without MC:
    (all, None)). A histogram's ``sum()`` is its number of tracks.
    """

    pulls: dict[str, hist.Hist] = field(default_factory=dict)
    pulls_outside: dict[str, int] = field(default_factory=dict)
    chi2_ndf_real: hist.Hist | None = None
    chi2_ndf_ghost: hist.Hist | None = None
    chi2_ndf_all: hist.Hist | None = None
    chi2_ndf_by_type: dict[str, tuple] = field(default_factory=dict)
    masses: np.ndarray = field(default_factory=lambda: np.zeros(0))  # all-kaon B_s candidates (Fig. 4)
    signal_masses: np.ndarray = field(default_factory=lambda: np.zeros(0))  # truth-matched decays
    mass_decays: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # decay index per signal mass
    mass_fit: MassFit | None = None


@dataclass
class ReportData:
    """The report: ``summary`` (summary.json) and per-entry (``LABEL/FITTER``) arrays for the plots."""

    summary: dict
    arrays: dict[str, FitterArrays]

    @property
    def entry_order(self) -> list[str]:
        """Entry names ``LABEL/FITTER`` in the order of the runs given and their fitters."""
        return list(self.summary["entries"])


# ----------------------------------------------------------------------------- helpers


def _f(value) -> float | None:
    """A float for JSON, None when undefined."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _rms(values: np.ndarray) -> float:
    """sqrt(mean(v²)) of the finite values, summed in float64 (also for float32 values)."""
    v = values[np.isfinite(values)].astype(np.float64, copy=False)
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def _core_stats(values: np.ndarray) -> dict:
    core = gaussian_core(values)
    return {
        "n": int(np.isfinite(values).sum()),
        "rms": _f(_rms(values)),
        "core_mean": _f(core.mean),
        "core_sigma": _f(core.sigma),
        "core_sigma_error": _f(core.sigma_error),
        "core_valid": bool(core.valid),
    }


def _track_key(table: pa.Table) -> np.ndarray:
    return column(table, "event_id", np.int64) * _KEY + column(table, "track_id", np.int64)


def lookup_sorted(sorted_keys: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of each key in the sorted key array, and whether it was found."""
    if sorted_keys.size == 0:
        return np.zeros(keys.size, dtype=np.int64), np.zeros(keys.size, dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, keys), sorted_keys.size - 1)
    return pos, sorted_keys[pos] == keys


#: Track types (docs/formats.md chi2.track_type): VELO + UT + SciFi, VELO + UT, VELO only.
TRACK_TYPES = ("long", "upstream", "velo")


def track_types(chi2: pa.Table) -> np.ndarray:
    """The type of each track of a ``chi2`` table (its ``track_type`` column when present).

    Otherwise from the hit counts: ``long`` with SciFi hits, ``upstream`` with UT hits, else
    ``velo``; in a detector without UT and SciFi (a run where no track has such hits, e.g. the
    ``telescope``) every track spans the whole detector and measures its momentum: ``long``.
    """
    if "track_type" in chi2.column_names:
        return np.asarray(chi2.column("track_type").to_pylist(), dtype=object)
    n_ut, n_scifi = column(chi2, "n_ut", np.int64), column(chi2, "n_scifi", np.int64)
    if not (np.any(n_ut > 0) or np.any(n_scifi > 0)):
        return np.full(chi2.num_rows, "long", dtype=object)
    return np.where(n_scifi > 0, "long", np.where(n_ut > 0, "upstream", "velo")).astype(object)


def _types_of(rows: pa.Table, chi2: pa.Table, types: np.ndarray) -> np.ndarray:
    """Track type of each row of ``rows`` (a pulls or states table of one fitter), via (event, track)."""
    keys = _track_key(chi2)
    order = np.argsort(keys, kind="stable")
    pos, found = lookup_sorted(keys[order], _track_key(rows))
    return np.where(found, types[order][pos], "unknown")


def _fit_dict(values: dict) -> dict:
    return {k: _f(v) if isinstance(v, float) else v for k, v in values.items()}


def _section(available: bool, note: str | None = None, **values) -> dict:
    return {"available": available, "note": note, **values}


# ----------------------------------------------------------------------------- resolution and pulls


def delta_p_over_p(pulls: pa.Table, states: pa.Table) -> np.ndarray:
    """δp/p = 1/(p_true·|qop_fit|) − 1 for each row of ``pulls``; qop_fit from the ``states``
    row of the same (event, track, fitter, location). NaN where no state row exists."""
    out = np.full(pulls.num_rows, np.nan)
    if pulls.num_rows == 0:
        return out
    fitters = sorted(set(pulls.column("fitter").to_pylist()))
    locations = sorted(set(pulls.column("location").to_pylist()))
    for fitter in fitters:
        for location in locations:
            mask = (
                pc.and_(pc.equal(pulls.column("fitter"), fitter), pc.equal(pulls.column("location"), location))
                .to_numpy(zero_copy_only=False)
            )
            if not mask.any():
                continue
            st = rows_of(states, fitter, location)
            skey = _track_key(st)
            order = np.argsort(skey, kind="stable")
            pos, found = lookup_sorted(skey[order], _track_key(pulls.filter(pa.array(mask))))
            qop = column(st, "qop")[order][pos]
            p_true = column(pulls, "p_true")[mask]
            out[np.flatnonzero(mask)] = np.where(found, 1.0 / (p_true * np.abs(qop)) - 1.0, np.nan)
    return out


def bin_index(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Index i of the bin [edges[i], edges[i+1]) of each value (int8); -1 below the first edge,
    ``edges.size - 1`` at or above the last one and for NaN (outside every bin)."""
    return (np.searchsorted(edges, np.asarray(values, dtype=float), side="right") - 1).astype(np.int8)


def resolution_summary(p_true: np.ndarray, values: np.ndarray, p_edges: np.ndarray = P_EDGES_MEV) -> dict:
    """RMS and Gaussian core of ``values`` over all tracks and in bins of ``p_true`` [MeV].

    Returns ``{"all": {...}, "bins": {key: [per bin]}}`` with keys ``n``, ``rms``,
    ``core_mean``, ``core_sigma``, ``core_sigma_error``, ``core_valid``. Bins are
    [lo, hi) in p_true.
    """
    return resolution_in_bins(bin_index(p_true, p_edges), values, p_edges.size - 1)


def resolution_in_bins(p_bin: np.ndarray, values: np.ndarray, n_bins: int) -> dict:
    """:func:`resolution_summary` with each value's momentum bin given (:func:`bin_index`):
    the values may be float32 (the report keeps per-track values so); the sums and fits are
    made in float64."""
    bins: dict[str, list] = {k: [] for k in ("n", "rms", "core_mean", "core_sigma", "core_sigma_error", "core_valid")}
    for i in range(n_bins):
        stats = _core_stats(values[p_bin == i])
        for k in bins:
            bins[k].append(stats[k])
    return {"all": _core_stats(values), "bins": bins}


#: Allowance on the Kolmogorov distance for the mild non-Gaussian shape of real pull cores
#: (multiple-scattering tails, mixtures of momenta): measured D = 0.005–0.017 on the pulls of
#: 5,000–6,000 gun and minimum-bias tracks that are Gaussian by eye, 0.15 on GSF q/p pulls whose
#: double peak a single Gaussian does not describe.
CORE_SHAPE_ALLOWANCE = 0.03


def core_shape_distance(values: np.ndarray, mean: float, sigma: float, window: float = 3.0) -> tuple[float, int]:
    """Kolmogorov distance between the values within ``mean ± window·sigma`` and the fitted
    Gaussian truncated to that window; and the number of values in it."""
    x = np.asarray(values, dtype=float)
    if not (np.isfinite(mean) and np.isfinite(sigma) and sigma > 0):
        return float("nan"), 0
    lo, hi = mean - window * sigma, mean + window * sigma
    inside = np.sort(x[(x > lo) & (x < hi)])
    n = inside.size
    if n == 0:
        return float("nan"), 0
    a, b = ndtr(-window), ndtr(window)
    cdf = (ndtr((inside - mean) / sigma) - a) / (b - a)
    rank = np.arange(1, n + 1)
    return float(max(np.max(rank / n - cdf), np.max(cdf - (rank - 1) / n))), int(n)


def gaussian_describes_core(distance: float, n: int) -> bool:
    """Whether a Gaussian describes the core: the Kolmogorov distance is below the 1 % critical
    value for a normal with fitted mean and width (Lilliefors, 1.035/√n) plus
    :data:`CORE_SHAPE_ALLOWANCE`."""
    return bool(n >= 10 and distance < CORE_SHAPE_ALLOWANCE + 1.035 / math.sqrt(n))


def pull_summary(values: np.ndarray) -> dict:
    """Gaussian core (mean, width and their errors), RMS and counts of a pull distribution.

    ``valid`` is true only when the core fit converged *and* a Gaussian describes the core
    (:func:`gaussian_describes_core`; ``core_distance`` is the Kolmogorov distance): a
    double-peaked or flat distribution gets a fitted "width" but ``valid`` false, and the
    figure says so instead of drawing the curve.
    """
    values = np.asarray(values, dtype=float)
    core = gaussian_core(values)
    distance, n_window = core_shape_distance(values[np.isfinite(values)], core.mean, core.sigma)
    return {
        "mean": _f(core.mean),
        "mean_error": _f(core.mean_error),
        "width": _f(core.sigma),
        "width_error": _f(core.sigma_error),
        "rms": _f(_rms(values)),
        "n": int(np.isfinite(values).sum()),
        "n_core": int(core.n),
        "fit_converged": bool(core.valid),
        "core_distance": _f(distance),
        "valid": bool(core.valid) and gaussian_describes_core(distance, n_window),
    }


def _ratio(a: list, b: list) -> list:
    out = []
    for x, y in zip(a, b):
        out.append(_f(x / y) if x is not None and y not in (None, 0.0) else None)
    return out


# ----------------------------------------------------------------------------- χ²/ndf


def _distribution(values: np.ndarray) -> dict | None:
    if values.size == 0:
        return {"n": 0, "mean": None, "median": None, "q90": None, "q99": None}
    q = np.quantile(values, [0.5, 0.9, 0.99])
    return {"n": int(values.size), "mean": _f(values.mean()), "median": _f(q[0]), "q90": _f(q[1]), "q99": _f(q[2])}


def chi2_summary(chi2_ndf: np.ndarray, is_ghost: np.ndarray, has_mc: bool, cuts=CHI2_NDF_CUTS) -> dict:
    """χ²/ndf distributions of real and ghost tracks and the efficiency / rejection scan.

    ``chi2_ndf`` and ``is_ghost`` are per track with fit status ok (non-finite values dropped).
    """
    chi2_ndf = np.asarray(chi2_ndf, dtype=float)
    is_ghost = np.asarray(is_ghost, dtype=bool)
    finite = np.isfinite(chi2_ndf)
    chi2_ndf, is_ghost = chi2_ndf[finite], is_ghost[finite]
    cuts = np.asarray(cuts, dtype=float)
    out = _section(True, None, has_mc=has_mc, has_ghosts=False, all=_distribution(chi2_ndf), real=None, ghost=None)
    scan = {"cuts": cuts.tolist(), "real_efficiency": None, "ghost_rejection": None}
    if not has_mc:
        out["note"] = "no MC truth in this run: real and ghost tracks cannot be told apart"
        scan["all_efficiency"] = [_f(np.mean(chi2_ndf < c)) if chi2_ndf.size else None for c in cuts]
        out["cut_scan"] = scan
        return out
    real, ghost = chi2_ndf[~is_ghost], chi2_ndf[is_ghost]
    out["real"] = _distribution(real)
    scan["real_efficiency"] = [_f(np.mean(real < c)) if real.size else None for c in cuts]
    if ghost.size:
        out["has_ghosts"] = True
        out["ghost"] = _distribution(ghost)
        scan["ghost_rejection"] = [_f(np.mean(ghost >= c)) for c in cuts]
    else:
        out["note"] = "no ghost tracks in this run (e.g. truth pattern recognition): ghost rejection is undefined"
    out["cut_scan"] = scan
    return out


# ----------------------------------------------------------------------------- efficiency


def _clopper_pearson(k: np.ndarray, n: np.ndarray, cl: float = 0.6827) -> tuple[np.ndarray, np.ndarray]:
    alpha = 1.0 - cl
    k, n = np.asarray(k, dtype=float), np.asarray(n, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        lo = np.where(k > 0, beta.ppf(alpha / 2, k, n - k + 1), 0.0)
        hi = np.where(k < n, beta.ppf(1 - alpha / 2, k + 1, n - k), 1.0)
    return lo, hi


def efficiency_in_bins(values: np.ndarray, found: np.ndarray, edges: np.ndarray) -> dict:
    """Efficiency of ``found`` among particles binned in ``values`` ([lo, hi) bins),
    with Clopper–Pearson 68.3% errors (``error_low``/``error_high`` are distances)."""
    return efficiency_of_bins(bin_index(values, edges), found, edges.size - 1)


def efficiency_of_bins(idx: np.ndarray, found: np.ndarray, n_bins: int) -> dict:
    """:func:`efficiency_in_bins` with each particle's bin index given (:func:`bin_index`)."""
    found = np.asarray(found, dtype=bool)
    idx = np.asarray(idx, dtype=np.int64)
    inside = (idx >= 0) & (idx < n_bins)
    n = np.bincount(idx[inside], minlength=n_bins)
    k = np.bincount(idx[inside], weights=found[inside], minlength=n_bins).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        eff = np.where(n > 0, k / np.maximum(n, 1), np.nan)
    lo, hi = _clopper_pearson(k, n)
    return {
        "reconstructible": n.tolist(),
        "found": k.tolist(),
        "efficiency": [_f(e) for e in eff],
        "error_low": [_f(e - a) if n_ > 0 else None for e, a, n_ in zip(eff, lo, n)],
        "error_high": [_f(b - e) if n_ > 0 else None for e, b, n_ in zip(eff, hi, n)],
    }


@dataclass
class DatasetTruth:
    """MC truth of one dataset that the report needs (`pkf.pipeline.report.load_truth` reads it)."""

    status: str  # "ok" or why not available
    n_events: int = 0
    reco_key: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # sorted particle keys
    #: bin of each one's true p in P_EDGES_MEV and of its η in ETA_EDGES (:func:`bin_index`, int8):
    #: all the efficiencies need of them, 2 bytes per particle instead of 16
    reco_p_bin: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    reco_eta_bin: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int8))
    kaon_keys: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int64))  # per B_s decay
    n_bs: int = 0
    kaon_particles: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # sorted, |pdg| = 321
    #: "upstream", "velo" → (sorted keys, p bin, η bin) of the particles reconstructible as that
    #: type (long: reco_key, reco_p_bin, reco_eta_bin)
    by_type: dict = field(default_factory=dict)

    def reconstructible(self, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(sorted keys, p bin, η bin) of the particles reconstructible as ``kind`` (:data:`TRACK_TYPES`)."""
        if kind == "long":
            return self.reco_key, self.reco_p_bin, self.reco_eta_bin
        none = np.zeros(0, dtype=np.int8)
        return self.by_type.get(kind, (np.zeros(0, dtype=np.int64), none, none))


@dataclass
class FoundFlags:
    """Which particles of a sorted key set (``keys``) a track matches, marked part by part:
    one byte per particle, instead of the particle keys of the matched tracks."""

    keys: np.ndarray
    flags: np.ndarray

    @classmethod
    def over(cls, keys: np.ndarray) -> FoundFlags:
        return cls(keys, np.zeros(keys.size, dtype=bool))

    def mark(self, found_keys: np.ndarray) -> None:
        """Flag the particles among ``found_keys`` (keys not in ``keys`` are ignored)."""
        pos, hit = lookup_sorted(self.keys, found_keys)
        self.flags[pos[hit]] = True


def _found_particles(chi2: pa.Table, ok_only: bool) -> np.ndarray:
    mc = column(chi2, "mc_particle_id", np.int64)
    sel = mc > 0
    if ok_only:
        sel &= (pc.equal(chi2.column("status"), "ok")).to_numpy(zero_copy_only=False)
    return np.unique(particle_key(column(chi2, "event_id", np.int64)[sel], mc[sel]))


def _efficiency_section(truth: DatasetTruth, tracks_of: EntryTracks, has_mc: bool) -> dict:
    if not has_mc:
        return _section(False, "no MC truth in this run")
    if truth.status != "ok":
        return _section(False, truth.status)
    found = tracks_of.found_ok.flags
    ghost_rate, clone_rate = _rates_of_counts(tracks_of.rates_ok)
    n = int(truth.reco_key.size)
    by_type = _efficiency_by_type(truth, tracks_of)
    return _section(
        True,
        None if n else "no reconstructible particle in the dataset",
        reconstructible=n,
        found=int(found.sum()),
        efficiency=_f(found.mean()) if n else None,
        ghost_rate=ghost_rate,
        clone_rate=clone_rate,
        p_edges_mev=P_EDGES_MEV.tolist(),
        vs_p=efficiency_of_bins(truth.reco_p_bin, found, P_EDGES_MEV.size - 1),
        eta_edges=ETA_EDGES.tolist(),
        vs_eta=efficiency_of_bins(truth.reco_eta_bin, found, ETA_EDGES.size - 1),
        by_type=by_type,
    )


#: Per track type: the particles counted (reconstructible as that type, docs/physics.md#matching-and-metrics)
#: and the ok tracks that find one (a long track also carries the particle's upstream segment).
EFFICIENCY_TYPES = {
    "long": ("≥ 3 VELO hits and an x and a stereo hit in every SciFi station", ("long",)),
    "upstream": ("≥ 3 VELO hits and ≥ 3 UT hits", ("upstream", "long")),
    "velo": ("≥ 3 VELO hits", TRACK_TYPES),
}


def _efficiency_by_type(truth: DatasetTruth, tracks_of: EntryTracks) -> dict:
    """Efficiency vs p and η per track type (:data:`EFFICIENCY_TYPES`); a type without
    reconstructible particles in the dataset is left out."""
    out = {}
    for kind, (reconstructible, found_by) in EFFICIENCY_TYPES.items():
        keys, p_bin, eta_bin = truth.reconstructible(kind)
        if keys.size == 0:
            continue
        # a run without track_type on a detector without UT and SciFi: every track is long
        sources = TRACK_TYPES if tracks_of.every_track_long else found_by
        found = np.logical_or.reduce([tracks_of.found_by_type[t][kind].flags for t in sources])
        out[kind] = {
            "reconstructible_as": reconstructible,
            "found_by": list(found_by),
            "reconstructible": int(keys.size),
            "found": int(found.sum()),
            "efficiency": _f(found.mean()),
            "vs_p": efficiency_of_bins(p_bin, found, P_EDGES_MEV.size - 1),
            "vs_eta": efficiency_of_bins(eta_bin, found, ETA_EDGES.size - 1),
        }
    return out


# ----------------------------------------------------------------------------- B_s mass


def long_decays(truth: DatasetTruth) -> np.ndarray:
    """Per signal decay (row of ``truth.kaon_keys``): are its four kaons long reconstructible
    particles (docs/physics.md#matching-and-metrics: ≥ 3 VELO hits, an x and a stereo hit in every SciFi station)?"""
    return np.isin(truth.kaon_keys, truth.reco_key).all(axis=1)


def _best_track_per_particle(chi2_ok: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """(particle keys sorted, track key of each): the matched, non-ghost track of each particle;
    among clones the highest match fraction, then the lowest track key."""
    ghost = column(chi2_ok, "is_ghost", bool)
    mc = column(chi2_ok, "mc_particle_id", np.int64)
    sel = ~ghost & (mc > 0)
    ev = column(chi2_ok, "event_id", np.int64)[sel]
    pkey = particle_key(ev, mc[sel])
    tkey = ev * _KEY + column(chi2_ok, "track_id", np.int64)[sel]
    frac = column(chi2_ok, "match_fraction")[sel]
    order = np.lexsort((tkey, -frac, pkey))
    pkey, tkey = pkey[order], tkey[order]
    first = np.r_[True, pkey[1:] != pkey[:-1]] if pkey.size else np.zeros(0, dtype=bool)
    return pkey[first], tkey[first]


def all_kaon_bs_masses(truth: DatasetTruth, chi2_ok: pa.Table, states: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """B_s candidate masses [MeV] from all kaon tracks of each event (kaon identification from MC
    truth; :mod:`pkf.report.combinatorics`), and whether each candidate's four kaons are signal kaons.
    ``states`` holds the beamline states of one fitter."""
    pkey, tkey = _best_track_per_particle(chi2_ok)
    kpos, is_kaon = lookup_sorted(truth.kaon_particles, pkey)
    tkey, pkey = tkey[is_kaon], pkey[is_kaon]
    skey = _track_key(states)
    sorder = np.argsort(skey, kind="stable")
    spos, found = lookup_sorted(skey[sorder], tkey)
    rows, pkey = sorder[spos][found], pkey[found]
    signal = np.isin(pkey, truth.kaon_keys.reshape(-1))
    return combinatorial_bs_masses(column(states, "event_id", np.int64)[rows], column(states, "qop")[rows],
                                   column(states, "tx")[rows], column(states, "ty")[rows],
                                   column(states, "z")[rows], signal)


def bs_kaon_state_rows(truth: DatasetTruth, chi2_ok: pa.Table, states: pa.Table,
                       long_only: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``states`` of the four kaons of each signal decay whose four kaons have a
    fitted, matched track: (decay index into ``truth.kaon_keys`` (n,), rows (n, 4) in the
    order of ``truth.kaon_keys``). Among clones the track with the highest match fraction,
    then the lowest track key, is taken. With ``long_only`` only decays whose four kaons are
    long reconstructible particles (`long_decays`; paper §5: "only tracks with
    measurements in each of the subdetectors are considered")."""
    none = (np.zeros(0, dtype=np.int64), np.zeros((0, 4), dtype=np.int64))
    if truth.kaon_keys.shape[0] == 0:
        return none
    pkey, tkey = _best_track_per_particle(chi2_ok)
    kaons = truth.kaon_keys.reshape(-1)
    kpos, kfound = lookup_sorted(pkey, kaons)
    track = tkey[kpos]
    skey = _track_key(states)
    sorder = np.argsort(skey, kind="stable")
    spos, sfound = lookup_sorted(skey[sorder], track)
    have = (kfound & sfound).reshape(-1, 4).all(axis=1)
    if long_only:
        have &= long_decays(truth)
    if not have.any():
        return none
    return np.flatnonzero(have), sorder[spos].reshape(-1, 4)[have]


def _bs_masses(truth: DatasetTruth, chi2_ok: pa.Table, states: pa.Table) -> tuple[np.ndarray, np.ndarray]:
    """Four-kaon masses [MeV] of the signal decays whose four kaons have a fitted track, and
    the index of each decay in ``truth.kaon_keys`` (the same decay in every fitter's list)."""
    decays, rows = bs_kaon_state_rows(truth, chi2_ok, states)
    if decays.size == 0:
        return np.zeros(0), decays
    rows = rows.reshape(-1)
    mom = four_momenta(column(states, "qop")[rows], column(states, "tx")[rows], column(states, "ty")[rows],
                       KAON_MASS)
    return invariant_mass(mom.reshape(-1, 4, 4)), decays


def _mass_sigma(masses: np.ndarray) -> float:
    fit = fit_mass_peak(masses, MASS_WINDOW_MEV)
    return fit.sigma if fit.valid else float("nan")


def mass_ratio_on_common_candidates(masses: np.ndarray, reference_masses: np.ndarray,
                                    groups: int = MASS_JACKKNIFE_GROUPS) -> dict:
    """σ(m) of two fitters on the *same* B_s candidates and their ratio (paper Fig. 4).

    ``masses`` and ``reference_masses`` are the four-kaon masses [MeV] of the same decays,
    in the same order. Each is fitted with :func:`~pkf.report.massfit.fit_mass_peak`; the
    two σ are strongly correlated (same decays, same kaons), so the ratio's error comes
    from a delete-one-group jackknife over the candidates (``groups`` groups by position,
    i mod groups): var = (G−1)/G·Σ(r_g − r̄)². Returns ``n_candidates``, ``fit`` and
    ``reference_fit`` (MassFit dicts), ``sigma_ratio`` (NaN unless both fits reach a
    valid minimum), ``sigma_ratio_error`` (NaN with fewer than max(groups,
    4·MIN_CANDIDATES) candidates or a failed jackknife fit), ``jackknife_groups``.
    """
    masses = np.asarray(masses, dtype=float)
    reference_masses = np.asarray(reference_masses, dtype=float)
    fit = fit_mass_peak(masses, MASS_WINDOW_MEV)
    ref = fit_mass_peak(reference_masses, MASS_WINDOW_MEV)
    # a valid minimum suffices for σ (a background yield at its limit 0 makes the
    # covariance "not accurate" without affecting σ; the fits keep their own status)
    ratio = fit.sigma / ref.sigma if fit.valid and ref.valid else float("nan")
    error = float("nan")
    n = masses.size
    if math.isfinite(ratio) and n >= max(groups, 4 * MIN_CANDIDATES):
        label = np.arange(n) % groups
        values = np.array([_mass_sigma(masses[label != g]) / _mass_sigma(reference_masses[label != g])
                           for g in range(groups)])
        if np.all(np.isfinite(values)):
            error = math.sqrt((groups - 1) / groups * np.sum((values - values.mean()) ** 2))
    return {"n_candidates": int(n), "fit": fit.as_dict(), "reference_fit": ref.as_dict(),
            "sigma_ratio": ratio, "sigma_ratio_error": error, "jackknife_groups": groups}


def _mass_comparison(mine: FitterArrays, reference: FitterArrays) -> dict:
    """`mass_ratio_on_common_candidates` on the decays both fitters have a candidate for."""
    common, i, j = np.intersect1d(mine.mass_decays, reference.mass_decays, return_indices=True)
    result = mass_ratio_on_common_candidates(mine.signal_masses[i], reference.signal_masses[j])
    return {
        "candidates": "B_s decays with four long kaons that both fitters fitted (the same decays, the same kaons)",
        "n_candidates": result["n_candidates"],
        "fit": _fit_dict(result["fit"]),
        "reference_fit": _fit_dict(result["reference_fit"]),
        "sigma_ratio": _f(result["sigma_ratio"]),
        "sigma_ratio_error": _f(result["sigma_ratio_error"]),
        "error_method": f"delete-one-group jackknife, {result['jackknife_groups']} groups",
    }


# ----------------------------------------------------------------------------- timing


def _timing_section(run: RunInput, name: str) -> dict:
    fit = ((run.info.get("timing") or {}).get("fit") or {}).get(name)
    if not isinstance(fit, dict):
        return _section(False, f"run.json of {run.path} has no timing.fit.{name}")
    keys = ("wall_s", "cpu_s", "tracks", "tracks_per_s", "ns_per_node")
    values = {}
    for k in keys:
        v = fit.get(k)
        values[k] = _f(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None
    if values["tracks"] is not None:
        values["tracks"] = int(values["tracks"])
    return _section(True, None, **values, speed_up_vs_reference=None, ns_per_node_ratio=None,
                    same_run_as_reference=None)


# ----------------------------------------------------------------------------- main entry


_PULL_COLUMNS = tuple(f"pull_{p}" for p in PULL_PARAMETERS)
_FIRST_COLUMNS = (*(f"res_{v}" for v in ("x", "y", "tx", "ty")), *_PULL_COLUMNS)
#: What the report keeps per first-hit pull row of a long track: the bin of p_true in
#: P_EDGES_MEV (int8) and the residuals, pulls and δp/p as float32 (relative rounding 6e-8,
#: far below the statistical errors of their RMS and core fits, which are made in float64).
_ALL_FIRST_COLUMNS = ("p_bin", *_FIRST_COLUMNS, "dp_over_p")
_KAON_CHI2_COLUMNS = ("event_id", "track_id", "mc_particle_id", "match_fraction", "is_ghost")
_KAON_STATE_COLUMNS = ("event_id", "track_id", "qop", "tx", "ty", "z")


def _type_codes(types: np.ndarray) -> np.ndarray:
    """Index into TRACK_TYPES of each track type name (int8)."""
    codes = np.zeros(types.size, dtype=np.int8)
    for i, kind in enumerate(TRACK_TYPES[1:], start=1):
        codes[types == kind] = i
    return codes


def _rate_counts(chi2: pa.Table) -> np.ndarray:
    """(tracks, ghosts, real, distinct real particles) of a chi2 table's rows: they add up over
    parts of whole events (particle keys hold the event)."""
    ghost = column(chi2, "is_ghost", bool)
    mc = column(chi2, "mc_particle_id", np.int64)
    real = particle_key(column(chi2, "event_id", np.int64)[~ghost], mc[~ghost])
    return np.array([chi2.num_rows, int(ghost.sum()), real.size, np.unique(real).size], dtype=np.int64)


def _rates_of_counts(counts: np.ndarray) -> tuple[float | None, float | None]:
    """Ghost rate and clone rate (docs/physics.md#matching-and-metrics) from summed :func:`_rate_counts`."""
    n, ghosts, real, unique_real = (int(c) for c in counts)
    if n == 0:
        return None, None
    return _f(ghosts / n), (_f((real - unique_real) / real) if real else None)


@dataclass
class EntryTracks:
    """What the report keeps of one entry's (run, fitter) tracks, gathered part by part of the
    run (:meth:`~pkf.report.runs.RunInput.partitions`), so that memory grows with the few values
    kept per track rather than with the run tables: counts; χ²/ndf and the ghost flag of the ok
    tracks; the particles found; the first-hit pull rows (with δp/p and the track type); for the
    B_s mass the ok tracks matched to kaons and their beamline states. The lists hold one
    array per part, in the run's order (the order of the rows of the whole tables).
    """

    fitter: str
    #: the dataset's MC truth (its reconstructible particles are flagged as found part by part)
    truth: DatasetTruth = field(default_factory=lambda: DatasetTruth("no MC truth"))
    total: int = 0
    chi2_ndf: list = field(default_factory=list)  # ok tracks
    ghost: list = field(default_factory=list)  # ok tracks
    chi2_type: list = field(default_factory=list)  # ok tracks: index into TRACK_TYPES (int8)
    #: long reconstructible particles matched by an ok track / by any track
    found_ok: FoundFlags = field(init=False)
    found_any: FoundFlags = field(init=False)
    #: track type of the ok track → kind of reconstructible particle → flags of those it matches
    found_by_type: dict = field(init=False)
    rates_ok: np.ndarray = field(default_factory=lambda: np.zeros(4, dtype=np.int64))
    rates_any: np.ndarray = field(default_factory=lambda: np.zeros(4, dtype=np.int64))
    # first-hit pull rows per track type: every column for long tracks (resolution and pulls),
    # the pulls alone for the other types (their pull summaries); "unknown" rows are not kept
    first: dict = field(default_factory=lambda: {kind: {c: [] for c in _ALL_FIRST_COLUMNS} for kind in TRACK_TYPES})
    kaon_chi2: list = field(default_factory=list)
    kaon_states: list = field(default_factory=list)
    explicit_types: bool = False  # chi2 has a track_type column
    spans_detector: bool = False  # some track has UT or SciFi hits (else every track is long)

    def __post_init__(self):
        self.found_ok = FoundFlags.over(self.truth.reco_key)
        self.found_any = FoundFlags.over(self.truth.reco_key)
        self.found_by_type = {track: {kind: FoundFlags.over(self.truth.reconstructible(kind)[0])
                                      for kind in TRACK_TYPES} for track in TRACK_TYPES}

    def add(self, chi2: pa.Table, states: pa.Table, pulls: pa.Table | None,
            kaon_particles: np.ndarray | None) -> None:
        """Add one part's rows of this fitter (``kaon_particles``: sorted particle keys of the
        dataset's kaons when the mass is made, else None)."""
        ok = pc.equal(chi2.column("status"), "ok")
        chi2_ok = chi2.filter(ok)
        types = self._part_types(chi2)
        self.total += chi2.num_rows
        self.chi2_ndf.append(column(chi2_ok, "chi2_ndf"))
        self.ghost.append(column(chi2_ok, "is_ghost", bool))
        ok_types = types[ok.to_numpy(zero_copy_only=False)]
        self.chi2_type.append(_type_codes(ok_types))
        for track in TRACK_TYPES:
            found = _found_particles(chi2_ok.filter(pa.array(ok_types == track)), ok_only=False)
            for flags in self.found_by_type[track].values():
                flags.mark(found)
        self.found_ok.mark(_found_particles(chi2_ok, ok_only=True))
        self.found_any.mark(_found_particles(chi2, ok_only=False))
        self.rates_ok += _rate_counts(chi2_ok)
        self.rates_any += _rate_counts(chi2)
        if pulls is not None:
            self._add_first_hit(chi2, states, pulls, types)
        if kaon_particles is not None:
            self._add_kaons(chi2_ok, states, kaon_particles)

    def _part_types(self, chi2: pa.Table) -> np.ndarray:
        """Track type of each row of one part's chi2 rows: its ``track_type`` column, else from
        the hit counts (a run without UT and SciFi hits is relabelled ``long`` at the end)."""
        if "track_type" in chi2.column_names:
            self.explicit_types = True
            return track_types(chi2)
        n_ut, n_scifi = column(chi2, "n_ut", np.int64), column(chi2, "n_scifi", np.int64)
        self.spans_detector |= bool(np.any(n_ut > 0) or np.any(n_scifi > 0))
        return np.where(n_scifi > 0, "long", np.where(n_ut > 0, "upstream", "velo")).astype(object)

    @property
    def every_track_long(self) -> bool:
        """No track_type column and no track with UT or SciFi hits (e.g. the telescope): every
        track spans the whole detector and measures its momentum."""
        return not self.explicit_types and not self.spans_detector

    def _add_first_hit(self, chi2: pa.Table, states: pa.Table, pulls: pa.Table, types: np.ndarray) -> None:
        first = rows_of(pulls, self.fitter, RESOLUTION_LOCATION)
        kinds = _types_of(first, chi2, types)
        values = {name: column(first, name, np.float32) for name in _FIRST_COLUMNS}
        values["dp_over_p"] = delta_p_over_p(first, states).astype(np.float32)
        values["p_bin"] = bin_index(column(first, "p_true"), P_EDGES_MEV)
        # without track_type and with no UT/SciFi hit so far every track may turn out to be long
        # (first_hit): its "velo" rows keep every column until then
        maybe_long = {"long", "velo"} if self.every_track_long else {"long"}
        for kind in TRACK_TYPES:
            rows = kinds == kind
            if rows.any():
                for name in _ALL_FIRST_COLUMNS if kind in maybe_long else _PULL_COLUMNS:
                    self.first[kind][name].append(values[name][rows])

    def _add_kaons(self, chi2_ok: pa.Table, states: pa.Table, kaon_particles: np.ndarray) -> None:
        """The ok tracks matched to kaons (all the mass needs of chi2: the best track of each
        particle is chosen among that particle's tracks) and their beamline states."""
        keys = particle_key(column(chi2_ok, "event_id", np.int64), column(chi2_ok, "mc_particle_id", np.int64))
        kaon = chi2_ok.filter(pa.array(lookup_sorted(kaon_particles, keys)[1])).select(list(_KAON_CHI2_COLUMNS))
        beamline = rows_of(states, self.fitter, MASS_LOCATION)
        wanted = np.sort(_track_key(kaon))
        self.kaon_chi2.append(kaon)
        self.kaon_states.append(beamline.filter(pa.array(lookup_sorted(wanted, _track_key(beamline))[1]))
                                .select(list(_KAON_STATE_COLUMNS)))

    def first_hit(self) -> dict[str, dict[str, np.ndarray]]:
        """The first-hit pull rows per track type, in the run's row order: for ``long`` the
        columns p_bin (bin of p_true in P_EDGES_MEV), res_*, pull_*, dp_over_p (float32); for
        ``upstream`` and ``velo`` the pull_* columns. Consumes the parts (one column's parts and its concatenation in memory at a time)."""
        first, self.first = self.first, {}
        if self.every_track_long:  # e.g. the telescope
            first["long"] = first.pop("velo")  # (no "long" or "upstream" row without UT/SciFi hits)
            first["velo"] = {}
        by_type = {}
        for kind in TRACK_TYPES:
            wanted = _ALL_FIRST_COLUMNS if kind == "long" else _PULL_COLUMNS
            by_type[kind] = {}
            for name in wanted:
                parts = first[kind].pop(name, [])
                empty = np.zeros(0, dtype=np.int8 if name == "p_bin" else np.float32)
                by_type[kind][name] = np.concatenate(parts) if parts else empty
                del parts
        return by_type

    def ok_tracks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """χ²/ndf, is_ghost and track type (index into TRACK_TYPES) of the ok tracks (consumes the parts)."""
        chi2_ndf = np.concatenate(self.chi2_ndf) if self.chi2_ndf else np.zeros(0)
        ghost = np.concatenate(self.ghost) if self.ghost else np.zeros(0, dtype=bool)
        types = np.concatenate(self.chi2_type) if self.chi2_type else np.zeros(0, dtype=np.int8)
        if self.every_track_long:
            types[:] = TRACK_TYPES.index("long")
        self.chi2_ndf, self.ghost, self.chi2_type = [], [], []
        return chi2_ndf, ghost, types

    def kaon_tables(self) -> tuple[pa.Table, pa.Table]:
        """(ok tracks matched to kaons, their beamline states)."""
        return pa.concat_tables(self.kaon_chi2), pa.concat_tables(self.kaon_states)


def _kaon_particles(run: RunInput, truth: DatasetTruth) -> np.ndarray | None:
    """The dataset's kaon particle keys when the run's B_s mass is made, else None."""
    return truth.kaon_particles if run.has_mc and truth.status == "ok" and truth.n_bs > 0 else None


def read_entries(run: RunInput, truth: DatasetTruth, progress=None) -> dict[str, EntryTracks]:
    """Each fitter's :class:`EntryTracks`, reading the run one part (partition) at a time.

    progress: called with the number of events of each part read (run.json ``partitions``).
    """
    entries = {name: EntryTracks(name, truth) for name in run.fitters}
    kaons = _kaon_particles(run, truth)
    events_of = {p.get("name"): p.get("events", 0) for p in run.info.get("partitions") or []
                 if isinstance(p, dict)}
    for part in run.partitions():
        chi2, states, pulls = run.read_part(part)
        for name, entry in entries.items():
            entry.add(rows_of(chi2, name), states, pulls, kaons)
        if progress is not None:
            stem = Path(part["chi2"]).stem
            progress(events_of.get(stem, 0) if len(events_of) > 1 else sum(events_of.values()))
    return entries


def _fitter_report(run: RunInput, run_index: int, name: str, truth: DatasetTruth,
                   tracks_of: EntryTracks) -> tuple[dict, FitterArrays]:
    arrays = FitterArrays()
    chi2_ndf, ghost_ok, type_ok = tracks_of.ok_tracks()
    tracks = {
        "total": tracks_of.total,
        "ok": int(chi2_ndf.size),
        "failed": tracks_of.total - int(chi2_ndf.size),
        "matched": int((~ghost_ok).sum()) if run.has_mc else None,
        "ghost": int(ghost_ok.sum()) if run.has_mc else None,
    }

    # resolution and pulls at the first hit (Figs. 1, 2), long tracks as in the paper
    if not run.has_pulls:
        note = f"no MC truth in run {run.path} (no pulls table)"
        resolution = _section(False, note, location=RESOLUTION_LOCATION)
        pulls = _section(False, note, location=PULL_LOCATION)
    else:
        first = tracks_of.first_hit()
        long = first["long"]
        empty = long["p_bin"].size == 0
        note = "no matched long track with a fitted first-hit state" if empty else None
        residual = {"dp_over_p": "dp_over_p", **{var: f"res_{var}" for var in ("x", "y", "tx", "ty")}}
        resolution = _section(
            not empty, note, location=RESOLUTION_LOCATION, track_type="long", p_edges_mev=P_EDGES_MEV.tolist(),
            variables={var: {"unit": unit, **resolution_in_bins(long["p_bin"], long[residual[var]],
                                                                 P_EDGES_MEV.size - 1)}
                       for var, unit in RESOLUTION_VARIABLES.items()},
            ratio_to_reference=None,
        )
        for par in PULL_PARAMETERS:
            values = long[f"pull_{par}"]
            arrays.pulls[par] = pull_histogram(values)
            arrays.pulls_outside[par] = int(np.sum(np.abs(values[np.isfinite(values)]) >= 5))
        by_type = {}
        for kind in TRACK_TYPES:
            n_tracks = first[kind]["pull_x"].size
            if n_tracks:
                by_type[kind] = {"n_tracks": int(n_tracks),
                                 **{par: pull_summary(first[kind][f"pull_{par}"]) for par in PULL_PARAMETERS}}
        pulls = _section(not empty, note, location=PULL_LOCATION, track_type="long",
                         parameters={par: pull_summary(long[f"pull_{par}"]) for par in PULL_PARAMETERS},
                         by_type=by_type)
        del first, long

    # χ²/ndf (Fig. 3)
    chi2_section = chi2_summary(chi2_ndf, ghost_ok, run.has_mc)
    finite = np.isfinite(chi2_ndf)
    arrays.chi2_ndf_all = _chi2_ndf_histogram_or_none(chi2_ndf[finite])
    if run.has_mc:
        arrays.chi2_ndf_real = _chi2_ndf_histogram_or_none(chi2_ndf[~ghost_ok & finite])
        arrays.chi2_ndf_ghost = _chi2_ndf_histogram_or_none(chi2_ndf[ghost_ok & finite])
    chi2_section["by_type"] = {}
    for i, kind in enumerate(TRACK_TYPES):
        rows = type_ok == i
        if rows.any():
            chi2_section["by_type"][kind] = chi2_summary(chi2_ndf[rows], ghost_ok[rows], run.has_mc)
            values, ghost, kept = chi2_ndf[rows], ghost_ok[rows], finite[rows]
            arrays.chi2_ndf_by_type[kind] = (
                (_chi2_ndf_histogram_or_none(values[kept & ~ghost]), _chi2_ndf_histogram_or_none(values[kept & ghost]))
                if run.has_mc else (_chi2_ndf_histogram_or_none(values[kept]), None))
    del type_ok, finite

    # B_s mass (Fig. 4)
    if not run.has_mc:
        mass = _section(False, "no MC truth in this run", location=MASS_LOCATION)
    elif truth.status != "ok":
        mass = _section(False, truth.status, location=MASS_LOCATION)
    elif truth.n_bs == 0:
        mass = _section(False, "the dataset has no B_s⁰ → φφ signal decay (generator bs2phiphi or pythia)",
                        location=MASS_LOCATION, n_signal_decays=0)
    else:
        kaon_chi2, states = tracks_of.kaon_tables()
        arrays.signal_masses, arrays.mass_decays = _bs_masses(truth, kaon_chi2, states)
        arrays.masses, signal = all_kaon_bs_masses(truth, kaon_chi2, states)
        arrays.mass_fit = fit_mass_peak(arrays.masses, MASS_WINDOW_MEV)
        lo, hi = MASS_WINDOW_MEV
        in_window = (arrays.masses > lo) & (arrays.masses < hi)
        mass = _section(
            arrays.mass_fit.status == "ok", None if arrays.mass_fit.status == "ok" else arrays.mass_fit.status,
            location=MASS_LOCATION, n_signal_decays=truth.n_bs,
            n_long_decays=int(long_decays(truth).sum()), n_truth_matched=int(arrays.signal_masses.size),
            n_candidates=int(in_window.sum()), n_signal_candidates=int((in_window & signal).sum()),
            selection={"kaon_pt_min_mev": KAON_PT_MIN, "phi_window_mev": PHI_WINDOW, "vertex_dz_mm": VERTEX_DZ,
                       "kaon_id": "MC truth (|pdg| = 321; no RICH is simulated)"},
            fit=_fit_dict(arrays.mass_fit.as_dict()), ratio_to_reference=None,
        )

    report = {
        "run": run_index,
        "label": run.label,
        "fitter": name,
        "tracks": tracks,
        "resolution": resolution,
        "pulls": pulls,
        "chi2": chi2_section,
        "mass": mass,
        "efficiency": _efficiency_section(truth, tracks_of, run.has_mc),
        "timing": _timing_section(run, name),
    }
    return report, arrays


def _chi2_ndf_histogram_or_none(values: np.ndarray) -> hist.Hist | None:
    return chi2_ndf_histogram(values) if values.size else None


def _run_summary(run: RunInput, truth: DatasetTruth | None, first_fitter: EntryTracks) -> dict:
    config = run.info.get("config") or {}
    counts = run.info.get("counts") or {}
    timing = {k: v for k, v in (run.info.get("timing") or {}).items() if k != "fit"}
    recomputed = None
    if run.has_mc and truth is not None and truth.status == "ok":
        # candidate level: every fitter's chi2 rows list all candidates; take the first fitter's
        found = first_fitter.found_any.flags
        ghost_rate, clone_rate = _rates_of_counts(first_fitter.rates_any)
        recomputed = {
            "tracks": first_fitter.total,
            "reconstructible": int(truth.reco_key.size),
            "found": int(found.sum()),
            "efficiency": _f(found.mean()) if found.size else None,
            "ghost_rate": ghost_rate,
            "clone_rate": clone_rate,
        }
    return {
        "path": str(run.path),
        "label": run.label,
        "dataset": str(run.dataset_path) if run.dataset_path else None,
        "dataset_hash": (run.info.get("input") or {}).get("content_hash"),
        "dataset_status": truth.status if truth is not None else "no MC truth in this run",
        "geometry": (run.info.get("input") or {}).get("geometry"),
        "pattern_recognition": config.get("pattern"),
        "fitters": list(run.fitters),
        "events": counts.get("events"),
        "has_mc": run.has_mc,
        "timing": timing,
        "pattern": {"run_json": run.info.get("pattern"), "recomputed": recomputed},
    }


def choose_reference(runs: list[RunInput], reference: str | None) -> str:
    """The entry that ratios and speed-ups compare with.

    ``reference`` is ``LABEL/FITTER`` or ``LABEL`` (then that run's ``reference`` fitter if it
    has one, else its first). Without it: the first entry whose fitter is the paper's
    baseline (``reference``), else the first entry.

    Raises:
        InputError: ``reference`` names no entry.
    """
    entries = [run.entry(name) for run in runs for name in run.fitters]
    if reference is None:
        baseline = [run.entry(REFERENCE_FITTER) for run in runs if REFERENCE_FITTER in run.fitters]
        return baseline[0] if baseline else entries[0]
    if reference in entries:
        return reference
    for run in runs:
        if run.label == reference:
            return run.entry(REFERENCE_FITTER if REFERENCE_FITTER in run.fitters else run.fitters[0])
    raise InputError(f"--reference {reference}: no such entry (entries: {', '.join(entries)})")


def dataset_warnings(runs: list[RunInput]) -> list[str]:
    """One line when the runs come from different datasets (their content hashes differ)."""
    hashes = {run.label: (run.info.get("input") or {}).get("content_hash") for run in runs}
    if len(set(hashes.values())) <= 1:
        return []
    shown = ", ".join(f"{label} {h or 'unknown'}" for label, h in hashes.items())
    return [f"report: the runs come from different datasets (content hashes: {shown}); "
            "efficiencies and resolutions compare different events"]


def _compare_with_reference(entries: dict[str, dict], arrays: dict[str, FitterArrays], reference: str,
                            dataset_of: dict[str, object]) -> None:
    """Fill each entry's ``ratio_to_reference`` and speed-up fields against the reference entry."""
    ref = entries[reference]
    ref_timing = ref["timing"]
    for name, rep in entries.items():
        if name == reference:
            continue
        if rep["resolution"]["available"] and ref["resolution"]["available"]:
            rep["resolution"]["ratio_to_reference"] = {
                var: {
                    key: _ratio(rep["resolution"]["variables"][var]["bins"][key],
                                ref["resolution"]["variables"][var]["bins"][key])
                    for key in ("rms", "core_sigma")
                }
                for var in RESOLUTION_VARIABLES
            }
        if (rep["mass"].get("available") and ref["mass"].get("available")
                and dataset_of[name] is not None and dataset_of[name] == dataset_of[reference]):
            rep["mass"]["ratio_to_reference"] = _mass_comparison(arrays[name], arrays[reference])
        timing = rep["timing"]
        if timing["available"] and ref_timing["available"]:
            if timing["tracks_per_s"] and ref_timing["tracks_per_s"]:
                timing["speed_up_vs_reference"] = _f(timing["tracks_per_s"] / ref_timing["tracks_per_s"])
            if timing["ns_per_node"] and ref_timing["ns_per_node"]:
                timing["ns_per_node_ratio"] = _f(ref_timing["ns_per_node"] / timing["ns_per_node"])
            timing["same_run_as_reference"] = rep["run"] == ref["run"]
    if ref_timing["available"]:
        ref_timing["speed_up_vs_reference"] = 1.0 if ref_timing["tracks_per_s"] else None
        ref_timing["ns_per_node_ratio"] = 1.0 if ref_timing["ns_per_node"] else None
        ref_timing["same_run_as_reference"] = True


def compute_report(runs: list[RunInput], truths: list[DatasetTruth | None],
                   reference: str | None = None, progress=None) -> ReportData:
    """All report numbers for the entries (label, fitter) of ``runs`` (validated, labels distinct).

    truths[i]: the MC truth of the dataset of runs[i] (`pkf.pipeline.report.load_truths`
    reads it), None for a run without MC truth.
    reference: ``LABEL/FITTER`` or ``LABEL`` of the entry to compare with (:func:`choose_reference`).
    progress: called with the number of events of each part of a run read (:func:`read_entries`).

    The run tables are read one partition at a time; what is kept per track is listed in
    :class:`EntryTracks` (the numbers are those of the whole tables: the same rows in the same order).

    Raises:
        InputError: a run's dataset is present but malformed, or ``reference`` names no entry.
    """
    labels = [run.label for run in runs]
    if len(set(labels)) != len(labels):  # load_runs already refuses this
        raise InputError("report: two runs have the same label")
    reference = choose_reference(runs, reference)
    entries: dict[str, dict] = {}
    arrays: dict[str, FitterArrays] = {}
    run_summaries = []
    dataset_of: dict[str, Path | None] = {}
    for index, run in enumerate(runs):
        truth = None
        key = None
        if run.has_mc:
            key = run.dataset_path.resolve() if run.dataset_path else Path(f"<none {index}>")
            truth = truths[index]
        tracks = read_entries(run, truth or DatasetTruth("no MC truth"), progress)
        run_summaries.append(_run_summary(run, truth, tracks[run.fitters[0]]))
        for name in run.fitters:
            entry = run.entry(name)
            entries[entry], arrays[entry] = _fitter_report(run, index, name, truth or DatasetTruth("no MC truth"),
                                                           tracks.pop(name))
            dataset_of[entry] = key if truth is not None else None
    _compare_with_reference(entries, arrays, reference, dataset_of)

    summary = {
        "kind": "report",
        "pkf_version": pkf.__version__,
        "reference": reference,
        "entry_order": list(entries),
        "warnings": dataset_warnings(runs),
        "settings": {
            "resolution_location": RESOLUTION_LOCATION,
            "pull_location": PULL_LOCATION,
            "mass_location": MASS_LOCATION,
            "p_edges_mev": P_EDGES_MEV.tolist(),
            "eta_edges": ETA_EDGES.tolist(),
            "chi2_ndf_cuts": CHI2_NDF_CUTS.tolist(),
            "mass_window_mev": list(MASS_WINDOW_MEV),
            "mass_fit": "Gaussian + linear background, extended unbinned maximum likelihood (iminuit)",
        },
        "runs": run_summaries,
        "entries": entries,
    }
    return ReportData(summary, arrays)
