"""`benchmarks/parametrized_steps.py`'s split of the parametrized steps: its groups cover every
node-to-node step once, and its table / RK4-fallback split of the UT→SciFi steps is the one
the extrapolator makes (the table's status for each state, without the fallback)."""


import numpy as np
import pytest
from bench_helpers import forget_twin, load_benchmark, truth_sample_class


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("parametrized_steps")


def test_step_groups_partition_the_steps_and_split_the_table_as_the_extrapolator(bench):
    from pkf.geometry import load_geometry
    from pkf.params.parameter_set import shipped_parameters
    from pkf.params.ut_to_scifi import STATUS_BELOW_P_MIN, ut_to_scifi_extrapolate

    geometry = load_geometry("lhcb-like")
    # 1.2–4 GeV pions: UT→SciFi steps on both sides of the table's p_low (1.5 GeV)
    sample = truth_sample_class()(geometry, events=20, seed=5, particles=10, p_min=1200.0, p_max=4000.0, eta_min=2.0,
                         eta_max=4.5)
    batch, params = sample.batch, shipped_parameters(geometry)
    ext = params.extrapolator(geometry)
    states_in = np.zeros((batch.z.size, 5))
    bench.chain_states(ext, batch.offsets, batch.z, sample.seeds, states_in)
    groups = bench.step_groups(ext, batch, geometry, states_in)
    by_subdetectors = np.concatenate([v for k, v in groups.items() if ":" not in k])
    steps = np.setdiff1d(np.arange(batch.z.size), batch.offsets[:-1])
    np.testing.assert_array_equal(np.sort(by_subdetectors), steps)
    table, fallback = groups["ut → scifi: table"], groups["ut → scifi: RK4 fallback"]
    np.testing.assert_array_equal(np.sort(np.concatenate([table, fallback])), np.sort(groups["ut → scifi"]))
    assert table.size > 20 and fallback.size > 2
    meta, cells = params.ut_to_scifi.as_arrays()
    out, jac = np.empty(5), np.empty((5, 5))
    for nodes, below in ((table, False), (fallback, True)):
        for k in nodes:
            state = states_in[k].copy()
            eloss = ext.extrapolation[ext.sub_last[ext.layer_sub[batch.layer[k - 1]]], 0]
            state[4] /= 1.0 - eloss * abs(state[4])
            assert (ut_to_scifi_extrapolate(meta, cells, state, out, jac) == STATUS_BELOW_P_MIN) == below


def test_a_twin_extrapolator_runs_in_the_kernels_with_its_own_step(bench, tmp_path, monkeypatch):
    """--against: the base checkout's extrapolator (here this checkout's own, as ``pkf_base_<digest>``)
    is registered with its step, and the module's kernels give bitwise this checkout's states."""
    from bench_helpers import BENCHMARKS

    from pkf.geometry import load_geometry
    from pkf.params.parameter_set import shipped_parameters

    monkeypatch.setenv("PKF_CACHE_DIR", str(tmp_path))
    forget_twin(monkeypatch)
    geometry = load_geometry("lhcb-like")
    sample = truth_sample_class()(geometry, events=3, seed=6, particles=5, p_min=2000.0, p_max=20000.0)
    batch = sample.batch
    ext = shipped_parameters(geometry).extrapolator(geometry)
    base = bench.base_extrapolator(BENCHMARKS.parent)
    assert type(base).__module__.startswith("pkf_base_") and type(base) is not type(ext)
    states = {}
    for name, e in (("new", ext), ("base", base)):
        states[name] = np.zeros((batch.z.size, 5))
        bench.chain_states(e, batch.offsets, batch.z, sample.seeds, states[name])
    np.testing.assert_array_equal(states["base"], states["new"])
    assert np.abs(states["new"][np.setdiff1d(np.arange(batch.z.size), batch.offsets[:-1])]).sum() > 0.0
