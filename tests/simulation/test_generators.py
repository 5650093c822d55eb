"""Generators: kinematics, composition and the B_s⁰ → φφ decay chain."""

import numpy as np
import pytest

from pkf.simulation.generators import (
    GunSettings,
    MinBiasSettings,
    generate_bs2phiphi,
    generate_bs2phiphi_decay,
    generate_gun,
    generate_minbias,
)
from pkf.physics.constants import CTAU_BS, MASS_BS, MASS_PHI


def _invariant_mass(ev, rows):
    p = np.stack([ev["px"][rows], ev["py"][rows], ev["pz"][rows]], axis=1)
    e = np.sqrt(np.sum(p**2, axis=1) + ev["mass"][rows] ** 2)
    return np.sqrt(e.sum() ** 2 - np.sum(p.sum(axis=0) ** 2))


def test_bs_decay_kaons_have_the_bs_mass():
    rng = np.random.default_rng(7)
    for _ in range(50):
        ev = generate_bs2phiphi_decay(rng, np.zeros(3))
        assert _invariant_mass(ev, slice(3, 7)) == pytest.approx(MASS_BS, abs=1e-6)
        assert _invariant_mass(ev, slice(3, 5)) == pytest.approx(MASS_PHI, abs=1e-6)
        assert list(ev["parent_id"]) == [0, 1, 1, 2, 2, 3, 3]
        assert ev["charge"].sum() == 0


def test_bs_flight_distance_follows_ctau():
    rng = np.random.default_rng(8)
    proper = []
    for _ in range(4000):
        ev = generate_bs2phiphi_decay(rng, np.zeros(3))
        flight = np.array([ev["vx"][1], ev["vy"][1], ev["vz"][1]])
        p = np.array([ev["px"][0], ev["py"][0], ev["pz"][0]])
        proper.append(np.linalg.norm(flight) * MASS_BS / np.linalg.norm(p))
    assert np.mean(proper) == pytest.approx(CTAU_BS, rel=0.05)


def test_bs_event_parents_point_into_the_event():
    rng = np.random.default_rng(9)
    ev = generate_bs2phiphi(rng, MinBiasSettings())
    n = ev["pdg"].size
    kaons = np.flatnonzero(ev["from_signal"] & (np.abs(ev["pdg"]) == 321))
    assert kaons.size == 4
    assert _invariant_mass(ev, kaons) == pytest.approx(MASS_BS, abs=1e-6)
    parents = ev["parent_id"][ev["parent_id"] > 0]
    assert np.all(parents <= n)
    assert np.all(np.abs(ev["pdg"][parents - 1]) != 321)


def test_minbias_composition_and_spectra():
    rng = np.random.default_rng(10)
    settings = MinBiasSettings()
    evs = [generate_minbias(rng, settings) for _ in range(400)]
    pdg = np.abs(np.concatenate([e["pdg"] for e in evs]))
    per_event = np.array([e["pdg"].size for e in evs])
    # zero-truncated Poisson(1) interactions × NB(mean 40): mean 40/(1 − e^−1)
    assert per_event.mean() == pytest.approx(40 / (1 - np.exp(-1)), rel=0.08)
    assert np.mean(pdg == 211) == pytest.approx(0.80, abs=0.02)
    assert np.mean(pdg == 321) == pytest.approx(0.12, abs=0.015)
    pt = np.hypot(np.concatenate([e["px"] for e in evs]), np.concatenate([e["py"] for e in evs]))
    assert pt.mean() == pytest.approx(600.0, rel=0.03)
    p = np.sqrt(pt**2 + np.concatenate([e["pz"] for e in evs]) ** 2)
    eta = np.arctanh(np.concatenate([e["pz"] for e in evs]) / p)
    assert eta.min() >= 1.8 and eta.max() <= 5.2


def test_gun_ranges():
    rng = np.random.default_rng(11)
    settings = GunSettings(species="kaon", particles=1000, p_min=3000, p_max=4000, eta_min=2.5, eta_max=3.0)
    ev = generate_gun(rng, settings)
    p = np.sqrt(ev["px"] ** 2 + ev["py"] ** 2 + ev["pz"] ** 2)
    assert p.min() >= 3000 and p.max() <= 4000
    eta = np.arctanh(ev["pz"] / p)
    assert eta.min() >= 2.5 - 1e-12 and eta.max() <= 3.0 + 1e-12
    assert set(np.abs(ev["pdg"])) == {321}
    assert np.all(np.sign(ev["pdg"]) == ev["charge"])
