"""The Gaussian-sum filter (issue 7): equals the Kalman fit without bremsstrahlung,
improves electron fits where the detector can see the radiation, calibrated posteriors."""

from dataclasses import replace

import numpy as np
import pytest
from fit_helpers import TruthSample, recorded_track
from scipy.special import ndtri
from scipy.stats import kstest

from pkf.fit.gsf import (
    _merge_siblings,
    _reduce,
    fit_batch_gsf,
    gsf_extrapolator,
    product_target,
    qop_mixture_cdf,
    sibling_target,
)
from pkf.fit.reference import reference_extrapolator
from pkf.fit.options import GSFOptions
from pkf.fit.seed import TRACK_UPSTREAM
from pkf.fit.hypothesis import with_hypothesis
from pkf.fit.tracks import FitOptions, fit_batch
from pkf.geometry import load_geometry, parse_geometry
from pkf.params.gauss import gaussian_core
from pkf.physics.constants import MASS_PION

ELECTRONS = {"species": "electron", "particles": 10, "p_min": 2000.0, "p_max": 50000.0, "eta_min": 2.0, "eta_max": 5.0}


def _nodes(sample, location):
    """Node index per track: first hit, last hit, or the last node of a subdetector."""
    b = sample.batch
    if location == "first_hit":
        return b.offsets[:-1]
    if location == "last_hit":
        return b.offsets[1:] - 1
    track = np.repeat(np.arange(b.n_tracks), b.n_nodes)
    last = np.full(b.n_tracks, -1)
    in_sub = np.flatnonzero(sample.geometry.layer_subdetector[b.layer] == {"last_ut_hit": 1}[location])
    np.maximum.at(last, track[in_sub], in_sub)
    return last


def _location(sample, result, location, select):
    """δp/p = p_fit/p_true − 1, q/p pulls and, for a GSF run with kept mixtures, the PIT
    (CDF of the smoothed q/p mixture at the true q/p) at `location` of the tracks `select`."""
    nodes = _nodes(sample, location)[select]
    assert np.all(nodes >= 0)
    state, cov = result.node_state[nodes], result.node_cov[nodes]
    truth = sample.truth[sample.batch.hit_row[nodes]]
    dp_over_p = np.abs(truth[:, 4]) / np.abs(state[:, 4]) - 1.0
    pull = (state[:, 4] - truth[:, 4]) / np.sqrt(cov[:, 4, 4])
    if getattr(result, "qop_mixture", np.zeros(0)).size == 0:
        return dp_over_p, pull
    return dp_over_p, pull, qop_mixture_cdf(result.qop_mixture[nodes], truth[:, 4])


def _pit_width(pit):
    """Core width of Φ⁻¹(PIT): 1 for a calibrated posterior."""
    return gaussian_core(ndtri(np.clip(pit, 1e-12, 1.0 - 1e-12))).sigma


def _covers(pull):
    """Whether q/p pulls say the written covariances cover the errors (issue 15): RMS in
    [0.8, 1.25] and at least 68 % of them within ±1.2."""
    rms = np.sqrt(np.mean(pull**2))
    return 0.8 <= rms <= 1.25 and np.mean(np.abs(pull) < 1.2) >= 0.68


def _sigma68(values):
    """Half-width of the central 68 % interval (robust for these skewed distributions)."""
    lo, hi = np.percentile(values, [16, 84])
    return 0.5 * (hi - lo)


def _fit_both(geometry, seed):
    sample = TruthSample(geometry, events=100, seed=seed, **ELECTRONS)
    kalman = sample.fit()  # the reference Kalman fitter as `pkf reconstruct` runs it
    gsf = fit_batch_gsf(gsf_extrapolator(sample.geometry), sample.batch, FitOptions(), sample.seeds,
                        sample.seed_covs, sample.beamline, keep_qop_mixtures=True)
    return sample, kalman, gsf, (kalman.status == 0) & (gsf.status == 0)


def _smoothing_everywhere(options=None):
    """FitOptions whose GSF smooths with the mixture product at every node."""
    options = options or FitOptions()
    return replace(options, gsf=replace(options.gsf, mixture_smoothing_everywhere=True))


def material_in_the_field():
    """The telescope with 3 % X0 planes in 2 T: 0.3 X0 across the 1 m where the momentum is
    measured, the material budget and field of a silicon tracker like ATLAS's."""
    text = load_geometry("telescope").text.replace("by = 1.0", "by = 2.0").replace("x_over_x0 = 0.01",
                                                                                   "x_over_x0 = 0.03")
    return parse_geometry(text, source="telescope-3pc-X0-2T")


@pytest.fixture(scope="module")
def lhcb_electrons():
    sample, kalman, gsf, ok = _fit_both(load_geometry("lhcb-like"), 4)
    return sample, kalman, gsf, ok & sample.long_tracks()


@pytest.fixture(scope="module")
def lhcb_electrons_smoothed_everywhere(lhcb_electrons):
    """The GSF of `lhcb_electrons` with the mixture product at every node."""
    sample = lhcb_electrons[0]
    return fit_batch_gsf(gsf_extrapolator(sample.geometry), sample.batch, _smoothing_everywhere(), sample.seeds,
                         sample.seed_covs, sample.beamline, keep_qop_mixtures=True)


def test_smoothing_at_the_written_nodes_changes_only_outlier_decisions(lhcb_electrons,
                                                                      lhcb_electrons_smoothed_everywhere):
    """The default smoothing (the mixture product at the first and last node only, module
    docstring "Smoothing at the written nodes") against the mixture product at every node: a
    track whose outlier removals are the same has bitwise the same written states, χ² and
    kept first-node q/p mixture; other outlier removals on a few tracks (1.5 % of 1,500 measured,
    < 5 % here) and the first- and last-hit q/p pulls unchanged (RMS within 0.02, share within
    ±1.2 within 0.01)."""
    sample, _, new, _ = lhcb_electrons
    old = lhcb_electrons_smoothed_everywhere
    both = (new.status == 0) & (old.status == 0)
    assert both.sum() > 900
    node_flags = np.add.reduceat(~new.node_active != ~old.node_active, sample.batch.offsets[:-1])
    same = both & (node_flags == 0)
    assert same.sum() >= 0.95 * both.sum()
    first = sample.batch.offsets[:-1]
    for name in ("first_hit", "last_hit", "beamline"):
        np.testing.assert_array_equal(new.locations[name][1][same], old.locations[name][1][same])
        np.testing.assert_array_equal(new.locations[name][2][same], old.locations[name][2][same])
    np.testing.assert_array_equal(new.chi2[same], old.chi2[same])
    np.testing.assert_array_equal(new.qop_mixture[first[same]], old.qop_mixture[first[same]])
    for location in ("first_hit", "last_hit"):
        pulls = [_location(sample, r, location, both)[1] for r in (new, old)]
        assert abs(np.sqrt(np.mean(pulls[0] ** 2)) - np.sqrt(np.mean(pulls[1] ** 2))) < 0.02
        assert abs(np.mean(np.abs(pulls[0]) < 1.2) - np.mean(np.abs(pulls[1]) < 1.2)) < 0.01


