"""`pkf simulate` output: determinism, consistency and the hits' physics (DESIGN §5, §6)."""

import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pkf.geometry import load_geometry
from pkf.pipeline.simulate import SimulationConfig, run_simulation, simulate_batch

TABLES = ("hits", "particles", "mc_hits")


@pytest.fixture(scope="module")
def minbias_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "ds"
    run_simulation(SimulationConfig(generator="bs2phiphi", events=30, seed=5), out, progress=False)
    return out


def test_same_seed_gives_identical_bytes(minbias_dataset, tmp_path):
    again = tmp_path / "again"
    run_simulation(SimulationConfig(generator="bs2phiphi", events=30, seed=5), again, progress=False)
    for name in TABLES:
        assert (again / f"{name}.parquet").read_bytes() == (minbias_dataset / f"{name}.parquet").read_bytes()


def test_other_seed_gives_other_events(minbias_dataset, tmp_path):
    other = tmp_path / "other"
    run_simulation(SimulationConfig(generator="bs2phiphi", events=30, seed=6), other, progress=False)
    a = pq.read_table(minbias_dataset / "hits.parquet")
    b = pq.read_table(other / "hits.parquet")
    assert a.num_rows != b.num_rows or not a.equals(b)


def test_events_do_not_depend_on_batching():
    geometry = load_geometry("lhcb-like")
    config = SimulationConfig(events=6, seed=3)
    whole = simulate_batch(geometry, config, 0, 6)
    parts = [simulate_batch(geometry, config, 0, 2), simulate_batch(geometry, config, 2, 4)]
    for i in range(3):
        joined = pa.concat_tables([parts[0][i], parts[1][i]])
        assert joined.equals(whole[i])


def test_tables_are_consistent(minbias_dataset):
    hits = pq.read_table(minbias_dataset / "hits.parquet").to_pydict()
    mc = pq.read_table(minbias_dataset / "mc_hits.parquet").to_pydict()
    particles = pq.read_table(minbias_dataset / "particles.parquet").to_pydict()
    assert hits["event_id"] == mc["event_id"] and hits["hit_id"] == mc["hit_id"]
    assert np.all(np.diff(hits["event_id"]) >= 0)
    known = set(zip(particles["event_id"], particles["particle_id"]))
    pid = np.array(mc["particle_id"])
    assert all((e, p) in known for e, p in zip(mc["event_id"], pid) if p != 0)
    # noise hits have no true slopes; particle hits do
    tx = np.array(mc["tx"], dtype=float)
    assert np.all(np.isnan(tx[pid == 0])) and not np.any(np.isnan(tx[pid > 0]))
    # strips measure u only
    geometry = load_geometry("lhcb-like")
    layer = np.array(hits["layer"])
    strip = geometry.layer_kind[layer] == 1
    v = np.array(hits["v"], dtype=float)
    assert np.all(np.isnan(v[strip])) and not np.any(np.isnan(v[~strip]))
    assert np.allclose(hits["z"], geometry.layer_z[layer])
    meta = json.loads((minbias_dataset / "meta.json").read_text())
    assert meta["geometry"]["hash"] == geometry.content_hash
    assert meta["counts"]["hits"] == len(hits["hit_id"])


def test_hits_are_smeared_true_positions(minbias_dataset):
    hits = pq.read_table(minbias_dataset / "hits.parquet").to_pydict()
    mc = pq.read_table(minbias_dataset / "mc_hits.parquet").to_pydict()
    geometry = load_geometry("lhcb-like")
    layer = np.array(hits["layer"])
    signal = np.array(mc["particle_id"]) > 0
    u_true = np.array(mc["x"]) * geometry.layer_cos[layer] + np.array(mc["y"]) * geometry.layer_sin[layer]
    pull = (np.array(hits["u"]) - u_true) / np.array(hits["sigma_u"])
    assert np.std(pull[signal]) == pytest.approx(1.0, abs=0.03)
    assert np.all(pull[~signal] == 0.0)  # noise: u is derived from the sampled (x, y)


