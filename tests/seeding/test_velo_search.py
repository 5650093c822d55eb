"""VELO triplet search, merging and arbitration (pkf.seeding.velo_search, DESIGN §7.1–7.3).

Physics performance on simulated lhcb-like minimum-bias events at ν = 7.6 (DESIGN §10
matching: ≥ 70 % of a track's hits from one particle), exact consistency of the chain
χ² with the triplet fit and `combine_triplet_chain` (paper eqs. 5–6), the handling of
the two overlapping VELO halves and of missing modules on synthetic straight tracks,
batching, input checks, and the scaling of the work with the number of hits.
"""

from __future__ import annotations

import time

import numpy as np
import pyarrow as pa
import pytest

from pkf.geometry import load_geometry
from pkf.geometry.acceptance import in_active_area
from pkf.pipeline.matching import match_tracks
from pkf.pipeline.simulate import SimulationConfig, simulate_batch
from pkf.seeding import (
    FORM_CURVATURE,
    VeloTracks,
    combine_triplet_chain,
    find_velo_tracks,
    find_velo_tracks_in_hits,
    fit_triplets,
)
from pkf.seeding.velo_search import VeloSearchOptions, velo_layer_table

SIGMA = 0.0125  # VELO pixel resolution [mm]


@pytest.fixture(scope="module")
def geometry():
    return load_geometry("lhcb-like")


def _simulate(geometry, pileup, events, seed):
    hits, particles, mc_hits = simulate_batch(
        geometry, SimulationConfig(generator="minbias", events=events, pileup=pileup, seed=seed),
        0, events)
    col = lambda t, c: t.column(c).to_numpy(zero_copy_only=False)  # noqa: E731
    h = {c: col(hits, c) for c in hits.column_names}
    p = {c: col(particles, c) for c in particles.column_names}
    m = {c: col(mc_hits, c) for c in mc_hits.column_names}
    return hits, h, p, m


class Sample:
    """A simulated sample, its VELO tracks and the truth needed for the metrics."""

    def __init__(self, geometry, pileup, events, seed, **options):
        self.table, self.h, self.p, self.m = _simulate(geometry, pileup, events, seed)
        self.events = events
        h = self.h
        self.args = (h["event_id"], h["layer"], h["u"], h["v"], h["z"], h["sigma_u"])
        find_velo_tracks(*(a[:50] for a in self.args), geometry, **options)  # JIT warm-up
        t0 = time.process_time()
        self.tracks = find_velo_tracks(*self.args, geometry, **options)
        self.cpu_s = time.process_time() - t0
        # particle keys unique over events (noise: 0)
        pid = self.m["particle_id"]
        self.hit_key = np.where(pid > 0, h["event_id"] * 1_000_000 + pid, 0)
        self.key = self.p["event_id"] * 1_000_000 + self.p["particle_id"]
        self.momentum = np.sqrt(self.p["px"] ** 2 + self.p["py"] ** 2 + self.p["pz"] ** 2)
        velo = np.isin(h["layer"], velo_layer_table(geometry)[0])
        keys, counts = np.unique(self.hit_key[velo & (pid > 0)], return_counts=True)
        self.n_velo = np.zeros(self.key.size, dtype=np.int64)
        self.n_velo[np.searchsorted(self.key, keys)] = counts
        tr = self.tracks
        self.best, self.fraction, self.ghost = match_tracks(
            tr.track_of_hit, self.hit_key[tr.hit_rows], tr.n_tracks)

    def efficiency(self, p_min=0.0):
        sel = (self.n_velo >= 3) & (self.momentum > p_min)
        return np.isin(self.key[sel], self.best).mean(), int(sel.sum())

    def ghost_rate(self):
        return self.ghost.mean()

    def clone_rate(self, p_min=0.0):
        real = self.best[self.best >= 0]
        real = real[self.momentum[np.searchsorted(self.key, real)] > p_min]
        return (real.size - np.unique(real).size) / real.size


@pytest.fixture(scope="module")
def minbias76(geometry):
    return Sample(geometry, pileup=7.6, events=60, seed=4242)


@pytest.fixture(scope="module")
def minbias1(geometry):
    return Sample(geometry, pileup=1.0, events=150, seed=4243)


