"""Pythia 8 generators (`pythia`, `pythia-bs2phiphi`, DESIGN §5) and the transport's stop at a decay."""

import sys

import numpy as np
import pyarrow as pa
import pytest

from pkf.cli import main
from pkf.geometry import load_geometry
from pkf.physics.constants import MASS_BS
from pkf.pipeline.simulate import SimulationConfig, run_simulation, simulate_batch
from pkf.simulation.generators import GunSettings, generate_gun
from pkf.simulation.pythia import (
    PythiaSettings,
    generate_pythia_bs2phiphi,
    generate_pythia_minbias,
    pythia_available,
    signal_in_acceptance,
)
from pkf.simulation.response import decay_z, simulate_response

needs_pythia = pytest.mark.skipif(
    not pythia_available(), reason="pythia8mc is not installed: pip install 'pkf[pythia]'"
)


def _final_charged(event):
    """Charged particles without daughters in the event."""
    parents = set(event["parent_id"][event["parent_id"] > 0].tolist())
    has_child = np.isin(np.arange(1, event["pdg"].size + 1), list(parents))
    return (event["charge"] != 0) & ~has_child


def _eta(event):
    return np.arcsinh(event["pz"] / np.hypot(event["px"], event["py"]))


@pytest.fixture(scope="module")
def minbias_events():
    settings = PythiaSettings(pileup=2.0)
    return [generate_pythia_minbias(np.random.default_rng([11, e]), settings) for e in range(150)]


@pytest.fixture(scope="module")
def signal_events():
    settings = PythiaSettings(pileup=1.0)
    return [generate_pythia_bs2phiphi(np.random.default_rng([12, e]), settings) for e in range(4)]


@needs_pythia
def test_same_seed_same_tables_whatever_the_batching():
    geometry = load_geometry("lhcb-like")
    config = SimulationConfig(generator="pythia", events=4, pileup=1.5, seed=3)
    whole = simulate_batch(geometry, config, 0, 4)
    parts = [simulate_batch(geometry, config, 2, 2), simulate_batch(geometry, config, 0, 2)]
    for i in range(3):
        assert pa.concat_tables([parts[1][i], parts[0][i]]).equals(whole[i])
    other = simulate_batch(geometry, SimulationConfig(generator="pythia", events=4, pileup=1.5, seed=4), 0, 4)
    assert not other[1].equals(whole[1])


@needs_pythia
def test_same_seed_gives_identical_bytes(tmp_path):
    config = SimulationConfig(generator="pythia-bs2phiphi", events=2, pileup=1.0, seed=9)
    for name in ("a", "b"):
        run_simulation(config, tmp_path / name, progress=False)
    for table in ("hits", "particles", "mc_hits"):
        assert (tmp_path / "a" / f"{table}.parquet").read_bytes() == (tmp_path / "b" / f"{table}.parquet").read_bytes()


@needs_pythia
def test_forward_charged_multiplicity_per_interaction(minbias_events):
    # LHCb: dN/dη ≈ 5–6 charged particles per unit η in 2 < η < 5 for inelastic pp at 13 TeV
    n_charged = sum(np.sum(_final_charged(ev) & (_eta(ev) > 2) & (_eta(ev) < 5)) for ev in minbias_events)
    n_interactions = sum(ev["interaction"].max() + 1 for ev in minbias_events)
    assert 4.0 < n_charged / n_interactions / 3.0 < 8.0


@needs_pythia
def test_pileup_is_zero_truncated_poisson(minbias_events):
    n = np.array([ev["interaction"].max() + 1 for ev in minbias_events])
    nu = 2.0
    mean = nu / (1 - np.exp(-nu))
    variance = mean * (1 + nu - mean)
    assert abs(n.mean() - mean) < 4 * np.sqrt(variance / n.size)
    vz = np.array([ev["vz"][(ev["interaction"] == k) & (ev["parent_id"] == 0)][0]
                   for ev in minbias_events for k in range(ev["interaction"].max() + 1)])
    assert np.std(vz) == pytest.approx(45.0, rel=0.2)