def test_a_node_where_the_product_with_moments_fails_takes_the_mixtures_product():
    """A minimum-bias track (ν = 7.6, seed 31, 15 events, truth track 1958; recorded) on which
    the product with the other filter's moments failed at a node (status "not positive
    definite", 7b6c52b) while the mixtures' product fits it: that node takes the mixtures'
    product, and the fit is the one with the product at every node."""
    geometry, batch, data = recorded_track("gsf_moments_product_fails")
    ctx = gsf_extrapolator(geometry)
    fits = [fit_batch_gsf(ctx, batch, options, data["seed"][None], data["seed_cov"][None])
            for options in (FitOptions(), _smoothing_everywhere())]
    assert [list(f.status) for f in fits] == [[0], [0]]
    assert fits[0].chi2[0] == fits[1].chi2[0]
    for name in ("first_hit", "last_hit"):
        np.testing.assert_array_equal(fits[0].locations[name][1], fits[1].locations[name][1])


def test_a_fit_whose_components_all_curl_away_is_repeated_with_the_seeds_q_over_p_width():
    """A real long track of the default path (Pythia minimum bias ν = 3, seed 5, triplet
    pattern: a 2.43 GeV π⁻ with ty = −0.25, recorded with its first hit's truth) through the
    GSF: from the widened q/p prior its one UT hit pulls every component below 1.5 GeV, and
    all of them curl away in the magnet ("extrapolation failed" before the fallback). The fit
    is repeated with the seed's own q/p width (passes 3): fitted, χ²/ndf below 2, and the
    first-hit state within 3σ of the truth in every parameter."""
    geometry, batch, data = recorded_track("gsf_wide_prior_curls")
    fit = fit_batch_gsf(gsf_extrapolator(geometry), batch, FitOptions(), data["seed"][None], data["seed_cov"][None])
    assert list(fit.status) == [0] and list(fit.passes) == [3]
    assert fit.chi2[0] / fit.ndf[0] < 2.0
    state, cov = fit.locations["first_hit"][1][0], fit.locations["first_hit"][2][0]
    assert np.all(np.abs((state - data["truth"]) / np.sqrt(np.diag(cov))) < 3.0)


def test_smoothing_at_the_written_nodes_is_exact_for_one_component():
    """Pions (no bremsstrahlung, one component): every node state bitwise the mixture product's."""
    geometry = load_geometry("lhcb-like")
    sample = TruthSample(geometry, events=20, seed=5, particles=10, p_min=2000.0, p_max=100000.0,
                         eta_min=2.0, eta_max=5.0)
    ctx = gsf_extrapolator(geometry, mass=MASS_PION)
    new = fit_batch_gsf(ctx, sample.batch, FitOptions(), sample.seeds, sample.seed_covs)
    old = fit_batch_gsf(ctx, sample.batch, _smoothing_everywhere(), sample.seeds, sample.seed_covs)
    assert np.mean(new.status == 0) > 0.95
    np.testing.assert_array_equal(new.node_state, old.node_state)
    np.testing.assert_array_equal(new.node_cov, old.node_cov)
    np.testing.assert_array_equal(new.n_outliers, old.n_outliers)


@pytest.fixture(scope="module")
def telescope_electrons():
    sample, kalman, gsf, ok = _fit_both(load_geometry("telescope"), 7)
    return sample, kalman, gsf, ok & (sample.batch.n_nodes >= 8)


@pytest.fixture(scope="module")
def material_in_field_electrons():
    sample, kalman, gsf, ok = _fit_both(material_in_the_field(), 8)
    return sample, kalman, gsf, ok & (sample.batch.n_nodes >= 8)


def test_gsf_without_bremsstrahlung_equals_the_kalman_fit():
    """Pions: one component all the way; the first-hit state equals the reference Kalman
    fit's within 0.1σ RMS (the Kalman fit iterated once, i.e. at the χ² minimum)."""
    geometry = load_geometry("lhcb-like")
    sample = TruthSample(geometry, events=80, seed=31, particles=10, p_min=2000.0, p_max=100000.0,
                         eta_min=2.0, eta_max=5.0)
    gsf = fit_batch_gsf(gsf_extrapolator(geometry, mass=MASS_PION), sample.batch, FitOptions(), sample.seeds,
                        sample.seed_covs, sample.beamline)
    assert np.all(gsf.n_components[gsf.status == 0] == 1)
    kalman = sample.fit(iterations=2)
    long = sample.long_tracks() & (gsf.status == 0) & (kalman.status == 0)
    assert long.sum() > 500
    assert np.all(gsf.n_outliers[long] == kalman.n_outliers[long])
    _, sg, cg = gsf.locations["first_hit"]
    _, sk, ck = kalman.locations["first_hit"]
    sigma = np.sqrt(np.einsum("nii->ni", ck[long]))
    rms = np.sqrt(np.mean(((sg[long] - sk[long]) / sigma) ** 2, axis=0))
    assert np.all(rms < 0.1), rms
    ratio = np.sqrt(np.einsum("nii->ni", cg[long])) / sigma
    assert np.all(np.abs(np.median(ratio, axis=0) - 1.0) < 0.02)
    assert np.median(np.abs(gsf.chi2[long] / kalman.chi2[long] - 1.0)) < 0.01


def test_electrons_where_the_field_measures_across_material(material_in_field_electrons):
    """Issue 7's electron criteria as written, where a GSF can meet them: the momentum is
    measured across material in which most electrons radiate more than the resolution
    (telescope, 3 % X0 planes in 2 T). At the first hit the Gaussian core of δp/p is
    ≥ 10 % narrower than the reference Kalman fit's and the q/p covariance covers the
    error (`_covers`; the written q/p variance is the mixture's about the written q/p),
    where the Kalman fit's pull core is > 2. Measured on five samples: core −30 … −40 %,
    Kalman pull core 3.2–3.8; this sample: GSF pull RMS 1.00, core 0.66 (the posterior is
    skewed: its Gaussian core is narrower than its RMS). The smoothed posteriors are calibrated at the
    first and last hit: Φ⁻¹(PIT) core width in [0.9, 1.1], PIT uniform (KS p > 1e−3)."""
    sample, kalman, gsf, ok = material_in_field_electrons
    assert ok.sum() > 900
    dp_k, pull_k = _location(sample, kalman, "first_hit", ok)
    dp_g, pull_g, pit = _location(sample, gsf, "first_hit", ok)
    assert gaussian_core(dp_g).sigma <= 0.9 * gaussian_core(dp_k).sigma
    assert _covers(pull_g) and gaussian_core(pull_k).sigma > 2.0
    for location in ("first_hit", "last_hit"):
        pit = _location(sample, gsf, location, ok)[2]
        assert 0.9 <= _pit_width(pit) <= 1.1 and kstest(pit, "uniform").pvalue > 1e-3, location