# ------------------------------------------------------------------------------------
# Physics performance (DESIGN §10) at ν = 7.6
# ------------------------------------------------------------------------------------


def test_efficiency_ghosts_clones_nu76(minbias76):
    s = minbias76
    eff2, n2 = s.efficiency(2000.0)
    eff1, _ = s.efficiency(1000.0)
    eff5, _ = s.efficiency(5000.0)
    eff_all, _ = s.efficiency(0.0)
    assert n2 > 5000
    assert eff2 >= 0.98, eff2
    assert eff1 >= 0.98 and eff5 >= 0.98, (eff1, eff5)
    assert eff_all >= 0.97, eff_all  # every particle with ≥ 3 VELO hits, p down to ~0.1 GeV
    assert s.ghost_rate() <= 0.05, s.ghost_rate()
    assert s.clone_rate() <= 0.01, s.clone_rate()
    assert s.clone_rate(1000.0) <= 0.005


def test_tracks_are_well_formed(minbias76, geometry):
    tr, h = minbias76.tracks, minbias76.h
    assert isinstance(tr, VeloTracks)
    assert tr.offsets[0] == 0 and tr.offsets[-1] == tr.hit_rows.size
    assert np.all(tr.n_hits >= 3)
    assert np.unique(tr.hit_rows).size == tr.hit_rows.size  # a hit in at most one track
    velo = velo_layer_table(geometry)[0]
    assert np.all(np.isin(h["layer"][tr.hit_rows], velo))
    toh = tr.track_of_hit
    assert np.all(h["event_id"][tr.hit_rows] == tr.event_id[toh])
    assert np.all(np.diff(tr.event_id) >= 0)
    z = h["z"][tr.hit_rows]
    inner = toh[1:] == toh[:-1]
    assert np.all(np.diff(z)[inner] > 0)  # sorted by z, one hit per module
    assert np.array_equal(tr.z, z[tr.offsets[:-1]])
    assert np.all(np.isfinite(tr.chi2)) and np.all(tr.ndf > 0)


def test_first_state_against_truth(minbias76):
    s = minbias76
    tr = s.tracks
    first = tr.hit_rows[tr.offsets[:-1]]
    matched = (s.best >= 0) & (s.hit_key[first] == s.best)
    p = np.where(s.best >= 0, s.momentum[np.searchsorted(s.key, np.maximum(s.best, 0))], 0.0)
    sel = matched & (p > 5000.0)
    assert sel.sum() > 2000
    res_x = tr.x[sel] - s.m["x"][first[sel]]
    res_y = tr.y[sel] - s.m["y"][first[sel]]
    res_tx = tr.tx[sel] - s.m["tx"][first[sel]]
    res_ty = tr.ty[sel] - s.m["ty"][first[sel]]
    for res, typical in ((res_x, 0.015), (res_y, 0.015), (res_tx, 4e-4), (res_ty, 4e-4)):
        assert np.median(np.abs(res)) < typical
        assert abs(np.mean(res)) < 0.2 * np.std(res) + 1e-6  # unbiased


# ------------------------------------------------------------------------------------
# Scaling: the work per hit must not grow with the occupancy (no N² or N³ search)
# ------------------------------------------------------------------------------------


def test_work_grows_linearly_with_hits(minbias1, minbias76):
    lo, hi = minbias1.tracks.stats, minbias76.tracks.stats
    hits_ratio = hi["hits"] / minbias76.events / (lo["hits"] / minbias1.events)
    assert hits_ratio > 3.5  # ν = 7.6 vs ν = 1
    per_hit = {k: (hi[k] / hi["hits"]) / (lo[k] / lo["hits"])
               for k in ("doublets", "fits", "triplets")}
    # a pairwise (N²) search would scale these by ≈ hits_ratio ≈ 4.4, N³ by ≈ 19
    assert per_hit["fits"] < 1.5, per_hit
    assert per_hit["triplets"] < 1.5, per_hit
    assert per_hit["doublets"] < 2.2, per_hit
    cpu_per_hit = (minbias76.cpu_s / hi["hits"]) / (minbias1.cpu_s / lo["hits"])
    assert cpu_per_hit < 2.5, cpu_per_hit
    assert minbias1.efficiency(2000.0)[0] >= 0.98
    assert minbias1.clone_rate() <= 0.01 and minbias1.ghost_rate() <= 0.05


