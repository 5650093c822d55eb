"""`benchmarks/twin.py`: another checkout's pkf imported beside this one as ``pkf_base_<digest>``, for
side-by-side timing in one process (`benchmarks/fit_core.py --against`)."""

import importlib
from pathlib import Path

import numpy as np
import pytest
from bench_helpers import forget_twin, load_benchmark

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def twin():
    return load_benchmark("twin")


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("from pkf.fit import kalman", "from pkf_base.fit import kalman"),
        ("import pkf\n", "import pkf_base\n"),
        ("import pkf", "import pkf_base"),
        ('resources.files("pkf.params")', 'resources.files("pkf_base.params")'),
        ("from pkf import errors", "from pkf_base import errors"),
        ("pkf_cache = mypkf + _pkf", "pkf_cache = mypkf + _pkf"),  # names that only contain it
    ],
)
def test_references_to_the_package_are_rewritten_and_nothing_else(twin, text, expected):
    assert twin.rewrite_references(text) == expected


def test_twin_of_this_checkout_has_its_own_kernels_and_computes_the_same_bits(twin, tmp_path, monkeypatch):
    """The copy imports, finds its package data (the shipped UT→SciFi table) and compiles its
    own kernels (its own dispatcher objects), which give bitwise this checkout's results."""
    monkeypatch.setenv("PKF_CACHE_DIR", str(tmp_path))
    forget_twin(monkeypatch)
    base = twin.load_twin(ROOT)
    assert base.__name__.startswith("pkf_base_") and Path(base.__file__).is_relative_to(tmp_path)
    from pkf.geometry import load_geometry
    from pkf.params.parameter_set import shipped_parameters
    from pkf.params.ut_to_scifi import ut_to_scifi_extrapolate_many

    base_parameter_set = importlib.import_module(f"{base.__name__}.params.parameter_set")
    base_ut_to_scifi = importlib.import_module(f"{base.__name__}.params.ut_to_scifi")
    base_load_geometry = importlib.import_module(f"{base.__name__}.geometry").load_geometry

    assert base_ut_to_scifi.ut_to_scifi_extrapolate_many is not ut_to_scifi_extrapolate_many
    meta, cells = shipped_parameters(load_geometry("lhcb-like")).ut_to_scifi.as_arrays()
    base_meta, base_cells = base_parameter_set.shipped_parameters(base_load_geometry("lhcb-like")).ut_to_scifi.as_arrays()
    np.testing.assert_array_equal(base_cells, cells)
    rng = np.random.default_rng(3)
    z = meta[0]
    states = np.column_stack([rng.uniform(-0.2, 0.2, 200) * z, rng.uniform(-0.15, 0.15, 200) * z,
                              rng.uniform(-0.25, 0.25, 200), rng.uniform(-0.2, 0.2, 200),
                              rng.choice([-1, 1], 200) / rng.uniform(1000.0, 50000.0, 200)])
    outputs = []
    for function, (m, c) in ((ut_to_scifi_extrapolate_many, (meta, cells)),
                             (base_ut_to_scifi.ut_to_scifi_extrapolate_many, (base_meta, base_cells))):
        out, jac, status = np.empty((200, 5)), np.empty((200, 5, 5)), np.empty(200, dtype=np.int64)
        function(m, c, states, out, jac, status)
        outputs.append((out, jac, status))
    for a, b in zip(*outputs):
        np.testing.assert_array_equal(a, b)
    assert np.isin(outputs[0][2], (0, 4)).all() and (outputs[0][2] == 0).sum() > 100


def test_side_by_side_alternates_the_order_and_keeps_each_rounds_minimum():
    bench = load_benchmark("twin")
    calls = []
    runs = {side: (lambda side=side: calls.append(side)) for side in ("base", "new")}
    times = bench.side_by_side(runs, rounds=4, repeat=2)
    assert calls == ["base", "new"] + ["base"] * 2 + ["new"] * 2 + ["new"] * 2 + ["base"] * 2 \
        + ["base"] * 2 + ["new"] * 2 + ["new"] * 2 + ["base"] * 2
    assert [len(t) for t in times.values()] == [4, 4] and min(min(t) for t in times.values()) >= 0.0
