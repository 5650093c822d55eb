"""Helpers for the pkf.io tests: a small valid dataset on a 4-layer toy geometry, bad-input assertions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pkf.errors import InputError
from pkf.io import HITS, MC_HITS, PARTICLES, atomic_write_json, table_from_columns

#: Toy geometry: two pixel layers then two strip layers [mm].
LAYER_Z = np.array([0.0, 10.0, 20.0, 30.0])
LAYER_KIND = np.array([0, 0, 1, 1])


def make_tables(n_events: int = 4) -> dict[str, pa.Table]:
    """Valid hits / particles / mc_hits: per event two particles crossing all four
    layers (particle 2 is a daughter of particle 1) and one noise hit on layer 2."""
    rng = np.random.default_rng(7)
    per_event_layer = np.array([0, 1, 2, 3, 0, 1, 2, 3, 2])
    per_event_pid = np.array([1, 1, 1, 1, 2, 2, 2, 2, 0])
    n = per_event_layer.size
    event_id = np.repeat(np.arange(n_events, dtype=np.int64), n)
    hit_id = np.tile(np.arange(n, dtype=np.int64), n_events)
    layer = np.tile(per_event_layer, n_events)
    pid = np.tile(per_event_pid, n_events)
    strip = LAYER_KIND[layer] == 1
    u = rng.normal(size=event_id.size)
    hits = table_from_columns(
        HITS,
        {
            "event_id": event_id,
            "hit_id": hit_id,
            "layer": layer,
            "z": LAYER_Z[layer],
            "u": u,
            "v": np.where(strip, np.nan, rng.normal(size=event_id.size)),
            "sigma_u": np.where(strip, 0.05, 0.0125),
            "sigma_v": np.where(strip, np.nan, 0.0125),
        },
    )
    noise = pid == 0
    mc_hits = table_from_columns(
        MC_HITS,
        {
            "event_id": event_id,
            "hit_id": hit_id,
            "particle_id": pid,
            "x": u,
            "y": rng.normal(size=event_id.size),
            "z": LAYER_Z[layer],
            "tx": np.where(noise, np.nan, 0.01),
            "ty": np.where(noise, np.nan, -0.02),
            "qop": np.where(noise, np.nan, 1e-4),
        },
    )
    m = 2 * n_events
    particles = table_from_columns(
        PARTICLES,
        {
            "event_id": np.repeat(np.arange(n_events, dtype=np.int64), 2),
            "particle_id": np.tile([1, 2], n_events),
            "pdg": np.tile([211, -321], n_events),
            "charge": np.tile([1, -1], n_events),
            "mass": np.tile([139.57, 493.68], n_events),
            "vx": np.zeros(m),
            "vy": np.zeros(m),
            "vz": rng.normal(size=m),
            "px": rng.normal(size=m) * 100,
            "py": rng.normal(size=m) * 100,
            "pz": np.full(m, 10_000.0),
            "parent_id": np.tile([0, 1], n_events),
            "interaction": np.zeros(m, dtype=np.int16),
            "from_signal": np.tile([False, True], n_events),
        },
    )
    return {"hits": hits, "particles": particles, "mc_hits": mc_hits}


def write_dataset(directory: Path, tables: dict[str, pa.Table], meta: dict | None = None) -> Path:
    """Write tables (raw: whatever schema they have) and meta.json into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    for name, table in tables.items():
        pq.write_table(table, directory / f"{name}.parquet")
    atomic_write_json(meta if meta is not None else {"geometry": "toy", "seed": 1}, directory / "meta.json")
    return directory


def replace_column(table: pa.Table, name: str, values, type_: pa.DataType | None = None) -> pa.Table:
    """Return ``table`` with column ``name`` replaced (nullable field; NaN stays NaN)."""
    i = table.schema.get_field_index(name)
    type_ = type_ or table.schema.field(name).type
    return table.set_column(i, pa.field(name, type_), pa.array(values, type=type_))


def raises_input_error(func, *parts: str) -> str:
    """Call ``func``, expect InputError with a one-line message containing every part."""
    with pytest.raises(InputError) as info:
        func()
    message = str(info.value)
    assert "\n" not in message, message
    for part in parts:
        assert part in message, f"{part!r} not in {message!r}"
    return message
