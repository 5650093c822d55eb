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
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pkf.fit.dispatch import dispatched
from pkf.fit.status import STATUS_NOT_POSITIVE_DEFINITE, STATUS_OK, STATUS_TOO_FEW_HITS
from pkf.jit import NO_REFCOUNT

begin_track = dispatched("begin_track", "fitter, t, seed", "Prepare the fit of track t; returns a status code.")
fit_track = dispatched("fit_track", "fitter, t, lo, hi, z, n_meas, hx, hy, m, sigma, active, seed, seed_cov, out_state, out_cov",
                       "Fit track t once with its active nodes; returns (status, χ²).")
end_track = dispatched("end_track", "fitter, t, lo, hi, status, out_state, out_cov",
                       "The fitter's own outputs of track t after its last fit.")


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
def find_outlier(state, cov, n_meas, hx, hy, m, sigma, active, outlier_cuts, out_node_chi2,
                 measurement_only_fallback):
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
def fit_one_track(fitter, t, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds, seed_covs,
                  outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2,
                  out_ndf, out_n_outliers):
    """Fit track t of a CSR batch with `fitter`, removing outliers (`_fit_tracks_loop`'s
    arguments): begin, then fit → find the outlier → deactivate → refit, then end."""
    out_active[offsets[t]:offsets[t + 1]] = True
    status = begin_track(fitter, t, seeds[t])
    refit_track(fitter, t, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds, seed_covs,
                outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2,
                out_ndf, out_n_outliers, status, 0)


@nb.njit(cache=True, inline="always")
def refit_track(fitter, t, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds, seed_covs,
                outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2,
                out_ndf, out_n_outliers, status, n_out):
    """`fit_one_track`'s loop (fit → find the outlier → deactivate → refit, then end) from
    `status` with `n_out` nodes already deactivated in out_active: after begin_track
    (n_out = 0), or after a first fit made elsewhere whose outlier was just deactivated
    (`pkf.fit.kalman_lanes`; the fitter's state then that of its first fit)."""
    lo = offsets[t]
    hi = offsets[t + 1]
    n_meas = node_n_meas[lo:hi]
    active = out_active[lo:hi]
    chi2 = 0.0
    ndf = 0
    while status == STATUS_OK:
        ndf = count_ndf(n_meas, active)
        if ndf <= 0:
            status = STATUS_TOO_FEW_HITS
            break
        status, chi2 = fit_track(fitter, t, lo, hi, node_z[lo:hi], n_meas, node_hx[lo:hi], node_hy[lo:hi],
                                 node_m[lo:hi], node_sigma[lo:hi], active, seeds[t], seed_covs[t],
                                 out_state[lo:hi], out_cov[lo:hi])
        if status != STATUS_OK:
            break
        status, worst = find_outlier(out_state[lo:hi], out_cov[lo:hi], n_meas, node_hx[lo:hi], node_hy[lo:hi],
                                     node_m[lo:hi], node_sigma[lo:hi], active, outlier_cuts,
                                     out_node_chi2[lo:hi], fitter.measurement_only_fallback)
        if status != STATUS_OK:
            break
        if n_out < max_outliers and worst >= 0:
            active[worst] = False
            n_out += 1
            continue
        break
    end_track(fitter, t, lo, hi, status, out_state[lo:hi], out_cov[lo:hi])
    out_status[t] = status
    out_chi2[t] = chi2 if status == STATUS_OK else np.nan
    out_ndf[t] = ndf
    out_n_outliers[t] = n_out


@nb.njit(cache=True, inline="always")
def _fit_tracks_loop(fitter, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds, seed_covs,
                     outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2,
                     out_ndf, out_n_outliers):
    """Fit every track of a CSR batch with `fitter`, removing outliers (`fit_one_track`).

    Node arrays: node_z [mm] (n), node_n_meas (1 or 2), node_hx/node_hy (n, 2) the
    measurement directions, node_m (n, 2) measured values [mm], node_sigma (n, 2) [mm];
    seeds (T, 5) at each first node, seed_covs (T, 5, 5). outlier_cuts (2): the cut on a
    node's standardised χ² for 1- and 2-dimensional nodes. Outputs per node: state and
    covariance, standardised χ², active (False: removed as outlier); per track: status,
    χ² (NaN unless ok), ndf and number of removed outliers.
    """
    for t in range(offsets.size - 1):
        fit_one_track(fitter, t, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds,
                      seed_covs, outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active,
                      out_status, out_chi2, out_ndf, out_n_outliers)


@nb.njit(cache=True)
def fit_tracks(fitter, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds, seed_covs,
               outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2,
               out_ndf, out_n_outliers):
    """The track loop (`_fit_tracks_loop`) for any fitter."""
    _fit_tracks_loop(fitter, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds, seed_covs,
                     outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2,
                     out_ndf, out_n_outliers)


@nb.njit(cache=True, **NO_REFCOUNT)
def fit_tracks_no_refcount(fitter, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds,
                           seed_covs, outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active,
                           out_status, out_chi2, out_ndf, out_n_outliers):
    """The track loop (`_fit_tracks_loop`) without reference counting, for fitters that
    allocate nothing (`register_fitter`)."""
    _fit_tracks_loop(fitter, offsets, node_z, node_n_meas, node_hx, node_hy, node_m, node_sigma, seeds, seed_covs,
                     outlier_cuts, max_outliers, out_state, out_cov, out_node_chi2, out_active, out_status, out_chi2,
                     out_ndf, out_n_outliers)