def test_electrons_in_the_built_in_telescope(telescope_electrons):
    """With 1 % X0 planes in 1 T half the electrons lose less than the 2 % resolution, and
    for them the Kalman fit is already optimal: the Gaussian core stays within 5 % of the
    Kalman fit's (measured −4 … +4 %), while the RMS of δp/p at the first hit drops by
    ≥ 30 % (measured −51 %) and the q/p covariance covers the error (`_covers`; the
    Kalman fit's pull core 1.25–1.32 is too wide)."""
    sample, kalman, gsf, ok = telescope_electrons
    assert ok.sum() > 900
    dp_k, pull_k = _location(sample, kalman, "first_hit", ok)
    dp_g, pull_g, _ = _location(sample, gsf, "first_hit", ok)
    rms_k, rms_g = np.sqrt(np.mean(dp_k**2)), np.sqrt(np.mean(dp_g**2))
    assert rms_g < 0.7 * rms_k, (rms_g, rms_k)
    assert _covers(pull_g)
    assert gaussian_core(pull_k).sigma > 1.2
    assert gaussian_core(dp_g).sigma < 1.05 * gaussian_core(dp_k).sigma


def test_electrons_lhcb_like_where_the_magnet_measures(lhcb_electrons, lhcb_electrons_smoothed_everywhere):
    """lhcb-like: the momentum is measured in the magnet, which holds no material. At the
    last UT hit (the state entering the magnet) there is no radiation left to model, and
    the GSF equals the Kalman fit: Gaussian cores of δp/p within ±10 % (measured 0.92–1.02
    on six samples), q/p pull core in [0.9, 1.2] (0.93–1.00) and a calibrated posterior
    (Φ⁻¹(PIT) width in [0.9, 1.1]; 0.94–1.00). Issue 7's "≥ 10 % narrower" cannot hold here."""
    sample, kalman, _, ok = lhcb_electrons
    gsf = lhcb_electrons_smoothed_everywhere  # the mixture posterior at the last UT hit
    ok = ok & (gsf.status == 0) & (_nodes(sample, "last_ut_hit") >= 0)
    assert ok.sum() > 900
    dp_k, _ = _location(sample, kalman, "last_ut_hit", ok)
    dp_g, pull_g, pit = _location(sample, gsf, "last_ut_hit", ok)
    assert 0.9 <= gaussian_core(dp_g).sigma / gaussian_core(dp_k).sigma <= 1.1
    # issue 15: no worse than the Kalman fit under the electron hypothesis (1,500 tracks:
    # δp/p core 0.317 % GSF, 0.336 % electron Kalman, 0.316 % pion Kalman)
    electron_ext = with_hypothesis(sample.extrapolator, sample.geometry, "electron")
    electron_kalman = fit_batch(electron_ext, sample.batch, FitOptions.from_flat(iterations=2, hypothesis="electron"),
                                sample.seeds, sample.seed_covs)
    dp_e, _ = _location(sample, electron_kalman, "last_ut_hit", ok & (electron_kalman.status == 0))
    assert gaussian_core(dp_g).sigma <= gaussian_core(dp_e).sigma
    assert 0.9 <= gaussian_core(pull_g).sigma <= 1.2
    assert 0.9 <= _pit_width(pit) <= 1.1


def test_electrons_lhcb_like_last_hit(lhcb_electrons):
    """At the last hit the SciFi radiation (0.12 X0) is seen only through the fringe field.
    The GSF's central 68 % of δp/p is ≥ 5 % narrower than the Kalman fit's (measured
    −6 … −26 % on six samples, −11 % on this one), its posterior is calibrated in width
    (Φ⁻¹(PIT) core in [0.9, 1.1], measured 0.97–1.03; the PIT's shape is not uniform, KS
    p ~1e−4–1e−6) and ≥ 68 % of its q/p pulls are within ±1.2 (measured 0.90) where the
    Kalman fit's are not (0.30; pull core 4.4–6.4). (The pull RMS, 2.3 on 1,500 tracks,
    is that of the ~1 % whose fit fails outright, |pull| > 10, in every fitter.)
    Its Gaussian core is ~2× the Kalman fit's, whose narrow core is the no-radiation
    hypothesis — right for the ~45 % who do not radiate."""
    sample, kalman, gsf, ok = lhcb_electrons
    dp_k, pull_k = _location(sample, kalman, "last_hit", ok)
    dp_g, pull_g, pit = _location(sample, gsf, "last_hit", ok)
    assert _sigma68(dp_g) <= 0.95 * _sigma68(dp_k)
    assert 0.9 <= _pit_width(pit) <= 1.1
    assert np.mean(np.abs(pull_g) < 1.2) >= 0.68 and np.mean(np.abs(pull_k) < 1.2) < 0.5


@pytest.mark.xfail(strict=True, reason="lhcb-like has almost no field between VELO and UT: the "
                   "bremsstrahlung between the first hit and the magnet (~0.25 X0) is not observable, "
                   "so no fit measures an electron's first-hit q/p (issue 7 note)")
def test_electrons_lhcb_like_first_hit_q_over_p_is_not_measured(lhcb_electrons):
    sample, kalman, gsf, ok = lhcb_electrons
    dp_k, _ = _location(sample, kalman, "first_hit", ok)
    dp_g, pull_g, _ = _location(sample, gsf, "first_hit", ok)
    assert gaussian_core(dp_g).sigma <= 0.9 * gaussian_core(dp_k).sigma
    assert 0.9 <= gaussian_core(pull_g).sigma <= 1.2


def test_electrons_lhcb_like_first_hit_and_beamline_covariances_cover_the_error(lhcb_electrons):
    """Issue 15: the first-hit q/p is not measured (above), so the honest answer is a wide q/p
    error. The "core" output wrote the width of the mixture's Gaussian core, the ~20 % who
    have not radiated before the magnet: covariances claiming 1 % where the error is 30 %
    (q/p pull RMS 51, core 11.6, 25 % within ±1.2 on 1,500 tracks). It now writes the
    mixture's q/p second moment about the written q/p: at the first hit and at the
    beamline (truth: the production q/p) pull RMS 0.99 / 1.02, 80 % / 79 % within ±1.2."""
    sample, _, gsf, ok = lhcb_electrons
    _, pull_first = _location(sample, gsf, "first_hit", ok)[:2]
    _, state, cov = gsf.locations["beamline"]
    truth = sample.production_qop[sample.batch.hit_row[sample.batch.offsets[:-1]]]
    pull_beamline = ((state[:, 4] - truth) / np.sqrt(cov[:, 4, 4]))[ok]
    assert _covers(pull_first), np.sqrt(np.mean(pull_first**2))
    assert _covers(pull_beamline), np.sqrt(np.mean(pull_beamline**2))