# ------------------------------------------------------------------------------------
# Merging: chain χ² is the combined χ² of its triplets (paper eqs. 5–6)
# ------------------------------------------------------------------------------------


@pytest.mark.parametrize("straight", [True, False])
def test_chain_chi2_is_combined_triplet_chi2(geometry, straight):
    _, h, _, _ = _simulate(geometry, pileup=2.0, events=8, seed=99)
    args = (h["event_id"], h["layer"], h["u"], h["v"], h["z"], h["sigma_u"])
    # plain chains: no gap filling or extension, no candidate that lost hits
    tr = find_velo_tracks(*args, geometry, straight=straight, extend=False, fill_gaps=False,
                          max_shared=0.0)
    assert tr.n_tracks > 50
    velo, lt = velo_layer_table(geometry)
    lz = {int(v): i for i, v in enumerate(velo)}
    triplets, n_trip = [], []
    for t in range(tr.n_tracks):  # test bookkeeping only; the search itself is compiled
        rows = tr.hit_rows[tr.offsets[t]:tr.offsets[t + 1]]
        triplets += [rows[i:i + 3] for i in range(rows.size - 2)]
        n_trip.append(rows.size - 2)
    trip = np.array(triplets)
    pos = np.stack([h["u"][trip], h["v"][trip], h["z"][trip]], axis=-1)
    var = np.zeros_like(pos)
    var[..., 0] = var[..., 1] = h["sigma_u"][trip] ** 2
    middle = np.array([lz[int(v)] for v in h["layer"][trip[:, 1]]])
    bfield = geometry.field.evaluate(np.zeros(middle.size), np.zeros(middle.size),
                                     lt[middle, 0])
    fit = fit_triplets(pos, bfield, geometry.layer_x_over_x0[velo[middle]], var,
                       p_min=1000.0, form=FORM_CURVATURE, straight_below_threshold=straight)
    assert np.all(fit.valid)
    assert np.all(fit.chi2 <= _chi2_cut(fit.ndf))
    offsets = np.concatenate([[0], np.cumsum(n_trip)])
    k, vk, chi2, ndf, status = combine_triplet_chain(offsets, fit.kappa, fit.var_kappa,
                                                     fit.chi2, fit.ndf)
    assert np.all(status == 0)
    np.testing.assert_allclose(tr.chi2, chi2, rtol=1e-9, atol=1e-9)
    n_trip = np.array(n_trip)
    expected_ndf = ndf - (n_trip - 1) if straight else ndf  # κ ≡ 0: no κ-consistency dof
    np.testing.assert_array_equal(tr.ndf, expected_ndf)


def _chi2_cut(ndf, pvalue=1e-3):
    from scipy.stats import chi2

    return chi2.isf(pvalue, ndf) * (1 + 1e-12)


# ------------------------------------------------------------------------------------
# Synthetic straight tracks: both VELO halves, missing modules, noise
# ------------------------------------------------------------------------------------


def _straight_event(geometry, lines, rng, drop=(), noise=0):
    """Hits of straight lines (x0, y0, z0, tx, ty) on the VELO modules whose active area
    they cross (smeared by σ), minus the (line, layer) pairs in `drop`, plus uniform
    noise hits. Returns (layer, x, y, z, line index or −1)."""
    velo, lt = velo_layer_table(geometry)
    pl = geometry.planes
    rows = {int(li): i for i, li in enumerate(pl.layer)}
    out = []
    for n, (x0, y0, z0, tx, ty) in enumerate(lines):
        for layer in velo:
            zl = geometry.layer_z[layer]
            if zl <= z0:
                continue
            x, y = x0 + tx * (zl - z0), y0 + ty * (zl - z0)
            r = rows[int(layer)]
            if not in_active_area(x, y, pl.half_x[r], pl.half_y[r], pl.hole_radius[r],
                                  pl.hole_half_x[r], pl.hole_half_y[r], pl.side[r],
                                  pl.side_overlap[r]):
                continue
            if (n, int(layer)) in drop:
                continue
            out.append((layer, x + rng.normal(0, SIGMA), y + rng.normal(0, SIGMA), zl, n))
    for _ in range(noise):
        layer = rng.choice(velo)
        r = rows[int(layer)]
        while True:
            x, y = rng.uniform(-45, 45, 2)
            if in_active_area(x, y, pl.half_x[r], pl.half_y[r], pl.hole_radius[r],
                              pl.hole_half_x[r], pl.hole_half_y[r], pl.side[r],
                              pl.side_overlap[r]):
                break
        out.append((layer, x, y, geometry.layer_z[layer], -1))
    out.sort(key=lambda t: (t[0], t[1]))
    a = np.array(out, dtype=float)
    return a[:, 0].astype(np.int64), a[:, 1], a[:, 2], a[:, 3], a[:, 4].astype(np.int64)


