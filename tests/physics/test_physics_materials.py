"""Material effects (pkf.physics.materials): Highland scattering, Bethe loss, bremsstrahlung."""

import math

import numpy as np
import pytest

from pkf.physics import materials as mat

PION_MASS = 139.57039
MUON_MASS = 105.6583755
PROTON_MASS = 938.27208816
N_SAMPLES = 200_000


# --- multiple scattering -------------------------------------------------------------


def test_highland_value_for_a_relativistic_particle():
    # β = 1 (mass 0), p = 1 GeV, t = 0.01: 13.6 MeV/1000 MeV·0.1·(1 + 0.038·ln 0.01)
    expected = 13.6e-3 * 0.1 * (1.0 + 0.038 * math.log(0.01))
    assert mat.highland_theta0(1000.0, 0.0, 1.0, 0.01) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(1.1220e-3, rel=1e-4)
    # charge enters as |q| and through ln(t q²/β²)
    q2 = 13.6e-3 * 0.1 * 2.0 * (1.0 + 0.038 * math.log(0.04))
    assert mat.highland_theta0(1000.0, 0.0, -2.0, 0.01) == pytest.approx(q2, rel=1e-12)
    # 1/(βp): a 200 MeV proton (β ≈ 0.21) scatters far more than a 200 MeV pion
    assert mat.highland_theta0(200.0, PROTON_MASS, 1.0, 0.01) > 4.0 * mat.highland_theta0(
        200.0, PION_MASS, 1.0, 0.01)
    assert mat.highland_theta0(1000.0, PION_MASS, 1.0, 0.0) == 0.0


def test_path_length_and_noise_matrix():
    assert mat.path_length_x0(0.01, 0.3, 0.4) == pytest.approx(0.01 * math.sqrt(1.25))
    assert mat.silicon_thickness_mm(0.01, 0.0, 0.0) == pytest.approx(0.937)
    qxx, qxy, qyy = mat.scattering_noise(0.3, -0.2, 1e-6)
    n2 = 1.0 + 0.09 + 0.04
    assert qxx == pytest.approx(1e-6 * n2 * 1.09)
    assert qyy == pytest.approx(1e-6 * n2 * 1.04)
    assert qxy == pytest.approx(1e-6 * n2 * (-0.06))
    assert qxx * qyy - qxy * qxy > 0.0


def _scatter_samples(tx, ty, theta0, seed):
    mat.seed_rng(seed)
    out = mat.apply_scattering_array(N_SAMPLES, tx, ty, theta0)
    return out[:, 0] - tx, out[:, 1] - ty


def test_scattering_width_at_normal_incidence():
    theta0 = 2e-3
    dtx, dty = _scatter_samples(0.0, 0.0, theta0, seed=11)
    assert np.std(dtx) == pytest.approx(theta0, rel=0.03)
    assert np.std(dty) == pytest.approx(theta0, rel=0.03)
    assert abs(np.mean(dtx)) < 5.0 * theta0 / math.sqrt(N_SAMPLES)
    assert abs(np.corrcoef(dtx, dty)[0, 1]) < 0.01


@pytest.mark.parametrize("tx, ty", ((0.3, 0.0), (0.3, -0.2), (-0.1, 0.45)))
def test_scattering_width_at_oblique_incidence_matches_noise_matrix(tx, ty):
    theta0 = 2e-3
    dtx, dty = _scatter_samples(tx, ty, theta0, seed=12)
    n = math.sqrt(1.0 + tx * tx + ty * ty)
    assert np.std(dtx) == pytest.approx(theta0 * n * math.sqrt(1.0 + tx * tx), rel=0.03)
    assert np.std(dty) == pytest.approx(theta0 * n * math.sqrt(1.0 + ty * ty), rel=0.03)
    qxx, qxy, qyy = mat.scattering_noise(tx, ty, theta0 * theta0)
    cov = np.cov(dtx, dty)
    assert cov[0, 0] == pytest.approx(qxx, rel=0.06)
    assert cov[1, 1] == pytest.approx(qyy, rel=0.06)
    assert cov[0, 1] == pytest.approx(qxy, abs=0.03 * math.sqrt(qxx * qyy))