def _position_pulls(sample, result, location, select):
    """Pulls (n, 4) of x, y, tx, ty at `location` of the tracks `select`."""
    nodes = _nodes(sample, location)[select]
    truth = sample.truth[sample.batch.hit_row[nodes]]
    error = np.sqrt(np.einsum("nii->ni", result.node_cov[nodes]))
    return ((result.node_state[nodes] - truth) / error)[:, :4]


def test_the_radiation_tail_does_not_widen_x_y_tx_ty_along_the_cores_slope(telescope_electrons, lhcb_electrons):
    """Where the mixture's q/p second moment exceeds the core's variance, the written
    covariance is the mixture's second moment about the written state (`widen_to_mixture`).
    It used to widen q/p alone and keep x, y, tx, ty given q/p, which carried the tail along
    the core's slope, and x, tx over-covered: pull cores (x, y, tx, ty) telescope first hit
    0.79/1.04/0.69/1.01, last hit 0.51/1.03/0.42/1.06; lhcb-like long first hit
    0.88/0.97/0.84/0.88, last hit 0.63/0.96/0.81/1.00. Now 0.99/1.04/0.87/1.01,
    1.02/1.03/0.91/1.05; 1.03/1.00/1.01/0.98, 0.99/1.04/0.97/1.03 (the telescope's tx at the
    first hit moves with q/p in the field: a tail, like q/p's, whose core is below 1)."""
    for sample, _, gsf, ok in (telescope_electrons, lhcb_electrons):
        for location in ("first_hit", "last_hit"):
            pulls = _position_pulls(sample, gsf, location, ok)
            cores = np.array([gaussian_core(pulls[:, i]).sigma for i in range(4)])
            assert np.all(cores[[0, 1, 3]] >= 0.9) and np.all(cores <= 1.1), (location, cores)
            assert cores[2] >= 0.82, (location, cores)
            if sample is lhcb_electrons[0]:
                assert np.all(np.sqrt(np.mean(pulls**2, axis=0)) <= 1.2), location


def test_first_hit_distribution_narrows_on_lhcb_like(lhcb_electrons):
    """What the GSF still gains at the first hit (measured σ68 −6 … −11 % on six samples)."""
    sample, kalman, gsf, ok = lhcb_electrons
    dp_k, _ = _location(sample, kalman, "first_hit", ok)
    dp_g, _, _ = _location(sample, gsf, "first_hit", ok)
    assert _sigma68(dp_g) < 0.97 * _sigma68(dp_k)
    assert np.mean(np.abs(dp_g) > 0.05) < np.mean(np.abs(dp_k) > 0.05)


def test_kl_reduction_merges_the_closest_q_over_p_pair():
    w = np.array([0.4, 0.3, 0.2, 0.1])
    mu = np.zeros((4, 5))
    mu[:, 4] = [1e-4, 1.01e-4, 2e-4, 3e-4]
    cov = np.tile(np.eye(5) * 1e-4, (4, 1, 1))
    cov[:, 4, 4] = 1e-12
    n = _reduce(w, mu, cov, 4, 3, np.zeros((2, 4), dtype=np.int64), np.zeros((5, 4)))
    assert n == 3
    assert np.isclose(w[:n].sum(), 1.0) and np.isclose(w[0], 0.7)
    assert np.isclose(mu[0, 4], (0.4 * 1e-4 + 0.3 * 1.01e-4) / 0.7)
    # moment matching: the merged variance includes the spread of the means
    spread = 0.4 * 0.3 / 0.49 * (1e-4 - 1.01e-4) ** 2
    assert np.isclose(cov[0, 4, 4], 1e-12 + spread)
    np.testing.assert_allclose(np.sort(mu[1:3, 4]), [2e-4, 3e-4])  # the survivors, in any order


def test_gsf_uses_the_electron_mass_and_bremsstrahlung_by_default():
    geometry = load_geometry("telescope")
    ctx = gsf_extrapolator(geometry)
    assert ctx.bethe_heitler and ctx.ref.mass < 1.0 and FitOptions().gsf.max_components == 12
    assert ctx.output == 3  # "core"
    assert not gsf_extrapolator(geometry, mass=MASS_PION).bethe_heitler
    assert reference_extrapolator(geometry).mass == MASS_PION
    with pytest.raises(ValueError):
        GSFOptions(output="median")


def test_max_components_reaches_the_gsf(tmp_path, capsys):
    """`pkf reconstruct --max-components N` limits the GSF's mixtures: through the API (the
    smoothed mixture at the first hit has at most N components) and the command line (the
    option is in run.json and changes the GSF's states; 0 is bad usage, exit 2)."""
    import json

    import pyarrow.parquet as pq

    from pkf.cli import main

    geometry = load_geometry("telescope")
    sample = TruthSample(geometry, events=10, seed=3, **ELECTRONS)
    ctx = gsf_extrapolator(geometry)
    for limit in (1, 4):
        result = fit_batch_gsf(ctx, sample.batch, FitOptions.from_flat(max_components=limit), sample.seeds,
                               sample.seed_covs)
        ok = result.status == 0
        assert ok.mean() > 0.95 and result.n_components[ok].max() == limit
    with pytest.raises(ValueError):
        fit_batch_gsf(ctx, sample.batch, FitOptions.from_flat(max_components=0), sample.seeds, sample.seed_covs)

    data = tmp_path / "data"
    assert main(["simulate", "--out", str(data), "--geometry", "telescope", "--generator", "gun", "--events", "3",
                 "--species", "electron", "--particles", "5", "--seed", "5"]) == 0
    states = {}
    for limit in ("1", "12"):
        run = tmp_path / f"run{limit}"
        assert main(["reconstruct", str(data), "--out", str(run), "--pattern", "truth", "--fitter", "gsf",
                     "--max-components", limit, "--workers", "1"]) == 0
        assert json.loads((run / "run.json").read_text())["config"]["gsf"]["max_components"] == int(limit)
        table = pq.read_table(run / "states")
        states[limit] = np.column_stack([table.column(c).to_numpy() for c in ("x", "tx", "qop")])
    assert states["1"].shape == states["12"].shape
    assert not np.allclose(states["1"], states["12"])
    capsys.readouterr()
    assert main(["reconstruct", str(data), "--out", str(tmp_path / "bad"), "--pattern", "truth", "--fitter", "gsf",
                 "--max-components", "0"]) == 2
    assert "--max-components" in capsys.readouterr().err


# A VELO-only track of a minimum-bias event (`pkf simulate --generator minbias --pileup 2
# --events 50 --seed 3`, partition of events 15-19) whose seed q/p says 3.9 MeV: under the
# electron hypothesis some mixture components stop in a VELO module (E − ΔE ≤ m).
_STOPPING_TRACK_Z = (37.5, 62.5, 87.5, 112.5, 137.5, 162.5, 187.5, 212.5, 237.5, 262.5, 312.5)
_STOPPING_TRACK_UV = ((-4.277827687650552, -3.3409329316726017), (-7.311386474901954, -5.549341402503658),
                      (-10.283078942281882, -7.744924504653722), (-13.420363797648863, -9.91816285974681),
                      (-16.685759373865157, -12.137825922407576), (-19.849973538121823, -14.28218636465747),
                      (-23.205174241172752, -16.380047591746493), (-26.554731302366296, -18.379201913674848),
                      (-30.00168429112829, -20.480125076608193), (-33.58669279718092, -22.476185337215316),
                      (-40.79008032079846, -26.426311382044023))
