"""gaussian_core: the Gaussian core of a distribution with tails (iterative ±3σ unbinned fits)."""

from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest

from pkf.params.gauss import COLLECT_ABOVE_VALUES, gaussian_core


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_core_of_gaussian_with_tails(seed):
    rng = np.random.default_rng(seed)
    values = np.concatenate([rng.normal(0.3, 1.7, 4000), 30 * rng.standard_cauchy(100), [np.nan, np.inf]])
    core = gaussian_core(values)
    assert core.valid
    assert abs(core.mean - 0.3) < 4 * core.mean_error
    assert abs(core.sigma - 1.7) < 4 * core.sigma_error and core.sigma_error < 0.05
    assert core.rms > 3 * core.sigma  # the tails are in the RMS, not in the core
    assert 3900 < core.n < 4100


def test_degenerate_inputs():
    assert not gaussian_core([1.0, 2.0]).valid  # fewer than 10 values
    constant = gaussian_core(np.full(50, 2.5))
    assert not constant.valid and constant.sigma == 0.0 and constant.mean == 2.5



def test_large_fit_leaves_no_copy_of_the_values_behind():
    """The report fits millions of values many times: each fit's Minuit (in a reference cycle
    with its views) holds a copy of the values until a full garbage collection. A large fit
    collects it at once, so the memory held afterwards does not grow with the values."""
    values = np.random.default_rng(3).normal(size=2 * COLLECT_ABOVE_VALUES)
    gc.collect()
    enabled = gc.isenabled()
    gc.disable()  # only the collection gaussian_core does itself
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        core = gaussian_core(values)
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
        if enabled:
            gc.enable()
    assert core.valid and abs(core.sigma - 1.0) < 0.01
    assert held < 0.1 * values.nbytes, held  # 3 passes of copies would be ~3 × values.nbytes
