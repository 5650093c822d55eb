"""pkf.jit's prefetch hint changes no value and never faults, inside or outside an array."""

import numba as nb
import numpy as np

from pkf.jit import prefetch_write


@nb.njit(cache=True)
def _prefetched_sum(a, beyond):
    """Sum of a (C-contiguous) after hinting every line of it and `beyond` bytes past its end."""
    for byte in range(0, a.nbytes + beyond, 64):
        prefetch_write(a, byte)
    s = 0.0
    for v in a.ravel():
        s += v
    return s


def test_prefetch_write_changes_nothing_and_does_not_fault():
    a = np.random.default_rng(3).normal(size=(257, 5, 5))
    before = a.copy()
    want = 0.0
    for v in a.ravel().tolist():  # the same additions in the same order
        want += v
    assert _prefetched_sum(a, 1 << 22) == want
    assert a.tobytes() == before.tobytes()
