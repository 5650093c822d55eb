"""Shared helpers of the fit tests: simulate a gun sample and fit its truth tracks."""

import numpy as np

from pkf.fit.beamline import straight_line_extrapolator
from pkf.fit.reference import reference_extrapolator
from pkf.fit.tracks import FitOptions, TrackBatch, fit_batch, seed_batch
from pkf.geometry import load_geometry, parse_geometry
from pkf.pipeline.simulate import SimulationConfig, simulate_batch
from pkf.pipeline.truth_pattern import truth_candidates

STATE = ("x", "y", "tx", "ty", "qop")


def telescope_without_material():
    text = load_geometry("telescope").text.replace("x_over_x0 = 0.01", "x_over_x0 = 0.0")
    return parse_geometry(text, source="telescope-no-material")


class TruthSample:
    """Hits of a gun sample grouped into truth tracks, ready to fit."""

    def __init__(self, geometry, events, seed=1, generator="gun", **gun):
        config = SimulationConfig(generator=generator, events=events, seed=seed, **gun)
        hits, particles, mc = simulate_batch(geometry, config, 0, events)
        self.geometry = geometry
        col = lambda t, c: t.column(c).to_numpy(zero_copy_only=False)  # noqa: E731
        self.hits = {c: col(hits, c).astype(float) for c in ("u", "v", "sigma_u", "sigma_v")}
        self.layer = col(hits, "layer").astype(np.int64)
        event = col(hits, "event_id").astype(np.int64)
        particle = col(mc, "particle_id").astype(np.int64)
        self.truth = np.column_stack([col(mc, c).astype(float) for c in STATE])
        # production q/p of each hit's particle (what the parametrized states carry)
        p_event = col(particles, "event_id").astype(np.int64)
        p_id = col(particles, "particle_id").astype(np.int64)
        momentum = np.sqrt(sum(col(particles, c).astype(float) ** 2 for c in ("px", "py", "pz")))
        p_qop = col(particles, "charge").astype(float) / momentum
        key = p_event * (1 << 24) + p_id
        order = np.argsort(key)
        pos = np.searchsorted(key[order], event * (1 << 24) + particle)
        pos = np.minimum(pos, key.size - 1)
        self.production_qop = np.where(particle > 0, p_qop[order][pos], np.nan)
        self.batch = TrackBatch.from_candidates(
            geometry,
            truth_candidates(event, self.layer, particle),
            self.layer,
            self.hits["u"],
            self.hits["v"],
            self.hits["sigma_u"],
            self.hits["sigma_v"],
        )
        self.field = geometry.reconstruction_field()
        self.seeds, self.seed_covs, self.qop_var = seed_batch(self.batch, self.field, geometry)
        self.extrapolator = reference_extrapolator(geometry)
        self.beamline = straight_line_extrapolator(geometry)

    def fit(self, batch=None, **options):
        batch = batch or self.batch
        return fit_batch(
            self.extrapolator, batch, FitOptions.from_flat(**options), self.seeds, self.seed_covs, self.beamline
        )

    def first_hit_pulls(self, result, select=None):
        """Pulls (n, 5) at the first hit of the tracks with status ok (and `select`)."""
        first = self.batch.offsets[:-1]
        ok = result.status == 0
        if select is not None:
            ok &= select
        _, state, cov = result.locations["first_hit"]
        truth = self.truth[self.batch.hit_row[first]]
        sigma = np.sqrt(np.einsum("nii->ni", cov))
        return ((state - truth) / sigma)[ok], (state - truth)[ok], truth[ok]

    def long_tracks(self):
        """Tracks with ≥ 3 VELO hits and hits in all three SciFi stations."""
        g = self.geometry
        track = np.repeat(np.arange(self.batch.n_tracks), self.batch.n_nodes)
        sub = g.layer_subdetector[self.batch.layer]
        velo = np.bincount(track, weights=sub == 0, minlength=self.batch.n_tracks)
        ok = velo >= 3
        for station in (1, 2, 3):
            in_station = (sub == 2) & (g.layer_station[self.batch.layer] == station)
            ok &= np.bincount(track, weights=in_station, minlength=self.batch.n_tracks) >= 2
        return ok


def recorded_track(name: str):
    """(geometry, a TrackBatch of the one track, the .npz) of the lhcb-like track recorded in
    tests/fit/data/<name>.npz: its hits' layer, m (u, v), sigma (σ_u, σ_v), its seed and
    seed_cov, and where recorded its first hit's true state (`truth`)."""
    from pathlib import Path

    from pkf.fit.candidates import Candidates

    data = np.load(Path(__file__).parent / "data" / f"{name}.npz")
    geometry = load_geometry("lhcb-like")
    rows = np.arange(data["layer"].size)
    candidates = Candidates.from_hit_lists(np.zeros(rows.size), np.zeros(rows.size), rows)
    batch = TrackBatch.from_candidates(geometry, candidates, data["layer"], data["m"][:, 0], data["m"][:, 1],
                                       data["sigma"][:, 0], data["sigma"][:, 1])
    return geometry, batch, data
