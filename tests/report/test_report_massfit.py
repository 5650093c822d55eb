"""The B_s mass fit (Gaussian + linear background) and the four-kaon invariant mass."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import trapezoid

from pkf.physics.constants import MASS_PHI
from pkf.report.massfit import BS_MASS, KAON_MASS, fit_mass_peak, four_momenta, invariant_mass

WINDOW = (BS_MASS - 250.0, BS_MASS + 250.0)


def _sample(rng, n_sig, mean, sigma, n_bkg, slope):
    signal = rng.normal(mean, sigma, n_sig)
    # linear background density ∝ 1 + slope·u, u ∈ [−1, 1], by accept–reject
    u = rng.uniform(-1, 1, 4 * n_bkg)
    u = u[rng.uniform(0, 1 + abs(slope), u.size) < 1 + slope * u][:n_bkg]
    lo, hi = WINDOW
    background = 0.5 * (lo + hi) + 0.5 * (hi - lo) * u
    return np.concatenate([signal, background])


@pytest.mark.parametrize("seed", [1, 2])
def test_fit_recovers_known_gaussian(seed):
    rng = np.random.default_rng(seed)
    mean, sigma = 5366.0, 13.0
    fit = fit_mass_peak(_sample(rng, 2000, mean, sigma, 800, 0.4), WINDOW)
    assert fit.status == "ok" and fit.valid
    assert fit.n_candidates == 2800
    assert abs(fit.mean - mean) < 4 * fit.mean_error and fit.mean_error < 0.5
    assert abs(fit.sigma - sigma) < 4 * fit.sigma_error and fit.sigma_error < 0.5
    assert abs(fit.n_signal - 2000) < 4 * fit.n_signal_error
    assert abs(fit.n_background - 800) < 4 * fit.n_background_error
    assert fit.n_signal + fit.n_background == pytest.approx(2800, rel=1e-3)
    assert 0.1 < fit.slope < 0.7
    # the fitted density integrates to the number of candidates in the window
    grid = np.linspace(*WINDOW, 20001)
    assert trapezoid(fit.density(grid), grid) == pytest.approx(2800, rel=1e-3)


def test_fit_without_background_and_width_scale():
    rng = np.random.default_rng(5)
    fit = fit_mass_peak(rng.normal(5370.0, 30.0, 500), WINDOW)
    assert fit.status == "ok"
    assert abs(fit.sigma - 30.0) < 4 * fit.sigma_error
    assert fit.n_background < 4 * fit.n_background_error + 5


def test_too_few_candidates_no_fit():
    fit = fit_mass_peak([5366.0, 5367.0, 5000.0, 9000.0], WINDOW)
    assert fit.status.startswith("too few candidates") and not fit.valid
    assert fit.n_candidates == 2 and np.isnan(fit.sigma)
    assert fit.as_dict()["window"] == list(WINDOW)


def test_invariant_mass_of_kaons():
    # two kaons with the same momentum vector: mass 2 m_K exactly
    mom = four_momenta([1 / 5000.0, -1 / 5000.0], [0.1, 0.1], [-0.05, -0.05])
    assert invariant_mass(mom[None, :, :])[0] == pytest.approx(2 * KAON_MASS, rel=1e-9)
    # a φ at rest decaying to K⁺K⁻ back to back, then boosted along z: mass is invariant
    m_phi = MASS_PHI
    p_star = np.sqrt((m_phi / 2) ** 2 - KAON_MASS**2)
    theta = 0.7
    k1 = np.array([m_phi / 2, p_star * np.sin(theta), 0.0, p_star * np.cos(theta)])
    k2 = np.array([m_phi / 2, -p_star * np.sin(theta), 0.0, -p_star * np.cos(theta)])
    gamma = 20.0
    beta_gamma = np.sqrt(gamma**2 - 1)
    boosted = [np.array([gamma * k[0] + beta_gamma * k[3], k[1], k[2], beta_gamma * k[0] + gamma * k[3]])
               for k in (k1, k2)]
    tx = [k[1] / k[3] for k in boosted]
    ty = [k[2] / k[3] for k in boosted]
    qop = [1 / np.linalg.norm(k[1:]) for k in boosted]
    assert invariant_mass(four_momenta(qop, tx, ty)[None])[0] == pytest.approx(m_phi, rel=1e-9)


# ---------------------------------------------------------------- σ(m) ratio on common candidates


def test_ratio_on_common_candidates_of_a_scaled_copy():
    """A fitter whose masses are the reference's stretched by 1.1 about the peak has
    σ ratio 1.1 in the full sample and in every jackknife sample: error ≈ 0."""
    from pkf.report.metrics import mass_ratio_on_common_candidates

    rng = np.random.default_rng(11)
    ref = rng.normal(BS_MASS, 10.0, 1500)
    result = mass_ratio_on_common_candidates(BS_MASS + 1.1 * (ref - BS_MASS), ref)
    assert result["n_candidates"] == 1500
    assert result["fit"]["status"] == "ok" and result["reference_fit"]["status"] == "ok"
    assert result["sigma_ratio"] == pytest.approx(1.1, rel=2e-3)
    assert result["sigma_ratio_error"] < 3e-3


def test_ratio_error_of_independent_samples_matches_the_gaussian_expectation():
    """Independent Gaussian masses with σ 11 and 10 MeV: the ratio is 1.1 within its
    jackknife error, and that error is the Gaussian one, r·√(1/(2n) + 1/(2n))."""
    from pkf.report.metrics import mass_ratio_on_common_candidates

    n = 3000
    rng = np.random.default_rng(12)
    # with a flat background of 5% (real peaks have tails): every fit has accurate errors
    mine = _sample(rng, n, BS_MASS, 11.0, n // 20, 0.0)
    ref = _sample(rng, n, BS_MASS, 10.0, n // 20, 0.0)
    result = mass_ratio_on_common_candidates(mine, ref)
    assert result["fit"]["status"] == "ok" and result["reference_fit"]["status"] == "ok"
    expected = 1.1 * np.sqrt(1.0 / n)
    assert 0.6 * expected < result["sigma_ratio_error"] < 1.6 * expected
    assert abs(result["sigma_ratio"] - 1.1) < 4 * result["sigma_ratio_error"]


def test_mass_comparison_matches_decays_not_positions():
    """The comparison pairs masses by decay index, whatever order and subset each fitter has."""
    from pkf.report.metrics import FitterArrays, _mass_comparison

    rng = np.random.default_rng(13)
    truth = rng.normal(BS_MASS, 10.0, 1200)
    decays = np.arange(1200)
    ref = FitterArrays(signal_masses=truth, mass_decays=decays)
    keep = rng.permutation(1200)[:1000]  # the other fitter lost 200 decays, lists them shuffled
    mine = FitterArrays(signal_masses=BS_MASS + 1.2 * (truth[keep] - BS_MASS), mass_decays=decays[keep])
    result = _mass_comparison(mine, ref)
    assert result["n_candidates"] == 1000
    assert result["sigma_ratio"] == pytest.approx(1.2, rel=2e-3)
