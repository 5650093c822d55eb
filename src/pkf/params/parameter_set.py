"""Parameter sets of the parametrized extrapolator: JSON format, loading, shipped defaults.

A parameter file (``pkf tune`` writes it) holds, for one geometry (checked by its
content hash), the extrapolation and noise parameters of every step slot (slot i: the
step leaving layer i, see `pkf.params.transport`), the UT→SciFi table if the geometry
has such a step, and metadata: geometry and field-map hashes, the tuning sample, the
date, the pkf version and every fit's status.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from pkf.errors import InputError
from pkf.geometry.detector import SUBDETECTORS, Geometry
from pkf.io.atomic import atomic_write_json
from pkf.params.formulas import N_EXTRAPOLATION_PARAMS, N_NOISE_PARAMS
from pkf.params.transport import STEP_CODES, STEP_NONE, STEP_UT_TO_SCIFI, ParametrizedExtrapolator, area_record
from pkf.params.ut_to_scifi import META_SIZE, UTSciFiTable

FORMAT = "pkf-params/1"


@dataclass(frozen=True)
class SlotStructure:
    """Which step leaves each layer (docs/physics.md#the-parametrized-fitter, from the geometry's [[steps]] table)."""

    layer_sub: np.ndarray
    sub_first: np.ndarray
    sub_last: np.ndarray
    within_type: np.ndarray
    between_type: np.ndarray

    def slot_kind(self, slot: int) -> int:
        """The step type whose parameters live in `slot` (STEP_NONE for the last layer)."""
        s = self.layer_sub[slot]
        if slot == self.sub_last[s]:
            return int(self.between_type[s])
        return int(self.within_type[s])


def slot_structure(geometry: Geometry) -> SlotStructure:
    """Derive the subdetector ranges and step types of `geometry`."""
    sub = geometry.layer_subdetector.astype(np.int64)
    n_sub = len(SUBDETECTORS)
    first = np.full(n_sub, -1, dtype=np.int64)
    last = np.full(n_sub, -1, dtype=np.int64)
    for s in range(n_sub):
        idx = np.flatnonzero(sub == s)
        if idx.size:
            if np.any(np.diff(idx) != 1):
                raise InputError(f"{geometry.source}: the layers of subdetector {SUBDETECTORS[s]!r} are not contiguous in z")
            first[s], last[s] = idx[0], idx[-1]
    within = np.full(n_sub, STEP_NONE, dtype=np.int64)
    between = np.full(n_sub, STEP_NONE, dtype=np.int64)
    present = [s for s in np.argsort(np.where(first >= 0, first, 10**9)) if first[s] >= 0]
    for i, s in enumerate(present):
        name = SUBDETECTORS[s]
        if (name, name) in geometry.steps:
            within[s] = STEP_CODES[geometry.steps[(name, name)]]
        elif last[s] > first[s]:
            raise InputError(f"{geometry.source}: no [[steps]] entry from {name!r} to {name!r}")
        if i + 1 < len(present):
            nxt = SUBDETECTORS[present[i + 1]]
            if (name, nxt) not in geometry.steps:
                raise InputError(f"{geometry.source}: no [[steps]] entry from {name!r} to {nxt!r}")
            between[s] = STEP_CODES[geometry.steps[(name, nxt)]]
    return SlotStructure(sub, first, last, within, between)


@dataclass
class ParameterSet:
    """Tuned parameters for one geometry. extrapolation (L, 9), noise (L, 5) per slot."""

    geometry_name: str
    geometry_hash: str
    extrapolation: np.ndarray
    noise: np.ndarray
    ut_to_scifi: UTSciFiTable | None = None
    metadata: dict = field(default_factory=dict)

    def extrapolator(self, geometry: Geometry) -> ParametrizedExtrapolator:
        """The numba context for the Kalman core."""
        self.check_geometry(geometry, source="parameters")
        slots = slot_structure(geometry)
        if self.ut_to_scifi is not None:
            meta, cells = self.ut_to_scifi.as_arrays()
        else:
            meta, cells = np.zeros(META_SIZE), np.zeros((1, 1, 4, 1))
        field = geometry.reconstruction_field() if self.ut_to_scifi is not None else None
        fallback = (int(field.kind), field.params, field.grid) if field is not None else ()
        return ParametrizedExtrapolator(
            geometry.layer_z.astype(np.float64), slots.layer_sub, slots.sub_first, slots.sub_last,
            slots.within_type, slots.between_type, np.ascontiguousarray(self.extrapolation, dtype=np.float64),
            np.ascontiguousarray(self.noise, dtype=np.float64), area_record(geometry), meta, cells, *fallback,
        )

    def check_geometry(self, geometry: Geometry, source: str) -> None:
        _check_geometry_record(self.geometry_name, self.geometry_hash, geometry, source)

    def to_json_dict(self) -> dict:
        return {
            "format": FORMAT,
            "geometry": {"name": self.geometry_name, "hash": self.geometry_hash},
            "metadata": self.metadata,
            "slots": [
                {"slot": i, "extrapolation": [float(v) for v in self.extrapolation[i]],
                 "noise": [float(v) for v in self.noise[i]]}
                for i in range(self.extrapolation.shape[0])
            ],
            "ut_to_scifi": self.ut_to_scifi.to_json_dict() if self.ut_to_scifi is not None else None,
        }

    def save(self, path: str | Path) -> Path:
        return atomic_write_json(self.to_json_dict(), path)

    @classmethod
    def from_json_dict(cls, data: dict, source: str = "<params>") -> ParameterSet:
        try:
            if data.get("format") != FORMAT:
                raise InputError(f"{source}: not a pkf parameter file (format {data.get('format')!r}, expected {FORMAT!r})")
            slots = data["slots"]
            extrapolation = np.zeros((len(slots), N_EXTRAPOLATION_PARAMS))
            noise = np.zeros((len(slots), N_NOISE_PARAMS))
            for i, slot in enumerate(slots):
                extrapolation[i, : len(slot["extrapolation"])] = slot["extrapolation"]
                noise[i, : len(slot["noise"])] = slot["noise"]
            table = data.get("ut_to_scifi")
            return cls(
                geometry_name=data["geometry"]["name"], geometry_hash=data["geometry"]["hash"],
                extrapolation=extrapolation, noise=noise,
                ut_to_scifi=UTSciFiTable.from_json_dict(table) if table else None,
                metadata=dict(data.get("metadata", {})),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError(f"{source}: malformed parameter file ({type(exc).__name__}: {exc})") from None

    @classmethod
    def load(cls, path: str | Path) -> ParameterSet:
        path = Path(path)
        return cls.from_json_dict(_read_parameter_json(path), source=str(path))


def _check_geometry_record(name, content_hash, geometry: Geometry, source: str) -> None:
    if content_hash != geometry.content_hash:
        raise InputError(
            f"{source}: parameters are for geometry {name!r} (hash {content_hash}), "
            f"not for {geometry.name!r} (hash {geometry.content_hash}); run pkf tune for it"
        )


def _read_parameter_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"--params {path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"--params {path}: not a JSON parameter file ({exc})") from None
    if not isinstance(data, dict):
        raise InputError(f"--params {path}: not a JSON parameter file")
    return data


#: Fewest extrapolation coefficients each step type reads (its formula's parameters;
#: docs/parameters.md): velo p0–p1 (paper eq. 10), velo_to_ut p0–p8 (eqs. 15–20), ut/scifi p0–p14 (eq. 14
#: with the slope and field-shape terms; the degree-4 monomials p15–p49 may be absent, as in
#: files tuned before them: absent coefficients are zero), ut_to_scifi p0 (the energy lost
#: before the table step).
MIN_EXTRAPOLATION_PARAMS = {"velo": 2, "velo_to_ut": 9, "ut": 15, "scifi": 15, "ut_to_scifi": 1}
#: Fewest noise coefficients of a step: p̃0–p̃3 of paper eq. 11 (the floor p̃4 and the
#: straggling p̃5 are extensions that are zero when absent).
MIN_NOISE_PARAMS = 4


def _finite_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_coefficients(data: dict, geometry: Geometry, source: str) -> None:
    """Schema check of a parameter file's coefficients against the geometry it is for.

    One slot per layer of the geometry, in order; every coefficient a finite number; per
    slot, at least the coefficients its step type reads (``MIN_EXTRAPOLATION_PARAMS``,
    ``MIN_NOISE_PARAMS``) and at most as many as the formulas have; the UT→SciFi table
    present if the geometry has that step. A file failing this would fit every track with
    garbage (or zeros) and say ``ok``.

    Raises:
        InputError: one line naming the file (``source``) and the slot or key.
    """
    slots = data.get("slots")
    if not isinstance(slots, list) or len(slots) != geometry.n_layers:
        found = f"{len(slots)} entries" if isinstance(slots, list) else repr(slots)
        raise InputError(f"{source}: 'slots' has {found}; geometry {geometry.name!r} needs one per layer "
                         f"({geometry.n_layers})")
    structure = slot_structure(geometry)
    kind_names = {code: name for name, code in STEP_CODES.items()}
    for i, slot in enumerate(slots):
        if not isinstance(slot, dict) or slot.get("slot", i) != i:
            raise InputError(f"{source}: slots[{i}]: expected an object with \"slot\": {i}")
        kind = structure.slot_kind(i)
        step = kind_names.get(kind)
        for key, most, fewest in (("extrapolation", N_EXTRAPOLATION_PARAMS, MIN_EXTRAPOLATION_PARAMS.get(step, 0)),
                                  ("noise", N_NOISE_PARAMS, MIN_NOISE_PARAMS if step else 0)):
            values = slot.get(key)
            if not isinstance(values, list):
                raise InputError(f"{source}: slots[{i}].{key}: expected a list of numbers, found {values!r}")
            bad = next((j for j, v in enumerate(values) if not _finite_number(v)), None)
            if bad is not None:
                raise InputError(f"{source}: slots[{i}].{key}[{bad}] is {values[bad]!r}: coefficients must be "
                                 f"finite numbers")
            if not fewest <= len(values) <= most:
                leaving = f"the {step!r} step leaving layer {i}" if step else f"slot {i}"
                raise InputError(f"{source}: slots[{i}].{key} has {len(values)} coefficients; {leaving} needs "
                                 f"{fewest} to {most}")
    if STEP_UT_TO_SCIFI in (structure.within_type.tolist() + structure.between_type.tolist()) \
            and not isinstance(data.get("ut_to_scifi"), dict):
        raise InputError(f"{source}: 'ut_to_scifi' is {data.get('ut_to_scifi')!r}; geometry {geometry.name!r} "
                         f"has a ut_to_scifi step, which needs its table")


def shipped_parameters(geometry: Geometry) -> ParameterSet:
    """The tuned default shipped for a built-in geometry (package data)."""
    resource = resources.files("pkf.params").joinpath("data", f"{geometry.name}.json")
    if not resource.is_file():
        raise InputError(
            f"no shipped parameters for geometry {geometry.name!r}; run `pkf tune` and pass --params"
        )
    data = json.loads(resource.read_text())
    params = ParameterSet.from_json_dict(data, source=f"shipped {geometry.name}.json")
    params.check_geometry(geometry, source=f"shipped parameters {geometry.name}.json")
    check_coefficients(data, geometry, source=f"shipped parameters {geometry.name}.json")
    return params


#: Parameter sets this process has read and checked, by (geometry hash, file path and
#: content hash) — a run reads its file once per process, not once per user of it.
_LOADED: dict[tuple, ParameterSet] = {}


def load_parameters(geometry: Geometry, path: str | Path | None) -> ParameterSet:
    """`--params FILE` if given (checked against the geometry: its hash, then
    :func:`check_coefficients`), else the shipped default. Read once per process and
    content (the returned set is shared: do not modify it)."""
    key = (geometry.content_hash, None if path is None else str(path), _content_hash(path))
    if key not in _LOADED:
        _LOADED.clear()  # one run, one parameter set: keep no stale ones
        _LOADED[key] = _load_parameters(geometry, path)
    return _LOADED[key]


def _content_hash(path: str | Path | None) -> str | None:
    """SHA-256 of the file at `path` (None for the shipped set or a file that cannot be read:
    `_read_parameter_json` then says why)."""
    if path is None:
        return None
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def _load_parameters(geometry: Geometry, path: str | Path | None) -> ParameterSet:
    if path is None:
        return shipped_parameters(geometry)
    data = _read_parameter_json(Path(path))
    record = data.get("geometry")
    if data.get("format") == FORMAT and isinstance(record, dict) and "hash" in record:
        # a file for another geometry says so first; then its coefficients, before they are read
        _check_geometry_record(record.get("name"), record["hash"], geometry, f"--params {path}")
        check_coefficients(data, geometry, source=f"--params {path}")
    params = ParameterSet.from_json_dict(data, source=str(path))
    params.check_geometry(geometry, source=f"--params {path}")
    return params
