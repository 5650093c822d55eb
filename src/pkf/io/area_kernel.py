"""Compiled passes of :func:`pkf.io.reader.validate_hit_area` and :func:`~pkf.io.reader.validate_hit_layers`:
the first bad row of each check of hits against the geometry's layers.

The numpy form of the area checks made ~50 passes over each batch of hits and eight gathers of
per-layer bounds; on the 8.1 million hits of 1,000 minimum-bias events at ν = 7.6 it took
0.8 s of CPU, a fifth of the validation of the whole dataset. One loop over the rows does the
same arithmetic in the same order (so the same rows fail, NaN included) in ~0.05 s. Likewise
the layer, z and v/sigma_v checks (numpy: 0.15 s on those hits; one loop: ~0.03 s).

Both read the columns of a record batch in place (`HitColumns`: Arrow's values buffers and
validity bitmaps, a null read as NaN, a null layer as −1): converting them to numpy arrays first
(the columns of the batch and the previous batch's last event concatenated, nulls filled, int16
layers widened, two null masks) allocated ~60 bytes per hit, which cost 0.6 s of CPU on those
8.1 million hits, ten times the checks themselves (fresh memory is dear on this machine).
"""

from __future__ import annotations

import math

from typing import NamedTuple

import numba as nb
import numpy as np
import pyarrow as pa

from pkf.io.value_kernels import array_buffers, valid
from pkf.jit import NO_REFCOUNT


class HitColumns(NamedTuple):
    """The hit columns the layer and area checks read, of one Arrow record batch, in place:
    per column its values, validity bitmap (empty: no nulls) and first bit in the bitmap
    (`pkf.io.value_kernels.array_buffers`)."""

    layer: np.ndarray
    layer_valid: np.ndarray
    layer_bit: int
    z: np.ndarray
    z_valid: np.ndarray
    z_bit: int
    u: np.ndarray
    u_valid: np.ndarray
    u_bit: int
    sigma_u: np.ndarray
    sigma_u_valid: np.ndarray
    sigma_u_bit: int
    v: np.ndarray
    v_valid: np.ndarray
    v_bit: int
    sigma_v: np.ndarray
    sigma_v_valid: np.ndarray
    sigma_v_bit: int


def hit_columns(batch: pa.RecordBatch) -> HitColumns:
    """`HitColumns` of a record batch of hits: in place for the hits schema's types (layer int16,
    the others float64); a column of another type is cast first (layer to int64)."""
    parts = []
    for name in ("layer", "z", "u", "sigma_u", "v", "sigma_v"):
        column = batch.column(name)
        if name == "layer" and column.type != pa.int16():
            column = column.cast(pa.int64())
        elif name != "layer" and column.type != pa.float64():
            column = column.cast(pa.float64())
        parts.extend(array_buffers(column, column.type.to_pandas_dtype()))
    return HitColumns(*parts)


@nb.njit(cache=True, inline="always")
def _layer_at(cols, i):
    """The layer of row i (−1 if null)."""
    return np.int64(cols.layer[i]) if valid(cols.layer_valid, i + cols.layer_bit) else -1


@nb.njit(cache=True, inline="always")
def _value_at(values, validity, bit, i):
    """Row i of a float column, NaN if null."""
    return values[i] if valid(validity, i + bit) else np.nan

#: The checks, in the order their rows are reported by :func:`first_bad_area_rows`.
AREA_CHECKS = ("sigma_u", "sigma_v", "u", "v", "hole")