_STOPPING_TRACK_SEED = (-4.209848300979843, -3.5685078338222156, -0.12076103340782218, -0.08408610320514903,
                        -0.2565891440557948)


def _same_hits_twice(rows):
    """Two candidates (tracks 0 and 1 of event 0) of the same hit rows."""
    from pkf.fit.candidates import Candidates

    return Candidates.from_hit_lists(np.zeros(2 * rows.size), np.repeat([0, 1], rows.size), np.tile(rows, 2))


def test_a_mixture_component_that_stops_in_a_module_is_dropped_not_propagated():
    """Issue 13 case 3: a component whose particle stops in a plane (q/p → ±inf, its
    Jacobian inf·0 = NaN) was kept, merged into its neighbours, and a NaN-weighted peak
    then divided 0 by 0 (ZeroDivisionError: the whole run aborted). Now it is dropped
    (if every component stops, the track gets the status "extrapolation failed"): this
    track is fitted by the components that do not stop (as the same hits at 1 GeV are)."""
    from pkf.fit.tracks import TrackBatch

    geometry = load_geometry("lhcb-like")
    layers = np.array([int(np.flatnonzero(np.isclose(geometry.layer_z, z))[0]) for z in _STOPPING_TRACK_Z])
    uv = np.array(_STOPPING_TRACK_UV)
    rows = np.arange(layers.size)
    seeds = np.array([_STOPPING_TRACK_SEED, _STOPPING_TRACK_SEED])
    seeds[1, 4] = -1.0 / 1000.0  # the same hits as a 1 GeV electron: fitted
    seed_covs = np.tile(np.diag([100.0, 100.0, 0.01, 0.01, 6.664383619255776e-04]), (2, 1, 1))
    seed_covs[1, 4, 4] = 1e-6
    batch = TrackBatch.from_candidates(geometry, _same_hits_twice(rows), layers, uv[:, 0], uv[:, 1],
                                       np.full(rows.size, 0.0125), np.full(rows.size, 0.0125))
    result = fit_batch_gsf(gsf_extrapolator(geometry), batch, FitOptions(), seeds, seed_covs)
    assert list(result.status) == [0, 0]
    assert np.all(np.isfinite(result.node_state)) and np.all(np.isfinite(result.chi2))
    assert np.all(np.einsum("nii->ni", result.node_cov) > 0.0)
    # at 3.9 MeV the scattering lets the states follow the hits (12.5 µm)
    assert np.all(np.abs(result.node_state[:rows.size, :2] - uv) < 0.05)


def test_a_seed_without_q_over_p_variance_gets_the_widened_width():
    """A seed covariance with no q/p variance divided by zero when the forward filter
    widened it (ZeroDivisionError, the run aborted): the widened width replaces it, as
    for a seed with a negligible one. The hits are VELO hits; the track is declared long,
    because a VELO-only one is fitted as one Gaussian, without the widening (`pkf.fit.gsf`)."""
    import dataclasses

    from pkf.fit.seed import TRACK_LONG
    from pkf.fit.tracks import TrackBatch

    geometry = load_geometry("lhcb-like")
    layers = np.array([int(np.flatnonzero(np.isclose(geometry.layer_z, z))[0]) for z in _STOPPING_TRACK_Z])
    uv = np.array(_STOPPING_TRACK_UV)
    rows = np.arange(layers.size)
    batch = TrackBatch.from_candidates(geometry, _same_hits_twice(rows), layers, uv[:, 0], uv[:, 1],
                                       np.full(rows.size, 0.0125), np.full(rows.size, 0.0125))
    seeds = np.array([_STOPPING_TRACK_SEED, _STOPPING_TRACK_SEED])
    seeds[:, 4] = -1.0 / 1000.0
    seed_covs = np.tile(np.diag([100.0, 100.0, 0.01, 0.01, 0.0]), (2, 1, 1))
    seed_covs[1, 4, 4] = 1e-300
    batch = dataclasses.replace(batch, track_type=np.full(batch.n_tracks, TRACK_LONG, dtype=np.int64))
    result = fit_batch_gsf(gsf_extrapolator(geometry), batch, FitOptions(), seeds, seed_covs)
    assert list(result.status) == [0, 0]
    np.testing.assert_allclose(result.node_state[:rows.size], result.node_state[rows.size:], rtol=1e-9)


def _minbias_truth_hits(events, seed):
    """Minimum-bias events (lhcb-like, ν = 7.6) grouped into truth tracks: the geometry,
    the candidates, each hit's layer and its u, v, σ_u, σ_v columns."""
    from pkf.pipeline.simulate import SimulationConfig, simulate_batch
    from pkf.pipeline.truth_pattern import truth_candidates

    geometry = load_geometry("lhcb-like")
    config = SimulationConfig(generator="minbias", pileup=7.6, events=events, seed=seed)
    hits, _, mc = simulate_batch(geometry, config, 0, config.events)
    col = lambda t, c: t.column(c).to_numpy(zero_copy_only=False)  # noqa: E731
    layer = col(hits, "layer").astype(np.int64)
    candidates = truth_candidates(col(hits, "event_id").astype(np.int64), layer, col(mc, "particle_id").astype(np.int64))
    return geometry, candidates, layer, [col(hits, c).astype(float) for c in ("u", "v", "sigma_u", "sigma_v")]