def _run(geometry, event, **options):
    layer, x, y, z, line = event
    n = layer.size
    tr = find_velo_tracks(np.zeros(n, dtype=np.int64), layer, x, y, z, np.full(n, SIGMA),
                          geometry, **options)
    return tr, [line[tr.hit_rows[tr.offsets[t]:tr.offsets[t + 1]]] for t in range(tr.n_tracks)]


def test_overlap_track_is_one_track_on_both_halves(geometry):
    rng = np.random.default_rng(1)
    # |x| < 5 mm all along: hits on every module (both halves)
    overlap = (0.0, 0.0, 0.0, 0.003, 0.05)
    right = (0.0, 0.0, 10.0, 0.02, -0.06)  # x > 5 mm from z ≈ 260: right half only
    left = (0.0, 0.0, -30.0, -0.05, 0.04)
    event = _straight_event(geometry, [overlap, right, left], rng, noise=40)
    layer, line = event[0], event[4]
    tr, lines = _run(geometry, event)
    assert tr.n_tracks == 3
    for n in range(3):
        [found] = [ln for ln in lines if np.all(ln == n)]
        assert found.size == np.sum(line == n)  # every hit of the line, nothing else
    for n in (0, 1, 2):  # modules alternate halves: even = left, odd = right
        on = layer[line == n]
        assert np.any(on % 2 == 0) and np.any(on % 2 == 1)  # starts in the overlap strip
    assert np.sum(layer[line == 1] % 2 == 1) > 2 * np.sum(layer[line == 1] % 2 == 0)
    # triplets live on one half: without gap filling the overlap line is two tracks
    tr, lines = _run(geometry, event, fill_gaps=False, extend=False)
    halves = [ln for ln in lines if np.all(ln == 0)]
    assert len(halves) == 2 and sum(h.size for h in halves) == np.sum(line == 0)
    # triplets across halves (same_side=False) follow it as one chain
    tr, lines = _run(geometry, event, same_side=False, fill_gaps=False, extend=False)
    [found] = [ln for ln in lines if np.all(ln == 0)]
    assert found.size == np.sum(line == 0)


def test_short_track_across_halves(geometry):
    rng = np.random.default_rng(4)
    # large angle in the overlap strip: four hits, two per half, then out of the VELO
    short = (0.0, 0.0, -10.0, 0.01, 0.8)
    event = _straight_event(geometry, [short], rng, noise=20)
    layer, line = event[0], event[4]
    assert np.sum(line == 0) == 4 and np.sum(layer[line == 0] % 2 == 0) == 2
    tr, lines = _run(geometry, event, second_pass=False)
    assert not any(np.any(ln == 0) for ln in lines)  # no three modules of one half
    tr, lines = _run(geometry, event)
    [found] = [ln for ln in lines if np.all(ln == 0)]
    assert found.size == 4


def test_missing_modules(geometry):
    rng = np.random.default_rng(2)
    right = (0.0, 0.0, 0.0, 0.08, 0.01)
    full = _straight_event(geometry, [right], rng)
    layers = full[0]
    assert layers.size >= 8
    one = {(0, int(layers[3]))}  # one module without a hit: the chain skips it
    two = {(0, int(layers[3])), (0, int(layers[4]))}  # two consecutive ones
    tr, lines = _run(geometry, _straight_event(geometry, [right], rng, drop=one),
                     extend=False)
    assert tr.n_tracks == 1 and lines[0].size == layers.size - 1
    event = _straight_event(geometry, [right], rng, drop=two)
    tr, lines = _run(geometry, event, extend=False)
    assert tr.n_tracks == 2  # the triplet search alone cannot bridge two missing modules
    tr, lines = _run(geometry, event)
    assert tr.n_tracks == 1 and lines[0].size == layers.size - 2  # the extension does


