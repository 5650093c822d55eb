"""Reading a dataset for a stage: its geometry, validated tables and MC truth aligned to hits."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow as pa

from pkf.errors import InputError
from pkf.geometry.detector import (
    BUILTIN_GEOMETRIES,
    KIND_PIXEL,
    SIDE_LEFT,
    SIDE_RIGHT,
    Geometry,
    load_geometry,
    parse_geometry,
)
from pkf.io.reader import Dataset, LayerArea, check_dataset_dir, open_dataset, pair_keys, read_meta
from pkf.io.schemas import particle_key
from pkf.pipeline.batch_kernels import equal, hit_keys

STATE_NAMES = ("x", "y", "tx", "ty", "qop")


def load_dataset(path: str | Path, geometry: str | None = None) -> tuple[Geometry, Dataset]:
    """The geometry of the dataset at `path` and its validated tables (InputError if bad).

    geometry: ``--geometry`` NAME|FILE.toml, if given (see :func:`resolve_geometry`).
    """
    path = check_dataset_dir(path)
    meta = read_meta(path, required=False)
    found = resolve_geometry(path, meta, geometry)
    return found, open_dataset(path, **hit_layer_checks(found), meta=meta or {})


def option_geometry(option: str) -> Geometry:
    """The geometry of ``--geometry NAME|FILE.toml`` (InputError naming the option if bad)."""
    try:
        return load_geometry(option)
    except InputError as exc:
        raise InputError(f"--geometry: {exc}") from None


def resolve_geometry(path: Path, meta: dict | None, option: str | None) -> Geometry:
    """The geometry of the dataset at ``path`` with record ``meta`` (None: no meta.json).

    ``option`` (``--geometry NAME|FILE.toml``) is used when given; meta.json's ``geometry``
    (a name or pkf's record) then must agree with it (same content hash; when meta.json
    gives only a name that is not built in and has no copy, the same name). Without the
    option, the geometry meta.json records (:func:`dataset_geometry`).

    Raises:
        InputError: no meta.json and no option; meta.json and the option disagree.
    """
    if option is None:
        if meta is None:
            raise InputError(f"{path}: no meta.json to say which detector the hits come from: give "
                             f"--geometry NAME|FILE.toml (built in: {', '.join(BUILTIN_GEOMETRIES)})")
        return dataset_geometry(path, meta)
    given = option_geometry(option)
    if meta is not None and "geometry" in meta:
        _check_agrees(path, meta, given, option)
    return given


def _check_agrees(path: Path, meta: dict, given: Geometry, option: str) -> None:
    """InputError if meta.json's geometry is not the one of ``--geometry``."""
    info = _geometry_info(path, meta)
    if (path / str(info.get("file", "geometry.toml"))).is_file() or info.get("name") in BUILTIN_GEOMETRIES:
        recorded = dataset_geometry(path, meta)
        same, what = recorded.content_hash == given.content_hash, f"{recorded.name!r} (hash {recorded.content_hash})"
    elif "hash" in info:
        same, what = info["hash"] == given.content_hash, f"{info.get('name', '?')!r} (hash {info['hash']})"
    else:
        same, what = info.get("name") == given.name, f"{info.get('name')!r}"
    if not same:
        raise InputError(f"{path / 'meta.json'}: geometry {what} disagrees with --geometry {option} "
                         f"({given.name!r}, hash {given.content_hash}): give the geometry the data was made with")


def _geometry_info(path: Path, meta: dict) -> dict:
    """meta.json's ``geometry`` as a dict (a plain name becomes ``{"name": ...}``)."""
    info = meta.get("geometry", {})
    if isinstance(info, str):  # a plain name (docs/formats.md: datasets from other producers)
        info = {"name": info}
    if not isinstance(info, dict):
        raise InputError(f"{path / 'meta.json'}: key 'geometry' must be a name or an object, not {info!r}")
    return info


def hit_layer_checks(geometry: Geometry) -> dict:
    """What the readers check hits against (keyword arguments of
    :func:`pkf.io.reader.validate_hit_layers`): the layers' z and kind and their areas."""
    return {"layer_z": geometry.layer_z, "layer_kind": geometry.layer_kind, "area": layer_area(geometry)}


