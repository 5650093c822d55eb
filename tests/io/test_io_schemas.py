"""Tests of pkf.io.schemas: column names and types of DESIGN §6, covariance packing, table builder."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from pkf.io import (
    CANDIDATES,
    CHI2,
    COV_COLUMNS,
    DATASET_SCHEMAS,
    HITS,
    MC_HITS,
    PARTICLES,
    PULLS,
    RUN_SCHEMAS,
    STATES,
    TABLE_SPECS,
    pack_covariance,
    spec_for,
    table_from_columns,
    unpack_covariance,
)

I64, I16, F64, STR = "int64", "int16", "double", "string"


def _columns(schema: pa.Schema) -> list[tuple[str, str, bool]]:
    return [(f.name, str(f.type), f.nullable) for f in schema]


def test_hits_schema():
    assert _columns(HITS) == [
        ("event_id", I64, False),
        ("hit_id", I64, False),
        ("layer", I16, False),
        ("z", F64, False),
        ("u", F64, False),
        ("v", F64, True),
        ("sigma_u", F64, False),
        ("sigma_v", F64, True),
    ]


def test_particles_schema():
    assert _columns(PARTICLES) == [
        ("event_id", I64, False),
        ("particle_id", I64, False),
        ("pdg", "int32", False),
        ("charge", "int8", False),
        *((c, F64, False) for c in ("mass", "vx", "vy", "vz", "px", "py", "pz")),
        ("parent_id", I64, False),
        ("interaction", I16, False),
        ("from_signal", "bool", False),
    ]


def test_mc_hits_schema():
    assert _columns(MC_HITS) == [
        ("event_id", I64, False),
        ("hit_id", I64, False),
        ("particle_id", I64, False),
        ("x", F64, True),  # null on noise rows (particle_id 0) of foreign files; never on a particle's row
        ("y", F64, True),
        ("z", F64, True),
        ("tx", F64, True),
        ("ty", F64, True),
        ("qop", F64, True),
    ]


def test_run_schemas():
    assert _columns(CHI2) == [
        ("event_id", I64, False),
        ("track_id", I64, False),
        ("fitter", STR, False),
        ("track_type", STR, False),
        ("n_velo", I16, False),
        ("n_ut", I16, False),
        ("n_scifi", I16, False),
        ("n_outliers", I16, False),
        ("chi2", F64, False),
        ("ndf", I16, False),
        ("chi2_ndf", F64, False),
        ("status", STR, False),
        ("mc_particle_id", I64, False),
        ("match_fraction", F64, False),
        ("is_ghost", "bool", False),
    ]
    assert CANDIDATES.names == ["event_id", "track_id", "hit_id"]
    assert STATES.names == [
        "event_id", "track_id", "fitter", "location", "z", "x", "y", "tx", "ty", "qop", *COV_COLUMNS,
    ]
    assert all(str(STATES.field(c).type) == F64 for c in ("z", "x", "qop", *COV_COLUMNS))
    assert PULLS.names == [
        "event_id", "track_id", "fitter", "location", "p_true",
        "res_x", "res_y", "res_tx", "res_ty", "res_qop",
        "pull_x", "pull_y", "pull_tx", "pull_ty", "pull_qop",
    ]
    assert str(PULLS.field("location").type) == STR


def test_registries_are_consistent():
    assert set(DATASET_SCHEMAS) | set(RUN_SCHEMAS) == set(TABLE_SPECS)
    for name, schema in {**DATASET_SCHEMAS, **RUN_SCHEMAS}.items():
        assert spec_for(schema) is TABLE_SPECS[name]
        for columns in (TABLE_SPECS[name].unique_key, TABLE_SPECS[name].finite, TABLE_SPECS[name].positive):
            assert set(columns) <= set(schema.names)
    assert spec_for(pa.schema([("event_id", pa.int64())])) is None


def test_cov_columns_order():
    assert COV_COLUMNS == (
        "c00", "c01", "c02", "c03", "c04", "c11", "c12", "c13", "c14",
        "c22", "c23", "c24", "c33", "c34", "c44",
    )


def test_covariance_round_trip():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(6, 5, 5))
    cov = a @ np.transpose(a, (0, 2, 1))
    packed = pack_covariance(cov)
    assert list(packed) == list(COV_COLUMNS)
    assert packed["c01"].shape == (6,)
    np.testing.assert_array_equal(packed["c13"], cov[:, 1, 3])
    np.testing.assert_array_equal(unpack_covariance(packed), cov)
    # via a table, and for a single matrix
    table = pa.table({k: v for k, v in packed.items()})
    np.testing.assert_array_equal(unpack_covariance(table), cov)
    np.testing.assert_array_equal(unpack_covariance(pack_covariance(cov[2])), cov[2])
    with pytest.raises(ValueError):
        pack_covariance(np.zeros((3, 4, 4)))


def test_table_from_columns_nan_to_null_only_in_nullable_columns():
    t = table_from_columns(
        HITS,
        {
            "event_id": [0, 0], "hit_id": [0, 1], "layer": [0, 2], "z": [0.0, 20.0],
            "u": np.array([1.0, np.nan]), "v": np.array([1.0, np.nan]),
            "sigma_u": 0.1, "sigma_v": np.array([0.1, np.nan]),
        },
    )
    assert t.schema.equals(HITS, check_metadata=True)
    assert t.column("v").null_count == 1 and t.column("sigma_v").null_count == 1
    assert t.column("u").null_count == 0 and np.isnan(t.column("u")[1].as_py())
    assert t.column("sigma_u").to_pylist() == [0.1, 0.1]


def test_table_from_columns_errors():
    good = {"event_id": [1], "track_id": [2], "hit_id": [3]}
    assert table_from_columns(CANDIDATES, good).num_rows == 1
    with pytest.raises(ValueError, match="missing"):
        table_from_columns(CANDIDATES, {"event_id": [1], "track_id": [2]})
    with pytest.raises(ValueError, match="unexpected"):
        table_from_columns(CANDIDATES, {**good, "x": [1.0]})
    with pytest.raises(ValueError, match="not nullable"):
        table_from_columns(CANDIDATES, {**good, "hit_id": [None]})
    with pytest.raises(ValueError, match="lengths"):
        table_from_columns(CANDIDATES, {**good, "hit_id": [1, 2]})
    with pytest.raises(pa.ArrowInvalid):
        table_from_columns(HITS, {
            "event_id": [0], "hit_id": [0], "layer": [70000], "z": [0.0], "u": [0.0],
            "v": [0.0], "sigma_u": [0.1], "sigma_v": [0.1],
        })
