"""Magnetic field models: homogeneous, the analytic LHCb-like dipole, and its tabulated map.

Units: positions in mm, field in tesla (docs/geometry.md#field).

Every model is a `FieldModel` whose three arrays ``(kind, params, grid)`` are what the
compiled kernels take; `field_at` evaluates any of them inside numba code, so the
simulation (analytic dipole) and the reference fit (field map) share one transport.
"""

from __future__ import annotations

import hashlib
import math
import os
from dataclasses import dataclass, field as dataclass_field
from pathlib import Path

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT

FIELD_UNIFORM = 0
FIELD_DIPOLE = 1
FIELD_MAP = 2

# Index of each parameter of the analytic dipole in FieldModel.params.
_DIPOLE_B0, _DIPOLE_Z1, _DIPOLE_Z2, _DIPOLE_LAMBDA, _DIPOLE_K, _DIPOLE_L = range(6)
# Parameters of a field map: grid origin, spacing and number of points per axis.
_MAP_X0, _MAP_Y0, _MAP_Z0, _MAP_DX, _MAP_DY, _MAP_DZ, _MAP_NX, _MAP_NY, _MAP_NZ = range(9)

_NO_GRID = np.zeros((1, 1, 1, 3))


@dataclass(frozen=True)
class FieldModel:
    """A field model as the compiled kernels see it.

    kind:   FIELD_UNIFORM, FIELD_DIPOLE or FIELD_MAP.
    params: float64 parameters of the model (see the constructors).
    grid:   for FIELD_MAP the sampled field, shape (nx, ny, nz, 3) in tesla; else a dummy.
    description: the model's defining parameters, used for hashing and metadata.
    """

    kind: int
    params: np.ndarray
    grid: np.ndarray = dataclass_field(default_factory=lambda: _NO_GRID)
    description: tuple = ()

    @property
    def args(self) -> tuple[int, np.ndarray, np.ndarray]:
        """The ``(kind, params, grid)`` triple passed to compiled kernels."""
        return self.kind, self.params, self.grid

    def content_hash(self) -> str:
        """SHA-256 (hex, first 16 digits) of the model definition."""
        return hashlib.sha256(repr(self.description).encode()).hexdigest()[:16]

    def evaluate(self, x, y, z) -> np.ndarray:
        """Field (bx, by, bz) [T] at arrays of positions [mm]; returns shape (n, 3)."""
        x, y, z = (np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in (x, y, z))
        x, y, z = np.broadcast_arrays(x, y, z)
        return _evaluate_many(self.kind, self.params, self.grid, x.ravel(), y.ravel(), z.ravel())


def uniform_field(bx: float = 0.0, by: float = 1.0, bz: float = 0.0) -> FieldModel:
    """A homogeneous field (bx, by, bz) in tesla."""
    params = np.array([bx, by, bz], dtype=np.float64)
    return FieldModel(FIELD_UNIFORM, params, description=("uniform", bx, by, bz))


def dipole_field(
    b0: float = -1.03,
    z1: float = 3000.0,
    z2: float = 7000.0,
    edge_length: float = 420.0,
    k: float = -0.10,
    length_scale: float = 1000.0,
) -> FieldModel:
    """The analytic dipole of docs/geometry.md#field.

    On axis B_y(0,0,z) = b(z) = b0·E(z − z1)·E(z2 − z), E(s) = 1/(1 + exp(−s/λ)),
    λ = edge_length [mm]. Off axis B = −∇Φ with
    Φ = −[b·y − b″·y³/6] − k·b·(x²y − y³/3)/L², L = length_scale [mm],
    so the field is curl-free by construction. b0 in tesla (negative: "MagDown").
    """
    params = np.array([b0, z1, z2, edge_length, k, length_scale], dtype=np.float64)
    return FieldModel(
        FIELD_DIPOLE,
        params,
        description=("dipole", b0, z1, z2, edge_length, k, length_scale),
    )


@nb.njit(cache=True)
def _logistic_derivatives(s, lam):
    """E(s) = 1/(1+exp(−s/λ)) and its first three derivatives with respect to s."""
    e = 1.0 / (1.0 + np.exp(-s / lam))
    d1 = e * (1.0 - e) / lam
    d2 = d1 * (1.0 - 2.0 * e) / lam
    d3 = d1 * (1.0 - 6.0 * e + 6.0 * e * e) / (lam * lam)
    return e, d1, d2, d3


