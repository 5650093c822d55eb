"""Compiled passes of :func:`pkf.io.reader.validate_hit_area` and :func:`~pkf.io.reader.validate_hit_layers`:
the first bad row of each check of hits against the geometry's layers.

The numpy form of the area checks made ~50 passes over each batch of hits and eight gathers of
per-layer bounds; on the 8.1 million hits of 1,000 minimum-bias events at ν = 7.6 it took
0.8 s of CPU, a fifth of the validation of the whole dataset. One loop over the rows does the
same arithmetic in the same order (so the same rows fail, NaN included) in ~0.05 s. Likewise
the layer, z and v/sigma_v checks (numpy: 0.15 s on those hits; one loop: ~0.03 s).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT

#: The checks, in the order their rows are reported by :func:`first_bad_area_rows`.
AREA_CHECKS = ("sigma_u", "sigma_v", "u", "v", "hole")


@nb.njit(cache=True, **NO_REFCOUNT)
def _nan_max(a: float, b: float) -> float:
    """``np.maximum`` of two floats: NaN if either is."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@nb.njit(cache=True, **NO_REFCOUNT)
def first_bad_area_rows(layer, u, sigma_u, v, sigma_v, u_min, u_max, v_min, v_max, hole_radius, hole_half_u,
                        hole_half_v, tol_sigmas, margin, out) -> None:
    """Write to ``out[k]`` the first row failing check ``AREA_CHECKS[k]``, or −1.

    Rows with a layer outside [0, n_layers) (−1 for null) are skipped. ``v``/``sigma_v`` are NaN
    on strip rows (a row is a pixel row where v is not NaN). Lengths in mm; tolerance of a row:
    ``tol_sigmas`` of its σ plus ``margin``.
    """
    n_layers = u_min.size
    for k in range(out.size):
        out[k] = -1
    missing = out.size
    for i in range(layer.size):
        lay = layer[i]
        if lay < 0 or lay >= n_layers:
            continue
        pixel = not math.isnan(v[i])
        tol_u = tol_sigmas * sigma_u[i] + margin
        tol_v = tol_sigmas * (sigma_v[i] if pixel else 0.0) + margin
        bad = (
            sigma_u[i] > u_max[lay] - u_min[lay],
            sigma_v[i] > v_max[lay] - v_min[lay],
            u[i] < u_min[lay] - tol_u or u[i] > u_max[lay] + tol_u,
            pixel and (v[i] < v_min[lay] - tol_v or v[i] > v_max[lay] + tol_v),
            pixel and ((hole_radius[lay] > 0 and math.hypot(u[i], v[i]) < hole_radius[lay] - _nan_max(tol_u, tol_v))
                       or (abs(u[i]) < hole_half_u[lay] - tol_u and abs(v[i]) < hole_half_v[lay] - tol_v)),
        )
        for k in range(5):
            if bad[k] and out[k] < 0:
                out[k] = i
                missing -= 1
        if missing == 0:
            return


#: The checks of :func:`first_bad_layer_rows`, in the order of ``out``.
LAYER_CHECKS = ("layer", "z", "measured")


@nb.njit(cache=True, **NO_REFCOUNT)
def first_bad_layer_rows(layer, z, v_null, sigma_v_null, layer_z, layer_kind, z_tolerance, out) -> None:
    """Write to ``out[k]`` the first row failing check ``LAYER_CHECKS[k]``, or −1.

    ``layer``: a row's layer is bad outside [0, n_layers) (−1 for null); the other checks skip
    such rows. ``z``: bad unless |z − layer_z[layer]| <= ``z_tolerance`` [mm] (NaN is bad).
    ``measured``: ``v_null``/``sigma_v_null`` (the columns' null masks) must be true on strip
    layers (``layer_kind`` 1) and false on pixel layers (0).
    """
    n_layers = layer_z.size
    for k in range(out.size):
        out[k] = -1
    missing = out.size
    for i in range(layer.size):
        lay = layer[i]
        if lay < 0 or lay >= n_layers:
            if out[0] < 0:
                out[0] = i
                missing -= 1
        else:
            if out[1] < 0 and not abs(z[i] - layer_z[lay]) <= z_tolerance:
                out[1] = i
                missing -= 1
            strip = layer_kind[lay] == 1
            if out[2] < 0 and (v_null[i] != strip or sigma_v_null[i] != strip):
                out[2] = i
                missing -= 1
        if missing == 0:
            return