def test_first_state_of_exact_line(geometry):
    rng = np.random.default_rng(3)
    line = (0.02, -0.03, 15.0, -0.07, 0.09)
    event = _straight_event(geometry, [line], rng)
    tr, _ = _run(geometry, event)
    assert tr.n_tracks == 1
    x0, y0, z0, tx, ty = line
    np.testing.assert_allclose(tr.x[0], x0 + tx * (tr.z[0] - z0), atol=4 * SIGMA)
    np.testing.assert_allclose(tr.y[0], y0 + ty * (tr.z[0] - z0), atol=4 * SIGMA)
    np.testing.assert_allclose([tr.tx[0], tr.ty[0]], [tx, ty], atol=1e-3)


# ------------------------------------------------------------------------------------
# Batching and the interface
# ------------------------------------------------------------------------------------


def test_batched_equals_event_by_event(geometry):
    table, h, _, _ = _simulate(geometry, pileup=3.0, events=6, seed=7)
    args = (h["event_id"], h["layer"], h["u"], h["v"], h["z"], h["sigma_u"])
    batch = find_velo_tracks(*args, geometry)
    for e in np.unique(h["event_id"]):
        rows = np.flatnonzero(h["event_id"] == e)
        one = find_velo_tracks(*(a[rows] for a in args), geometry)
        sel = batch.event_id == e
        assert one.n_tracks == sel.sum()
        t = np.flatnonzero(sel)
        got = [rows[one.hit_rows[one.offsets[i]:one.offsets[i + 1]]] for i in range(one.n_tracks)]
        want = [batch.hit_rows[batch.offsets[i]:batch.offsets[i + 1]] for i in t]
        assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))
        np.testing.assert_allclose(one.tx, batch.tx[sel])
    from_table = find_velo_tracks_in_hits(table, geometry)
    np.testing.assert_array_equal(from_table.hit_rows, batch.hit_rows)


def test_inputs(geometry):
    n = 5
    ev = np.zeros(n, dtype=np.int64)
    layer = np.arange(n)
    x = np.full(n, 10.0)
    z = geometry.layer_z[layer]
    empty = find_velo_tracks(ev[:0], layer[:0], x[:0], x[:0], z[:0], x[:0], geometry)
    assert empty.n_tracks == 0 and empty.offsets.tolist() == [0]
    few = find_velo_tracks(ev, layer, x, x, z, np.full(n, SIGMA), geometry)
    assert few.n_tracks == 0
    with pytest.raises(ValueError, match="sorted by event"):
        find_velo_tracks(np.array([1, 0, 0, 0, 0]), layer, x, x, z, np.full(n, SIGMA), geometry)
    with pytest.raises(ValueError, match="row 2"):
        bad = x.copy()
        bad[2] = np.nan
        find_velo_tracks(ev, layer, bad, x, z, np.full(n, SIGMA), geometry)
    with pytest.raises(ValueError, match="shape"):
        find_velo_tracks(ev, layer[:3], x, x, z, np.full(n, SIGMA), geometry)
    with pytest.raises(TypeError):
        find_velo_tracks(ev, layer, x, x, z, np.full(n, SIGMA), geometry, no_such_option=1)
    with pytest.raises(ValueError):
        VeloSearchOptions(pvalue=0.0)
    with pytest.raises(ValueError):
        VeloSearchOptions(min_hits=2)
    # strip hits (v = NaN) and unknown layers are ignored, not errors
    strip = np.array([geometry.n_layers - 1, 10**4])
    none = find_velo_tracks(np.zeros(2, dtype=np.int64), strip, np.ones(2), np.full(2, np.nan),
                            np.ones(2), np.full(2, 0.08), geometry)
    assert none.n_tracks == 0
    tab = pa.table({"event_id": ev, "layer": layer.astype(np.int16), "z": z, "u": x, "v": x,
                    "sigma_u": np.full(n, SIGMA), "sigma_v": np.full(n, SIGMA)})
    assert find_velo_tracks_in_hits(tab, geometry).n_tracks == 0