@nb.njit(cache=True, **NO_REFCOUNT)
def _dipole_profile(params, z):
    """On-axis profile b(z) [T] and its derivatives b′, b″, b‴ [T/mm^n]."""
    b0 = params[_DIPOLE_B0]
    lam = params[_DIPOLE_LAMBDA]
    e1, e1d, e1dd, e1ddd = _logistic_derivatives(z - params[_DIPOLE_Z1], lam)
    e2, e2d, e2dd, e2ddd = _logistic_derivatives(params[_DIPOLE_Z2] - z, lam)
    # d/dz E(z2 − z) = −E′(z2 − z): the signs alternate for the second factor.
    b = b0 * e1 * e2
    b1 = b0 * (e1d * e2 - e1 * e2d)
    b2 = b0 * (e1dd * e2 - 2.0 * e1d * e2d + e1 * e2dd)
    b3 = b0 * (e1ddd * e2 - 3.0 * e1dd * e2d + 3.0 * e1d * e2dd - e1 * e2ddd)
    return b, b1, b2, b3


@nb.njit(cache=True, **NO_REFCOUNT)
def _dipole_at(params, x, y, z):
    """B = −∇Φ of the analytic dipole potential (docs/geometry.md#field)."""
    b, b1, b2, b3 = _dipole_profile(params, z)
    c = params[_DIPOLE_K] / (params[_DIPOLE_L] * params[_DIPOLE_L])
    bx = c * b * 2.0 * x * y
    by = b - 0.5 * b2 * y * y + c * b * (x * x - y * y)
    bz = b1 * y - b3 * y * y * y / 6.0 + c * b1 * (x * x * y - y * y * y / 3.0)
    return bx, by, bz


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def map_cell_z(params, grid, z):
    """The z part of the map's trilinear interpolation at z [mm]: (z finite, cell index iz,
    fraction uz), shared by every lookup at that z (`map_at_cell_z`)."""
    ok = math.isfinite(z)
    fz = (z - params[_MAP_Z0]) / params[_MAP_DZ] if ok else 0.0
    nz = grid.shape[2]
    fz = min(max(fz, 0.0), nz - 1.0)
    iz = min(int(fz), nz - 2)
    return ok, iz, fz - iz


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def map_cell_xy(params, grid, x, y, good):
    """The x, y part of the map's trilinear interpolation at (x, y) [mm]: (cell indices ix,
    iy, fractions ux, uy, whether x and y lie inside the grid — not clamped to its edge); for
    `good` False the first cell (never an out-of-range read)."""
    rx = (x - params[_MAP_X0]) / params[_MAP_DX] if good else 0.0
    ry = (y - params[_MAP_Y0]) / params[_MAP_DY] if good else 0.0
    nx = grid.shape[0]
    ny = grid.shape[1]
    fx = min(max(rx, 0.0), nx - 1.0)
    fy = min(max(ry, 0.0), ny - 1.0)
    ix = min(int(fx), nx - 2)
    iy = min(int(fy), ny - 2)
    return ix, iy, fx - ix, fy - iy, fx == rx, fy == ry


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def map_at_cell_z(params, grid, x, y, z_ok, iz, uz):
    """Trilinear interpolation of the sampled field at (x, y) [mm] and the z cell of
    `map_cell_z`; outside the grid the edge value; NaN for a non-finite position (the
    grid is then read at the first cell: never an out-of-range read). Without branches,
    so that a loop over several positions has none."""
    good = math.isfinite(x) and math.isfinite(y) and z_ok
    ix, iy, ux, uy, _, _ = map_cell_xy(params, grid, x, y, good)
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    for cx in range(2):
        wx = ux if cx == 1 else 1.0 - ux
        for cy in range(2):
            wy = uy if cy == 1 else 1.0 - uy
            for cz in range(2):
                w = wx * wy * (uz if cz == 1 else 1.0 - uz)
                out0 += w * grid[ix + cx, iy + cy, iz + cz, 0]
                out1 += w * grid[ix + cx, iy + cy, iz + cz, 1]
                out2 += w * grid[ix + cx, iy + cy, iz + cz, 2]
    nan = math.nan
    return (out0 if good else nan), (out1 if good else nan), (out2 if good else nan)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def map_field_and_gradient(params, grid, x, y, z):
    """`_map_at` and its exact x and y derivatives (of the trilinear interpolation) from the same
    8 grid points: (bx, by, bz, ∂bx/∂x, ∂by/∂x, ∂bz/∂x, ∂bx/∂y, ∂by/∂y, ∂bz/∂y) [T, T/mm];
    0 derivative across an edge of the grid (the edge value is held there)."""
    z_ok, iz, uz = map_cell_z(params, grid, z)
    good = math.isfinite(x) and math.isfinite(y) and z_ok
    ix, iy, ux, uy, inside_x, inside_y = map_cell_xy(params, grid, x, y, good)
    sx = 1.0 / params[_MAP_DX] if inside_x else 0.0
    sy = 1.0 / params[_MAP_DY] if inside_y else 0.0
    b0 = b1 = b2 = 0.0
    gx0 = gx1 = gx2 = 0.0
    gy0 = gy1 = gy2 = 0.0
    for cx in range(2):
        wx = ux if cx == 1 else 1.0 - ux
        dx = sx if cx == 1 else -sx
        for cy in range(2):
            wy = uy if cy == 1 else 1.0 - uy
            dy = sy if cy == 1 else -sy
            for cz in range(2):
                wz = uz if cz == 1 else 1.0 - uz
                v0 = grid[ix + cx, iy + cy, iz + cz, 0]
                v1 = grid[ix + cx, iy + cy, iz + cz, 1]
                v2 = grid[ix + cx, iy + cy, iz + cz, 2]
                w = wx * wy * wz
                wgx = dx * wy * wz
                wgy = wx * dy * wz
                b0 += w * v0
                b1 += w * v1
                b2 += w * v2
                gx0 += wgx * v0
                gx1 += wgx * v1
                gx2 += wgx * v2
                gy0 += wgy * v0
                gy1 += wgy * v1
                gy2 += wgy * v2
    if not good:
        nan = math.nan
        return nan, nan, nan, nan, nan, nan, nan, nan, nan
    return b0, b1, b2, gx0, gx1, gx2, gy0, gy1, gy2


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _map_at(params, grid, x, y, z):
    """Trilinear interpolation of the sampled field; outside the grid the edge value;
    NaN for a non-finite position (never an out-of-range memory read)."""
    z_ok, iz, uz = map_cell_z(params, grid, z)
    return map_at_cell_z(params, grid, x, y, z_ok, iz, uz)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def field_at(kind, params, grid, x, y, z):
    """Field (bx, by, bz) [T] at (x, y, z) [mm] for any model kind. Inlined with the map's
    interpolation into its callers (the RK4 stages): as separate functions, the call and
    its returned tuple were a third of the field's time in the GSF (perf, lhcb-like
    electrons)."""
    if kind == FIELD_DIPOLE:
        return _dipole_at(params, x, y, z)
    if kind == FIELD_MAP:
        return _map_at(params, grid, x, y, z)
    return params[0], params[1], params[2]


