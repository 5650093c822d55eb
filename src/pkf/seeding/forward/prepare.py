"""Set-up of the forward extension in Python: the forward layers, the hits sorted for
bisection, the tracks moved to their VELO layer, the χ² cut tables and the option records
the kernels read. Units: mm, MeV.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtri

from pkf.errors import InputError
from pkf.geometry.detector import SUBDETECTORS, Geometry
from pkf.io.row_order import group_sort_order
from pkf.params.transport import STEP_SCIFI, STEP_UT, STEP_UT_TO_SCIFI, STEP_VELO_TO_UT
from pkf.params.ut_to_scifi import META_NX, META_NY, META_P_MIN, META_SIZE
from pkf.seeding.forward.hough import hough_grid
from pkf.seeding.forward.records import Config, Cuts, Layout
from pkf.seeding.forward_steps import new_table_buffers


def layout(geometry: Geometry) -> tuple[np.ndarray, Layout]:
    """The VELO layers and the forward layers (UT then SciFi) with their requirement bits."""
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
    return velo, Layout(
        layer=f_layer, cos=geometry.layer_cos[f_layer].astype(np.float64),
        sin=geometry.layer_sin[f_layer].astype(np.float64),
        sigma=geometry.layer_sigma[f_layer].astype(np.float64),
        acceptance=_acceptance(geometry, f_layer), bit=f_bit, group_end=f_group_end, need_end=f_need_end,
        scifi_need=int(sf_need), x_layers=x_layers.astype(np.int64), x_fwd=x_fwd.astype(np.int64),
        x_station_bit=x_station_bit, x_station_need=x_station_need, n_ut=int(ut.size),
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
    meta, cells = ext.uts_meta, ext.uts_cells
    if (meta.size < META_SIZE or meta[META_NX] < 3 or meta[META_NY] < 3 or meta[META_P_MIN] <= 0
            or cells.ndim != 4 or cells.shape[0] != int(meta[META_NX]) or cells.shape[1] != int(meta[META_NY])):
        raise InputError("the parameter set has no valid UT→SciFi table (eqs. 21–23): run `pkf tune`")


def _chi2_table(pvalue: float, n: int, offset: int) -> np.ndarray:
    """χ² upper cut per number of measurements m (index), ndf = max(m − offset, 1)."""
    m = np.arange(n)
    ndf = np.maximum(m - offset, 1)
    if pvalue <= 0.0:
        return np.full(n, np.inf)
    return chdtri(ndf, pvalue)  # = scipy.stats.chi2.isf(pvalue, ndf), without importing scipy.stats


@dataclass
class Prepared:
    """What `extend_velo_tracks` hands to the kernel: the layout, the forward hits sorted
    by (event, layer, u) (u, sigma; rows: their rows in the input; lay_off (events,
    n_fwd + 1): offsets per event and layer), the tracks (event index, VELO layer (−1:
    invalid), state (x, y, tx, ty) moved to it), the kernel's config, the scratch sizes and
    the UT→SciFi table's p_min [MeV]."""

    lay: Layout
    hit_u: np.ndarray
    hit_sigma: np.ndarray
    rows: np.ndarray
    lay_off: np.ndarray
    t_ev: np.ndarray
    t_layer: np.ndarray
    state: np.ndarray
    cfg: Config
    poly: np.ndarray
    table_ref: np.ndarray
    max_entries: int
    max_bins: int
    p_table: float

    @property
    def n_tracks(self) -> int:
        return int(self.t_ev.size)

    @property
    def n_events(self) -> int:
        return int(self.lay_off.shape[0])


