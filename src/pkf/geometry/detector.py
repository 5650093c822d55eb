"""Detector description: layers, passive planes, field and step types from a TOML file.

A geometry file (docs/geometry.md, built-ins in ``pkf/geometry/data``) holds groups of layers
(``[[layers]]``, one layer per z value of the group), passive material planes
(``[[passive]]``), the field model (``[field]``), optionally the field-map grid
(``[field_map]``), the transport envelope (``[envelope]``) and the parametrized
extrapolation type of each step between subdetectors (``[[steps]]``, docs/physics.md#the-parametrized-fitter).
Units: mm, tesla, degrees for ``stereo_deg`` only.
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path

import numpy as np

from pkf.errors import InputError
from pkf.geometry.field import FieldModel, build_field_map, dipole_field, uniform_field

BUILTIN_GEOMETRIES = ("lhcb-like", "telescope")

KIND_PIXEL = 0
KIND_STRIP = 1
KIND_NAMES = {"pixel": KIND_PIXEL, "strip": KIND_STRIP}

SIDE_BOTH = 0
SIDE_LEFT = 1  # covers x <= +side_overlap
SIDE_RIGHT = 2  # covers x >= -side_overlap

SUBDETECTORS = ("velo", "ut", "scifi")
STEP_TYPES = ("velo", "velo_to_ut", "ut", "ut_to_scifi", "scifi")

_LAYER_KEYS = {
    "subdetector", "kind", "z", "stereo_deg", "station", "sigma", "x_over_x0", "half_x",
    "half_y", "hole_radius", "hole_half_x", "hole_half_y", "side", "side_overlap",
    "efficiency", "noise_hits",
}
_PASSIVE_KEYS = {"name", "z", "x_over_x0", "half_x", "half_y"}
_TOP_KEYS = {"name", "description", "field", "field_map", "envelope", "layers", "passive", "steps"}


@dataclass(frozen=True)
class Envelope:
    """Where transport stops (docs/physics.md#simulation): |x| or |y| > half_width [mm], |tx| or |ty| >
    max_slope, or p < min_momentum [MeV]."""

    half_width: float = 4000.0
    max_slope: float = 10.0
    min_momentum: float = 100.0


@dataclass(frozen=True)
class Planes:
    """Every material plane (active layers and passive planes) sorted by z, as arrays
    that compiled kernels take. ``layer`` is the active-layer index or −1 if passive."""

    z: np.ndarray
    layer: np.ndarray
    x_over_x0: np.ndarray
    half_x: np.ndarray
    half_y: np.ndarray
    hole_radius: np.ndarray
    hole_half_x: np.ndarray
    hole_half_y: np.ndarray
    side: np.ndarray
    side_overlap: np.ndarray


class Geometry:
    """A loaded, validated detector geometry.

    Attributes (per active layer, sorted by z; index = the ``layer`` column of hits):
    ``layer_z`` [mm], ``layer_kind`` (0 pixel, 1 strip), ``layer_stereo`` [rad],
    ``layer_cos``/``layer_sin`` of the stereo angle, ``layer_sigma`` [mm],
    ``layer_x_over_x0``, ``layer_subdetector`` (index into ``SUBDETECTORS``),
    ``layer_station`` (0 where not given), ``layer_efficiency``, ``layer_noise_hits``.
    """

    def __init__(self, config: dict, text: str, source: str):
        self.config = config
        self.text = text
        self.source = source
        self.name = str(config["name"])
        self.description = str(config.get("description", ""))
        self._build_layers(config)
        self._build_passive(config)
        self.envelope = Envelope(**config.get("envelope", {}))
        self.steps = {
            (s["from"], s["to"]): s["type"] for s in config.get("steps", [])
        }

    # -- construction ---------------------------------------------------------
    def _build_layers(self, config: dict) -> None:
        rows = []
        for group in config["layers"]:
            zs = group["z"]
            n = len(zs)

            def per_layer(key, default, group=group, n=n):
                value = group.get(key, default)
                if isinstance(value, list):
                    if len(value) != n:
                        raise InputError(
                            f"{self.source}: layers.{key}: has {len(value)} values for {n} z values"
                        )
                    return value
                return [value] * n

            sides = _expand_sides(group.get("side", "both"), n, self.source)
            for i, (z, stereo, station) in enumerate(
                zip(zs, per_layer("stereo_deg", 0.0), per_layer("station", 0))
            ):
                rows.append(
                    dict(
                        z=float(z),
                        kind=KIND_NAMES[group["kind"]],
                        stereo=math.radians(float(stereo)),
                        station=int(station),
                        subdetector=SUBDETECTORS.index(group["subdetector"]),
                        sigma=float(group["sigma"]),
                        x_over_x0=float(group["x_over_x0"]),
                        half_x=float(group["half_x"]),
                        half_y=float(group["half_y"]),
                        hole_radius=float(group.get("hole_radius", 0.0)),
                        hole_half_x=float(group.get("hole_half_x", 0.0)),
                        hole_half_y=float(group.get("hole_half_y", 0.0)),
                        side=sides[i],
                        side_overlap=float(group.get("side_overlap", 0.0)),
                        efficiency=float(group.get("efficiency", 1.0)),
                        noise_hits=float(group.get("noise_hits", 0.0)),
                    )
                )
        rows.sort(key=lambda r: r["z"])
        zs = [r["z"] for r in rows]
        if len(set(zs)) != len(zs):
            raise InputError(f"{self.source}: layers: two layers at the same z")
        col = lambda key, dtype: np.array([r[key] for r in rows], dtype=dtype)  # noqa: E731
        self.layer_z = col("z", np.float64)
        self.layer_kind = col("kind", np.int64)
        self.layer_stereo = col("stereo", np.float64)
        self.layer_cos = np.cos(self.layer_stereo)
        self.layer_sin = np.sin(self.layer_stereo)
        self.layer_station = col("station", np.int64)
        self.layer_subdetector = col("subdetector", np.int64)
        self.layer_sigma = col("sigma", np.float64)
        self.layer_x_over_x0 = col("x_over_x0", np.float64)
        self.layer_efficiency = col("efficiency", np.float64)
        self.layer_noise_hits = col("noise_hits", np.float64)
        self._layer_rows = rows

    def _build_passive(self, config: dict) -> None:
        self.passive = sorted(
            (
                dict(
                    name=str(p.get("name", "")),
                    z=float(p["z"]),
                    x_over_x0=float(p["x_over_x0"]),
                    half_x=float(p.get("half_x", 1e9)),
                    half_y=float(p.get("half_y", 1e9)),
                )
                for p in config.get("passive", [])
            ),
            key=lambda p: p["z"],
        )

    # -- derived views ----------------------------------------------------------
    @property
    def n_layers(self) -> int:
        return self.layer_z.size

    @cached_property
    def content_hash(self) -> str:
        """SHA-256 (first 16 hex digits) of the parsed content; comments do not count."""
        canonical = json.dumps(self.config, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()[:16]

    @cached_property
    def planes(self) -> Planes:
        """Active layers and passive planes merged and sorted by z."""
        entries = [
            (r["z"], i, r["x_over_x0"], r["half_x"], r["half_y"], r["hole_radius"],
             r["hole_half_x"], r["hole_half_y"], r["side"], r["side_overlap"])
            for i, r in enumerate(self._layer_rows)
        ]
        entries += [
            (p["z"], -1, p["x_over_x0"], p["half_x"], p["half_y"], 0.0, 0.0, 0.0, SIDE_BOTH, 0.0)
            for p in self.passive
        ]
        entries.sort(key=lambda e: e[0])
        cols = list(zip(*entries))
        f8 = lambda c: np.array(c, dtype=np.float64)  # noqa: E731
        i8 = lambda c: np.array(c, dtype=np.int64)  # noqa: E731
        return Planes(
            z=f8(cols[0]), layer=i8(cols[1]), x_over_x0=f8(cols[2]), half_x=f8(cols[3]),
            half_y=f8(cols[4]), hole_radius=f8(cols[5]), hole_half_x=f8(cols[6]),
            hole_half_y=f8(cols[7]), side=i8(cols[8]), side_overlap=f8(cols[9]),
        )

    @cached_property
    def layer_plane(self) -> np.ndarray:
        """(n_layers,) int64: the row in `planes` of each active layer."""
        planes = self.planes
        active = planes.layer >= 0
        index = np.empty(self.n_layers, dtype=np.int64)
        index[planes.layer[active]] = np.flatnonzero(active)
        return index

    @cached_property
    def field(self) -> FieldModel:
        """The analytic field model (what the simulation uses)."""
        spec = dict(self.config["field"])
        model = spec.pop("model")
        if model == "dipole":
            return dipole_field(**spec)
        return uniform_field(**spec)

    def reconstruction_field(self, cache_dir: Path | None = None) -> FieldModel:
        """The field reconstruction uses: the tabulated map if ``[field_map]`` is given
        (built once and cached on disk), else the analytic model. The map is loaded once per
        geometry and cache directory: `pkf reconstruct` asks for it three times (the pattern's
        and the fit's extrapolators, the beamline), and each load of its 23 MB is new memory,
        which this VM backs with huge pages at up to 0.5 s of system CPU (measured)."""
        spec = self.config.get("field_map")
        if spec is None:
            return self.field
        loaded = self.__dict__.setdefault("_reconstruction_fields", {})
        if cache_dir not in loaded:
            loaded[cache_dir] = build_field_map(
                self.field,
                spacing=float(spec["spacing"]),
                x_range=tuple(spec["x_range"]),
                y_range=tuple(spec["y_range"]),
                z_range=tuple(spec["z_range"]),
                cache_dir=cache_dir,
            )
        return loaded[cache_dir]

    def subdetector_layers(self, name: str) -> np.ndarray:
        """Indices of the active layers of subdetector `name`."""
        return np.flatnonzero(self.layer_subdetector == SUBDETECTORS.index(name))

    def __repr__(self) -> str:
        return f"Geometry({self.name!r}, {self.n_layers} layers, hash={self.content_hash})"


def _expand_sides(value, n: int, source: str) -> list[int]:
    names = {"both": SIDE_BOTH, "left": SIDE_LEFT, "right": SIDE_RIGHT}
    if isinstance(value, list):
        if len(value) != n or any(v not in names for v in value):
            raise InputError(f"{source}: layers.side: need {n} values of {sorted(names)}")
        return [names[v] for v in value]
    if value in ("alternate-left", "alternate-right"):
        first, second = (SIDE_LEFT, SIDE_RIGHT) if value == "alternate-left" else (SIDE_RIGHT, SIDE_LEFT)
        return [first if i % 2 == 0 else second for i in range(n)]
    if value in names:
        return [names[value]] * n
    raise InputError(f"{source}: layers.side: unknown value {value!r}")


# Value types of every key of a geometry file, checked before any value is used:
# "number" (int or float, not bool, finite), "int", "string", "numbers" (a non-empty list of
# numbers), "range" (two numbers, low < high), and "X or Xs" (one value, or one per z value).
_TOP_TYPES = {"name": "string", "description": "string"}
_FIELD_TYPES = {"model": "string", "b0": "number", "z1": "number", "z2": "number", "edge_length": "number",
                "k": "number", "length_scale": "number", "bx": "number", "by": "number", "bz": "number"}
_FIELD_MAP_TYPES = {"spacing": "number", "x_range": "range", "y_range": "range", "z_range": "range"}
_ENVELOPE_TYPES = {"half_width": "number", "max_slope": "number", "min_momentum": "number"}
_LAYER_TYPES = {
    "subdetector": "string", "kind": "string", "z": "numbers", "stereo_deg": "number or numbers",
    "station": "int or ints", "sigma": "number", "x_over_x0": "number", "half_x": "number",
    "half_y": "number", "hole_radius": "number", "hole_half_x": "number", "hole_half_y": "number",
    "side": "string or strings", "side_overlap": "number", "efficiency": "number", "noise_hits": "number",
}
_PASSIVE_TYPES = {"name": "string", "z": "number", "x_over_x0": "number", "half_x": "number", "half_y": "number"}
_STEP_TYPES_OF_KEYS = {"from": "string", "to": "string", "type": "string"}
_TABLE_KEYS = {"field": dict, "field_map": dict, "envelope": dict, "layers": list, "passive": list, "steps": list}


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _type_error(value, expected: str) -> str | None:
    """Why ``value`` is not of the geometry-file type ``expected`` (None if it is)."""
    single = {"number": _is_number, "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
              "string": lambda v: isinstance(v, str)}
    if " or " in expected:  # one value, or a list of them (one per z value)
        one, _ = expected.split(" or ")
        if isinstance(value, list):
            bad = [i for i, v in enumerate(value) if not single[one](v)]
            return None if not bad else f"element {bad[0]} is {value[bad[0]]!r}, expected {_ARTICLE[one]}"
        return None if single[one](value) else f"is {value!r}, expected {_ARTICLE[one]} or a list of them"
    if expected == "numbers":
        if not isinstance(value, list) or not value:
            return f"is {value!r}, expected a non-empty list of finite numbers"
        bad = [i for i, v in enumerate(value) if not _is_number(v)]
        return None if not bad else f"element {bad[0]} is {value[bad[0]]!r}, expected a finite number"
    if expected == "range":
        if not (isinstance(value, list) and len(value) == 2 and all(_is_number(v) for v in value)
                and value[0] < value[1]):
            return f"is {value!r}, expected [low, high]: two finite numbers, low < high"
        return None
    return None if single[expected](value) else f"is {value!r}, expected {_ARTICLE[expected]}"


_ARTICLE = {"number": "a finite number", "int": "an integer", "string": "a string"}


def _check_types(table: dict, types: dict, where: str, fail, about: str = "") -> None:
    """Fail for the first key of ``table`` whose value is not of its type in ``types``."""
    for key, value in table.items():
        if key in types:
            problem = _type_error(value, types[key])
            if problem:
                fail(f"{where}{key}{about}: {problem}")


def _layer_about(group: dict) -> str:
    """How messages name the layers of a [[layers]] group: subdetector and z values."""
    what = [f"subdetector {group['subdetector']!r}"] if isinstance(group.get("subdetector"), str) else []
    z = group.get("z")
    if isinstance(z, list) and z and _is_number(z[0]):
        what.append(f"z = {z[0]!r}" + (f" … {z[-1]!r}" if len(z) > 1 and _is_number(z[-1]) else ""))
    return f" (layers of {', '.join(what)})" if what else ""


def _validate_types(config: dict, fail) -> None:
    """Fail (one line naming the key, and the layer group) for the first value of the wrong type."""
    _check_types(config, _TOP_TYPES, "", fail)
    for key, kind in _TABLE_KEYS.items():
        if key in config and not isinstance(config[key], kind):
            shape = "a table [" + key + "]" if kind is dict else "an array of tables [[" + key + "]]"
            fail(f"{key}: expected {shape}, found {type(config[key]).__name__}")
    _check_types(config.get("field", {}), _FIELD_TYPES, "field.", fail)
    _check_types(config.get("field_map", {}), _FIELD_MAP_TYPES, "field_map.", fail)
    _check_types(config.get("envelope", {}), _ENVELOPE_TYPES, "envelope.", fail)
    for name, types in (("layers", _LAYER_TYPES), ("passive", _PASSIVE_TYPES), ("steps", _STEP_TYPES_OF_KEYS)):
        for i, entry in enumerate(config.get(name, [])):
            if not isinstance(entry, dict):
                fail(f"{name}[{i}]: expected a table, found {type(entry).__name__}")
            about = _layer_about(entry) if name == "layers" else ""
            _check_types(entry, types, f"{name}[{i}].", fail, about)


def _validate(config: dict, source: str) -> None:
    """Raise InputError (one line) for the first thing wrong in a parsed geometry:
    unknown or missing keys, values of the wrong type (every key has one, see
    ``_LAYER_TYPES`` etc.; numbers must be finite), then values out of range."""

    def fail(msg: str):
        raise InputError(f"{source}: {msg}")

    unknown = set(config) - _TOP_KEYS
    if unknown:
        fail(f"unknown key {sorted(unknown)[0]!r}")
    for key in ("name", "field", "layers"):
        if key not in config:
            fail(f"missing key {key!r}")
    _validate_types(config, fail)
    field = config["field"]
    if field.get("model") not in ("dipole", "uniform"):
        fail(f"field.model must be 'dipole' or 'uniform', not {field.get('model')!r}")
    allowed = {"dipole": {"b0", "z1", "z2", "edge_length", "k", "length_scale"}, "uniform": {"bx", "by", "bz"}}
    extra = set(field) - {"model"} - allowed[field["model"]]
    if extra:
        fail(f"field: unknown key {sorted(extra)[0]!r}")
    if "field_map" in config:
        fm = config["field_map"]
        for key in ("spacing", "x_range", "y_range", "z_range"):
            if key not in fm:
                fail(f"field_map: missing key {key!r}")
        if not fm["spacing"] > 0:
            fail("field_map.spacing must be > 0")
    if not isinstance(config["layers"], list) or not config["layers"]:
        fail("layers: need at least one [[layers]] group")
    for gi, group in enumerate(config["layers"]):
        where = f"layers[{gi}]"
        extra = set(group) - _LAYER_KEYS
        if extra:
            fail(f"{where}: unknown key {sorted(extra)[0]!r}")
        for key in ("subdetector", "kind", "z", "sigma", "x_over_x0", "half_x", "half_y"):
            if key not in group:
                fail(f"{where}: missing key {key!r}")
        if group["subdetector"] not in SUBDETECTORS:
            fail(f"{where}.subdetector: {group['subdetector']!r} is not one of {list(SUBDETECTORS)}")
        if group["kind"] not in KIND_NAMES:
            fail(f"{where}.kind: {group['kind']!r} is not 'pixel' or 'strip'")
        if not isinstance(group["z"], list) or not group["z"]:
            fail(f"{where}.z: need a non-empty list")
        if not all(isinstance(z, (int, float)) and math.isfinite(z) for z in group["z"]):
            fail(f"{where}.z: values must be finite numbers")
        if not group["sigma"] > 0:
            fail(f"{where}.sigma must be > 0")
        if not group["x_over_x0"] >= 0:
            fail(f"{where}.x_over_x0 must be >= 0")
        if not 0.0 <= group.get("efficiency", 1.0) <= 1.0:
            fail(f"{where}.efficiency must be in [0, 1]")
        if not group.get("noise_hits", 0.0) >= 0:
            fail(f"{where}.noise_hits must be >= 0")
        for key in ("half_x", "half_y"):
            if not group[key] > 0:
                fail(f"{where}.{key} must be > 0")
        for key in ("hole_radius", "hole_half_x", "hole_half_y", "side_overlap"):
            if not group.get(key, 0.0) >= 0:
                fail(f"{where}.{key} must be >= 0")
    for pi, plane in enumerate(config.get("passive", [])):
        extra = set(plane) - _PASSIVE_KEYS
        if extra:
            fail(f"passive[{pi}]: unknown key {sorted(extra)[0]!r}")
        for key in ("z", "x_over_x0"):
            if key not in plane:
                fail(f"passive[{pi}]: missing key {key!r}")
        if not plane["x_over_x0"] >= 0:
            fail(f"passive[{pi}].x_over_x0 must be >= 0")
    envelope = config.get("envelope", {})
    extra = set(envelope) - {"half_width", "max_slope", "min_momentum"}
    if extra:
        fail(f"envelope: unknown key {sorted(extra)[0]!r}")
    for key, value in envelope.items():
        if not value > 0:
            fail(f"envelope.{key} must be > 0")
    for si, step in enumerate(config.get("steps", [])):
        if set(step) != {"from", "to", "type"}:
            fail(f"steps[{si}]: need exactly the keys 'from', 'to', 'type'")
        if step["from"] not in SUBDETECTORS or step["to"] not in SUBDETECTORS:
            fail(f"steps[{si}]: from/to must be subdetectors {list(SUBDETECTORS)}")
        if step["type"] not in STEP_TYPES:
            fail(f"steps[{si}].type: {step['type']!r} is not one of {list(STEP_TYPES)}")


def parse_geometry(text: str, source: str = "<string>") -> Geometry:
    """Parse and validate geometry TOML text; errors are one-line InputErrors."""
    try:
        config = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: not valid TOML: {exc}") from None
    _validate(config, source)
    try:
        return Geometry(config, text, source)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{source}: invalid geometry: {exc}") from None


def load_geometry(name_or_path: str | Path) -> Geometry:
    """A built-in geometry by name (``lhcb-like``, ``telescope``) or a TOML file path."""
    name = str(name_or_path)
    if name in BUILTIN_GEOMETRIES:
        text = resources.files("pkf.geometry").joinpath("data", f"{name}.toml").read_text()
        return parse_geometry(text, source=name)
    path = Path(name)
    if not path.is_file():
        raise InputError(
            f"unknown geometry {name!r}: not a built-in ({', '.join(BUILTIN_GEOMETRIES)}) and no such file"
        )
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read geometry: {exc}") from None
    return parse_geometry(text, source=str(path))