def layer_area(geometry: Geometry) -> LayerArea:
    """Bounds of the measured coordinates on each layer's active area [mm] (docs/geometry.md).

    Pixel layers measure (u, v) = (x, y): x within ±half_x, cut to the side a VELO-like
    module covers (left: x ≤ +overlap, right: x ≥ −overlap), y within ±half_y, outside
    the beam hole. Strip layers measure u = x·cos α + y·sin α: its extremes over the
    rectangle of x and y ranges (the strip's unmeasured coordinate may lie anywhere on it).
    """
    planes = geometry.planes
    index = geometry.layer_plane
    half_x, half_y = planes.half_x[index], planes.half_y[index]
    side, overlap = planes.side[index], planes.side_overlap[index]
    x_lo = np.where(side == SIDE_RIGHT, np.maximum(-half_x, -overlap), -half_x)
    x_hi = np.where(side == SIDE_LEFT, np.minimum(half_x, overlap), half_x)
    cos, sin = geometry.layer_cos, geometry.layer_sin
    corners = np.stack([x * cos + y * sin for x in (x_lo, x_hi) for y in (-half_y, half_y)])
    pixel = geometry.layer_kind == KIND_PIXEL
    zero = np.zeros(geometry.n_layers)
    return LayerArea(
        u_min=np.where(pixel, x_lo, corners.min(axis=0)),
        u_max=np.where(pixel, x_hi, corners.max(axis=0)),
        v_min=np.where(pixel, -half_y, np.nan),
        v_max=np.where(pixel, half_y, np.nan),
        hole_radius=np.where(pixel, planes.hole_radius[index], zero),
        hole_half_u=np.where(pixel, planes.hole_half_x[index], zero),
        hole_half_v=np.where(pixel, planes.hole_half_y[index], zero),
    )


def dataset_geometry(path: Path, meta: dict) -> Geometry:
    """The geometry a dataset was simulated with: its ``geometry.toml`` copy, else the
    built-in named in meta.json; the content hash must match meta.json."""
    info = _geometry_info(path, meta)
    copy = path / str(info.get("file", "geometry.toml"))
    if copy.is_file():
        geometry = parse_geometry(copy.read_text(), source=str(copy))
    elif info.get("name") in BUILTIN_GEOMETRIES:  # the copy of a built-in may go: the hash checks it
        geometry = load_geometry(info["name"])
    elif "name" in info:
        raise InputError(
            f"{path}: geometry file {copy} not found: meta.json names geometry {info['name']!r}, which is "
            f"not built in ({', '.join(BUILTIN_GEOMETRIES)}); restore the file"
        )
    else:
        raise InputError(f"{path / 'meta.json'}: no geometry recorded (key 'geometry'): give --geometry NAME|FILE.toml")
    if "hash" in info and info["hash"] != geometry.content_hash:
        raise InputError(f"{path}: geometry hash {geometry.content_hash} does not match meta.json ({info['hash']})")
    return geometry


def content_hash(dataset) -> str:
    """16 hex digits of SHA-256 over the bytes of every file of the dataset's tables."""
    return files_content_hash([file for source in dataset.sources.values() for file in getattr(source, "files", [])])


def files_content_hash(files, block: int = 1 << 20) -> str:
    """16 hex digits of SHA-256 over the concatenated bytes of ``files``, read in blocks."""
    digest = hashlib.sha256()
    for file in files:
        with open(file, "rb") as f:
            while chunk := f.read(block):
                digest.update(chunk)
    return digest.hexdigest()[:16]


def column(table: pa.Table, name: str, dtype=np.float64) -> np.ndarray:
    """Column ``name`` of ``table`` as a new, writable numpy array of ``dtype``: one copy (a column
    of several chunks, or with nulls, is already one when pyarrow converts it)."""
    values = table.column(name).to_numpy(zero_copy_only=False)
    if values.dtype == dtype and values.flags.writeable:
        return values  # pyarrow's zero-copy views are read-only: this one is new
    return values.astype(dtype)


