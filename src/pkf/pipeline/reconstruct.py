"""The `pkf reconstruct` stage: pattern recognition, fits, MC matching, run tables (DESIGN §6–§10).

Events are processed in chunks (bounded memory); within a chunk every step works on
arrays of all its tracks. The run directory holds ``candidates``, ``chi2``, ``states``,
``pulls`` (when MC is present) and ``run.json``, staged and renamed into place only
when everything succeeded.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
from tqdm import tqdm

import pkf
from pkf.errors import InputError
from pkf.fit.beamline import straight_line_extrapolator
from pkf.fit.extrapolator import STATUS_NAMES, STATUS_OK
from pkf.fit.fitters import Fitter, get_fitter
from pkf.params.parameter_set import load_parameters
from pkf.fit.tracks import FitOptions, TrackBatch, seed_batch
from pkf.geometry.detector import SUBDETECTORS, Geometry
from pkf.io.atomic import atomic_write_json, check_output_dir, staged_output_dir
from pkf.io.schemas import CANDIDATES, CHI2, PULLS, STATES, pack_covariance, table_from_columns
from pkf.io.writer import StreamingTableWriter
from pkf.pipeline.inputs import (
    STATE_NAMES,
    _PARTICLE_KEY_BASE,
    align_mc,
    column,
    content_hash,
    load_dataset,
    particle_key,
    production_truth,
)
from pkf.pipeline.matching import (
    match_tracks,
    pattern_metrics,
    reconstructible_particles,
    velo_reconstructible_particles,
)
from pkf.pipeline.triplet_pattern import triplet_candidates
from pkf.pipeline.truth_pattern import truth_candidates

EVENTS_PER_CHUNK = 500
PATTERNS = ("triplet", "truth")


@dataclass(frozen=True)
class ReconstructionConfig:
    """Every option of `pkf reconstruct` (DESIGN §1.1)."""

    fitters: tuple[str, ...] = ("parametrized",)
    pattern: str = "triplet"
    params: str | None = None
    outlier_chi2: float = 9.0
    max_outliers: int = 2
    iterations: int = 1

    def validate(self) -> list[Fitter]:
        if self.pattern not in PATTERNS:
            raise InputError(f"--pattern: unknown pattern {self.pattern!r} (one of {', '.join(PATTERNS)})")
        if not self.outlier_chi2 > 0:
            raise InputError(f"--outlier-chi2: must be > 0, not {self.outlier_chi2}")
        if self.max_outliers < 0:
            raise InputError(f"--max-outliers: must be >= 0, not {self.max_outliers}")
        if self.iterations < 1:
            raise InputError(f"--iterations: must be >= 1, not {self.iterations}")
        if len(set(self.fitters)) != len(self.fitters):
            raise InputError("--fitter: a fitter is given twice")
        return [get_fitter(name) for name in self.fitters]


@dataclass
class _Timing:
    wall: dict = field(default_factory=dict)
    cpu: dict = field(default_factory=dict)

    def add(self, stage: str, wall: float, cpu: float) -> None:
        self.wall[stage] = self.wall.get(stage, 0.0) + wall
        self.cpu[stage] = self.cpu.get(stage, 0.0) + cpu


class _Clock:
    def __init__(self, timing: _Timing, stage: str):
        self.timing, self.stage = timing, stage

    def __enter__(self):
        self.w, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.elapsed = time.perf_counter() - self.w
        self.timing.add(self.stage, self.elapsed, time.process_time() - self.c)


def _warm_up(fitters_ext, batch: TrackBatch, seeds, covs, options, beamline_ext) -> None:
    """Compile (or load from cache) every kernel on a few tracks before timing."""
    n = min(batch.n_tracks, 3)
    if n == 0:
        return
    end = batch.offsets[n]
    small = TrackBatch(batch.offsets[: n + 1], batch.z[:end], batch.layer[:end], batch.hit_row[:end],
                       batch.n_meas[:end], batch.hx[:end], batch.hy[:end], batch.m[:end], batch.sigma[:end])
    for fitter, ext in fitters_ext:
        fitter.fit(ext, small, options, seeds[:n], covs[:n], beamline_ext)


def run_reconstruction(dataset_path: str | Path, out: str | Path, config: ReconstructionConfig,
                       overwrite: bool = False, progress: bool | None = None) -> dict:
    """Reconstruct the dataset at `dataset_path` into the run directory `out`; returns run.json."""
    fitters = config.validate()
    dataset_path = Path(dataset_path)
    check_output_dir(out, overwrite)
    if Path(out).resolve() == dataset_path.resolve():
        raise InputError(f"--out {out}: is the input dataset")
    geometry, dataset = load_dataset(dataset_path)
    if config.pattern == "truth" and dataset.mc_hits is None:
        raise InputError(f"{dataset_path}: --pattern truth needs mc_hits, and the dataset has none")
    field_map = geometry.reconstruction_field()
    fit_options = FitOptions(outlier_chi2=config.outlier_chi2, max_outliers=config.max_outliers,
                             iterations=config.iterations)
    fitters_ext = [(f, f.make_extrapolator(geometry, config.params)) for f in fitters]
    # the forward extension of the triplet pattern uses the parametrized extrapolations
    pattern_ext = (load_parameters(geometry, config.params).extrapolator(geometry)
                   if config.pattern == "triplet" else None)
    beamline_ext = straight_line_extrapolator(geometry)

    hits = dataset.hits
    event_id = column(hits, "event_id", np.int64)
    has_mc = dataset.mc_hits is not None
    if has_mc:
        hit_particle, hit_truth = align_mc(dataset, event_id)
        particle_momentum = production_truth(dataset)
    timing = _Timing()
    fit_stats = {f.name: {"wall_s": 0.0, "tracks": 0, "nodes": 0} for f in fitters}
    counts = {"events": int(np.unique(event_id).size), "hits": int(hits.num_rows), "candidates": 0,
              "tracks": {f.name: 0 for f in fitters}}
    matched_all, long_all, reconstructible_all, velo_reconstructible_all = [], [], [], []
    bounds = _chunk_bounds(event_id, EVENTS_PER_CHUNK)
    warmed = False
    with staged_output_dir(out, overwrite) as staging:
        writers = {"candidates": StreamingTableWriter(staging / "candidates.parquet", CANDIDATES),
                   "chi2": StreamingTableWriter(staging / "chi2.parquet", CHI2),
                   "states": StreamingTableWriter(staging / "states.parquet", STATES)}
        if has_mc:
            writers["pulls"] = StreamingTableWriter(staging / "pulls.parquet", PULLS)
        with tqdm(total=counts["events"], unit="event", desc="reconstruct",
                  disable=None if progress is None else not progress) as bar:
            for lo, hi in bounds:
                chunk = hits.slice(lo, hi - lo)
                ev = event_id[lo:hi]
                layer = column(chunk, "layer", np.int64)
                with _Clock(timing, "pattern"):
                    if config.pattern == "truth":
                        cand_event, cand_track, cand_row = truth_candidates(ev, layer, hit_particle[lo:hi])
                    else:
                        cand_event, cand_track, cand_row = triplet_candidates(
                            geometry, pattern_ext, ev, layer, column(chunk, "u"), column(chunk, "v"),
                            column(chunk, "z"), column(chunk, "sigma_u"), column(chunk, "sigma_v"))
                    n_tracks, track_of_hit = _global_tracks(cand_event, cand_track)
                    batch = TrackBatch.from_candidates(
                        geometry, track_of_hit, cand_row, layer, column(chunk, "u"),
                        column(chunk, "v"), column(chunk, "sigma_u"), column(chunk, "sigma_v"), n_tracks)
                    seeds, seed_covs, _ = seed_batch(batch, field_map)
                track_event, track_id = _track_keys(cand_event, cand_track, n_tracks)
                hit_id = column(chunk, "hit_id", np.int64)
                writers["candidates"].write(table_from_columns(CANDIDATES, {
                    "event_id": cand_event, "track_id": cand_track, "hit_id": hit_id[cand_row]}))
                counts["candidates"] += n_tracks
                if has_mc:
                    hit_key = particle_key(ev, hit_particle[lo:hi])
                    mc_id, fraction, ghost = match_tracks(track_of_hit, hit_key[cand_row], n_tracks)
                    mc_particle = np.where(mc_id >= 0, mc_id % _PARTICLE_KEY_BASE, -1)
                    matched_all.append(mc_id)
                    scifi_hits = np.bincount(track_of_hit, weights=geometry.layer_subdetector[layer[cand_row]]
                                             == SUBDETECTORS.index("scifi"), minlength=n_tracks)
                    long_all.append(scifi_hits > 0)
                    reconstructible_all.append(reconstructible_particles(geometry, hit_key, layer))
                    velo_reconstructible_all.append(velo_reconstructible_particles(geometry, hit_key, layer))
                else:
                    mc_particle = np.full(n_tracks, -1, dtype=np.int64)
                    fraction = np.zeros(n_tracks)
                    ghost = np.ones(n_tracks, dtype=bool)
                if not warmed:
                    _warm_up(fitters_ext, batch, seeds, seed_covs, fit_options, beamline_ext)
                    warmed = True
                chunk_tables = {"chi2": [], "states": [], "pulls": []}
                for fitter, ext in fitters_ext:
                    with _Clock(timing, f"fit.{fitter.name}") as clock:
                        result = fitter.fit(ext, batch, fit_options, seeds, seed_covs, beamline_ext)
                    stats = fit_stats[fitter.name]
                    stats["wall_s"] += clock.elapsed
                    stats["tracks"] += n_tracks
                    stats["nodes"] += int(batch.z.size)
                    counts["tracks"][fitter.name] += int(np.sum(result.status == STATUS_OK))
                    chunk_tables["chi2"].append(_chi2_table(fitter, geometry, batch, result, track_event,
                                                            track_id, mc_particle, fraction, ghost))
                    chunk_tables["states"].append(_states_table(fitter, result, track_event, track_id))
                    if has_mc:
                        chunk_tables["pulls"].append(_pulls_table(
                            fitter, batch, result, track_event, track_id, mc_particle,
                            hit_truth[lo:hi], particle_momentum))
                for name, tables in chunk_tables.items():
                    if tables:
                        writers[name].write(_sorted(pa.concat_tables(tables)))
                bar.update(int(np.unique(ev).size))
        for writer in writers.values():
            writer.close()
        run = {
            "pkf_version": pkf.__version__,
            "kind": "run",
            "config": asdict(config) | {"dataset": str(dataset_path)},
            "input": {"path": str(dataset_path.resolve()), "content_hash": content_hash(dataset),
                      "geometry": geometry.name, "geometry_hash": geometry.content_hash},
            "counts": counts,
            "timing": _timing_json(timing, fit_stats),
        }
        if has_mc:
            matched = np.concatenate(matched_all)
            is_long = np.concatenate(long_all)
            run["pattern"] = pattern_metrics(matched[is_long], np.concatenate(reconstructible_all))
            run["pattern"]["definition"] = ("long tracks (with SciFi hits) against long-reconstructible "
                                            "particles (DESIGN §10)")
            run["pattern"]["velo"] = pattern_metrics(matched, np.concatenate(velo_reconstructible_all))
        atomic_write_json(run, staging / "run.json")
    return run


def _sorted(table: pa.Table) -> pa.Table:
    """Rows ordered by event, track, then fitter and location (run tables are sorted by event)."""
    keys = [(k, "ascending") for k in ("event_id", "track_id", "fitter", "location") if k in table.column_names]
    return table.sort_by(keys)


def _chunk_bounds(event_id: np.ndarray, events_per_chunk: int) -> list[tuple[int, int]]:
    """Row ranges of consecutive events, at most `events_per_chunk` events each."""
    starts = np.flatnonzero(np.r_[True, event_id[1:] != event_id[:-1]])
    cuts = list(starts[::events_per_chunk]) + [event_id.size]
    return [(int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:])]


def _global_tracks(cand_event, cand_track):
    """Number of tracks and the global (chunk) track index of each candidate hit."""
    if cand_event.size == 0:
        return 0, np.zeros(0, dtype=np.int64)
    new = np.r_[True, (cand_event[1:] != cand_event[:-1]) | (cand_track[1:] != cand_track[:-1])]
    index = np.cumsum(new) - 1
    return int(index[-1] + 1), index


def _track_keys(cand_event, cand_track, n_tracks):
    """(event_id, track_id) of each global track index."""
    if n_tracks == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    new = np.r_[True, (cand_event[1:] != cand_event[:-1]) | (cand_track[1:] != cand_track[:-1])]
    return cand_event[new], cand_track[new]


def _subdetector_counts(geometry: Geometry, batch: TrackBatch, active: np.ndarray):
    track_of_node = np.repeat(np.arange(batch.n_tracks), batch.n_nodes)
    sub = geometry.layer_subdetector[batch.layer]
    out = {}
    for i, name in enumerate(SUBDETECTORS):
        sel = (sub == i) & active
        out[name] = np.bincount(track_of_node[sel], minlength=batch.n_tracks)
    return out


def _chi2_table(fitter, geometry, batch, result, track_event, track_id, mc_particle, fraction, ghost):
    counts = _subdetector_counts(geometry, batch, result.node_active)
    ok = result.status == STATUS_OK
    ndf = result.ndf
    return table_from_columns(CHI2, {
        "event_id": track_event, "track_id": track_id, "fitter": fitter.name,
        "n_velo": counts["velo"], "n_ut": counts["ut"], "n_scifi": counts["scifi"],
        "n_outliers": result.n_outliers, "chi2": result.chi2, "ndf": ndf,
        "chi2_ndf": np.where(ok & (ndf > 0), result.chi2 / np.maximum(ndf, 1), np.nan),
        "status": np.array(STATUS_NAMES, dtype=object)[result.status],
        "mc_particle_id": mc_particle, "match_fraction": fraction, "is_ghost": ghost,
    })


def _states_table(fitter, result, track_event, track_id):
    ok = result.status == STATUS_OK
    parts = []
    for location, (z, state, cov) in result.locations.items():
        cols = {"event_id": track_event[ok], "track_id": track_id[ok], "fitter": fitter.name,
                "location": location, "z": z[ok]}
        cols.update({name: state[ok, i] for i, name in enumerate(STATE_NAMES)})
        cols.update(pack_covariance(cov[ok]))
        parts.append(table_from_columns(STATES, cols))
    return pa.concat_tables(parts)


def _pulls_table(fitter, batch, result, track_event, track_id, mc_particle, hit_truth, production):
    """Residuals and pulls at each location for tracks matched to a particle.

    Truth at the first/last hit: the mc_hit state of that node's hit (q/p replaced by the
    production q/p for fitters whose states carry it); at the beamline: the production
    vertex and momentum, straight-line extrapolated to the fitted z."""
    ok = (result.status == STATUS_OK) & (mc_particle > 0)
    pkey = particle_key(track_event, mc_particle)
    pos = np.searchsorted(production["key"], pkey) if production else None
    has_particle = np.zeros(ok.size, dtype=bool)
    if production:
        pos = np.minimum(pos, production["key"].size - 1)
        has_particle = production["key"][pos] == pkey
    parts = []
    node_index = {"first_hit": batch.offsets[:-1], "last_hit": batch.offsets[1:] - 1}
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
            nodes = np.minimum(node_index[location], max(batch.z.size - 1, 0))
            truth_all = hit_truth[batch.hit_row[nodes]] if batch.z.size else np.zeros((0, 5))
            sel = ok & np.all(np.isfinite(truth_all), axis=1)
            if fitter.qop_at_production:
                sel &= has_particle
            truth = truth_all[sel]
            if fitter.qop_at_production:
                truth[:, 4] = production["qop"][pos[sel]]
        est = state[sel]
        sigma = np.sqrt(np.maximum(np.einsum("nii->ni", cov[sel]), 0.0))
        res = est - truth
        cols = {"event_id": track_event[sel], "track_id": track_id[sel], "fitter": fitter.name,
                "location": location, "p_true": 1.0 / np.abs(truth[:, 4])}
        for i, name in enumerate(STATE_NAMES):
            cols[f"res_{name}"] = res[:, i]
            cols[f"pull_{name}"] = res[:, i] / sigma[:, i]
        parts.append(table_from_columns(PULLS, cols))
    return pa.concat_tables(parts)


def _timing_json(timing: _Timing, fit_stats: dict) -> dict:
    out = {stage: {"wall_s": timing.wall[stage], "cpu_s": timing.cpu[stage]}
           for stage in timing.wall if not stage.startswith("fit.")}
    out["fit"] = {}
    for name, stats in fit_stats.items():
        wall = stats["wall_s"]
        out["fit"][name] = {
            "wall_s": wall, "cpu_s": timing.cpu.get(f"fit.{name}", 0.0), "tracks": stats["tracks"],
            "tracks_per_s": stats["tracks"] / wall if wall > 0 else None,
            "ns_per_node": 1e9 * wall / stats["nodes"] if stats["nodes"] else None,
        }
    return out
