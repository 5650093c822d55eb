"""The Kalman fitters' electron hypothesis (issue 15): the Bethe–Heitler mean loss and its
variance on q/p at every material plane, as LHCb's electron fit."""

import math

import numpy as np
import pytest
from fit_helpers import TruthSample

from pkf.fit.extrapolator import extrapolate
from pkf.fit.hypothesis import ElectronHypothesis, with_hypothesis
from pkf.fit.options import KalmanOptions
from pkf.fit.reference import reference_extrapolator
from pkf.fit.tracks import FitOptions, fit_batch
from pkf.geometry import load_geometry
from pkf.params.parameter_set import shipped_parameters
from pkf.physics.constants import MASS_ELECTRON

ELECTRONS = {"species": "electron", "particles": 10, "p_min": 2000.0, "p_max": 50000.0, "eta_min": 2.0, "eta_max": 5.0}


def _step(ext, state, z_from, z_to):
    out = np.zeros(5)
    jac = np.zeros((5, 5))
    noise = np.zeros((5, 5))
    status = extrapolate(ext, np.array(state, dtype=float), z_from, z_to, out, jac, noise, np.zeros((6, 5, 5)))
    assert status == 0
    return out, jac, noise


def test_a_step_through_material_adds_the_bethe_heitler_mean_and_variance():
    """From the VELO module at z = 12.5 to the one at 37.5 (the planes at 25 and 37.5, 1 %
    X0 each, one per VELO side, both crossed within their overlap): the electron hypothesis multiplies q/p by e^t and adds
    (q/p′)²·Var z/E[z]² to its noise, t = 2·0.01·√(1 + tx² + ty²); the pion's step is
    the same transport without it."""
    geometry = load_geometry("lhcb-like")
    pion = with_hypothesis(shipped_parameters(geometry).extrapolator(geometry), geometry, "pion")
    electron = with_hypothesis(shipped_parameters(geometry).extrapolator(geometry), geometry, "electron")
    assert isinstance(electron, ElectronHypothesis) and not isinstance(pion, ElectronHypothesis)
    state = [2.0, 8.0, 0.01, 0.04, 1.0 / 5000.0]
    out_p, jac_p, noise_p = _step(pion, state, 12.5, 37.5)
    out_e, jac_e, noise_e = _step(electron, state, 12.5, 37.5)
    t = 2 * 0.01 * math.sqrt(1 + 0.01**2 + 0.04**2)
    mean_z, var_z = math.exp(-t), math.exp(-t * math.log(3) / math.log(2)) - math.exp(-2 * t)
    np.testing.assert_allclose(out_e[:4], out_p[:4])
    assert out_e[4] == pytest.approx(out_p[4] / mean_z, rel=1e-8)
    np.testing.assert_allclose(jac_e[4], jac_p[4] / mean_z, rtol=1e-8)
    added = noise_e[4, 4] - noise_p[4, 4] / mean_z**2
    assert added == pytest.approx(out_e[4] ** 2 * var_z / mean_z**2, rel=1e-9)
    assert noise_e[4, 4] > noise_p[4, 4]


def test_the_reference_extrapolator_takes_the_electron_mass():
    geometry = load_geometry("lhcb-like")
    electron = with_hypothesis(reference_extrapolator(geometry), geometry, "electron")
    assert electron.inner.mass == MASS_ELECTRON and electron.planes is electron.inner
    with pytest.raises(ValueError):
        KalmanOptions(hypothesis="muon")


@pytest.fixture(scope="module")
def electron_gun():
    return TruthSample(load_geometry("lhcb-like"), events=60, seed=11, **ELECTRONS)


def _first_hit_qop(sample, result):
    first = sample.batch.offsets[:-1]
    _, state, cov = result.locations["first_hit"]
    truth = sample.truth[sample.batch.hit_row[first], 4]
    return state[:, 4], cov[:, 4, 4], truth


@pytest.mark.parametrize("fitter", ["reference", "parametrized"])
def test_electron_hypothesis_covers_the_first_hit_q_over_p_error(electron_gun, fitter):
    """Electron gun 2–50 GeV, lhcb-like, truth tracks, two passes: under the pion hypothesis
    the first-hit q/p pulls have an RMS of ~120 (no radiation modelled: a 0.3 % error
    claimed where it is 30 %); under the electron hypothesis the q/p variance is wider on
    every long track and > 100× wider on most (VELO-only tracks keep about the same
    momentum assumption),
    and the pull RMS is in [0.7, 1.4] (measured 1.22 on 1,500 tracks, both
    fitters; the truth: the local q/p, which the parametrized fitter's q/p is under the
    electron hypothesis)."""
    sample = electron_gun
    geometry = sample.geometry
    base = sample.extrapolator if fitter == "reference" else shipped_parameters(geometry).extrapolator(geometry)
    results = {}
    for hypothesis in ("pion", "electron"):
        ext = with_hypothesis(base, geometry, hypothesis)
        options = FitOptions.from_flat(iterations=2, hypothesis=hypothesis)
        results[hypothesis] = fit_batch(ext, sample.batch, options, sample.seeds, sample.seed_covs, sample.beamline)
    ok = (results["pion"].status == 0) & (results["electron"].status == 0)
    assert ok.sum() > 550
    pulls = {}
    for hypothesis, result in results.items():
        qop, var, truth = _first_hit_qop(sample, result)
        pulls[hypothesis] = ((qop - truth) / np.sqrt(var))[ok]
        results[hypothesis] = var[ok]
    ratio = results["electron"] / results["pion"]
    long = sample.long_tracks()[ok]
    assert np.all(ratio[long] > 1.0) and np.median(ratio) > 100.0, np.percentile(ratio, [0, 50])
    rms = {h: np.sqrt(np.mean(p**2)) for h, p in pulls.items()}
    assert rms["pion"] > 10.0
    assert 0.7 <= rms["electron"] <= 1.4, rms


def test_fit_batch_refuses_a_hypothesis_its_extrapolator_does_not_carry(electron_gun):
    sample = electron_gun
    with pytest.raises(ValueError, match="hypothesis"):
        fit_batch(sample.extrapolator, sample.batch, FitOptions.from_flat(hypothesis="electron"), sample.seeds,
                  sample.seed_covs)