def _sorted_hits(events, n_fwd, fwd_of_layer, hit_event, hit_layer, hit_u, hit_sigma):
    """Rows of the usable forward hits of the given events sorted by (event, layer, u) and
    the offsets (events, n_fwd + 1) of each (event, forward layer) in them."""
    valid_layer = (hit_layer >= 0) & (hit_layer < fwd_of_layer.size)
    hf = np.where(valid_layer, fwd_of_layer[np.clip(hit_layer, 0, fwd_of_layer.size - 1)], -1)
    use = np.flatnonzero((hf >= 0) & np.isfinite(hit_u) & (hit_sigma > 0))
    ev_index = np.searchsorted(events, hit_event[use])
    if events.size:
        known = (ev_index < events.size) & (events[np.minimum(ev_index, events.size - 1)] == hit_event[use])
    else:
        known = np.zeros(use.size, dtype=bool)
    use = use[known]
    ev_index = ev_index[known]
    n_ev = events.size
    # counting sort by (event, layer), then by u within each: a lexsort of all hits cost half of the
    # extension's set-up
    order, bounds = group_sort_order(ev_index * n_fwd + hf[use], hit_u[use], n_ev * n_fwd)
    lay_off = bounds[np.arange(n_ev)[:, None] * n_fwd + np.arange(n_fwd + 1)[None, :]].astype(np.int64)
    return use[order], lay_off


def _tracks_at_velo(velo, geometry, velo_state, z_state):
    """The VELO layer nearest to each track's z (−1: z not finite or > 50 mm outside the
    VELO) and the state moved along its straight line to it."""
    n = z_state.size
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
    return t_layer, state


def _config(options, p_table: float, n_fwd: int) -> Config:
    """Option vectors, χ² cut tables (index: measurements) and the Hough grid."""
    fopt, iopt = options.vectors(p_table)
    n_meas = n_fwd + 2
    cuts = Cuts(ut_prune=_chi2_table(1e-6, n_meas, 1) + 10.0, sf_prune=_chi2_table(1e-7, n_meas, 1) + 10.0,
                final=_chi2_table(options.pvalue, n_meas, 1), no_ut=_chi2_table(options.no_ut_pvalue, n_meas, 1),
                good=_chi2_table(options.good_pvalue, n_meas, 1), ut=_chi2_table(options.ut_pvalue, n_meas, 1),
                upstream=_chi2_table(options.upstream_pvalue, n_meas, 1))
    hough = hough_grid(options.hough_tol_abs, options.hough_tol_rel, 1.0 / options.p_min)
    return Config(fopt, iopt, cuts, hough)


def _max_bins(options) -> int:
    """Bins of the Hough coordinate over |q/p| ≤ 1/p_min (+ margin)."""
    qmax = 1.0 / options.p_min
    t_max = (math.log1p(options.hough_tol_rel * qmax / options.hough_tol_abs) / options.hough_tol_rel
             if options.hough_tol_rel > 0 else qmax / options.hough_tol_abs)
    return int(2.0 * t_max) + 4


def prepare(track_event, velo_state, z_state, hit_event, hit_layer, hit_u, hit_sigma, geometry, ext,
            options) -> Prepared:
    """Check and arrange the inputs of `extend_velo_tracks` for the kernel."""
    velo, lay = layout(geometry)
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
    f_layer = lay.layer
    n_fwd = f_layer.size
    fwd_of_layer = np.full(geometry.layer_z.size, -1, dtype=np.int64)  # forward index (−1 VELO/other)
    fwd_of_layer[f_layer] = np.arange(n_fwd)
    events = np.unique(track_event)
    rows, lay_off = _sorted_hits(events, n_fwd, fwd_of_layer, hit_event, hit_layer, hit_u, hit_sigma)
    t_layer, state = _tracks_at_velo(velo, geometry, velo_state, z_state)
    p_table = float(ext.uts_meta[META_P_MIN])
    x_fwd = np.isin(f_layer, lay.x_layers)
    per_event_x = np.diff(lay_off, axis=1)[:, x_fwd].sum(axis=1) if events.size else np.zeros(0)
    poly, table_ref = new_table_buffers(ext)
    return Prepared(
        lay=lay, hit_u=np.ascontiguousarray(hit_u[rows]), hit_sigma=np.ascontiguousarray(hit_sigma[rows]),
        rows=rows, lay_off=lay_off, t_ev=np.searchsorted(events, track_event).astype(np.int64), t_layer=t_layer,
        state=state, cfg=_config(options, p_table, n_fwd), poly=poly, table_ref=table_ref,
        max_entries=int(per_event_x.max()) + 1 if events.size else 1, max_bins=_max_bins(options),
        p_table=p_table)
