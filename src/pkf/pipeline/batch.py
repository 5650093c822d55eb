"""Reconstruction of one batch of events: pattern recognition, fits, MC matching, run-table rows.

The unit of work of `pkf reconstruct` (docs/formats.md): a worker gets a batch's hits and
MC truth, returns its rows of ``candidates``, ``chi2``, ``states``, ``pulls`` (and, with
``--track-states``, ``track_states``) and a small summary (counts, timing, pattern-recognition counts) that adds up over batches. The
output of a batch depends only on its events, so any split into batches and any number
of workers give the same rows.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa

from pkf.fit.beamline import straight_line_extrapolator
from pkf.fit.extrapolator import STATUS_NAMES, STATUS_OK
from pkf.fit.fitters import get_fitter
from pkf.fit.seed import TRACK_LONG, TRACK_TYPE_NAMES
from pkf.fit.tracks import TrackBatch, seed_batch
from pkf.geometry.detector import SUBDETECTORS, Geometry
from pkf.io.reader import Dataset
from pkf.io.schemas import (
    CANDIDATES,
    CHI2,
    COV_COLUMNS,
    PARTICLE_KEY_BASE,
    PULLS,
    STATES,
    TRACK_STATES,
    pack_covariance,
    particle_key,
)
from pkf.params.parameter_set import load_parameters
from pkf.params.transport import ParametrizedExtrapolator
from pkf.params.ut_to_scifi import covered_p_min
from pkf.pipeline import triplet_pattern
from pkf.pipeline.batch_kernels import match_candidates, pull_columns, state_columns, subdetector_counts
from pkf.pipeline.inputs import STATE_NAMES, column, mc_alignment, production_truth
from pkf.pipeline.matching import matches_of, particle_truth_at_hits, reconstructible_sets
from pkf.pipeline.rows import Coded, RowBlocks
from pkf.pipeline.triplet_pattern import crowded_events, triplet_candidates
from pkf.pipeline.truth_pattern import truth_candidates

RUN_TABLES = ("candidates", "chi2", "states", "pulls", "track_states")
RUN_SCHEMAS = {"candidates": CANDIDATES, "chi2": CHI2, "states": STATES, "pulls": PULLS,
               "track_states": TRACK_STATES}


class StageClock:
    """Adds wall and CPU seconds of a ``with`` block to ``timing[stage]``."""

    def __init__(self, timing: dict, stage: str):
        self.timing, self.stage = timing, stage

    def __enter__(self):
        self.w, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.elapsed = time.perf_counter() - self.w
        entry = self.timing.setdefault(self.stage, {"wall_s": 0.0, "cpu_s": 0.0})
        entry["wall_s"] += self.elapsed
        entry["cpu_s"] += time.process_time() - self.c


@dataclass
class ReconstructionContext:
    """What every batch of a run needs: geometry, field, extrapolators, fit options.

    Built once per process (:func:`context_for`); ``warmed`` records that the fit
    kernels were compiled or loaded from numba's cache before the first timed fit.
    """

    geometry: Geometry
    pattern: str
    fitters_ext: list
    pattern_ext: object
    beamline_ext: object
    field_map: object
    fit_options: dict  # fitter name → FitOptions
    track_states: bool = False  # also the per-node states of every stage (`--track-states`)
    warmed: bool = field(default=False)


_CONTEXTS: dict = {}


def context_for(geometry: Geometry, config) -> ReconstructionContext:
    """The (per-process cached) context of ``geometry`` and a ReconstructionConfig."""
    key = (geometry.content_hash, config)
    if key not in _CONTEXTS:
        fitters = [get_fitter(name) for name in config.fitters]
        _CONTEXTS.clear()
        _CONTEXTS[key] = ReconstructionContext(
            geometry=geometry,
            pattern=config.pattern,
            fitters_ext=[(f, f.extrapolator(geometry, config.params, config.kalman.hypothesis)) for f in fitters],
            # the forward extension of the triplet pattern uses the parametrized extrapolations
            pattern_ext=(load_parameters(geometry, config.params).extrapolator(geometry)
                         if config.pattern == "triplet" else None),
            beamline_ext=straight_line_extrapolator(geometry),
            field_map=geometry.reconstruction_field(),
            fit_options={f.name: config.fit_options(f) for f in fitters},
            track_states=config.track_states,
        )
    return _CONTEXTS[key]


def _n_events(event_id: np.ndarray) -> int:
    """Events among hit rows grouped by event (what ``np.unique(event_id).size`` sorts for)."""
    return int(event_id.size and 1 + np.count_nonzero(event_id[1:] != event_id[:-1]))


def _true_momentum(production: dict, keys: np.ndarray) -> np.ndarray | None:
    """True production momentum [MeV] of particle keys (NaN where unknown; None without MC)."""
    if not production:
        return None
    table = production["key"]
    if table.size == 0:
        return np.full(keys.size, np.nan)
    pos = np.minimum(np.searchsorted(table, keys), table.size - 1)
    return np.where(table[pos] == keys, production["p"][pos], np.nan)


def _warm_up(fitters_ext, batch: TrackBatch, seeds, covs, options, beamline_ext) -> None:
    """Compile (or load from cache) every kernel on a few tracks before timing."""
    n = min(batch.n_tracks, 3)
    if n == 0:
        return
    end = batch.offsets[n]
    small = TrackBatch(batch.offsets[: n + 1], batch.z[:end], batch.layer[:end], batch.hit_row[:end],
                       batch.n_meas[:end], batch.hx[:end], batch.hy[:end], batch.m[:end], batch.sigma[:end])
    for fitter, ext in fitters_ext:
        fitter.fit(ext, small, options[fitter.name], seeds[:n], covs[:n], beamline_ext)


#: Momentum bins [MeV] of the efficiencies in run.json (docs/physics.md#matching-and-metrics; issue 5's targets are
#: quoted for 2–5 GeV and p > 5 GeV).
P_BINS = ((0.0, 1000.0, "p_lt_1GeV"), (1000.0, 2000.0, "p_1_2GeV"), (2000.0, 5000.0, "p_2_5GeV"),
          (5000.0, math.inf, "p_gt_5GeV"))


def pattern_counts(matched: np.ndarray, reconstructible: np.ndarray,
                   reconstructible_p: np.ndarray | None = None) -> dict:
    """Counts behind efficiency, ghost and clone rate (docs/physics.md#matching-and-metrics) that add up over batches
    (particle keys are unique per event, and a batch holds whole events). With the true
    momenta [MeV] of the reconstructible particles, also per momentum bin (`P_BINS`). reconstructible:
    sorted keys (`reconstructible_sets`)."""
    real = matched[matched >= 0]
    unique_real = _sorted_unique(real)
    found = _sorted_isin(reconstructible, unique_real)
    counts = {"tracks": int(matched.size), "ghosts": int(np.sum(matched < 0)), "real": int(real.size),
              "unique_real": int(unique_real.size), "reconstructible": int(reconstructible.size),
              "found": int(np.sum(found))}
    if reconstructible_p is not None:
        for lo, hi, name in P_BINS:
            in_bin = (reconstructible_p >= lo) & (reconstructible_p < hi)
            counts[f"reconstructible_{name}"] = int(np.sum(in_bin))
            counts[f"found_{name}"] = int(np.sum(found & in_bin))
    return counts


def _sorted_unique(values: np.ndarray) -> np.ndarray:
    """``np.unique(values)`` of integers, from one sort (what it does without its dispatch overheads)."""
    values = np.sort(values)
    return values[np.r_[True, values[1:] != values[:-1]]] if values.size else values


def _sorted_isin(values: np.ndarray, sorted_unique: np.ndarray) -> np.ndarray:
    """``np.isin(values, sorted_unique)`` by binary search in the sorted distinct ``sorted_unique``
    (``isin`` sorts both arrays together: 1,000 minimum-bias events 0.11 s of CPU)."""
    if sorted_unique.size == 0:
        return np.zeros(values.shape, dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_unique, values), sorted_unique.size - 1)
    return sorted_unique[pos] == values


def metrics_from_counts(c: dict) -> dict:
    """Efficiency, ghost rate and clone rate from summed :func:`pattern_counts` (as
    pattern_metrics), and the efficiency per momentum bin when counted."""
    out = {
        "tracks": c["tracks"],
        "reconstructible": c["reconstructible"],
        "efficiency": c["found"] / c["reconstructible"] if c["reconstructible"] else None,
        "ghost_rate": c["ghosts"] / c["tracks"] if c["tracks"] else None,
        "clone_rate": (c["real"] - c["unique_real"]) / c["real"] if c["real"] else None,
    }
    if f"found_{P_BINS[0][2]}" in c:
        out["efficiency_by_p"] = {
            name: {"reconstructible": c[f"reconstructible_{name}"],
                   "efficiency": (c[f"found_{name}"] / c[f"reconstructible_{name}"]
                                  if c[f"reconstructible_{name}"] else None)}
            for _, _, name in P_BINS}
    return out


def reconstruct_batch(ctx: ReconstructionContext, data: Dataset) -> tuple[dict, dict]:
    """Reconstruct the events of ``data`` (hits, and MC truth if present, of whole events).

    Returns:
        (tables, summary): the batch's rows per run table (:func:`run_tables`) and its
        summary (:func:`batch_rows`).
    """
    rows, summary = batch_rows(ctx, data)
    return run_tables(rows), summary


#: Sort keys of the run tables (`run_tables`): event, track, then fitter and location or node.
SORT_KEYS = ("event_id", "track_id", "fitter", "location", "node")


def run_tables(rows: RowBlocks) -> dict[str, pa.Table]:
    """The run tables of ``rows`` (those :func:`batch_rows` declared, in :data:`RUN_TABLES` order):
    candidates in the pattern's hit order, the others ordered by :data:`SORT_KEYS` (stable: the
    stages of a node keep their order). Rows of several batches in event order give the tables
    of one batch of all their events."""
    return {name: rows.table(name, RUN_SCHEMAS[name], () if name == "candidates" else SORT_KEYS)
            for name in RUN_TABLES if name in rows.blocks}


def batch_rows(ctx: ReconstructionContext, data: Dataset) -> tuple[RowBlocks, dict]:
    """Reconstruct the events of ``data`` (hits, and MC truth if present, of whole events).

    Returns:
        (rows, summary): the batch's rows per run table (numpy blocks, :func:`run_tables` builds
        the tables) and its summary: ``events``, ``hits``, ``candidates``,
        ``tracks`` per fitter, ``timing`` per stage (wall_s, cpu_s), ``fit`` per
        fitter (wall_s, tracks, nodes), with MC ``pattern``/``velo`` counts, and
        ``events_over_hit_limit`` (events, limit, first event ids) if the triplet pattern
        left events above its occupancy limit unsearched
        (`pkf.pipeline.triplet_pattern.MAX_EVENT_HITS`).
    """
    geometry = ctx.geometry
    chunk = data.hits
    ev = column(chunk, "event_id", np.int64)
    hit_id = chunk.column("hit_id").to_numpy(zero_copy_only=False).astype(np.int64, copy=False)  # only indexed: a view will do
    has_mc = data.mc_hits is not None
    if has_mc:
        mc = mc_alignment(data, ev, hit_id)
        production = production_truth(data)
    fitter_names = [f.name for f, _ in ctx.fitters_ext]
    timing: dict = {}
    summary = {"events": _n_events(ev), "hits": int(chunk.num_rows), "candidates": 0,
               "tracks": {n: 0 for n in fitter_names}, "fit": {n: {"wall_s": 0.0, "tracks": 0, "nodes": 0}
                                                              for n in fitter_names}}
    layer = column(chunk, "layer", np.int64)
    with StageClock(timing, "pattern"):
        # each column converted once, for the pattern and the nodes (neither writes to them)
        u, v, z, sigma_u, sigma_v = (column(chunk, name) for name in ("u", "v", "z", "sigma_u", "sigma_v"))
        if ctx.pattern == "truth":
            candidates = truth_candidates(ev, layer, mc.particle_id.astype(np.int64, copy=False))
        else:
            crowded = crowded_events(ev)
            if crowded.size:  # not searched: counted, reported in run.json and on stderr
                summary["events_over_hit_limit"] = {"events": int(crowded.size),
                                                    "limit": triplet_pattern.MAX_EVENT_HITS,
                                                    "event_ids": crowded[:10].tolist()}
            candidates = triplet_candidates(geometry, ctx.pattern_ext, ev, layer, u, v, z, sigma_u, sigma_v)
        batch = TrackBatch.from_candidates(geometry, candidates, layer, u, v, sigma_u, sigma_v)
        seeds, seed_covs, _ = seed_batch(batch, ctx.field_map, geometry)
    n_tracks, cand_row = candidates.n_tracks, candidates.hit_row
    track_event, track_id = candidates.event_id, candidates.track_id
    rows = RowBlocks()
    for name in RUN_TABLES:  # the tables of this run, even without rows
        if (name != "pulls" or has_mc) and (name != "track_states" or ctx.track_states):
            rows.blocks[name] = []
    rows.add("candidates", {"event_id": candidates.hit_event, "track_id": candidates.hit_track,
                            "hit_id": hit_id[cand_row]})
    summary["candidates"] = n_tracks
    if has_mc:
        mc_particle, fraction, ghost, node_truth = _mc_truth(geometry, summary, mc, production, candidates,
                                                             batch, layer, z)
    else:
        mc_particle = np.full(n_tracks, -1, dtype=np.int64)
        fraction = np.zeros(n_tracks)
        ghost = np.ones(n_tracks, dtype=bool)
    if not ctx.warmed and n_tracks:
        _warm_up(ctx.fitters_ext, batch, seeds, seed_covs, ctx.fit_options, ctx.beamline_ext)
        ctx.warmed = True
    for fitter, ext in ctx.fitters_ext:
        with StageClock(timing, f"fit.{fitter.name}") as clock:
            result = fitter.fit(ext, batch, ctx.fit_options[fitter.name], seeds, seed_covs, ctx.beamline_ext,
                                track_states=ctx.track_states)
        stats = summary["fit"][fitter.name]
        stats["wall_s"] += clock.elapsed
        stats["tracks"] += n_tracks
        stats["nodes"] += int(batch.z.size)
        summary["tracks"][fitter.name] += int(np.sum(result.status == STATUS_OK))
        summary.setdefault("below_p_min", {})[fitter.name] = _below_p_min(ext, batch, result)
        rows.add("chi2", _chi2_rows(fitter, geometry, batch, result, track_event, track_id,
                                    mc_particle, fraction, ghost))
        _add_states_rows(rows, fitter, result, track_event, track_id)
        if ctx.track_states:
            rows.add("track_states", _track_states_rows(fitter, batch, result, track_event, track_id, hit_id))
        if has_mc:
            # under the electron hypothesis the parametrized q/p is no longer the production one
            # (it loses the expected radiation, pkf.fit.hypothesis): its truth is the local q/p
            at_production = fitter.qop_at_production and ctx.fit_options[fitter.name].kalman.hypothesis == "pion"
            _add_pulls_rows(rows, fitter, result, track_event, track_id, mc_particle, node_truth,
                            production, at_production)
    summary["timing"] = timing
    return rows, summary


def _mc_truth(geometry: Geometry, summary: dict, mc, production: dict, candidates, batch: TrackBatch,
              layer: np.ndarray, hit_z: np.ndarray):
    """MC matching of a batch's candidates (`pkf.pipeline.inputs.MCHits` ``mc``): per track the matched
    particle id (−1 for a ghost), match fraction and ghost flag, and the truth at its first and last
    node (`_node_truth`); the long- and VELO-track pattern counts go to ``summary``. Both matchings
    (all hits; VELO hits) in one pass over the candidates' hits (`batch_kernels.match_candidates`):
    `match_tracks` twice (sorting the (track, particle) pairs) took 0.25 s of CPU per 1,000
    minimum-bias events (cProfile), besides gathering the hits' keys and subdetectors and
    selecting the VELO hits."""
    n_tracks, offsets = candidates.n_tracks, candidates.offsets
    matches = np.empty((7, n_tracks), dtype=np.int64)
    longest = int(np.max(np.diff(offsets))) if n_tracks else 0
    match_candidates(offsets, candidates.hit_row, mc.key, layer, geometry.layer_subdetector, SUBDETECTORS.index("velo"),
                     SUBDETECTORS.index("scifi"), np.empty((2, max(longest, 1)), dtype=np.int64), matches)
    mc_id, fraction, ghost = matches_of(*matches[0:3])
    mc_particle = np.where(mc_id >= 0, mc_id % PARTICLE_KEY_BASE, -1)
    reconstructible = reconstructible_sets(geometry, mc.key, layer)
    long_rec = reconstructible["long"]
    summary["pattern"] = pattern_counts(mc_id[matches[6] > 0], long_rec, _true_momentum(production, long_rec))
    # VELO tracks are matched on their VELO hits alone: a VELO track with a wrong
    # forward extension is a correct VELO track (and a ghost long track)
    velo_id, _, _ = matches_of(*matches[3:6])
    velo_rec = reconstructible["velo"]
    summary["velo"] = pattern_counts(velo_id[matches[5] > 0], velo_rec, _true_momentum(production, velo_rec))
    node_truth = _node_truth(batch, candidates.event_id, mc_particle, mc.key, mc.truth, hit_z, layer)
    return mc_particle, fraction, ghost, node_truth


def _subdetector_counts(geometry: Geometry, batch: TrackBatch, active: np.ndarray):
    """Per subdetector (`SUBDETECTORS`): the active nodes of each track on its layers, one pass
    (`batch_kernels.subdetector_counts`; a mask and a ``bincount`` per subdetector before)."""
    out = np.zeros((len(SUBDETECTORS), batch.n_tracks), dtype=np.int64)
    subdetector_counts(batch.offsets, batch.layer, geometry.layer_subdetector, active, out)
    return dict(zip(SUBDETECTORS, out))


def _below_p_min(ext, batch: TrackBatch, result) -> int:
    """Long tracks a parametrized fit extrapolated from the UT to the SciFi below the momentum
    its table covers (`covered_p_min`: p_low of the soft range, else p_min), by RK4 through the
    field map (`pkf.params.transport`): fitted |q/p| at the first hit above 1/that. 0 for the
    other fitters."""
    if not isinstance(ext, ParametrizedExtrapolator):
        return 0
    p_covered = covered_p_min(ext.uts_meta)
    if p_covered <= 0.0:
        return 0
    qop = result.locations["first_hit"][1][:, 4]
    fitted = (result.status == STATUS_OK) & (batch.track_type == TRACK_LONG)
    return int(np.sum(fitted & (np.abs(qop) * p_covered > 1.0)))


def _chi2_rows(fitter, geometry, batch, result, track_event, track_id, mc_particle, fraction, ghost) -> dict:
    counts = _subdetector_counts(geometry, batch, result.node_active)
    ok = result.status == STATUS_OK
    ndf = result.ndf
    return {
        "event_id": track_event, "track_id": track_id, "fitter": fitter.name,
        "track_type": Coded(TRACK_TYPE_NAMES, batch.track_type),
        "n_velo": counts["velo"], "n_ut": counts["ut"], "n_scifi": counts["scifi"],
        "n_outliers": result.n_outliers, "chi2": result.chi2, "ndf": ndf,
        "chi2_ndf": np.where(ok & (ndf > 0), result.chi2 / np.maximum(ndf, 1), np.nan),
        "status": Coded(STATUS_NAMES, result.status),
        "mc_particle_id": mc_particle, "match_fraction": fraction, "is_ghost": ghost,
    }


def _add_states_rows(rows: RowBlocks, fitter, result, track_event, track_id) -> None:
    """The ``states`` rows of the tracks with status ok: per location z, the state and the
    covariance's upper triangle (`pkf.io.schemas.pack_covariance`), gathered in one pass
    (`batch_kernels.state_columns`) into one block whose rows are the columns."""
    ok = np.flatnonzero(result.status == STATUS_OK)
    event, track = track_event[ok], track_id[ok]
    for location, (z, state, cov) in result.locations.items():
        values = np.empty((1 + len(STATE_NAMES) + len(COV_COLUMNS), ok.size))
        state_columns(ok, z, state, cov, values)
        cols = {"event_id": event, "track_id": track, "fitter": fitter.name, "location": location,
                "z": values[0]}
        cols.update(zip(STATE_NAMES, values[1:6]))
        cols.update(zip(COV_COLUMNS, values[6:]))
        rows.add("states", cols)


def _track_states_rows(fitter, batch, result, track_event, track_id, hit_id):
    """Rows of ``track_states`` of one fitter (docs/formats.md#track_states): every node of
    the tracks with status ok, one row per stage the fitter provides, node by node in z
    order and the stages in the order of the fit."""
    states = result.track_states
    stages = states.stages
    track_of_node = np.repeat(np.arange(batch.n_tracks), batch.n_nodes)
    nodes = np.flatnonzero((result.status == STATUS_OK)[track_of_node])
    node_tracks = track_of_node[nodes]

    def per_row(values):  # a per-node column on every stage's row
        return np.repeat(values, len(stages), axis=0)

    def stage_major(arrays):  # per-stage arrays (nodes, …) → rows node-major, stage-minor
        return np.stack([a[nodes] for a in arrays], axis=1).reshape((-1,) + arrays[0].shape[1:])

    residuals = [states.residuals(batch, stage) for stage in stages]
    state = stage_major([states.state[stage] for stage in stages])
    cols = {"event_id": per_row(track_event[node_tracks]), "track_id": per_row(track_id[node_tracks]),
            "fitter": fitter.name, "node": per_row(nodes - batch.offsets[node_tracks]),
            "layer": per_row(batch.layer[nodes]), "hit_id": per_row(hit_id[batch.hit_row[nodes]]),
            "z": per_row(batch.z[nodes]),
            "stage": Coded(tuple(stages), np.tile(np.arange(len(stages)), nodes.size))}
    cols.update({name: state[:, i] for i, name in enumerate(STATE_NAMES)})
    cols.update(pack_covariance(stage_major([states.cov[stage] for stage in stages])))
    res = stage_major([r.res for r in residuals])
    var = stage_major([r.var for r in residuals])
    cols.update({"res_u": res[:, 0], "var_res_u": var[:, 0], "res_v": res[:, 1], "var_res_v": var[:, 1],
                 "chi2": stage_major([r.chi2 for r in residuals]), "is_outlier": per_row(states.is_outlier[nodes])})
    return cols


def _node_truth(batch: TrackBatch, track_event, mc_particle, hit_key, hit_truth, hit_z, layer) -> dict:
    """Per location ``first_hit``/``last_hit``: the matched particle's true state at that node's
    plane, (n_tracks, 5), NaN for unmatched tracks and where the particle has no hit on the
    node's layer (`particle_truth_at_hits`: the node's mc_hit, or where the hit is another
    particle's or noise the particle's own hit on that layer). Once per batch, for every fitter;
    hit_truth: per hit row, an array (n_hits, 5) or `pkf.pipeline.inputs.HitTruth`."""
    matched = np.flatnonzero(mc_particle > 0)
    locations = (("first_hit", batch.offsets[:-1]), ("last_hit", batch.offsets[1:] - 1))
    out = {location: np.full((mc_particle.size, 5), np.nan) for location, _ in locations}
    if batch.z.size and matched.size:  # both locations in one pass over the hits
        key = particle_key(track_event[matched], mc_particle[matched])
        truth = particle_truth_at_hits(np.concatenate([batch.hit_row[nodes[matched]] for _, nodes in locations]),
                                       np.concatenate([key, key]), hit_key, hit_truth, hit_z, layer)
        for i, (location, _) in enumerate(locations):
            out[location][matched] = truth[i * matched.size:(i + 1) * matched.size]
    return out


def _add_pulls_rows(rows: RowBlocks, fitter, result, track_event, track_id, mc_particle, node_truth: dict,
                    production, at_production) -> None:
    """Residuals and pulls at each location for tracks matched to a particle.

    Truth at the first/last hit: the matched particle's state at that node's plane
    (`_node_truth`; no row where it has none), q/p replaced by the
    production q/p where the states carry it (`at_production`); at the beamline: the production
    vertex and momentum, straight-line extrapolated to the fitted z. (Taking the node's
    mc_hit whoever's it was gave the tracks with a foreign first hit the pulls of another
    particle's state.) Residuals, pulls (σ = √max(C_ii, 0)) and p_true of the selected tracks in
    one pass (`batch_kernels.pull_columns`)."""
    ok = (result.status == STATUS_OK) & (mc_particle > 0)
    pkey = particle_key(track_event, mc_particle)
    pos = np.searchsorted(production["key"], pkey) if production else None
    has_particle = np.zeros(ok.size, dtype=bool)
    if production:
        pos = np.minimum(pos, production["key"].size - 1)
        has_particle = production["key"][pos] == pkey
    for location, (z, state, cov) in result.locations.items():
        if location == "beamline":
            if not production:
                continue
            sel = ok & has_particle
            q = pos[sel]
            dz = z[sel] - production["vz"][q]
            truth = np.column_stack([production["vx"][q] + production["tx"][q] * dz,
                                     production["vy"][q] + production["ty"][q] * dz,
                                     production["tx"][q], production["ty"][q], production["qop"][q]])
        else:
            truth_all = node_truth[location]
            sel = ok & np.all(np.isfinite(truth_all), axis=1)
            if at_production:
                sel &= has_particle
            truth = truth_all[sel]
            if at_production:
                truth[:, 4] = production["qop"][pos[sel]]
        tracks = np.flatnonzero(sel)
        values = np.empty((1 + 2 * len(STATE_NAMES), tracks.size))
        pull_columns(tracks, state, cov, np.ascontiguousarray(truth, dtype=np.float64), values)
        cols = {"event_id": track_event[tracks], "track_id": track_id[tracks], "fitter": fitter.name,
                "location": location, "p_true": values[0]}
        for i, name in enumerate(STATE_NAMES):
            cols[f"res_{name}"] = values[1 + i]
            cols[f"pull_{name}"] = values[1 + len(STATE_NAMES) + i]
        rows.add("pulls", cols)
