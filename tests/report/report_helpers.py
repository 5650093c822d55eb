"""Helpers for the report tests: synthetic run directories with controlled contents, HTML checks."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pyarrow as pa

from pkf.io import atomic_write_json, atomic_write_table, table_from_columns
from pkf.io.schemas import CANDIDATES, CHI2, COV_COLUMNS, PULLS, STATE_COLUMNS, STATES


def write_synthetic_run(
    path: Path,
    fitters=("parametrized",),
    n_tracks: int = 600,
    ghost_fraction: float = 0.2,
    has_mc: bool = True,
    dataset: str | None = None,
    seed: int = 1,
    track_types: tuple[str, ...] = ("long",),
) -> dict:
    """A run directory (DESIGN §6) with one event per 100 tracks.

    Real tracks have χ²/ndf ~ χ²(20)/20, ghosts ~ 3 × that; pulls are N(0, 1) with
    residuals scaled by p-dependent resolutions; track i has type track_types[i % len]. Returns
    the arrays used, per fitter.
    """
    rng = np.random.default_rng(seed)
    path.mkdir(parents=True)
    event = np.arange(n_tracks, dtype=np.int64) // 100
    track = np.arange(n_tracks, dtype=np.int64) % 100
    ghost = rng.random(n_tracks) < ghost_fraction if has_mc else np.ones(n_tracks, dtype=bool)
    mc = np.where(ghost, -1, track + 1) if has_mc else np.full(n_tracks, -1)
    chi2_parts, state_parts, pull_parts, truth = [], [], [], {}
    types = np.asarray(track_types, dtype=object)[np.arange(n_tracks) % len(track_types)]
    n_ut = np.where(types == "velo", 0, 3)
    n_scifi = np.where(types == "long", 12, 0)
    for k, fitter in enumerate(fitters):
        chi2_ndf = rng.chisquare(20, n_tracks) / 20 * np.where(ghost, 3.0, 1.0)
        status = np.where(rng.random(n_tracks) < 0.01, "too few hits", "ok")
        ok = status == "ok"
        chi2_ndf = np.where(ok, chi2_ndf, np.nan)
        chi2_parts.append(table_from_columns(CHI2, {
            "event_id": event, "track_id": track, "fitter": fitter, "track_type": types, "n_velo": 5,
            "n_ut": n_ut, "n_scifi": n_scifi,
            "n_outliers": 0, "chi2": chi2_ndf * 20, "ndf": 20, "chi2_ndf": chi2_ndf, "status": status,
            "mc_particle_id": mc, "match_fraction": np.where(ghost, 0.5, 1.0), "is_ghost": ghost}))
        p_true = np.exp(rng.uniform(np.log(1500.0), np.log(120000.0), n_tracks))
        charge = rng.choice([-1.0, 1.0], n_tracks)
        dp_over_p = rng.normal(0, 0.005 * (1 + k * 0.1), n_tracks)
        qop = charge / (p_true * (1 + dp_over_p))
        states = {}
        for location in ("first_hit", "last_hit", "beamline"):
            cols = {"event_id": event[ok], "track_id": track[ok], "fitter": fitter, "location": location,
                    "z": rng.normal(0, 50, ok.sum())}
            for name in STATE_COLUMNS:
                cols[name] = rng.normal(0, 0.1, ok.sum())
            cols["qop"] = qop[ok]
            for c in COV_COLUMNS:
                cols[c] = np.full(ok.sum(), 1e-4 if c[1] == c[2] else 0.0)
            states[location] = table_from_columns(STATES, cols)
            state_parts.append(states[location])
        sel = ok & ~ghost if has_mc else np.zeros(n_tracks, dtype=bool)
        if has_mc:
            for location in ("first_hit", "beamline"):
                cols = {"event_id": event[sel], "track_id": track[sel], "fitter": fitter, "location": location,
                        "p_true": p_true[sel]}
                for name in STATE_COLUMNS:
                    pull = rng.normal(0.1 * k, 1.0 + 0.1 * k, sel.sum())
                    cols[f"pull_{name}"] = pull
                    cols[f"res_{name}"] = pull * 0.01 * (1 + 10000.0 / p_true[sel])
                pull_parts.append(table_from_columns(PULLS, cols))
        truth[fitter] = {"chi2_ndf": chi2_ndf, "ghost": ghost, "ok": ok, "type": types}

    def _write(parts, name, schema):
        table = pa.concat_tables(parts).sort_by([(c, "ascending") for c in
                                                 ("event_id", "track_id", "fitter", "location")
                                                 if c in schema.names])
        atomic_write_table(table, path / f"{name}.parquet", schema=schema)

    _write(chi2_parts, "chi2", CHI2)
    _write(state_parts, "states", STATES)
    if has_mc:
        _write(pull_parts, "pulls", PULLS)
    atomic_write_table(table_from_columns(CANDIDATES, {"event_id": event, "track_id": track, "hit_id": track}),
                       path / "candidates.parquet", schema=CANDIDATES)
    run = {
        "pkf_version": "test", "kind": "run",
        "config": {"fitters": list(fitters), "pattern": "synthetic", "dataset": dataset},
        "input": {"path": dataset, "geometry": "synthetic"},
        "counts": {"events": int(event.max() + 1), "tracks": {f: n_tracks for f in fitters}},
        "timing": {"pattern": {"wall_s": 0.1, "cpu_s": 0.1},
                   "fit": {f: {"wall_s": 0.5 * (i + 1), "cpu_s": 0.5, "tracks": n_tracks,
                               "tracks_per_s": n_tracks / (0.5 * (i + 1)), "ns_per_node": 1000.0 * (i + 1)}
                           for i, f in enumerate(fitters)}},
    }
    if has_mc:
        run["pattern"] = {"efficiency": None, "ghost_rate": float(ghost.mean()), "clone_rate": 0.0}
    atomic_write_json(run, path / "run.json")
    return truth


SECTION_IDS = ("resolution", "pulls", "chi2", "mass", "efficiency", "timing")


def image_sources(html_text: str) -> list[str]:
    return re.findall(r'<img[^>]*\ssrc="([^"]+)"', html_text)


def read_summary(report: Path) -> dict:
    return json.loads((report / "summary.json").read_text())


def entry(summary: dict, fitter: str) -> dict:
    """The report entry (``LABEL/FITTER``) of ``fitter``, which must be the only one of that fitter."""
    found = [rep for rep in summary["entries"].values() if rep["fitter"] == fitter]
    assert len(found) == 1, f"{len(found)} entries of fitter {fitter!r}"
    return found[0]
