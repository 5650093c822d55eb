"""Material effects as the simulation applies them at one layer (DESIGN §4, issue 2)."""

import numpy as np
import pytest

from pkf.physics.materials import SI_X0_MM, bethe_mean_loss, highland_theta0
from pkf.pipeline.simulate import SimulationConfig, simulate_batch

ONE_LAYER = """
name = "one-layer"
[field]
model = "uniform"
bx = 0.0
by = 0.0
bz = 0.0
[[layers]]
subdetector = "velo"
kind = "pixel"
z = [500.0]
sigma = 0.01
x_over_x0 = {x0}
half_x = 1000.0
half_y = 1000.0
"""


def _one_layer_sample(tmp_path, species, p, x_over_x0, events=400):
    geometry_file = tmp_path / "one.toml"
    geometry_file.write_text(ONE_LAYER.format(x0=x_over_x0))
    config = SimulationConfig(
        geometry=str(geometry_file), generator="gun", events=events, particles=100,
        species=species, p_min=p, p_max=p, eta_min=4.0, eta_max=5.0, seed=11,
    )
    from pkf.geometry import load_geometry

    _, particles, mc_hits = simulate_batch(load_geometry(geometry_file), config, 0, events)
    particles = particles.to_pydict()
    mc = mc_hits.to_pydict()
    key = {(e, i): n for n, (e, i) in enumerate(zip(particles["event_id"], particles["particle_id"]))}
    idx = np.array([key[(e, i)] for e, i in zip(mc["event_id"], mc["particle_id"])])
    pz = np.array(particles["pz"])[idx]
    tx0 = np.array(particles["px"])[idx] / pz
    ty0 = np.array(particles["py"])[idx] / pz
    mass = np.array(particles["mass"])[idx]
    return tx0, ty0, np.array(mc["tx"]), np.array(mc["ty"]), np.array(mc["qop"]), mass


@pytest.mark.parametrize("species, p", [("muon", 5000.0), ("pion", 2000.0)])
def test_scattering_width_equals_highland(tmp_path, species, p):
    x0 = 0.01
    tx0, ty0, tx1, ty1, qop, mass = _one_layer_sample(tmp_path, species, p, x0)
    # small slopes (η 4–5): the path length factor N ≈ 1 + 1e-3
    t = x0 * np.sqrt(1 + tx0**2 + ty0**2)
    theta0 = np.mean([highland_theta0(p, mass[0], 1.0, ti) for ti in t[:100]])
    for d in (tx1 - tx0, ty1 - ty0):
        assert np.std(d) == pytest.approx(theta0, rel=0.03)
        assert abs(np.mean(d)) < 3 * theta0 / np.sqrt(d.size)


@pytest.mark.parametrize("species, p", [("muon", 5000.0), ("proton", 1500.0)])
def test_mean_energy_loss_equals_bethe(tmp_path, species, p):
    x0 = 0.01
    tx0, ty0, _, _, qop, mass = _one_layer_sample(tmp_path, species, p, x0)
    m = mass[0]
    e0 = np.hypot(p, m)
    e1 = np.hypot(1.0 / np.abs(qop), m)
    thickness = x0 * np.sqrt(1 + tx0**2 + ty0**2) * SI_X0_MM
    expected = np.mean([bethe_mean_loss(p, m, th) for th in thickness])
    assert np.mean(e0 - e1) == pytest.approx(expected, rel=0.05)
    assert 0.2 < expected < 2.0  # ~0.36 MeV per 0.94 mm of silicon near minimum ionisation


def test_electrons_radiate(tmp_path):
    x0 = 0.05
    _, _, _, _, qop, _ = _one_layer_sample(tmp_path, "electron", 10000.0, x0, events=100)
    kept = (1.0 / np.abs(qop)) / 10000.0
    # Bethe–Heitler: E[z] = exp(−t); ionisation adds < 0.1% here
    assert np.mean(kept) == pytest.approx(np.exp(-x0), abs=0.004)
    assert np.min(kept) < 0.5  # a hard photon now and then
