"""Arrow/Parquet schemas of every pkf table (docs/formats.md), their validation rules and table builders.

Dataset tables (written by ``pkf simulate``): :data:`HITS`, :data:`PARTICLES`,
:data:`MC_HITS`. Run tables (written by ``pkf reconstruct``): :data:`CHI2`,
:data:`CANDIDATES`, :data:`STATES`, :data:`PULLS` and, with ``--track-states``,
:data:`TRACK_STATES`.

Units (docs/formats.md#conventions): lengths in mm, momenta and masses in MeV, ``qop`` in 1/MeV,
slopes ``tx = dx/dz``, ``ty = dy/dz`` dimensionless.

Every schema carries the metadata key ``pkf.table`` (its table name); the reader
uses it to find the table's validation rules (:data:`TABLE_SPECS`). A column is
nullable only where docs/formats.md allows a missing value (``v``/``sigma_v`` of strip hits,
the true slopes and ``qop`` of noise hits in ``mc_hits``). Run-table floats are not
nullable: a failed fit writes NaN and says why in ``status``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

__all__ = [
    "HITS",
    "PARTICLES",
    "MC_HITS",
    "CHI2",
    "CANDIDATES",
    "STATES",
    "PULLS",
    "TRACK_STATES",
    "DATASET_SCHEMAS",
    "RUN_SCHEMAS",
    "COV_COLUMNS",
    "STATE_COLUMNS",
    "STATE_LOCATIONS",
    "TRACK_STATE_STAGES",
    "TableSpec",
    "TABLE_SPECS",
    "EVENT_ID_LIMIT",
    "PARTICLE_ID_LIMIT",
    "MIN_SIGMA_MM",
    "spec_for",
    "pack_covariance",
    "unpack_covariance",
    "table_from_columns",
]

_F64 = pa.float64()
_I64 = pa.int64()
_I16 = pa.int16()
_STR = pa.string()

#: The five track parameters in state-vector order (docs/formats.md#conventions).
STATE_COLUMNS: tuple[str, ...] = ("x", "y", "tx", "ty", "qop")

#: The 15 upper-triangle covariance elements, row-major: c00 c01 … c04 c11 … c44 (docs/formats.md#conventions).
COV_COLUMNS: tuple[str, ...] = tuple(f"c{i}{j}" for i in range(5) for j in range(i, 5))

#: Values of the ``location`` column of ``states`` and ``pulls`` (docs/physics.md#the-kalman-core).
STATE_LOCATIONS: tuple[str, ...] = ("first_hit", "last_hit", "beamline")

#: Values of the ``stage`` column of ``track_states`` (the ACTS convention, seeds/002).
TRACK_STATE_STAGES: tuple[str, ...] = ("predicted", "filtered", "smoothed")

_TRIU = np.triu_indices(5)

#: particle_id < 2²⁴ and −2³⁸ ≤ event_id < 2³⁸ in ``particles``: MC matching combines both
#: into one int64 key per particle (``pkf.pipeline.inputs.particle_key``); larger ids
#: would overflow it or make two particles share a key.
PARTICLE_ID_LIMIT = 1 << 24
EVENT_ID_LIMIT = 1 << 38

#: Smallest measurement error accepted [mm] (1 nm): no tracking detector resolves
#: positions a thousand times better than a micrometre, and the fits and the pattern
#: recognition divide by σ² (σ = 1e-300 overflows to infinity).
MIN_SIGMA_MM = 1e-6


def _field(name: str, type_: pa.DataType, nullable: bool = False) -> pa.Field:
    return pa.field(name, type_, nullable=nullable)


def _schema(table: str, fields: list[pa.Field]) -> pa.Schema:
    return pa.schema(fields, metadata={"pkf.table": table})


#: ``hits``: one row per measurement. z, u, v in mm; sigma_u, sigma_v in mm.
#: v and sigma_v are null on strip layers.
HITS = _schema(
    "hits",
    [
        _field("event_id", _I64),
        _field("hit_id", _I64),
        _field("layer", _I16),
        _field("z", _F64),
        _field("u", _F64),
        _field("v", _F64, nullable=True),
        _field("sigma_u", _F64),
        _field("sigma_v", _F64, nullable=True),
    ],
)

#: ``particles``: MC truth, one row per generated particle. mass, px, py, pz in MeV;
#: vx, vy, vz (production vertex) in mm. particle_id > 0; parent_id 0 for primaries;
#: interaction = pileup vertex index.
PARTICLES = _schema(
    "particles",
    [
        _field("event_id", _I64),
        _field("particle_id", _I64),
        _field("pdg", pa.int32()),
        _field("charge", pa.int8()),
        _field("mass", _F64),
        _field("vx", _F64),
        _field("vy", _F64),
        _field("vz", _F64),
        _field("px", _F64),
        _field("py", _F64),
        _field("pz", _F64),
        _field("parent_id", _I64),
        _field("interaction", _I16),
        _field("from_signal", pa.bool_()),
    ],
)

#: ``mc_hits``: MC truth per hit. particle_id 0 for noise hits; x, y, z in mm and the
#: true local state tx, ty, qop (1/MeV) at the layer after material effects; tx, ty,
#: qop are null for noise hits (a NaN there is read as null) and set on every other row.
#: x, y, z may be null (or NaN, read as null) on noise rows too: a noise hit has no true
#: position (pkf's simulation writes the position it drew); a particle's row has them all.
MC_HITS = _schema(
    "mc_hits",
    [
        _field("event_id", _I64),
        _field("hit_id", _I64),
        _field("particle_id", _I64),
        _field("x", _F64, nullable=True),
        _field("y", _F64, nullable=True),
        _field("z", _F64, nullable=True),
        _field("tx", _F64, nullable=True),
        _field("ty", _F64, nullable=True),
        _field("qop", _F64, nullable=True),
    ],
)

#: ``chi2``: one row per (event, track, fitter). status is ``ok`` or why the fit
#: failed (then chi2/chi2_ndf are NaN); mc_particle_id is -1 if unmatched or no MC;
#: track_type is ``long``, ``upstream`` (VELO+UT) or ``velo`` (`pkf.fit.seed.track_type_codes`).
CHI2 = _schema(
    "chi2",
    [
        _field("event_id", _I64),
        _field("track_id", _I64),
        _field("fitter", _STR),
        _field("track_type", _STR),
        _field("n_velo", _I16),
        _field("n_ut", _I16),
        _field("n_scifi", _I16),
        _field("n_outliers", _I16),
        _field("chi2", _F64),
        _field("ndf", _I16),
        _field("chi2_ndf", _F64),
        _field("status", _STR),
        _field("mc_particle_id", _I64),
        _field("match_fraction", _F64),
        _field("is_ghost", pa.bool_()),
    ],
)

#: ``candidates``: one row per hit of each track candidate from pattern recognition.
CANDIDATES = _schema(
    "candidates",
    [
        _field("event_id", _I64),
        _field("track_id", _I64),
        _field("hit_id", _I64),
    ],
)

#: ``states``: fitted state (x, y in mm at plane z in mm; tx, ty; qop in 1/MeV) and its
#: covariance (15 upper-triangle elements, :data:`COV_COLUMNS`) at each location.
STATES = _schema(
    "states",
    [
        _field("event_id", _I64),
        _field("track_id", _I64),
        _field("fitter", _STR),
        _field("location", _STR),
        _field("z", _F64),
        *(_field(c, _F64) for c in STATE_COLUMNS),
        *(_field(c, _F64) for c in COV_COLUMNS),
    ],
)

#: ``pulls``: matched tracks only. p_true in MeV; res_* = fit − true (units of the
#: parameter), pull_* = res / σ (dimensionless).
PULLS = _schema(
    "pulls",
    [
        _field("event_id", _I64),
        _field("track_id", _I64),
        _field("fitter", _STR),
        _field("location", _STR),
        _field("p_true", _F64),
        *(_field(f"res_{c}", _F64) for c in STATE_COLUMNS),
        *(_field(f"pull_{c}", _F64) for c in STATE_COLUMNS),
    ],
)

#: ``track_states`` (only with ``--track-states``): one row per (event, track, fitter, node,
#: stage). node: index in z order along the track; stage: :data:`TRACK_STATE_STAGES`; the
#: stage's state and covariance as in ``states``; res_u/res_v [mm] = measured − the stage
#: state's u/v and var_res_u/var_res_v [mm²] their variances (v columns null on strip
#: layers); chi2 the node's χ² at this stage; is_outlier: removed as an outlier.
TRACK_STATES = _schema(
    "track_states",
    [
        _field("event_id", _I64),
        _field("track_id", _I64),
        _field("fitter", _STR),
        _field("node", _I16),
        _field("layer", _I16),
        _field("hit_id", _I64),
        _field("z", _F64),
        _field("stage", _STR),
        *(_field(c, _F64) for c in STATE_COLUMNS),
        *(_field(c, _F64) for c in COV_COLUMNS),
        _field("res_u", _F64),
        _field("var_res_u", _F64),
        _field("res_v", _F64, nullable=True),
        _field("var_res_v", _F64, nullable=True),
        _field("chi2", _F64),
        _field("is_outlier", pa.bool_()),
    ],
)

#: Tables of a dataset directory, by table name (file stem).
DATASET_SCHEMAS: dict[str, pa.Schema] = {"hits": HITS, "particles": PARTICLES, "mc_hits": MC_HITS}
#: Tables of a run directory, by table name (file stem).
RUN_SCHEMAS: dict[str, pa.Schema] = {
    "chi2": CHI2,
    "candidates": CANDIDATES,
    "states": STATES,
    "pulls": PULLS,
    "track_states": TRACK_STATES,
}


@dataclass(frozen=True)
class TableSpec:
    """Validation rules of one table, beyond its schema (used by :mod:`pkf.io.reader`).

    Every table must also be sorted by ``event_id`` and have no nulls in
    non-nullable columns.

    Attributes:
        name: table name (file stem).
        schema: the Arrow schema.
        unique_key: columns whose combination identifies a row (no duplicates);
            also the columns shown when an error names a row.
        finite: float columns that must be finite where not null.
        positive: numeric columns that must be > 0 where not null.
        non_negative: numeric columns that must be >= 0 where not null.
        null_together: groups of columns that must be all null or all non-null in a row.
        allow_empty: whether a table with zero rows is valid.
        ranges: (column, lowest, highest, why) where not null: lowest <= value <= highest
            (None: unbounded on that side); ``why`` is said in the message.
        nonzero_vectors: (columns, why): the components of a vector whose length must be
            > 0 (e.g. a particle's momentum); ``why`` is said in the message.
        noise_truth: (columns, particle column): truth columns that only rows of a particle
            (particle column != 0) must have; on noise rows (0) a NaN is read as null, the
            natural "no truth" of other producers.
    """

    name: str
    schema: pa.Schema
    unique_key: tuple[str, ...]
    finite: tuple[str, ...] = ()
    positive: tuple[str, ...] = ()
    non_negative: tuple[str, ...] = ()
    null_together: tuple[tuple[str, ...], ...] = ()
    allow_empty: bool = True
    ranges: tuple[tuple[str, float | None, float | None, str], ...] = ()
    nonzero_vectors: tuple[tuple[tuple[str, ...], str], ...] = ()
    noise_truth: tuple[tuple[str, ...], str] | None = None


#: Validation rules per table name.
TABLE_SPECS: dict[str, TableSpec] = {
    "hits": TableSpec(
        "hits",
        HITS,
        unique_key=("event_id", "hit_id"),
        finite=("z", "u", "v", "sigma_u", "sigma_v"),
        positive=("sigma_u", "sigma_v"),
        null_together=(("v", "sigma_v"),),
        allow_empty=False,
        ranges=tuple((c, MIN_SIGMA_MM, None, "in mm; no detector measures positions to 1 nm")
                     for c in ("sigma_u", "sigma_v")),
    ),
    "particles": TableSpec(
        "particles",
        PARTICLES,
        unique_key=("event_id", "particle_id"),
        finite=("mass", "vx", "vy", "vz", "px", "py", "pz"),
        positive=("particle_id",),
        non_negative=("mass", "parent_id"),
        ranges=(("particle_id", None, PARTICLE_ID_LIMIT - 1, "MC matching keys particles by event and id"),
                ("parent_id", None, PARTICLE_ID_LIMIT - 1, "MC matching keys particles by event and id"),
                ("event_id", -EVENT_ID_LIMIT, EVENT_ID_LIMIT - 1, "MC matching keys particles by event and id")),
        # every particle of the table was produced with a momentum: a charged particle that
        # left hits cannot have p = 0, and q/p, p_true and the pulls would not be finite
        nonzero_vectors=((("px", "py", "pz"), "a particle's momentum; q/p = charge/p"),),
    ),
    "mc_hits": TableSpec(
        "mc_hits",
        MC_HITS,
        unique_key=("event_id", "hit_id"),
        finite=("x", "y", "z", "tx", "ty", "qop"),
        non_negative=("particle_id",),
        null_together=(("tx", "ty", "qop"),),
        # a particle's hit has a finite momentum: p_true = 1/|qop| in the pulls
        nonzero_vectors=((("qop",), "the true q/p of a particle's hit; p = 1/|qop|"),),
        noise_truth=(("x", "y", "z", "tx", "ty", "qop"), "particle_id"),
    ),
    "chi2": TableSpec("chi2", CHI2, unique_key=("event_id", "track_id", "fitter")),
    "candidates": TableSpec("candidates", CANDIDATES, unique_key=("event_id", "track_id", "hit_id")),
    "states": TableSpec("states", STATES, unique_key=("event_id", "track_id", "fitter", "location")),
    "pulls": TableSpec("pulls", PULLS, unique_key=("event_id", "track_id", "fitter", "location")),
    "track_states": TableSpec("track_states", TRACK_STATES,
                              unique_key=("event_id", "track_id", "fitter", "node", "stage"),
                              null_together=(("res_v", "var_res_v"),)),
}


def spec_for(schema: pa.Schema) -> TableSpec | None:
    """Return the :class:`TableSpec` of one of the pkf schemas, or None for another schema.

    The schema is recognised by its ``pkf.table`` metadata and must equal the
    registered schema field by field.
    """
    meta = schema.metadata or {}
    name = meta.get(b"pkf.table")
    if name is None:
        return None
    spec = TABLE_SPECS.get(name.decode())
    if spec is None or not spec.schema.equals(schema):
        return None
    return spec


def pack_covariance(cov: np.ndarray) -> dict[str, np.ndarray]:
    """Split covariance matrices into the 15 columns ``c00 … c44`` (docs/formats.md#conventions).

    Args:
        cov: array of shape (n, 5, 5) (or (5, 5) for one matrix), in the units of
            the state (x, y, tx, ty, qop). Only the upper triangle is read.

    Returns:
        dict from each name of :data:`COV_COLUMNS` to a float64 array of shape (n,)
        (or a 0-d array for one matrix).
    """
    cov = np.asarray(cov, dtype=np.float64)
    if cov.shape[-2:] != (5, 5):
        raise ValueError(f"covariance must have shape (n, 5, 5), got {cov.shape}")
    upper = cov[..., _TRIU[0], _TRIU[1]]
    return {name: np.array(upper[..., k], order="C") for k, name in enumerate(COV_COLUMNS)}


def unpack_covariance(columns: Mapping[str, object] | pa.Table) -> np.ndarray:
    """Rebuild symmetric (n, 5, 5) covariance matrices from the columns ``c00 … c44``.

    Args:
        columns: a table (e.g. ``states``) or a mapping holding the 15
            :data:`COV_COLUMNS` as arrays of length n (numpy or Arrow).

    Returns:
        float64 array of shape (n, 5, 5), symmetric.
    """
    arrays = []
    for name in COV_COLUMNS:
        col = columns[name] if not isinstance(columns, pa.Table) else columns.column(name)
        if isinstance(col, (pa.Array, pa.ChunkedArray)):
            col = col.to_numpy()
        arrays.append(np.asarray(col, dtype=np.float64))
    upper = np.stack(arrays, axis=-1)
    cov = np.zeros(upper.shape[:-1] + (5, 5), dtype=np.float64)
    cov[..., _TRIU[0], _TRIU[1]] = upper
    cov[..., _TRIU[1], _TRIU[0]] = upper
    return cov


def table_from_columns(schema: pa.Schema, columns: Mapping[str, object]) -> pa.Table:
    """Build a table with exactly ``schema`` from numpy arrays / sequences, one per column.

    Every schema column must be given and no other. Values are converted to the
    column type (integers must fit). In *nullable* float columns NaN becomes null
    (so strip hits can pass ``v = nan``); in non-nullable columns NaN is kept and
    null is refused. Scalars (e.g. ``fitter="parametrized"``) are broadcast to the
    common length.

    Raises:
        ValueError: missing/extra columns, different lengths, or nulls in a
            non-nullable column. (These are programming errors, not bad input.)
    """
    names = set(columns)
    missing = [n for n in schema.names if n not in names]
    extra = sorted(names - set(schema.names))
    if missing or extra:
        raise ValueError(f"table_from_columns: missing columns {missing}, unexpected columns {extra}")
    lengths = {n: len(v) for n, v in columns.items() if not np.isscalar(v) and not isinstance(v, str)}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"table_from_columns: columns have different lengths {lengths}")
    n = next(iter(lengths.values()), 1)
    arrays = []
    for field in schema:
        value = columns[field.name]
        if np.isscalar(value) or isinstance(value, str):
            value = [value] * n
        if isinstance(value, (pa.Array, pa.ChunkedArray)):
            arr = value.cast(field.type)
        else:
            from_pandas = field.nullable and pa.types.is_floating(field.type)
            arr = pa.array(value, type=field.type, from_pandas=from_pandas)
        if not field.nullable and arr.null_count:
            raise ValueError(f"table_from_columns: column {field.name!r} has nulls but is not nullable")
        arrays.append(arr)
    return pa.Table.from_arrays(arrays, schema=schema)


#: particle keys: zigzag(event_id)·PARTICLE_KEY_BASE + particle_id (`particle_key`)
PARTICLE_KEY_BASE = PARTICLE_ID_LIMIT


def particle_key(event_id, particle_id):
    """A particle id unique across events: > 0 for every particle, 0 for noise (particle_id 0).

    key = zigzag(event_id)·2²⁴ + particle_id, where zigzag maps event ids 0, −1, 1, −2, …
    to 0, 1, 2, 3, …: negative event ids are legitimate and must give positive keys, as
    every user of a key takes key > 0 to mean "a particle" (matching, reconstructibility,
    pulls). key % 2²⁴ = particle_id. The reader guarantees the ranges that make the key
    unique and free of overflow (:data:`PARTICLE_ID_LIMIT`, :data:`EVENT_ID_LIMIT`).
    """
    event = np.asarray(event_id, dtype=np.int64)
    zigzag = np.where(event >= 0, 2 * event, -2 * event - 1)
    return np.where(particle_id > 0, zigzag * PARTICLE_KEY_BASE + particle_id, 0)
