"""A parametrized VELO step across a layer without a hit carries that layer's scattering
(`pkf.params.transport.add_crossed_velo_layers`, issue 15).

Pion gun on lhcb-like, 1–4 GeV, truth tracks with the second VELO hit of every track taken
away (the track still crosses its module: the modules alternate sides, so the next hit on
the same side is the next module it crosses). The first-hit slope is then measured by hits
50 mm apart with a module's scattering in between, the case where the old step (one
plane's noise whatever the layers crossed) claimed the slope to the hit resolution.
Measured (120 events × 10, 1,198 tracks with ≥ 3 VELO hits left): first-hit tx/ty pull
cores 0.96/0.97 (reference fit 0.99/0.99), parametrized/reference tx variance median 1.05;
without the crossed layer (the old step) 1.51/1.55 and 0.48.
"""

import numpy as np
import pytest

from pkf.fit.beamline import straight_line_extrapolator
from pkf.fit.reference import reference_extrapolator
from pkf.fit.tracks import FitOptions, TrackBatch, fit_batch, seed_batch
from pkf.geometry import load_geometry
from pkf.params.gauss import gaussian_core
from pkf.params.parameter_set import shipped_parameters
from pkf.pipeline.simulate import SimulationConfig, simulate_batch
from pkf.pipeline.truth_pattern import truth_candidates

STATE = ("x", "y", "tx", "ty", "qop")


def _column(table, name):
    return table.column(name).to_numpy(zero_copy_only=False)


@pytest.fixture(scope="module")
def gapped_sample():
    """Truth tracks of a 1–4 GeV pion gun without their second VELO hit, and their fits."""
    geometry = load_geometry("lhcb-like")
    config = SimulationConfig(generator="gun", events=120, seed=17, particles=10, p_min=1000.0,
                              p_max=4000.0, eta_min=2.0, eta_max=4.5)
    hits, _, mc = simulate_batch(geometry, config, 0, config.events)
    layer = _column(hits, "layer").astype(np.int64)
    event = _column(hits, "event_id").astype(np.int64)
    particle = _column(mc, "particle_id").astype(np.int64)
    truth = np.column_stack([_column(mc, c).astype(float) for c in STATE])
    velo = geometry.layer_subdetector[layer] == 0
    order = np.lexsort((layer, particle, event))
    ranked = order[velo[order] & (particle[order] > 0)]
    key = event[ranked] * (1 << 24) + particle[ranked]
    start = np.r_[True, key[1:] != key[:-1]]
    rank = np.arange(ranked.size) - np.maximum.accumulate(np.where(start, np.arange(ranked.size), 0))
    particle = particle.copy()
    particle[ranked[rank == 1]] = 0  # the second VELO hit: treated as not on the track
    batch = TrackBatch.from_candidates(geometry, truth_candidates(event, layer, particle), layer,
                                       *(_column(hits, c).astype(float) for c in ("u", "v", "sigma_u", "sigma_v")))
    seeds, seed_covs, _ = seed_batch(batch, geometry.reconstruction_field(), geometry)
    beamline = straight_line_extrapolator(geometry)
    fits = {}
    for name, ext in (("parametrized", shipped_parameters(geometry).extrapolator(geometry)),
                      ("reference", reference_extrapolator(geometry))):
        fits[name] = fit_batch(ext, batch, FitOptions(), seeds, seed_covs, beamline)
    first = batch.offsets[:-1]
    velo_hits = np.add.reduceat((geometry.layer_subdetector[batch.layer] == 0).astype(int), first)
    return fits, truth[batch.hit_row[first]], velo_hits


def test_slopes_after_a_missing_velo_hit_are_covered(gapped_sample):
    fits, truth, velo_hits = gapped_sample
    par, ref = fits["parametrized"], fits["reference"]
    ok = (par.status == 0) & (ref.status == 0) & (velo_hits >= 3)
    assert ok.sum() > 500
    _, state, cov = par.locations["first_hit"]
    _, _, ref_cov = ref.locations["first_hit"]
    for i in (2, 3):
        pull = (state[ok, i] - truth[ok, i]) / np.sqrt(cov[ok, i, i])
        assert 0.93 < gaussian_core(pull).sigma < 1.08, (STATE[i], gaussian_core(pull).sigma)
    ratio = cov[ok, 2, 2] / ref_cov[ok, 2, 2]
    assert 0.9 < np.median(ratio) < 1.1, np.median(ratio)
