"""pkf.jit's prefetch hints change no value and never fault, inside or outside an array."""

import numba as nb
import numpy as np

from pkf.jit import prefetch_write, prefetch_write_rows


@nb.njit(cache=True)
def _prefetched_sum(a, beyond):
    """Sum of a (C-contiguous) after hinting every line of it and `beyond` bytes past its end."""
    for byte in range(0, a.nbytes + beyond, 64):
        prefetch_write(a, byte)
    prefetch_write_rows(a, 0, a.shape[0])
    prefetch_write_rows(a, a.shape[0], a.shape[0] + beyond // a.strides[0])
    s = 0.0
    for v in a.ravel():
        s += v
    return s


def test_prefetch_write_and_its_rows_change_nothing_and_do_not_fault():
    a = np.random.default_rng(3).normal(size=(257, 5, 5))
    before = a.copy()
    want = 0.0
    for v in a.ravel().tolist():  # the same additions in the same order
        want += v
    assert _prefetched_sum(a, 1 << 22) == want
    assert a.tobytes() == before.tobytes()