def test_velo_only_tracks_keep_the_momentum_assumption_and_its_width():
    """Issue 15: a VELO-only track's q/p is the momentum assumption of
    `pkf.fit.seed.velo_qop_prior` and its error the assumption's width. The GSF's backward
    filter started with a 10 % q/p prior that the smoothing counted: the first-hit q/p
    error was 0.05× the assumption's (median; minimum bias ν = 7.6, truth pattern). Now
    (backward prior 100× the seed's width for tracks that do not cross the magnet) it is
    0.999×, the q/p within 0.03σ of the assumption, as the reference Kalman fit's. The seed's
    q/p is now the tracks' multiple-scattering momentum (`pkf.fit.seed.velo_momentum_estimate`),
    its width ≥ √2·|q/p| (the unknown sign), above the GSF's floor SEED_QOP_FRACTION·|q/p|."""
    from pkf.fit.gsf import SEED_QOP_FRACTION
    from pkf.fit.reference import reference_extrapolator
    from pkf.fit.seed import TRACK_VELO
    from pkf.fit.tracks import TrackBatch, fit_batch, seed_batch
    from pkf.physics.constants import MASS_ELECTRON

    geometry, candidates, layer, columns = _minbias_truth_hits(events=8, seed=31)
    batch = TrackBatch.from_candidates(geometry, candidates, layer, *columns)
    seeds, covs, _ = seed_batch(batch, geometry.reconstruction_field(), geometry)
    velo = batch.track_type == TRACK_VELO
    result = fit_batch_gsf(gsf_extrapolator(geometry), batch, FitOptions(), seeds, covs)
    sel = velo & (result.status == 0)
    assert sel.sum() >= 20
    _, state, cov = result.locations["first_hit"]
    # the forward filter's prior: the seed's q/p width, at least SEED_QOP_FRACTION·|q/p| (with
    # bremsstrahlung modelled)
    prior = np.maximum(covs[sel, 4, 4], (SEED_QOP_FRACTION * seeds[sel, 4]) ** 2)
    width = np.sqrt(cov[sel, 4, 4] / prior)
    assert 0.95 <= np.median(width) <= 1.05, np.median(width)
    # the q/p stays the prior's: VELO-only tracks are one Gaussian now (no Bethe–Heitler
    # convolution), whose fit lets the VELO's few mT move it a little (measured: median 0.006σ,
    # largest 0.46σ of 30 tracks, the next 0.04σ)
    dev = np.abs(state[sel, 4] - seeds[sel, 4]) / np.sqrt(prior)
    assert np.median(dev) < 0.03 and np.mean(dev > 0.2) < 0.05, np.sort(dev)[-3:]
    # x, y, tx, ty are the Kalman fit's (one Gaussian, the same electron-mass material):
    # with the vague backward q/p prior the first-hit tx variance was 2.9× the reference
    # Kalman fit's (median; 10 %/90 %: 1.2×/22×, 5 minimum-bias events); with the 10 % prior
    # and the forward prediction's q/p block, 0.99× (0.98×/1.00×; here, truth pattern, 8 events:
    # 1.01×, 1.00×/1.11× for tx)
    kalman = fit_batch(reference_extrapolator(geometry, mass=MASS_ELECTRON), batch,
                       FitOptions.from_flat(iterations=1), seeds, covs)
    _, _, kalman_cov = kalman.locations["first_hit"]
    both = sel & (kalman.status == 0)
    for i in (2, 3):
        ratio = cov[both, i, i] / kalman_cov[both, i, i]
        assert 0.95 <= np.median(ratio) <= 1.05 and np.percentile(ratio, 90) < 1.25, np.percentile(ratio, [10, 50, 90])


def test_velo_only_q_over_p_is_not_moved_by_a_wrong_hit():
    """Issue 15: the hits of a VELO-only track carry no q/p information, only the VELO's
    few-mT fringe field couples them to it. A wrong first hit (here every VELO-only truth
    track's first hit moved by 0.5 mm in x and y: the kink of a hit from another particle)
    was absorbed by moving the filters' q/p by factors (to 30 MeV on a minimum-bias
    candidate), and their scattering noise with it: first-hit tx pulls of 10³ where the
    Kalman fits had 10–40. Now (`_decouple_qop`) the filters keep the assumption: from the
    same seed, the q/p written at the last hit is the same with and without the wrong hit
    (it changes only by the mean ionisation loss, which depends on the slopes). Measured on
    21 tracks: |Δ(q/p)|/|q/p| median 5e-6, largest 4e-5; before: median 0.14, largest 1.65."""
    from pkf.fit.seed import TRACK_VELO
    from pkf.fit.tracks import TrackBatch, seed_batch

    geometry, candidates, layer, (u, v, *sigmas) = _minbias_truth_hits(events=4, seed=32)
    clean = TrackBatch.from_candidates(geometry, candidates, layer, u, v, *sigmas)
    velo = clean.track_type == TRACK_VELO
    first_rows = clean.hit_row[clean.offsets[:-1][velo]]
    u, v = u.copy(), v.copy()
    u[first_rows] += 0.5
    v[first_rows] += 0.5
    wrong = TrackBatch.from_candidates(geometry, candidates, layer, u, v, *sigmas)
    seeds, covs, _ = seed_batch(clean, geometry.reconstruction_field(), geometry)
    options = FitOptions.from_flat(max_outliers=0)
    fits = [fit_batch_gsf(gsf_extrapolator(geometry), b, options, seeds, covs) for b in (clean, wrong)]
    sel = velo & (fits[0].status == 0) & (fits[1].status == 0)
    assert sel.sum() >= 20
    last = [f.locations["last_hit"][1][sel, 4] for f in fits]
    change = np.abs(last[1] / last[0] - 1.0)
    assert np.max(change) < 1e-3, np.sort(change)[-3:]


def test_kl_reduction_reaches_max_components_when_distances_are_nan():
    """A mixture whose q/p variances are NaN has no comparable KL distance: the reduction
    used to 'merge' each component with index −1 and return all n > max_n components, and
    the next plane's Bethe–Heitler convolution then wrote n·K components past the scratch
    arrays (heap corruption: 'double free or corruption' on minbias events)."""
    n = 6
    w = np.full(n, 1.0 / n)
    mu = np.zeros((n, 5))
    mu[:, 4] = np.linspace(1e-4, 2e-4, n)
    cov = np.tile(np.eye(5), (n, 1, 1))
    cov[:, 4, 4] = np.nan
    nearest, moments = np.zeros((2, n + 1), dtype=np.int64), np.zeros((5, n + 1))
    count = _reduce(w, mu, cov, n, 3, nearest, moments)
    assert count == 3
    # nothing written past the n components (index −1 of the scratch)
    assert np.all(nearest[:, n] == 0) and np.all(moments[:, n] == 0)
    assert np.isclose(w[:count].sum(), 1.0)


def test_siblings_merge_only_within_their_family_keeping_the_moments():
    """`_merge_siblings` merges the closest pair of siblings (same parent, consecutive) until
    the target count: never two components of different parents, the mixture's weight,
    mean and second moment kept (moment matching), and nothing done at or below the target."""
    rng = np.random.default_rng(3)
    parent = np.repeat(np.arange(4), [5, 1, 4, 6])
    n = parent.size
    w = rng.uniform(0.1, 1.0, n)
    w /= w.sum()
    mu = np.zeros((n, 5))
    mu[:, :4] = rng.normal(size=4)[None, :] + 0.1 * parent[:, None]
    mu[:, 0] = parent  # the family, read back from the survivors
    mu[:, 4] = 1e-4 / rng.uniform(0.3, 1.0, n)
    cov = np.tile(np.diag([1e-2, 1e-2, 1e-6, 1e-6, 1e-10]), (n, 1, 1))
    cov[:, 4, 4] *= rng.uniform(0.5, 3.0, n)
    mean0 = w @ mu
    second0 = np.einsum("c,cij->ij", w, cov + np.einsum("ci,cj->cij", mu - mean0, mu - mean0))
    nearest, moments = np.zeros((4, n + 1), dtype=np.int64), np.zeros((5, n))
    labels = parent.copy()
    assert _merge_siblings(w.copy(), mu.copy(), cov.copy(), n, n, labels, nearest, moments) == n
    count = _merge_siblings(w, mu, cov, n, 8, labels, nearest, moments)
    assert count == 8
    assert np.isclose(w[:count].sum(), 1.0)
    mean = w[:count] @ mu[:count]
    d = mu[:count] - mean
    second = np.einsum("c,cij->ij", w[:count], cov[:count] + np.einsum("ci,cj->cij", d, d))
    np.testing.assert_allclose(mean, mean0, rtol=1e-12)
    np.testing.assert_allclose(second, second0, rtol=1e-9, atol=1e-20)
    # the x, y, tx, ty means of each family are its parent's: no cross-family merge happened
    assert len({tuple(np.round(m, 12)) for m in mu[:count, :4]}) == 4
    # below one component per family nothing is left to merge
    assert np.array_equal(np.unique(np.rint(mu[:count, 0])), np.arange(4))
    count = _merge_siblings(w, mu, cov, count, 1, np.rint(mu[:count, 0]).astype(np.int64), nearest, moments)
    assert count == 4