@nb.njit(cache=True, **NO_REFCOUNT)
def _nan_max(a: float, b: float) -> float:
    """``np.maximum`` of two floats: NaN if either is."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@nb.njit(cache=True, **NO_REFCOUNT)
def first_bad_area_rows(cols, u_min, u_max, v_min, v_max, hole_radius, hole_half_u, hole_half_v, tol_sigmas,
                        margin, out) -> None:
    """Write to ``out[k]`` the first row of the batch `cols` (`HitColumns`) failing check
    ``AREA_CHECKS[k]``, or −1.

    Rows with a layer outside [0, n_layers) (−1 for null) are skipped; a null value is NaN. ``v``/``sigma_v`` are NaN
    on strip rows (a row is a pixel row where v is not NaN). Lengths in mm; tolerance of a row:
    ``tol_sigmas`` of its σ plus ``margin``.
    """
    n_layers = u_min.size
    for k in range(out.size):
        out[k] = -1
    missing = out.size
    for i in range(cols.layer.size):
        lay = _layer_at(cols, i)
        if lay < 0 or lay >= n_layers:
            continue
        u = _value_at(cols.u, cols.u_valid, cols.u_bit, i)
        sigma_u = _value_at(cols.sigma_u, cols.sigma_u_valid, cols.sigma_u_bit, i)
        v = _value_at(cols.v, cols.v_valid, cols.v_bit, i)
        sigma_v = _value_at(cols.sigma_v, cols.sigma_v_valid, cols.sigma_v_bit, i)
        pixel = not math.isnan(v)
        tol_u = tol_sigmas * sigma_u + margin
        tol_v = tol_sigmas * (sigma_v if pixel else 0.0) + margin
        bad = (
            sigma_u > u_max[lay] - u_min[lay],
            sigma_v > v_max[lay] - v_min[lay],
            u < u_min[lay] - tol_u or u > u_max[lay] + tol_u,
            pixel and (v < v_min[lay] - tol_v or v > v_max[lay] + tol_v),
            pixel and ((hole_radius[lay] > 0 and math.hypot(u, v) < hole_radius[lay] - _nan_max(tol_u, tol_v))
                       or (abs(u) < hole_half_u[lay] - tol_u and abs(v) < hole_half_v[lay] - tol_v)),
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
def first_bad_layer_rows(cols, layer_z, layer_kind, z_tolerance, out) -> None:
    """Write to ``out[k]`` the first row of the batch `cols` (`HitColumns`) failing check
    ``LAYER_CHECKS[k]``, or −1.

    ``layer``: a row's layer is bad outside [0, n_layers) (−1 for null); the other checks skip
    such rows. ``z``: bad unless |z − layer_z[layer]| <= ``z_tolerance`` [mm] (NaN or null is bad).
    ``measured``: ``v``/``sigma_v`` must be null on strip layers (``layer_kind`` 1) and not
    null on pixel layers (0).
    """
    n_layers = layer_z.size
    for k in range(out.size):
        out[k] = -1
    missing = out.size
    for i in range(cols.layer.size):
        lay = _layer_at(cols, i)
        if lay < 0 or lay >= n_layers:
            if out[0] < 0:
                out[0] = i
                missing -= 1
        else:
            z = _value_at(cols.z, cols.z_valid, cols.z_bit, i)
            if out[1] < 0 and not abs(z - layer_z[lay]) <= z_tolerance:
                out[1] = i
                missing -= 1
            strip = layer_kind[lay] == 1
            v_null = not valid(cols.v_valid, i + cols.v_bit)
            sigma_v_null = not valid(cols.sigma_v_valid, i + cols.sigma_v_bit)
            if out[2] < 0 and (v_null != strip or sigma_v_null != strip):
                out[2] = i
                missing -= 1
        if missing == 0:
            return


def first_bad_rows(table: pa.Table, kernel, n_checks: int, *args) -> np.ndarray:
    """The first row of ``table`` (hits) failing each of the n_checks checks of ``kernel``
    (`first_bad_area_rows`, `first_bad_layer_rows`, called with ``args`` after the columns), or
    −1: the kernel over each record batch of the table in turn, its columns read in place."""
    first = np.full(n_checks, -1, np.int64)
    out = np.empty(n_checks, np.int64)
    start = 0
    for batch in table.to_batches():
        if batch.num_rows:
            kernel(hit_columns(batch), *args, out)
            found = (first < 0) & (out >= 0)
            first[found] = start + out[found]
            if np.all(first >= 0):
                break
        start += batch.num_rows
    return first
