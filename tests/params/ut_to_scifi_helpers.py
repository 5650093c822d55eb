"""Helpers shared by the UT→SciFi table tests (test_ut_to_scifi.py, test_ut_to_scifi_soft.py)."""

from __future__ import annotations

import numpy as np

from pkf.params.ut_to_scifi import ut_to_scifi_extrapolate


def near_cell_boundary(states, meta, margin=1e-3):
    """Rows of states (n×5) within `margin` (in grid steps) of a cell edge or midline of the
    table's (x/z, y/z) grid, where the six-point interpolation switches stencils."""
    u = (states[:, 0] / meta[0] - meta[3]) / meta[4]
    v = (states[:, 1] / meta[0] - meta[6]) / meta[7]
    frac = lambda a: np.abs(a - np.round(a))  # noqa: E731
    return (np.abs(frac(u) - 0.5) < margin) | (frac(u) < margin) | (np.abs(frac(v) - 0.5) < margin) | (frac(v) < margin)


def finite_difference_jacobian(meta, cells, state, steps):
    """Central differences of `ut_to_scifi_extrapolate` with the step `steps[j]` in state j."""
    jac = np.empty((5, 5))
    out_p, out_m, scratch = np.empty(5), np.empty(5), np.empty((5, 5))
    for j in range(5):
        sp, sm = state.copy(), state.copy()
        sp[j] += steps[j]
        sm[j] -= steps[j]
        ut_to_scifi_extrapolate(meta, cells, sp, out_p, scratch)
        ut_to_scifi_extrapolate(meta, cells, sm, out_m, scratch)
        jac[:, j] = (out_p - out_m) / (2.0 * steps[j])
    return jac