def test_hits_respect_acceptance_and_velo_sides(minbias_dataset):
    mc = pq.read_table(minbias_dataset / "mc_hits.parquet").to_pydict()
    hits = pq.read_table(minbias_dataset / "hits.parquet").to_pydict()
    x, y, layer = np.array(mc["x"]), np.array(mc["y"]), np.array(hits["layer"])
    velo = layer < 52
    r = np.hypot(x, y)
    assert np.all(r[velo] >= 5.1) and np.all(np.abs(x[velo]) <= 45)
    left = velo & (layer % 2 == 0)
    right = velo & (layer % 2 == 1)
    assert np.all(x[left] <= 5.0) and np.all(x[right] >= -5.0)
    ut = (layer >= 52) & (layer < 56)
    assert np.all(r[ut] >= 35.0)
    scifi = layer >= 56
    assert not np.any((np.abs(x[scifi]) < 50) & (np.abs(y[scifi]) < 50))


def test_long_tracks_bend_the_right_way(tmp_path):
    """In B_y < 0 (MagDown) the slope change from the VELO to the SciFi has the sign of
    the charge (Lorentz force) and the size κ·∫B dl/p."""
    out = tmp_path / "gun"
    run_simulation(SimulationConfig(generator="gun", events=20, particles=20, p_min=5000, p_max=5000, seed=2), out, progress=False)
    mc = pq.read_table(out / "mc_hits.parquet").to_pydict()
    hits = pq.read_table(out / "hits.parquet").to_pydict()
    layer = np.array(hits["layer"])
    tx = np.array(mc["tx"], dtype=float)
    qop = np.array(mc["qop"], dtype=float)
    particle_id = np.array(mc["particle_id"])
    key = np.array(mc["event_id"]) * 10000 + particle_id
    first_scifi = (layer == 56) & (particle_id > 0)
    last_velo_slope = {}
    for k, lay, t in zip(key, layer, tx):
        if lay < 52 and k % 10000:
            last_velo_slope[k] = t
    kicks = [(t - last_velo_slope[k], q) for k, t, q in zip(key[first_scifi], tx[first_scifi], qop[first_scifi]) if k in last_velo_slope]
    kicks = np.array(kicks)
    assert len(kicks) > 100
    # dtx/dz = κ·qop·N·[−(1+tx²)·By]: with By < 0, Δtx has the sign of q
    assert np.all(np.sign(kicks[:, 0]) == np.sign(kicks[:, 1]))
    # size: Δtx ≈ κ·∫B dl / p = 0.2998·4120/5000 ≈ 0.25
    assert np.median(np.abs(kicks[:, 0])) == pytest.approx(0.299792458 * 4120 / 5000, rel=0.1)


def test_output_passes_the_validating_reader(minbias_dataset):
    """Every check of the readers, with the layers' active areas (issue 13: no false positives)."""
    from pkf.io.reader import validate_consistency
    from pkf.pipeline.inputs import load_dataset
    from pkf.pipeline.plan import plan_dataset

    _, ds = load_dataset(minbias_dataset)
    assert ds.has_mc
    validate_consistency(ds.hits, ds.particles, ds.mc_hits)
    assert ds.hits.num_rows == ds.mc_hits.num_rows
    plan_dataset(minbias_dataset, 7)  # the streamed validation of `pkf reconstruct`


@pytest.mark.parametrize("geometry, generator", [("lhcb-like", "gun"), ("lhcb-like", "minbias"),
                                                 ("telescope", "gun")])
def test_every_builtin_geometry_passes_the_area_checks(tmp_path, geometry, generator):
    """Hits of every built-in geometry lie within the tolerance of their layers' areas
    (measured on 200 minbias ν=7.6 events, 500 gun events per geometry, 50 B_s events: the
    worst hit 3.1 σ outside, the tolerance is 5 σ + 0.1 mm)."""
    from pkf.pipeline.inputs import load_dataset

    out = tmp_path / "ds"
    config = SimulationConfig(geometry=geometry, generator=generator, events=20, pileup=4.0, seed=11)
    run_simulation(config, out, progress=False)
    _, ds = load_dataset(out)
    assert ds.hits.num_rows > 1000