def _mc_rows(mc: pa.Table, event_id: np.ndarray, hit_id: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(rows, found): the mc_hits row of each hit row (event_id, hit_id) and whether it has one;
    None where the mc_hits are row by row as the hits (pkf simulate writes them so: no search;
    1,000 minimum-bias events at ν = 7.6, 0.35 s of CPU)."""
    mc_event = mc.column("event_id").to_numpy(zero_copy_only=False)
    mc_hit = mc.column("hit_id").to_numpy(zero_copy_only=False)
    if equal(mc_event, event_id) and equal(mc_hit, hit_id):
        return None
    mc_key, hit_key = pair_keys(mc_event.astype(np.int64), mc_hit.astype(np.int64), event_id, hit_id.astype(np.int64))
    order = np.argsort(mc_key, kind="stable")
    pos = np.minimum(np.searchsorted(mc_key[order], hit_key), max(mc_key.size - 1, 0))
    rows = order[pos]
    return rows, mc_key[rows] == hit_key


def align_mc(dataset, event_id: np.ndarray):
    """Per hit row: its MC particle (0 for noise or no MC record) and the true state
    (x, y, tx, ty, q/p) of its mc_hit (NaN for noise), shape (n_hits, 5)."""
    mc = dataset.mc_hits

    def values(table, name):  # read-only where pyarrow gives a view: nothing here writes to them
        return table.column(name).to_numpy(zero_copy_only=False)

    hit_id = values(dataset.hits, "hit_id")
    match = _mc_rows(mc, event_id, hit_id)
    rows, found = (slice(None), np.ones(hit_id.size, dtype=bool)) if match is None else match
    truth = np.empty((hit_id.size, len(STATE_NAMES)))
    for i, name in enumerate(STATE_NAMES):
        truth[:, i] = values(mc, name)[rows]
    truth[~found] = np.nan
    return np.where(found, values(mc, "particle_id")[rows].astype(np.int64, copy=False), 0), truth


class HitTruth:
    """The true state (x, y, tx, ty, q/p) of the mc_hit of each hit row of a batch, gathered only
    for the rows asked for (:meth:`take`): the pulls need it at two nodes per matched track, and
    converting the five columns for every hit (as :func:`align_mc` does) cost 0.17 s of CPU per
    1,000 minimum-bias events. rows/found: the mc_hits row of each hit row and whether it has one
    (None: mc_hits row by row as the hits)."""

    def __init__(self, mc: pa.Table, rows: np.ndarray | None = None, found: np.ndarray | None = None):
        self.mc, self.rows, self.found = mc, rows, found
        self.columns = None

    def take(self, hit_rows: np.ndarray) -> np.ndarray:
        """(len(hit_rows), 5): the truth of those hit rows, NaN for noise (as :func:`align_mc`'s)."""
        if self.columns is None:  # views where pyarrow gives them (nulls: a copy with NaN), read only
            self.columns = [self.mc.column(name).to_numpy(zero_copy_only=False) for name in STATE_NAMES]
        rows = hit_rows if self.rows is None else self.rows[hit_rows]
        out = np.empty((rows.size, len(STATE_NAMES)))
        for i, values in enumerate(self.columns):
            out[:, i] = values[rows]
        if self.found is not None:
            out[~self.found[hit_rows]] = np.nan
        return out


class MCHits(NamedTuple):
    """MC truth aligned to a batch's hit rows (:func:`mc_alignment`): ``key``, the particle key
    (`pkf.io.schemas.particle_key`, 0 for noise) of each hit row, ``truth`` its mc_hit's state
    (:class:`HitTruth`), ``particle_id`` the per-row particle ids (0 for noise or no MC record;
    a read-only view where pyarrow gives one)."""

    key: np.ndarray
    truth: HitTruth
    particle_id: np.ndarray


def mc_alignment(dataset, event_id: np.ndarray, hit_id: np.ndarray) -> MCHits:
    """:func:`align_mc` for a batch of `pkf reconstruct`: the same particle per hit row, as keys
    (`batch_kernels.hit_keys`, one pass), and the truth gathered on demand (:class:`HitTruth`).
    event_id (int64), hit_id: per hit row."""
    mc = dataset.mc_hits

    def values(name):  # read-only where pyarrow gives a view: nothing here writes to them
        return mc.column(name).to_numpy(zero_copy_only=False)

    particle = values("particle_id")
    match = _mc_rows(mc, event_id, hit_id)
    if match is None:
        truth = HitTruth(mc)
    else:
        rows, found = match
        particle = np.where(found, particle[rows].astype(np.int64, copy=False), 0)
        truth = HitTruth(mc, rows, found)
    key = np.empty(event_id.size, np.int64)
    hit_keys(event_id, particle, key)
    return MCHits(key, truth, particle)


def production_truth(dataset) -> dict:
    """Per particle key: production q/p [1/MeV] and vertex/momentum for beamline truth."""
    p = dataset.particles
    if p is None:
        return {}

    def values(name, dtype=np.float64):  # read-only views where pyarrow gives them: only read, and gathered below
        return p.column(name).to_numpy(zero_copy_only=False).astype(dtype, copy=False)

    key = particle_key(values("event_id", np.int64), values("particle_id", np.int64))
    px, py, pz = values("px"), values("py"), values("pz")
    mom = np.sqrt(px**2 + py**2 + pz**2)
    charge = values("charge")
    order = np.argsort(key)
    return {"key": key[order], "qop": (charge / mom)[order], "p": mom[order],
            "pdg": values("pdg", np.int64)[order],
            "vx": values("vx")[order], "vy": values("vy")[order], "vz": values("vz")[order],
            "tx": np.divide(px, pz, out=np.full_like(px, np.nan), where=pz != 0)[order],
            "ty": np.divide(py, pz, out=np.full_like(py, np.nan), where=pz != 0)[order]}
