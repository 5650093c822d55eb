"""pkf.jit.fma rounds a·b + c once (IEEE fusedMultiplyAdd), and no compiled kernel of pkf lets
LLVM contract on its own (fastmath): the fit's results are those of its source, the same in
every process, whether its code was compiled there or loaded from numba's cache."""

import importlib
import pkgutil
from fractions import Fraction

import numba as nb
import numpy as np
from numba.core.registry import CPUDispatcher

import pkf
from pkf.jit import fma


@nb.njit(cache=True)
def _fused(a, b, c):
    return fma(a, b, c)


@nb.njit(cache=True)
def _unfused(a, b, c):
    return a * b + c


def test_fma_rounds_once():
    a = 1.0 + 2.0**-30
    b = 1.0 - 2.0**-30
    # a·b = 1 − 2⁻⁶⁰ exactly; rounded first it is 1.0, so the unfused sum loses everything
    assert _fused(a, b, -1.0) == -(2.0**-60)
    assert _unfused(a, b, -1.0) == 0.0


def test_fma_is_the_correctly_rounded_exact_value():
    rng = np.random.default_rng(11)
    a, b, c = (rng.normal(size=2000) * 10.0 ** rng.integers(-8, 8, size=2000) for _ in range(3))
    for x, y, z in zip(a.tolist(), b.tolist(), c.tolist()):
        assert _fused(x, y, z) == float(Fraction(x) * Fraction(y) + Fraction(z))


def test_fma_takes_integer_arguments():
    assert _fused(2, 3.0, 1) == 7.0


def test_no_kernel_lets_the_compiler_contract():
    """fastmath (contract, reassoc, …) makes LLVM choose per optimised module what it fuses:
    code loaded from the cache and the same code compiled fresh rounded differently (two
    processes of one partitioned run gave different tables). Fused multiply–adds are written
    as pkf.jit.fma instead."""
    allowed = {
        # a finiteness test: Σ v·0 is 0, or NaN if one v is not finite, in any order of the sum
        "pkf.io.value_kernels._block_sum_times_zero": {"reassoc"},
    }
    offenders = []
    for info in pkgutil.walk_packages(pkf.__path__, "pkf."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if not isinstance(obj, CPUDispatcher) or not obj.targetoptions.get("fastmath"):
                continue
            qualified = f"{info.name}.{name}"
            if obj.targetoptions["fastmath"] != allowed.get(qualified):
                offenders.append(qualified)
    assert offenders == []