def test_deflection_is_a_rotation():
    """|d'| = 1 and the angle between d and d' is exactly √(θ1² + θ2²)."""
    tx, ty = 0.25, -0.4
    d = np.array([tx, ty, 1.0]) / math.sqrt(1 + tx * tx + ty * ty)
    for theta1, theta2 in ((0.01, 0.0), (0.0, 0.02), (0.03, -0.04)):
        ntx, nty = mat.deflect(tx, ty, theta1, theta2)
        d2 = np.array([ntx, nty, 1.0]) / math.sqrt(1 + ntx * ntx + nty * nty)
        angle = math.acos(min(1.0, float(d @ d2)))
        assert angle == pytest.approx(math.hypot(theta1, theta2), rel=1e-6)
    assert mat.deflect(tx, ty, 0.0, 0.0) == (tx, ty)
    # a deflection past 90° from z is flagged with infinite slopes
    assert math.isinf(mat.deflect(0.0, 0.0, 2.0, 0.0)[0])


# --- ionisation energy loss --------------------------------------------------------


def test_bethe_minimum_ionisation_in_silicon():
    """PDG "Atomic and nuclear properties of materials", silicon: ⟨−dE/dx⟩_min =
    1.664 MeV cm²/g (= 3.876 MeV/cm, the "388 eV/µm" of PDG RPP Fig. 34.9); PDG RPP §34.2.3:
    the minimum lies at βγ ≈ 3.5 to 3.0 as Z goes from 7 to 100."""
    bg = np.logspace(0.0, 1.5, 3001)
    dedx = mat.bethe_mean_loss_array(bg * MUON_MASS, MUON_MASS, 10.0) / (mat.SI_DENSITY * 1.0)
    i = int(np.argmin(dedx))
    assert dedx[i] == pytest.approx(1.664, rel=3e-3)
    assert 3.0 < bg[i] < 4.0
    # mean loss of a minimum-ionising particle in 300 µm of silicon: 1.664·2.329·0.03 MeV
    assert mat.bethe_mean_loss(bg[i] * MUON_MASS, MUON_MASS, 0.3) == pytest.approx(0.1163, rel=3e-3)


def test_bethe_shape():
    # dE/dx is (nearly) a function of βγ only: pion, muon and proton agree at equal βγ
    for bg in (0.5, 2.0, 4.0):
        values = [mat.bethe_stopping_power(bg * m, m) for m in (MUON_MASS, PION_MASS, PROTON_MASS)]
        assert max(values) / min(values) < 1.01
    # 1/β² rise at low momentum and the (density-effect damped) relativistic rise
    assert mat.bethe_stopping_power(0.5 * MUON_MASS, MUON_MASS) > 3.0 * 1.664
    high = mat.bethe_stopping_power(1e4 * MUON_MASS, MUON_MASS)
    assert 1.664 * 1.3 < high < 1.664 * 1.7


def test_density_effect_parameters_are_consistent():
    """C̄ = 2 ln(I/ħω_p) + 1 with ħω_p = 28.816 eV·√(ρ⟨Z/A⟩) (PDG RPP eq. 34.6 ff.),
    δ is continuous at x0 and x1, and δ → 2 ln(βγ) − C̄ on the plateau."""
    plasma = 28.816 * math.sqrt(mat.SI_DENSITY * mat.SI_Z_OVER_A)
    assert plasma == pytest.approx(31.05, abs=0.01)
    assert 2.0 * math.log(173.0 / plasma) + 1.0 == pytest.approx(mat.SI_STERNHEIMER_CBAR, abs=2e-3)
    for x in (mat.SI_STERNHEIMER_X0, mat.SI_STERNHEIMER_X1):
        below = mat.silicon_density_effect(10.0 ** (x - 1e-9))
        above = mat.silicon_density_effect(10.0 ** (x + 1e-9))
        assert below == pytest.approx(above, abs=1e-3)
    assert mat.silicon_density_effect(1e4) == pytest.approx(2.0 * math.log(1e4) - 4.4355)


@pytest.mark.parametrize("p, mass, thickness", (
    (1000.0, PION_MASS, 0.3),     # MIP-like pion, 300 µm silicon (VELO-like)
    (300.0, PROTON_MASS, 0.937),  # slow proton, x/X0 = 0.01
    (5000.0, MUON_MASS, 3.0),
))
def test_sampled_loss_mean_equals_bethe(p, mass, thickness):
    mat.seed_rng(21)
    samples = mat.sample_energy_loss_array(N_SAMPLES, p, mass, thickness)
    mean = mat.bethe_mean_loss(p, mass, thickness)
    assert np.mean(samples) == pytest.approx(mean, rel=0.01)
    assert np.all(samples >= 0.0)
    # Landau-like: long upper tail, most probable value below the mean
    assert np.median(samples) < mean
    assert np.quantile(samples, 0.999) - mean > 3.0 * (mean - np.quantile(samples, 0.001))
    xi = mat.landau_xi(p, mass, thickness)
    assert np.std(samples) == pytest.approx(xi * math.pi / math.sqrt(2.0), rel=0.05)


