"""The track loop every fitter shares: count ndf → fit → find the outlier → deactivate → refit.

docs/physics.md#the-kalman-core: after a fit, the active node whose standardised χ² exceeds its cut by the
largest factor (`find_outlier`) is deactivated and the track refitted,
at most ``max_outliers`` times; a track with ndf ≤ 0 has status "too few hits".

A fitter is a NamedTuple (its context, options and scratch arrays, sized for the
batch) whose class is registered with `register_fitter(cls, begin, fit, end)`:

    begin(fitter, t, seed) -> status
        before the first fit of track t (e.g. reject a non-finite seed);
    fit(fitter, t, lo, hi, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov,
        out_state, out_cov) -> (status, χ²)
        one fit of track t (nodes lo:hi; the node arrays are those slices) with the
        nodes marked in ``active``, writing each node's output state and covariance;
    end(fitter, t, lo, hi, status, out_state, out_cov)
        after the last fit (the fitter's own per-track outputs).

A fitter tuple also has the field ``measurement_only_fallback`` (`find_outlier`'s
option for mixture outputs). numba resolves the three calls when it compiles
`fit_tracks` for the fitter's type (`pkf.fit.dispatch`): one compiled loop per fitter.
A fitter registered with ``allocates=False`` runs through `fit_tracks_no_refcount`, the
same loop compiled without reference counting (`track_loop` picks the kernel).

Every track loop is called as ``loop(fitter, nodes, rule, out)`` with three records,
NamedTuples of arrays: `TrackNodes` the CSR node inputs and seeds, `OutlierRule` the
outlier cuts and the number of removals allowed, `FitOutputs` the arrays the loop
writes. `pkf.fit.tracks.run_fitter` builds them from a `TrackBatch`, the seeds and a
`FitResult` (`TrackNodes.of`, `OutlierRule.of`, `FitOutputs.of`). numba passes a
NamedTuple as its fields, as it passed the 19 loose arguments before: every output is
bitwise the same, and the speed too (CPU time, 257,055 minimum-bias nodes, loose
arrays → records, the two alternating, min / median ns per node: benchmarks/fit_core.py
parametrized full fit 303/308 → 293/310, reference 2584/2640 → 2552/2683; `fit_batch`
with 2 passes and outlier removal, parametrized 590/631 → 585/642, reference
5749/6051 → 5763/5986). The per-track call ``fit`` above keeps its node slices as
loose arguments (`track_measurements` cuts them): it is the interface each fitter
implements on one track, not the batch.
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.fit.dispatch import dispatched
from pkf.fit.status import STATUS_NOT_POSITIVE_DEFINITE, STATUS_OK, STATUS_TOO_FEW_HITS
from pkf.jit import NO_REFCOUNT

begin_track = dispatched("begin_track", "fitter, t, seed", "Prepare the fit of track t; returns a status code.")
fit_track = dispatched(
    "fit_track",
    "fitter, t, lo, hi, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, out_state, out_cov",
    "Fit track t once with its active nodes; returns (status, χ²).",
)
end_track = dispatched(
    "end_track",
    "fitter, t, lo, hi, status, out_state, out_cov",
    "The fitter's own outputs of track t after its last fit.",
)


class TrackNodes(NamedTuple):
    """The inputs of a batch's fit, tracks as CSR node arrays (`pkf.fit.tracks.TrackBatch`'s
    names): offsets (T+1), track t's nodes offsets[t]:offsets[t + 1], sorted by z; per node
    z [mm], n_meas (1 strip, 2 pixel), hx/hy (n, 2) the measurement directions, m (n, 2)
    the measured values [mm], sigma (n, 2) their errors [mm]; per track the seed (T, 5) =
    (x, y [mm], tx, ty, q/p [1/MeV]) at its first node and its covariance seed_covs (T, 5, 5)."""

    offsets: np.ndarray
    z: np.ndarray
    n_meas: np.ndarray
    hx: np.ndarray
    hy: np.ndarray
    m: np.ndarray
    sigma: np.ndarray
    seeds: np.ndarray
    seed_covs: np.ndarray

    @classmethod
    def of(cls, batch, seeds: np.ndarray, seed_covs: np.ndarray) -> TrackNodes:
        """The node arrays of `batch` (a `TrackBatch`, its `node_inputs`) with these seeds and
        covariances (as contiguous float64 arrays)."""
        seeds = np.ascontiguousarray(seeds, dtype=np.float64)
        return cls(*batch.node_inputs, seeds, np.ascontiguousarray(seed_covs, dtype=np.float64))


class OutlierRule(NamedTuple):
    """The outlier removal of the track loop (docs/physics.md#the-kalman-core): cuts (2) on
    a node's standardised χ² for 1- and 2-dimensional nodes (`find_outlier`), and at most
    max_outliers nodes removed per track."""

    cuts: np.ndarray
    max_outliers: int

    @classmethod
    def of(cls, options) -> OutlierRule:
        """The rule of `options` (a `pkf.fit.options.FitOptions`)."""
        return cls(options.outlier_cuts(), int(options.max_outliers))


class FitOutputs(NamedTuple):
    """What the track loop writes, in place (a `pkf.fit.tracks.FitResult`'s arrays): per
    node the output state (n, 5) = (x, y [mm], tx, ty, q/p [1/MeV]) and its covariance cov
    (n, 5, 5), the standardised χ² node_chi2 (n) and active (n; False: removed as outlier);
    per track status (T), χ² chi2 (T; NaN unless ok), ndf (T) and the number of removed
    outliers n_outliers (T)."""

    state: np.ndarray
    cov: np.ndarray
    node_chi2: np.ndarray
    active: np.ndarray
    status: np.ndarray
    chi2: np.ndarray
    ndf: np.ndarray
    n_outliers: np.ndarray

    @classmethod
    def of(cls, result) -> FitOutputs:
        """The arrays of `result` (a `FitResult`)."""
        r = result
        return cls(r.node_state, r.node_cov, r.node_chi2, r.node_active, r.status, r.chi2, r.ndf, r.n_outliers)


@nb.njit(cache=True, inline="always")
def node_chi2(state, cov, n_meas, hx, hy, m, sigma, active, with_cov=True):
    """Standardised χ² r·R⁻¹·r of one node's smoothed residual r = m − H·x, with
    R = V − H·C·Hᵀ (active node) or V + H·C·Hᵀ (outlier) the residual's covariance
    (with_cov False: R = V, the measurement variance alone); −1 if R is not positive
    definite. Used to find outliers (`find_outlier`)."""
    sign = -1.0 if active else 1.0
    r0 = m[0] - (hx[0] * state[0] + hy[0] * state[1])
    v0 = sigma[0] * sigma[0]
    c00 = 0.0
    if with_cov:
        c00 = hx[0] * (hx[0] * cov[0, 0] + hy[0] * cov[0, 1]) + hy[0] * (hx[0] * cov[1, 0] + hy[0] * cov[1, 1])
    r00 = v0 + sign * c00
    if n_meas == 1:
        if not r00 > 0.0:
            return -1.0
        return r0 * r0 / r00
    r1 = m[1] - (hx[1] * state[0] + hy[1] * state[1])
    v1 = sigma[1] * sigma[1]
    c11 = 0.0
    c01 = 0.0
    if with_cov:
        c11 = hx[1] * (hx[1] * cov[0, 0] + hy[1] * cov[0, 1]) + hy[1] * (hx[1] * cov[1, 0] + hy[1] * cov[1, 1])
        c01 = hx[0] * (hx[1] * cov[0, 0] + hy[1] * cov[0, 1]) + hy[0] * (hx[1] * cov[1, 0] + hy[1] * cov[1, 1])
    r11 = v1 + sign * c11
    r01 = sign * c01
    det = r00 * r11 - r01 * r01
    if not (r00 > 0.0 and det > 0.0):
        return -1.0
    return (r0 * r0 * r11 - 2.0 * r0 * r1 * r01 + r1 * r1 * r00) / det


@nb.njit(cache=True, inline="always")
def count_ndf(n_meas, active):
    """ndf = Σ measurement dimensions of the active nodes − 5 (docs/physics.md#the-kalman-core)."""
    ndf = -5
    for k in range(n_meas.size):
        if active[k]:
            ndf += n_meas[k]
    return ndf


@nb.njit(cache=True, **NO_REFCOUNT)
def find_outlier(state, cov, n_meas, hx, hy, m, sigma, active, outlier_cuts, out_node_chi2, measurement_only_fallback):
    """Every node's standardised χ² (`node_chi2` of its output state and covariance) into
    out_node_chi2, and the outlier candidate: the active node whose χ² exceeds its cut
    (outlier_cuts[dimensions − 1]) by the largest factor.

    Returns (status, candidate index, −1 if no active node exceeds its cut). A residual
    covariance that is not positive definite gives STATUS_NOT_POSITIVE_DEFINITE, or, with
    `measurement_only_fallback` (mixture outputs, whose covariance can exceed the
    measurement variance), the χ² standardised by the measurement variance alone.
    Shared by every fitter's outlier removal (docs/physics.md#the-kalman-core): the caller deactivates the
    candidate and refits, at most `--max-outliers` times.
    """
    status = STATUS_OK
    worst = -1
    worst_excess = 1.0
    for k in range(n_meas.size):
        c_node = node_chi2(state[k], cov[k], n_meas[k], hx[k], hy[k], m[k], sigma[k], active[k])
        if c_node < 0.0:
            if measurement_only_fallback:
                c_node = node_chi2(state[k], cov[k], n_meas[k], hx[k], hy[k], m[k], sigma[k], active[k], False)
            else:
                status = STATUS_NOT_POSITIVE_DEFINITE
        out_node_chi2[k] = c_node
        if active[k]:
            excess = c_node / outlier_cuts[n_meas[k] - 1]
            if excess > worst_excess:
                worst_excess = excess
                worst = k
    return status, worst


#: Fitter classes whose begin/fit/end allocate nothing (`register_fitter`).
_NOT_ALLOCATING: set[type] = set()


def register_fitter(fitter_class: type, begin, fit, end, allocates: bool = True) -> None:
    """Make the njit functions begin, fit and end those of fitters of `fitter_class`.
    With allocates=False (they create no array) its tracks run through
    `fit_tracks_no_refcount`, compiled without reference counting (`pkf.jit`)."""
    begin_track.register(fitter_class, begin)
    fit_track.register(fitter_class, fit)
    end_track.register(fitter_class, end)
    if not allocates:
        _NOT_ALLOCATING.add(fitter_class)


#: Fitter class → chooser of its own track loop (`register_track_loop`).
_OWN_LOOPS: dict[type, object] = {}


def register_track_loop(fitter_class: type, choose) -> None:
    """Make `choose(fitter)` pick the track loop of fitters of `fitter_class`: a function
    with the signature and outputs of `fit_tracks`, or None for the shared loop (the
    Kalman core's tracks in SIMD lanes, `pkf.fit.kalman_lanes`)."""
    _OWN_LOOPS[fitter_class] = choose


def track_loop(fitter, own: bool = True):
    """The track loop for `fitter`: its class's own (`register_track_loop`) if `own` and
    it takes this fitter; else `fit_tracks_no_refcount` if its class was registered with
    allocates=False, else `fit_tracks`."""
    choose = _OWN_LOOPS.get(type(fitter)) if own else None
    loop = choose(fitter) if choose is not None else None
    if loop is not None:
        return loop
    return fit_tracks_no_refcount if type(fitter) in _NOT_ALLOCATING else fit_tracks


def max_nodes(offsets: np.ndarray) -> int:
    """The largest number of nodes of a track of the CSR batch (at least 1): scratch size."""
    return max(1, int(np.max(np.diff(offsets), initial=0)))


@nb.njit(cache=True, inline="always")
def fit_one_track(fitter, t, nodes, rule, out):
    """Fit track t of `nodes` with `fitter` into `out`, removing outliers by `rule`:
    begin, then fit → find the outlier → deactivate → refit, then end (`refit_track`)."""
    out.active[nodes.offsets[t] : nodes.offsets[t + 1]] = True
    status = begin_track(fitter, t, nodes.seeds[t])
    refit_track(fitter, t, nodes, rule, out, status, 0)


@nb.njit(cache=True, inline="always")
def track_measurements(nodes, lo, hi):
    """The measurement arrays of nodes lo:hi of `nodes` (one track's slices, the node
    arguments of `fit_track`): (z, n_meas, hx, hy, m, sigma)."""
    return nodes.z[lo:hi], nodes.n_meas[lo:hi], nodes.hx[lo:hi], nodes.hy[lo:hi], nodes.m[lo:hi], nodes.sigma[lo:hi]


@nb.njit(cache=True, inline="always")
def track_outlier(fitter, lo, hi, nodes, rule, out):
    """`find_outlier` of the track of nodes lo:hi from its output states in `out` (its
    node χ² into out.node_chi2): (status, index in the track of the outlier candidate or −1)."""
    _, n_meas, hx, hy, m, sigma = track_measurements(nodes, lo, hi)
    state, cov, active, chi2 = out.state[lo:hi], out.cov[lo:hi], out.active[lo:hi], out.node_chi2[lo:hi]
    return find_outlier(state, cov, n_meas, hx, hy, m, sigma, active, rule.cuts, chi2, fitter.measurement_only_fallback)


@nb.njit(cache=True, inline="always")
def finish_track(fitter, t, lo, hi, out, status, chi2, ndf, n_out):
    """After the last fit of track t (nodes lo:hi): the fitter's `end_track`, then the
    track's status, χ² (NaN unless ok), ndf and number of removed outliers into `out`."""
    end_track(fitter, t, lo, hi, status, out.state[lo:hi], out.cov[lo:hi])
    out.status[t] = status
    out.chi2[t] = chi2 if status == STATUS_OK else np.nan
    out.ndf[t] = ndf
    out.n_outliers[t] = n_out


@nb.njit(cache=True, inline="always")
def refit_track(fitter, t, nodes, rule, out, status, n_out):
    """`fit_one_track`'s loop (fit → find the outlier → deactivate → refit, then end) from
    `status` with `n_out` nodes already deactivated in out.active: after begin_track
    (n_out = 0), or after a first fit made elsewhere whose outlier was just deactivated
    (`pkf.fit.kalman_lanes`; the fitter's state then that of its first fit)."""
    lo = nodes.offsets[t]
    hi = nodes.offsets[t + 1]
    z, n_meas, hx, hy, m, sigma = track_measurements(nodes, lo, hi)
    active, state, cov = out.active[lo:hi], out.state[lo:hi], out.cov[lo:hi]
    seed, seed_cov = nodes.seeds[t], nodes.seed_covs[t]
    chi2 = 0.0
    ndf = 0
    while status == STATUS_OK:
        ndf = count_ndf(n_meas, active)
        if ndf <= 0:
            status = STATUS_TOO_FEW_HITS
            break
        status, chi2 = fit_track(fitter, t, lo, hi, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, state, cov)
        if status != STATUS_OK:
            break
        status, worst = track_outlier(fitter, lo, hi, nodes, rule, out)
        if status != STATUS_OK:
            break
        if n_out < rule.max_outliers and worst >= 0:
            active[worst] = False
            n_out += 1
            continue
        break
    finish_track(fitter, t, lo, hi, out, status, chi2, ndf, n_out)


@nb.njit(cache=True, inline="always")
def _fit_tracks_loop(fitter, nodes, rule, out):
    """Fit every track of `nodes` (`TrackNodes`) with `fitter` into `out` (`FitOutputs`),
    removing outliers by `rule` (`OutlierRule`), track by track (`fit_one_track`)."""
    for t in range(nodes.offsets.size - 1):
        fit_one_track(fitter, t, nodes, rule, out)


@nb.njit(cache=True)
def fit_tracks(fitter, nodes, rule, out):
    """The track loop (`_fit_tracks_loop`) for any fitter."""
    _fit_tracks_loop(fitter, nodes, rule, out)


@nb.njit(cache=True, **NO_REFCOUNT)
def fit_tracks_no_refcount(fitter, nodes, rule, out):
    """The track loop (`_fit_tracks_loop`) without reference counting, for fitters that
    allocate nothing (`register_fitter`)."""
    _fit_tracks_loop(fitter, nodes, rule, out)
