"""pkf's Gaussian-mixture approximation of the Bethe–Heitler distribution (issue 7)."""

import json
import math

import numpy as np
import pytest

from pkf.params.bethe_heitler import (
    NO_LOSS_BELOW,
    T_MAX,
    T_MIN,
    Z_GRID,
    BetheHeitlerMixture,
    bethe_heitler_cdf,
    load_bethe_heitler_mixture,
    max_cdf_difference,
)
from pkf.physics.materials import sample_bremsstrahlung_fraction_array, seed_rng


@pytest.fixture(scope="module")
def mixture():
    return load_bethe_heitler_mixture()


def test_cdf_within_0p01_of_bethe_heitler_over_the_fitted_range(mixture):
    """max_z |F_mix − F_BH| < 0.01 for x/X0 in [0.002, 0.2] (z grid 0, 0.001, …, 1)."""
    t = np.geomspace(T_MIN, T_MAX, 120)
    diff = max_cdf_difference(mixture, t)
    assert diff.max() < 0.01, (t[np.argmax(diff)], diff.max())
    # the stored metadata say the same as a recomputation
    assert mixture.metadata["max_cdf_difference"] < 0.01


def test_true_cdf_agrees_with_the_simulation_sampler():
    """The reference CDF is the law the simulation draws from (−ln z ~ Gamma(t/ln 2, 1))."""
    seed_rng(3)
    t = 0.05
    z = np.sort(sample_bremsstrahlung_fraction_array(20000, t))
    empirical = np.arange(1, z.size + 1) / z.size
    grid = np.linspace(0.0, 0.999, 200)
    assert np.abs(np.interp(grid, z, empirical) - bethe_heitler_cdf(grid, t)).max() < 0.015


def test_components_are_a_proper_mixture_and_keep_the_mean(mixture):
    for t in np.geomspace(T_MIN, T_MAX, 15):
        w, mu, var = mixture.components(t)
        assert w.size == mixture.n_components
        assert np.all(w > 0) and math.isclose(w.sum(), 1.0, rel_tol=1e-12)
        assert np.all((mu > 0) & (mu < 1)) and np.all(var > 0)
        # E[z] = 2^(−c): the mean energy loss is right to a few 1e−4
        assert abs(np.sum(w * mu) - 2.0 ** (-t / math.log(2.0))) < 1e-3


def test_acts_shortcuts(mixture):
    assert mixture.components(0.5 * NO_LOSS_BELOW)[0].size == 0  # no loss
    t = 0.001
    w, mu, var = mixture.components(t)
    c = t / math.log(2.0)
    assert w.size == 1 and math.isclose(mu[0], 2.0 ** -c) and math.isclose(var[0], 3.0 ** -c - 4.0 ** -c)
    # above t_max the mixture is the one at t_max (clipped)
    np.testing.assert_array_equal(mixture.components(0.5)[1], mixture.components(T_MAX)[1])


def test_json_round_trip(mixture, tmp_path):
    path = tmp_path / "bh.json"
    path.write_text(json.dumps(mixture.to_json_dict()))
    again = load_bethe_heitler_mixture(path)
    np.testing.assert_array_equal(again.coefficients, mixture.coefficients)
    assert isinstance(again, BetheHeitlerMixture)


def test_a_bad_mixture_fails_the_cdf_check(mixture):
    """The CDF check can fail: a single Gaussian at the exact mean and variance is far off."""
    single = BetheHeitlerMixture(mixture.coefficients[:, :1, :] * 0.0 + np.array([[[0.0]], [[math.log(0.1)]], [[0.0]]]))
    assert max_cdf_difference(single, [0.05]).max() > 0.05
    assert Z_GRID[0] == 0.0 and Z_GRID[-1] == 1.0