def test_sibling_and_product_targets_scale_with_max_components_and_can_be_off():
    assert sibling_target(GSFOptions()) == 42
    assert sibling_target(GSFOptions(max_components=4, sibling_merge=2.0)) == 8
    assert sibling_target(GSFOptions(sibling_merge=0.0)) == 0
    with pytest.raises(ValueError):
        GSFOptions(sibling_merge=-1.0)
    assert product_target(GSFOptions()) == 24
    assert product_target(GSFOptions(product_merge=0.0)) == 0
    with pytest.raises(ValueError):
        GSFOptions(product_merge=-1.0)


def _backward_from_scifi_to_velo(share_jacobians):
    """Two components at the first SciFi layer transported back to the VELO end: the
    leading one (weight 0.7) at 25 MeV curls out of the z-parametrised envelope in the
    magnet, the other (5 GeV) does not."""
    from pkf.fit.gsf import _transport

    ctx = gsf_extrapolator(load_geometry("lhcb-like"), share_jacobians=share_jacobians)
    w = np.array([0.7, 0.3])
    mu = np.array([[-3.3, 4.8, -0.03, 0.036, 1.0 / 25.0], [-3.3, 4.8, -0.03, 0.036, 1.0 / 5000.0]])
    cov = np.tile(np.diag([1e-2, 1e-2, 1e-6, 1e-6, 1e-10]), (2, 1, 1))
    alive = _transport(ctx, w, mu, cov, 2, 7826.0, 737.5, np.zeros((5, 5)), np.zeros((5, 5)), np.zeros((5, 5)),
                       np.zeros((5, 5, 5)), np.zeros((5, 2)), np.zeros((2, 5, 5)),
                       np.zeros((2, 2), dtype=np.int64))
    return alive, w, mu, cov


def test_a_leading_component_that_leaves_the_envelope_shares_no_jacobian():
    """With shared Jacobians the leading component's Jacobian transports every covariance;
    when that component curls out of the envelope its Jacobian is NaN and every covariance
    became NaN while the other components stayed 'alive' (found on minbias event 6xx: a
    2.2 GeV pion's backward GSF pass through the magnet). Now each component takes its own
    Jacobian then: the survivor's covariance is what the per-component transport gives."""
    alive, w, mu, cov = _backward_from_scifi_to_velo(True)
    alive_own, w_own, mu_own, cov_own = _backward_from_scifi_to_velo(False)
    assert alive == alive_own == 1
    assert w[0] == 0.0 and w[1] == 0.3
    assert np.all(np.isfinite(cov[1])) and np.all(np.linalg.eigvalsh(cov[1]) > 0.0)
    np.testing.assert_array_equal(mu[1], mu_own[1])
    np.testing.assert_array_equal(cov[1], cov_own[1])


def _fit_heap_track(**context):
    """The track of the heap corruption above (lhcb-like minbias ν = 7.6, seed 77, event
    650–699; VELO + SciFi, no UT, p = 2.2 GeV), fitted by the GSF with `context`
    (`gsf_extrapolator`'s options)."""
    geometry, batch, data = recorded_track("gsf_lead_leaves_envelope")
    return fit_batch_gsf(gsf_extrapolator(geometry, **context), batch, FitOptions(), data["seed"][None],
                         data["seed_cov"][None])


def test_the_minbias_track_that_corrupted_the_heap_is_fitted():
    """The heap-corruption track: fitted, finite, positive variances."""
    result = _fit_heap_track()
    assert list(result.status) == [0]
    assert np.all(np.isfinite(result.node_state)) and np.all(np.einsum("nii->ni", result.node_cov) > 0.0)
    assert abs(1.0 / result.node_state[0, 4]) > 1000.0  # not the sub-GeV component that curled away


def test_the_heap_track_fit_is_continuous_in_its_bethe_heitler_mixture():
    """The heap-corruption track's mixture spans a factor of several in q/p through the
    magnet. With the lead's Jacobian shared by every component its fit changed
    discontinuously with the mixture (χ² 102.37 with each component's Bethe–Heitler
    mixture evaluated, 102.64 sharing them within 1e-9 of t, failed within 1e-4); with
    Jacobians shared only within bends of 0.03 rad (`_share_jacobians`) sharing the
    mixtures within 1e-4 of t (the default) moves χ² by 1e-7, and the fit agrees with
    per-component Jacobians (61.62 against 61.27)."""
    shared = _fit_heap_track()
    exact = _fit_heap_track(bh_shared_t_tolerance=0.0)
    own = _fit_heap_track(share_jacobians=False)
    assert list(shared.status) == list(exact.status) == list(own.status) == [0]
    assert abs(shared.chi2[0] - exact.chi2[0]) < 1e-5 * exact.chi2[0]
    assert abs(shared.chi2[0] - own.chi2[0]) < 0.01 * own.chi2[0]
    np.testing.assert_allclose(shared.node_state[0, 4], own.node_state[0, 4], rtol=0.01)


def _transport_through_magnet(**context):
    """Four components at the VELO end transported to the first SciFi layer: the lead
    (10 GeV, weight 0.4), one at 10.1 GeV, one at 2 GeV and one at 2.01 GeV."""
    from pkf.fit.gsf import _transport

    ctx = gsf_extrapolator(load_geometry("lhcb-like"), **context)
    w = np.array([0.4, 0.2, 0.25, 0.15])
    mu = np.tile([5.0, 5.0, 0.05, 0.02, 0.0], (4, 1))
    mu[:, 4] = 1.0 / np.array([10000.0, 10100.0, 2000.0, 2010.0])
    cov = np.tile(np.diag([1e-2, 1e-2, 1e-6, 1e-6, 1e-10]), (4, 1, 1))
    alive = _transport(ctx, w, mu, cov, 4, 737.5, 7826.0, np.zeros((5, 5)), np.zeros((5, 5)), np.zeros((5, 5)),
                       np.zeros((5, 5, 5)), np.zeros((5, 4)), np.zeros((4, 5, 5)),
                       np.zeros((2, 4), dtype=np.int64))
    assert alive == 4
    return mu, cov