@needs_pythia
def test_decay_products_start_at_their_parent_decay(minbias_events):
    ev = minbias_events[0]
    child = np.flatnonzero(ev["parent_id"] > 0)
    parent = ev["parent_id"][child] - 1
    assert np.all(parent < child)  # ancestors come first
    assert np.all(ev["interaction"][parent] == ev["interaction"][child])
    k0s_daughters = child[ev["pdg"][parent] == 310]
    assert k0s_daughters.size and np.all(np.abs(ev["pdg"][k0s_daughters]) == 211)
    flight = ev["vz"][k0s_daughters] - ev["vz"][ev["parent_id"][k0s_daughters] - 1]
    assert np.all(flight != 0) and np.median(np.abs(flight)) > 1.0  # cτ(K0S) = 26.8 mm


@needs_pythia
def test_bs_events_have_four_kaons_with_the_bs_mass(signal_events):
    for ev in signal_events:
        assert signal_in_acceptance(ev)
        pdg, parent = ev["pdg"], ev["parent_id"]
        signal = np.flatnonzero(ev["from_signal"])
        assert np.all(ev["interaction"][signal] == 0)
        kaons = signal[np.abs(pdg[signal]) == 321]
        phis = parent[kaons] - 1
        assert np.all(pdg[phis] == 333)
        bs = np.unique(parent[phis] - 1)
        assert np.all(np.abs(pdg[bs]) == 531)
        for b in bs[:1]:
            k = kaons[parent[phis] - 1 == b]
            assert k.size == 4 and np.sum(ev["charge"][k]) == 0
            p = np.stack([ev["px"][k], ev["py"][k], ev["pz"][k]], axis=1)
            energy = np.sqrt(np.sum(p**2, axis=1) + ev["mass"][k] ** 2)
            mass = np.sqrt(energy.sum() ** 2 - np.sum(p.sum(axis=0) ** 2))
            assert mass == pytest.approx(MASS_BS, abs=1.0)


@needs_pythia
def test_reconstruct_pythia_events(tmp_path):
    from pkf.pipeline.reconstruct import ReconstructionConfig, run_reconstruction

    run_simulation(SimulationConfig(generator="pythia", events=12, pileup=2.0, seed=5), tmp_path / "ds",
                   progress=False)
    run = run_reconstruction(tmp_path / "ds", tmp_path / "run", ReconstructionConfig(), progress=False)
    high_p = run["pattern"]["efficiency_by_p"]["p_gt_5GeV"]
    assert high_p["reconstructible"] > 30
    assert high_p["efficiency"] > 0.9


def test_transport_stops_at_the_decay_vertex():
    geometry = load_geometry("lhcb-like")
    ev = generate_gun(np.random.default_rng(1), GunSettings(particles=20, p_min=10000.0))
    state = np.column_stack([ev["vx"], ev["vy"], ev["px"] / ev["pz"], ev["py"] / ev["pz"],
                             ev["charge"] / np.linalg.norm(np.column_stack([ev["px"], ev["py"], ev["pz"]]), axis=1)])
    offsets = np.array([0, 10, 20])  # stopped particles in event 0, free ones in event 1
    args = (geometry, np.array([7, 8]), offsets, state, ev["vz"], ev["mass"], ev["charge"], np.zeros(20, bool))
    free = simulate_response(*args)
    stop = np.full(20, np.inf)
    stop[:10] = ev["vz"][:10] + 300.0
    stopped = simulate_response(*args, stop_z=stop)
    early = (stopped.particle >= 0) & (stopped.particle < 10)
    late = stopped.event == 1
    assert np.all(stopped.z[early] <= stop[stopped.particle[early]])
    assert 0 < np.sum(early) < np.sum((free.particle >= 0) & (free.particle < 10))
    assert np.array_equal(stopped.u[late], free.u[free.event == 1], equal_nan=True)


def test_decay_z_is_the_first_daughter_vertex():
    offsets = np.array([0, 3, 5])
    parent_id = np.array([0, 1, 1, 0, 1])
    vz = np.array([0.0, 12.0, 5.0, 1.0, 40.0])
    assert decay_z(offsets, parent_id, vz).tolist() == [5.0, np.inf, np.inf, 40.0, np.inf]


def test_missing_extra_exits_2_with_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pythia8mc", None)  # import fails as if not installed
    code = main(["simulate", "--generator", "pythia", "--events", "1", "--out", str(tmp_path / "ds")])
    err = capsys.readouterr().err
    assert code == 2
    assert err == "pkf: error: --generator pythia: needs the pythia extra: pip install 'pkf[pythia]'\n"
    assert not (tmp_path / "ds").exists()