@nb.njit(cache=True)
def _evaluate_many(kind, params, grid, x, y, z):
    out = np.empty((x.size, 3))
    for i in range(x.size):
        bx, by, bz = field_at(kind, params, grid, x[i], y[i], z[i])
        out[i, 0] = bx
        out[i, 1] = by
        out[i, 2] = bz
    return out


def default_cache_dir() -> Path:
    """Where field maps are cached: $PKF_CACHE_DIR, else $XDG_CACHE_HOME/pkf, else ~/.cache/pkf."""
    if os.environ.get("PKF_CACHE_DIR"):
        return Path(os.environ["PKF_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or (Path.home() / ".cache")
    return Path(base) / "pkf"


def build_field_map(
    model: FieldModel,
    spacing: float = 100.0,
    x_range: tuple[float, float] = (-4000.0, 4000.0),
    y_range: tuple[float, float] = (-4000.0, 4000.0),
    z_range: tuple[float, float] = (-500.0, 14000.0),
    cache_dir: Path | None = None,
) -> FieldModel:
    """Sample `model` on a regular grid (spacing [mm]) for trilinear interpolation.

    The map is built once per (model, grid) and cached on disk as ``.npy`` under
    `cache_dir` (default `default_cache_dir()`); a cached map is reused when present.
    Outside the grid the map returns the value of the nearest grid edge.
    """
    axes = [np.arange(lo, hi + 0.5 * spacing, spacing) for lo, hi in (x_range, y_range, z_range)]
    description = ("map", model.description, spacing, tuple(x_range), tuple(y_range), tuple(z_range))
    params = np.array(
        [axes[0][0], axes[1][0], axes[2][0], spacing, spacing, spacing, *(len(a) for a in axes)],
        dtype=np.float64,
    )
    key = hashlib.sha256(repr(description).encode()).hexdigest()[:16]
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = cache / f"fieldmap-{key}.npy"
    grid = None
    if path.exists():
        try:
            grid = np.load(path)
        except (OSError, ValueError):
            grid = None
        if grid is not None and grid.shape != tuple(len(a) for a in axes) + (3,):
            grid = None
    if grid is None:
        gx, gy, gz = np.meshgrid(*axes, indexing="ij")
        grid = model.evaluate(gx.ravel(), gy.ravel(), gz.ravel()).reshape(gx.shape + (3,))
        try:
            cache.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp.npy")
            np.save(tmp, grid)
            os.replace(tmp, path)
        except OSError:
            pass  # an unwritable cache only costs the rebuild next time
    return FieldModel(FIELD_MAP, params, np.ascontiguousarray(grid), description=description)