def test_sampled_loss_never_exceeds_kinetic_energy():
    p = 60.0  # MeV pion (kinetic ≈ 12 MeV) through 5 cm of silicon: would lose far more
    kinetic = math.hypot(p, PION_MASS) - PION_MASS
    mat.seed_rng(22)
    samples = mat.sample_energy_loss_array(10_000, p, PION_MASS, 50.0)
    assert np.all(samples <= kinetic)
    assert np.max(samples) == kinetic


def test_energy_loss_changes_qop_consistently():
    qop = -1.0 / 2000.0
    e0 = math.hypot(2000.0, PION_MASS)
    out = mat.apply_energy_loss_to_qop(qop, PION_MASS, 5.0)
    assert out < 0.0
    assert math.hypot(1.0 / out, PION_MASS) == pytest.approx(e0 - 5.0, rel=1e-12)
    # a negative loss (running against the flight direction) undoes it
    assert mat.apply_energy_loss_to_qop(out, PION_MASS, -5.0) == pytest.approx(qop, rel=1e-12)
    # stopping: zero momentum is q/p = ±inf, sign kept
    assert mat.apply_energy_loss_to_qop(1.0 / 50.0, PION_MASS, 20.0) == math.inf
    assert mat.apply_energy_loss_to_qop(-1.0 / 50.0, PION_MASS, 20.0) == -math.inf
    assert mat.apply_energy_loss_to_qop(0.0, PION_MASS, 1.0) == 0.0
    # derivative for the Kalman Jacobian, against central differences
    h = 1e-6 * abs(qop)
    fd = (mat.apply_energy_loss_to_qop(qop + h, PION_MASS, 5.0)
          - mat.apply_energy_loss_to_qop(qop - h, PION_MASS, 5.0)) / (2 * h)
    assert mat.energy_loss_qop_derivative(qop, PION_MASS, 5.0) == pytest.approx(fd, rel=1e-6)


# --- bremsstrahlung ------------------------------------------------------------------


@pytest.mark.parametrize("t", (0.02, 0.1, 0.5))
def test_bremsstrahlung_fraction_moments(t):
    """−ln z ~ Gamma(t/ln 2, 1): E[−ln z] = t/ln 2 and E[z] = 2^(−t/ln 2) = e^(−t),
    E[z²] = 3^(−t/ln 2) (the moments ACTS uses for its single-Gaussian approximation)."""
    mat.seed_rng(31)
    z = mat.sample_bremsstrahlung_fraction_array(N_SAMPLES, t)
    assert np.all((z > 0.0) & (z <= 1.0))
    c = t / math.log(2.0)
    assert np.mean(-np.log(z)) == pytest.approx(c, rel=0.03)
    assert np.mean(z) == pytest.approx(math.exp(-t), rel=2e-3)
    assert np.var(z) == pytest.approx(3.0 ** (-c) - 4.0 ** (-c), rel=0.05)


def test_bremsstrahlung_edge_cases_and_qop():
    assert mat.sample_bremsstrahlung_fraction(0.0) == 1.0
    qop = 1.0 / 1000.0
    out = mat.apply_bremsstrahlung_to_qop(qop, mat.ELECTRON_MASS, 0.5)
    assert math.hypot(1.0 / out, mat.ELECTRON_MASS) == pytest.approx(
        0.5 * math.hypot(1000.0, mat.ELECTRON_MASS), rel=1e-12)
    assert mat.apply_bremsstrahlung_to_qop(-qop, mat.ELECTRON_MASS, 1e-4) == -math.inf


def test_same_seed_same_samples():
    mat.seed_rng(5)
    a = mat.sample_energy_loss_array(100, 1000.0, PION_MASS, 0.3)
    mat.seed_rng(5)
    b = mat.sample_energy_loss_array(100, 1000.0, PION_MASS, 0.3)
    np.testing.assert_array_equal(a, b)
