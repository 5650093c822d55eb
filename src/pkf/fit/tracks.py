"""Track batches (CSR) built from hits and candidates, and the Python entry point of the fit.

`TrackBatch.from_candidates` turns candidate hit lists into the node arrays of the
Kalman core (vectorised, no per-hit Python loop); `fit_batch` fits with the Kalman core
for any extrapolator; `FitResult.empty` and `fit_locations` (first-hit, last-hit and
beamline states) are the bookkeeping every fitter's entry point shares.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2 as chi2_distribution

from pkf.fit.beamline import beamline_states
from pkf.fit.driver import fit_tracks, max_nodes
from pkf.fit.kalman import SMOOTHER_WEIGHTED_MEAN, kalman_fitter
from pkf.fit.status import STATUS_NAMES, STATUS_NO_SEED, STATUS_OK
from pkf.fit.seed import TRACK_LONG, seed_tracks, track_type_codes
from pkf.geometry.detector import KIND_PIXEL, Geometry


@dataclass
class TrackBatch:
    """Tracks as CSR node arrays, nodes sorted by z within each track.

    offsets (T+1); per node: z [mm], layer, hit_row (row in the hits table), n_meas
    (1 strip, 2 pixel), hx/hy (n, 2) measurement directions, m (n, 2) measured values
    [mm], sigma (n, 2) errors [mm]; per track its type (`pkf.fit.seed.TRACK_*`; None:
    every track long).
    """

    offsets: np.ndarray
    z: np.ndarray
    layer: np.ndarray
    hit_row: np.ndarray
    n_meas: np.ndarray
    hx: np.ndarray
    hy: np.ndarray
    m: np.ndarray
    sigma: np.ndarray
    track_type: np.ndarray | None = None

    @property
    def n_tracks(self) -> int:
        return self.offsets.size - 1

    @property
    def n_nodes(self) -> np.ndarray:
        return np.diff(self.offsets)

    @classmethod
    def from_candidates(cls, geometry: Geometry, track_index: np.ndarray, hit_row: np.ndarray,
                        layer: np.ndarray, u: np.ndarray, v: np.ndarray, sigma_u: np.ndarray,
                        sigma_v: np.ndarray, n_tracks: int) -> TrackBatch:
        """Nodes from (track_index, hit_row) pairs; hit columns are indexed by hit_row.

        Nodes are sorted by (track, z); every track index in [0, n_tracks) may appear.
        """
        layer_of = layer[hit_row].astype(np.int64)
        order = np.lexsort((geometry.layer_z[layer_of], track_index))
        track_index = track_index[order]
        hit_row = hit_row[order]
        layer_of = layer_of[order]
        counts = np.bincount(track_index, minlength=n_tracks)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        pixel = geometry.layer_kind[layer_of] == KIND_PIXEL
        n = hit_row.size
        hx = np.zeros((n, 2))
        hy = np.zeros((n, 2))
        hx[:, 0] = geometry.layer_cos[layer_of]
        hy[:, 0] = geometry.layer_sin[layer_of]
        hy[:, 1] = 1.0
        m = np.zeros((n, 2))
        sigma = np.ones((n, 2))
        m[:, 0] = u[hit_row]
        sigma[:, 0] = sigma_u[hit_row]
        m[pixel, 1] = v[hit_row][pixel]
        sigma[pixel, 1] = sigma_v[hit_row][pixel]
        return cls(offsets, geometry.layer_z[layer_of].copy(), layer_of, hit_row,
                   np.where(pixel, 2, 1).astype(np.int64), hx, hy, m, sigma,
                   track_type_codes(geometry, offsets, layer_of))


@dataclass(frozen=True)
class FitOptions:
    """Options of the fit (docs/physics.md#the-kalman-core): outlier χ² cut and maximum number removed,
    iterations of the Kalman fitters (the 2nd and later linearise around the previous
    optimal states), their combination method (weighted mean, or the RTS smoother), and
    the Gaussian-sum filter's largest number of mixture components (`--max-components`)."""

    outlier_chi2: float = 9.0
    max_outliers: int = 2
    iterations: int = 1
    smoother: int = SMOOTHER_WEIGHTED_MEAN
    max_components: int = 12

    def outlier_cuts(self) -> np.ndarray:
        """Cuts on a node's standardised χ² for 1-D and 2-D nodes: `outlier_chi2` for 1-D,
        and for 2-D the value with the same tail probability (9 → 11.83)."""
        p_value = chi2_distribution.sf(self.outlier_chi2, 1)
        return np.array([self.outlier_chi2, chi2_distribution.isf(p_value, 2)])


@dataclass
class FitResult:
    """Output of `fit_batch`: per node optimal states/covariances, χ² contributions and
    activity (False: removed as outlier); per track status, χ², ndf, outliers, and the
    states at the first hit, last hit and beamline (z, state (T, 5), cov (T, 5, 5))."""

    node_state: np.ndarray
    node_cov: np.ndarray
    node_chi2: np.ndarray
    node_active: np.ndarray
    status: np.ndarray
    chi2: np.ndarray
    ndf: np.ndarray
    n_outliers: np.ndarray
    locations: dict = field(default_factory=dict)

    @classmethod
    def empty(cls, batch: TrackBatch, **fields):
        """A result for `batch` before the fit: NaN states, covariances and χ², every node
        active, status ok, zero ndf and outliers; `fields` set a subclass's own fields."""
        n = batch.z.size
        t = batch.n_tracks
        return cls(node_state=np.full((n, 5), np.nan), node_cov=np.full((n, 5, 5), np.nan),
                   node_chi2=np.full(n, np.nan), node_active=np.ones(n, dtype=np.bool_),
                   status=np.zeros(t, dtype=np.int64), chi2=np.full(t, np.nan),
                   ndf=np.zeros(t, dtype=np.int64), n_outliers=np.zeros(t, dtype=np.int64), **fields)

    def status_names(self) -> np.ndarray:
        return np.array(STATUS_NAMES, dtype=object)[self.status]


def seed_batch(batch: TrackBatch, field) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seed states (T, 5) at each track's first node, seed covariances and q/p variances.

    VELO-only tracks (``batch.track_type``) get the momentum assumption of
    `pkf.fit.seed.velo_qop_prior`."""
    seeds = np.empty((batch.n_tracks, 5))
    covs = np.empty((batch.n_tracks, 5, 5))
    qop_var = np.empty(batch.n_tracks)
    track_type = batch.track_type
    if track_type is None:
        track_type = np.full(batch.n_tracks, TRACK_LONG, dtype=np.int64)
    seed_tracks(batch.offsets, batch.z, batch.n_meas, batch.hx, batch.hy, batch.m, batch.sigma,
                *field.args, seeds, covs, qop_var, np.ascontiguousarray(track_type, dtype=np.int64))
    return seeds, covs, qop_var


def fit_batch(extrapolator, batch: TrackBatch, options: FitOptions, seeds: np.ndarray,
              seed_covs: np.ndarray, beamline_extrapolator=None) -> FitResult:
    """Fit every track of `batch` with `extrapolator` from the given seeds."""
    result = FitResult.empty(batch)
    fitter = kalman_fitter(extrapolator, max_nodes(batch.offsets), options.iterations, options.smoother)
    run_fitter(fitter, batch, options, seeds, seed_covs, result)
    bad_seed = ~np.all(np.isfinite(seeds), axis=1)
    result.status[bad_seed] = STATUS_NO_SEED
    fit_locations(result, batch, beamline_extrapolator)
    return result


def run_fitter(fitter, batch: TrackBatch, options: FitOptions, seeds: np.ndarray, seed_covs: np.ndarray,
               result: FitResult) -> None:
    """Fit every track of `batch` with `fitter` (a registered fitter tuple, `pkf.fit.driver`)
    into `result`, with the outlier cut and removals of `options`."""
    fit_tracks(fitter, batch.offsets, batch.z, batch.n_meas, batch.hx, batch.hy, batch.m, batch.sigma,
               np.ascontiguousarray(seeds, dtype=np.float64), np.ascontiguousarray(seed_covs, dtype=np.float64),
               options.outlier_cuts(), int(options.max_outliers), result.node_state, result.node_cov,
               result.node_chi2, result.node_active, result.status, result.chi2, result.ndf, result.n_outliers)


def fit_locations(result: FitResult, batch: TrackBatch, beamline_extrapolator=None) -> None:
    """Add the first-hit and last-hit states and, given a beamline extrapolator, the
    beamline state of the tracks with status ok (`beamline_states`, the same code for
    every fitter, docs/physics.md#the-kalman-core) to `result.locations`: name → (z, state (T, 5), cov (T, 5, 5))."""
    t = batch.n_tracks
    has_nodes = batch.n_nodes > 0
    first = np.where(has_nodes, batch.offsets[:-1], 0)
    last = np.where(has_nodes, batch.offsets[1:] - 1, 0)
    result.locations["first_hit"] = (batch.z[first], result.node_state[first], result.node_cov[first])
    result.locations["last_hit"] = (batch.z[last], result.node_state[last], result.node_cov[last])
    if beamline_extrapolator is not None:
        idx = np.flatnonzero(result.status == STATUS_OK)
        bz = np.full(t, np.nan)
        bs = np.full((t, 5), np.nan)
        bc = np.full((t, 5, 5), np.nan)
        zb = np.empty(idx.size)
        s_out = np.empty((idx.size, 5))
        c_out = np.empty((idx.size, 5, 5))
        beamline_states(beamline_extrapolator, np.ascontiguousarray(batch.z[first][idx]),
                        np.ascontiguousarray(result.node_state[first][idx]),
                        np.ascontiguousarray(result.node_cov[first][idx]), zb, s_out, c_out)
        bz[idx], bs[idx], bc[idx] = zb, s_out, c_out
        result.locations["beamline"] = (bz, bs, bc)