def test_components_share_a_jacobian_only_where_their_bends_agree():
    """Through the magnet (a bend of 0.12 rad at 10 GeV, 0.72 at 2 GeV) the 2 GeV component
    integrates its own Jacobian and the 2.01 GeV one (0.003 rad from it) shares it; the
    10.1 GeV one shares the lead's. The lead's and the 2 GeV covariance are those of
    per-component Jacobians bit for bit, the sharers' within 0.02 σ_iσ_j of theirs
    (measured 0.0008 and 0.010); the lead's Jacobian for all (the previous rule) moved
    the 2 GeV covariances by 0.58 σ_iσ_j. The means never depend on the sharing."""
    mu, cov = _transport_through_magnet()
    mu_own, cov_own = _transport_through_magnet(share_jacobians=False)
    mu_all, cov_all = _transport_through_magnet(jacobian_share_kick=np.inf)
    np.testing.assert_array_equal(mu, mu_own)
    np.testing.assert_array_equal(mu_all, mu_own)
    np.testing.assert_array_equal(cov[[0, 2]], cov_own[[0, 2]])
    sigma = np.sqrt(np.einsum("nii->ni", cov_own))
    unit = sigma[:, :, None] * sigma[:, None, :]
    assert np.abs((cov - cov_own) / unit)[[1, 3]].max() < 0.02
    assert np.abs((cov_all - cov_own) / unit)[[2, 3]].max(axis=(1, 2)).min() > 0.3


def test_components_with_equal_paths_share_their_bethe_heitler_mixture():
    """`_material`: two components whose paths through a plane agree within the tolerance
    take the first one's Bethe–Heitler mixture (children's weights and q/p within 1e-5 of
    each evaluating its own, not bitwise: the mixture was shared), a third one at a
    steeper slope its own (bitwise)."""
    from pkf.fit.gsf import _material
    from pkf.fit.propagate import plane_path_x0

    def convolve(tolerance):
        ctx = gsf_extrapolator(load_geometry("lhcb-like"), bh_shared_t_tolerance=tolerance)
        mu = np.tile([20.0, 15.0, 0.02, 0.01, 1.0 / 8000.0], (3, 1))
        mu[1, 2] = 0.020001  # t differs by ~2e-8 relative
        mu[2, 2] = 0.2
        k = next(k for k in range(ctx.ref.plane_x_over_x0.size) if plane_path_x0(ctx.ref, k, mu[0]) > ctx.bh_t_min)
        cov = np.tile(np.diag([1e-2, 1e-2, 1e-6, 1e-6, 1e-12]), (3, 1, 1))
        out = (np.zeros(24), np.zeros((24, 5)), np.zeros((24, 5, 5)))
        k_bh = ctx.bh_coefficients.shape[1]
        n = _material(ctx, k, 1.0, np.array([0.5, 0.3, 0.2]), mu, cov, 3, *out, np.zeros((5, 5)),
                      np.zeros((5, 5)), np.zeros(k_bh), np.zeros(k_bh), np.zeros(k_bh), np.zeros(24, dtype=np.int64))
        return n, k_bh, out

    n, k_bh, (w, mu, cov) = convolve(1e-4)
    n0, _, (w0, mu0, cov0) = convolve(0.0)
    assert n == n0 == 3 * k_bh
    second, third = slice(k_bh, 2 * k_bh), slice(2 * k_bh, 3 * k_bh)
    np.testing.assert_allclose(w[second], w0[second], rtol=1e-5)
    np.testing.assert_allclose(mu[second, 4], mu0[second, 4], rtol=1e-5)
    assert not np.array_equal(mu[second, 4], mu0[second, 4])
    np.testing.assert_array_equal(mu[third], mu0[third])
    np.testing.assert_array_equal(w[third], w0[third])


@pytest.fixture(scope="module")
def upstream_electrons():
    """Electron gun 0.3–6 GeV (150 events × 10, seed 2), truth tracks, GSF with kept mixtures;
    the upstream (VELO + UT) tracks fitted ok."""
    geometry = load_geometry("lhcb-like")
    sample = TruthSample(geometry, events=150, seed=2, species="electron", particles=10, p_min=300.0,
                         p_max=6000.0, eta_min=2.0, eta_max=5.0)
    gsf = fit_batch_gsf(gsf_extrapolator(geometry), sample.batch, FitOptions(), sample.seeds, sample.seed_covs,
                        sample.beamline, keep_qop_mixtures=True)
    return sample, gsf, (gsf.status == 0) & (sample.batch.track_type == TRACK_UPSTREAM)


def test_upstream_electrons_q_over_p_is_calibrated(upstream_electrons):
    """Issue 15, upstream tracks (VELO + UT): the first-hit q/p is measured to ~15 % by the
    VELO→UT kink, and what the electron radiated upstream of it is not observed, so the
    posterior is the measurement convolved with the Bethe–Heitler tail. It is calibrated:
    electron gun 0.3–6 GeV, truth tracks, upstream tracks fitted at 0.8–2 GeV (their
    radiation tail lies inside the generated range), seeds 1–4 of 150 events: q/p pull RMS
    1.02 / 1.05 / 0.99 / 0.95, Φ⁻¹(PIT) core 0.99 / 0.98 / 0.95 / 0.92. (A gun that ends at
    2 GeV gives pull RMS 0.77 in the same window: the true first-hit momenta cannot exceed
    2 GeV there, while the posterior rightly allows them — a prior the gun imposes, not an
    over-covering fit; so this test keeps the gun's end well above the window.)"""
    sample, gsf, upstream = upstream_electrons
    qop = np.abs(gsf.node_state[sample.batch.offsets[:-1], 4])
    select = upstream & (qop > 1 / 2000.0) & (qop < 1 / 800.0)
    assert select.sum() > 200
    _, pull, pit = _location(sample, gsf, "first_hit", select)
    rms = np.sqrt(np.mean(pull**2))
    assert 0.9 <= rms <= 1.15, rms
    assert 0.85 <= _pit_width(pit) <= 1.1, _pit_width(pit)


def test_upstream_electrons_chi2_follows_its_ndf(upstream_electrons):
    """The forward filter starts at the seed's q/p, the momentum measured downstream of the
    radiation: too much scattering noise upstream, χ²/ndf 0.75 on these upstream electrons
    (gun 0.3–6 GeV, seed 5). Fits whose first-hit momentum came out > 10 % above the seed's are
    repeated from it (`RELINEARISE_QOP_CHANGE`): 0.98 (seed 5), with the pulls unchanged."""
    sample, gsf, upstream = upstream_electrons
    chi2_ndf = np.sum(gsf.chi2[upstream]) / np.sum(gsf.ndf[upstream])
    assert 0.9 <= chi2_ndf <= 1.1, chi2_ndf
    assert 0.3 <= np.mean(gsf.passes[upstream] == 2) <= 0.9
