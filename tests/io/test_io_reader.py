"""Tests of pkf.io.reader: round trips and every bad-table case of DESIGN §13, with one-line messages
naming file, column and first bad row."""

from __future__ import annotations

import json

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from io_helpers import LAYER_KIND, LAYER_Z, make_tables, raises_input_error, replace_column, write_dataset

from pkf.io import (
    CANDIDATES,
    CHI2,
    COV_COLUMNS,
    HITS,
    MC_HITS,
    PARTICLES,
    PULLS,
    STATES,
    atomic_write_table,
    open_dataset,
    read_meta,
    read_table,
    table_from_columns,
    validate_consistency,
    validate_hit_layers,
)

# ----------------------------------------------------------------------------- round trips


def _run_tables(n_tracks: int = 5) -> dict[str, pa.Table]:
    rng = np.random.default_rng(3)
    ev = np.repeat([0, 1], [3, n_tracks - 3]).astype(np.int64)
    tid = np.array([0, 1, 2] + list(range(n_tracks - 3)), dtype=np.int64)
    chi2 = table_from_columns(CHI2, {
        "event_id": ev, "track_id": tid, "fitter": "parametrized", "track_type": "long",
        "n_velo": np.full(n_tracks, 10),
        "n_ut": 4, "n_scifi": 12, "n_outliers": 0, "chi2": rng.random(n_tracks) * 30, "ndf": 29,
        "chi2_ndf": np.append(rng.random(n_tracks - 1), np.nan), "status": ["ok"] * (n_tracks - 1) + ["too few hits"],
        "mc_particle_id": np.arange(n_tracks) - 1, "match_fraction": rng.random(n_tracks),
        "is_ghost": np.arange(n_tracks) == 0,
    })
    candidates = table_from_columns(CANDIDATES, {
        "event_id": np.repeat(ev, 3), "track_id": np.repeat(tid, 3), "hit_id": np.arange(3 * n_tracks),
    })
    loc = np.tile(["first_hit", "last_hit", "beamline"], n_tracks)
    states = table_from_columns(STATES, {
        "event_id": np.repeat(ev, 3), "track_id": np.repeat(tid, 3), "fitter": "reference", "location": loc,
        **{c: rng.normal(size=3 * n_tracks) for c in ("z", "x", "y", "tx", "ty", "qop", *COV_COLUMNS)},
    })
    pulls = table_from_columns(PULLS, {
        "event_id": np.repeat(ev, 3), "track_id": np.repeat(tid, 3), "fitter": "gsf", "location": loc,
        **{c: rng.normal(size=3 * n_tracks) for c in PULLS.names[4:]},
    })
    return {"chi2": chi2, "candidates": candidates, "states": states, "pulls": pulls}


_SCHEMAS = {"hits": HITS, "particles": PARTICLES, "mc_hits": MC_HITS, "chi2": CHI2,
            "candidates": CANDIDATES, "states": STATES, "pulls": PULLS}


@pytest.mark.parametrize("name", list(_SCHEMAS))
def test_round_trip(tmp_path, name):
    table = {**make_tables(), **_run_tables()}[name]
    atomic_write_table(table, tmp_path / f"{name}.parquet", schema=_SCHEMAS[name])
    back = read_table(tmp_path, _SCHEMAS[name], name=name)
    assert back.schema.equals(_SCHEMAS[name], check_metadata=True)
    _assert_tables_equal(back, table)
    # the table file itself may be passed too
    _assert_tables_equal(read_table(tmp_path / f"{name}.parquet", _SCHEMAS[name], name=name), table)


def _assert_tables_equal(a: pa.Table, b: pa.Table) -> None:
    """Equal schemas and values, NaN equal to NaN (chi2_ndf of a failed fit is NaN)."""
    assert a.schema.equals(b.schema) and a.num_rows == b.num_rows
    for name in a.column_names:
        np.testing.assert_array_equal(a.column(name).to_numpy(), b.column(name).to_numpy(), err_msg=name)


def test_empty_run_tables_are_allowed(tmp_path):
    atomic_write_table(CHI2.empty_table(), tmp_path / "chi2.parquet")
    assert read_table(tmp_path, CHI2, name="chi2").num_rows == 0


def test_open_dataset(dataset_dir, tables):
    ds = open_dataset(dataset_dir, layer_z=LAYER_Z, layer_kind=LAYER_KIND)
    assert ds.path == dataset_dir and ds.meta == {"geometry": "toy", "seed": 1}
    assert ds.hits.equals(tables["hits"])
    assert ds.particles.equals(tables["particles"]) and ds.mc_hits.equals(tables["mc_hits"])
    assert ds.has_mc


def test_open_dataset_without_mc(dataset_dir):
    (dataset_dir / "particles.parquet").unlink()
    (dataset_dir / "mc_hits.parquet").unlink()
    ds = open_dataset(dataset_dir)
    assert ds.particles is None and ds.mc_hits is None and not ds.has_mc


def test_directory_of_files(tmp_path, tables):
    hits = make_tables(12)["hits"]
    d = tmp_path / "ds" / "hits"
    d.mkdir(parents=True)
    # natural order: part-2 is read before part-10
    bounds = [(0, 30), (30, 60), (60, hits.num_rows)]
    for name, (lo, hi) in zip(["part-1.parquet", "part-2.parquet", "part-10.parquet"], bounds):
        pq.write_table(hits.slice(lo, hi - lo), d / name)
    (d / "_SUCCESS").write_text("")  # hidden/underscore files are ignored, as by pyarrow.dataset
    (d / ".part-3.parquet.tmp").write_text("junk")
    back = read_table(tmp_path / "ds", HITS, name="hits")
    assert back.equals(hits)
    # a directory named hits.parquet/ (as Spark writes) works the same way
    d.rename(tmp_path / "ds" / "hits.parquet")
    assert read_table(tmp_path / "ds", HITS, name="hits").equals(hits)


def test_integer_and_float_widths_are_converted(tmp_path, tables):
    hits = tables["hits"]
    hits = replace_column(hits, "event_id", hits.column("event_id").to_numpy().astype(np.int32), pa.int32())
    hits = replace_column(hits, "layer", hits.column("layer").to_numpy().astype(np.uint8), pa.uint8())
    hits = replace_column(hits, "u", hits.column("u").to_numpy().astype(np.float32), pa.float32())
    hits = replace_column(hits, "z", hits.column("z").to_numpy().astype(np.int64), pa.int64())
    hits = hits.select(list(reversed(hits.column_names)))
    pq.write_table(hits, tmp_path / "hits.parquet")
    back = read_table(tmp_path, HITS, name="hits")
    assert back.schema.equals(HITS)
    assert back.column("layer").to_pylist() == tables["hits"].column("layer").to_pylist()


# ----------------------------------------------------------------------------- bad tables


def _write_hits(tmp_path, hits: pa.Table):
    pq.write_table(hits, tmp_path / "hits.parquet")
    return lambda: read_table(tmp_path, HITS, name="hits")


def test_missing_column(tmp_path, tables):
    read = _write_hits(tmp_path, tables["hits"].drop_columns(["u"]))
    raises_input_error(read, "hits.parquet", "column 'u'", "missing")


def test_extra_columns_are_ignored_and_listed(dataset_dir, tables):
    """Issue 16: producers add columns (times, cluster sizes); the reader ignores them and
    lists them per table (the stages print one warning line each)."""
    n = tables["hits"].num_rows
    pq.write_table(tables["hits"].append_column("w", pa.array(np.zeros(n))).append_column("t", pa.array(np.ones(n))),
                   dataset_dir / "hits.parquet")
    ds = open_dataset(dataset_dir)
    assert ds.hits.equals(tables["hits"])
    assert ds.ignored_columns == {"hits": ("w", "t")}
    assert read_table(dataset_dir, HITS, name="hits").equals(tables["hits"])


def _mc_with(tables, column: str, row: int, value) -> pa.Table:
    mc = tables["mc_hits"]
    values = mc.column(column).to_pylist()
    values[row] = value
    return replace_column(mc, column, values, pa.float64())


def test_nan_truth_on_noise_rows_is_read_as_null(dataset_dir, tables):
    """Issue 16: NaN, the natural "no truth" of other producers, is null on noise rows."""
    mc = tables["mc_hits"]
    noise = np.flatnonzero(mc.column("particle_id").to_numpy() == 0)
    nan_mc = mc
    for name in ("tx", "ty", "qop"):
        values = mc.column(name).to_numpy(zero_copy_only=False)  # NaN where null
        nan_mc = replace_column(nan_mc, name, pa.array(values, pa.float64()), pa.float64())
    assert nan_mc.column("qop").null_count == 0
    assert np.isnan(nan_mc.column("qop").to_numpy()[noise]).all()
    pq.write_table(nan_mc, dataset_dir / "mc_hits.parquet")
    assert open_dataset(dataset_dir).mc_hits.equals(mc)


@pytest.mark.parametrize("column", ["x", "y", "z"])
def test_nan_or_null_position_on_noise_rows_is_accepted(dataset_dir, tables, column):
    """Issue 16: a noise hit has no true position either; NaN there is read as null."""
    mc = tables["mc_hits"]
    pid = mc.column("particle_id").to_numpy()
    noise = np.flatnonzero(pid == 0)
    assert noise.size and (pid != 0).any()
    for missing, null_count in ((np.nan, 0), (None, noise.size)):
        values = mc.column(column).to_pylist()
        for row in noise:
            values[row] = missing
        written = replace_column(mc, column, values, pa.float64())
        assert written.column(column).null_count == null_count
        pq.write_table(written, dataset_dir / "mc_hits.parquet")
        read = open_dataset(dataset_dir).mc_hits
        assert read.column(column).null_count == noise.size  # NaN and null both read as null
        assert read.column(column).drop_null().equals(mc.column(column).filter(pc.not_equal(mc.column("particle_id"), 0)))
        assert read.drop_columns([column]).equals(mc.drop_columns([column]))


@pytest.mark.parametrize("column", ["ty", "x", "y", "z"])
@pytest.mark.parametrize("value, problem", [(None, "is null on a particle's hit (particle_id=1)"),
                                            (float("nan"), "is NaN")])
def test_missing_truth_on_a_particle_row_is_bad(dataset_dir, tables, column, value, problem):
    pq.write_table(_mc_with(tables, column, 1, value), dataset_dir / "mc_hits.parquet")
    raises_input_error(lambda: open_dataset(dataset_dir), "mc_hits.parquet", f"column '{column}': row 1 (", problem)


def test_wrong_dtype(tmp_path, tables):
    hits = tables["hits"]
    as_text = [str(x) for x in hits.column("layer").to_pylist()]
    read = _write_hits(tmp_path, replace_column(hits, "layer", as_text, pa.string()))
    raises_input_error(read, "hits.parquet", "column 'layer'", "wrong dtype string, expected int16")
    read = _write_hits(tmp_path, replace_column(hits, "hit_id", hits.column("hit_id").to_numpy() * 1.0, pa.float64()))
    raises_input_error(read, "hits.parquet", "column 'hit_id'", "expected int64")


def test_integer_out_of_range(tmp_path, tables):
    layer = tables["hits"].column("layer").to_numpy().astype(np.int64)
    layer[20] = 40000
    read = _write_hits(tmp_path, replace_column(tables["hits"], "layer", layer, pa.int64()))
    raises_input_error(read, "hits.parquet", "column 'layer'", "row 20 (event_id=2, hit_id=2)", "does not fit in int16")


def test_null_in_required_column(tmp_path, tables):
    u = tables["hits"].column("u").to_pylist()
    u[5] = None
    read = _write_hits(tmp_path, replace_column(tables["hits"], "u", u))
    raises_input_error(read, "hits.parquet: column 'u': row 5 (event_id=0, hit_id=5) is null")


@pytest.mark.parametrize(
    ("column", "value", "expected"),
    [("u", np.nan, "is NaN"), ("z", np.inf, "is inf"), ("sigma_u", -np.inf, "is -inf"), ("v", np.nan, "is NaN"),
     ("sigma_v", np.inf, "is inf")],
)
def test_non_finite_values(tmp_path, tables, column, value, expected):
    values = tables["hits"].column(column).to_numpy(zero_copy_only=False)  # nulls become NaN here,
    values = pa.array(values, from_pandas=True).to_pylist()  # so rebuild keeping nulls
    values[19] = value  # row 19: event 2, hit 1, a pixel layer
    read = _write_hits(tmp_path, replace_column(tables["hits"], column, values))
    message = raises_input_error(read, "hits.parquet", f"column '{column}'", "row 19 (event_id=2, hit_id=1)", expected)
    assert message == f"{tmp_path / 'hits.parquet'}: column '{column}': row 19 (event_id=2, hit_id=1) {expected}"


def test_sigma_must_be_positive(tmp_path, tables):
    sigma = tables["hits"].column("sigma_u").to_numpy().copy()
    sigma[3] = 0.0
    read = _write_hits(tmp_path, replace_column(tables["hits"], "sigma_u", sigma))
    raises_input_error(read, "hits.parquet", "column 'sigma_u'", "row 3 (event_id=0, hit_id=3)", "must be > 0")


def test_v_and_sigma_v_null_together(tmp_path, tables):
    sigma_v = tables["hits"].column("sigma_v").to_pylist()
    sigma_v[1] = None
    read = _write_hits(tmp_path, replace_column(tables["hits"], "sigma_v", sigma_v))
    raises_input_error(
        read, "hits.parquet", "column 'sigma_v'", "row 1 (event_id=0, hit_id=1)", "is null but 'v' is not"
    )


def test_unsorted_events(tmp_path, tables):
    hits = tables["hits"]
    order = np.arange(hits.num_rows)
    order[[9, 18]] = order[[18, 9]]  # event 2's first hit before event 1's
    read = _write_hits(tmp_path, hits.take(order))
    raises_input_error(read, "hits.parquet", "column 'event_id'", "row 10 (event_id=1, hit_id=1)", "sorted by event_id")


def test_duplicate_hit_ids(tmp_path, tables):
    hit_id = tables["hits"].column("hit_id").to_numpy().copy()
    hit_id[[12, 15]] = 1  # rows 12 and 15 of event 1 repeat hit 1 (row 10)
    read = _write_hits(tmp_path, replace_column(tables["hits"], "hit_id", hit_id))
    raises_input_error(read, "hits.parquet", "column 'hit_id'", "row 12 (event_id=1, hit_id=1)", "duplicates row 10")


def test_duplicate_mc_hit_and_particle_ids(tmp_path, tables):
    hit_id = tables["mc_hits"].column("hit_id").to_numpy().copy()
    hit_id[8] = 0
    pq.write_table(replace_column(tables["mc_hits"], "hit_id", hit_id), tmp_path / "mc_hits.parquet")
    raises_input_error(lambda: read_table(tmp_path, MC_HITS, name="mc_hits"),
                       "mc_hits.parquet", "column 'hit_id'", "row 8 (event_id=0, hit_id=0)", "duplicates row 0")
    pid = tables["particles"].column("particle_id").to_numpy().copy()
    pid[5] = 1
    pq.write_table(replace_column(tables["particles"], "particle_id", pid), tmp_path / "particles.parquet")
    raises_input_error(lambda: read_table(tmp_path, PARTICLES, name="particles"),
                       "particles.parquet", "column 'particle_id'", "row 5 (event_id=2, particle_id=1)",
                       "duplicates row 4")


def test_duplicate_string_keys_in_run_table(tmp_path):
    states = _run_tables()["states"]
    loc = states.column("location").to_pylist()
    assert loc[:3] == ["first_hit", "last_hit", "beamline"]
    loc[2] = "first_hit"
    pq.write_table(replace_column(states, "location", loc), tmp_path / "states.parquet")
    raises_input_error(lambda: read_table(tmp_path, STATES, name="states"),
                       "states.parquet", "column 'location'", "row 2 (event_id=0, track_id=0, fitter='reference', "
                       "location='first_hit') duplicates row 0")


def test_empty_hits(tmp_path):
    read = _write_hits(tmp_path, HITS.empty_table())
    raises_input_error(read, "hits.parquet", "empty")
    (tmp_path / "hits.parquet").unlink()
    (tmp_path / "hits").mkdir()
    raises_input_error(read, "hits", "no Parquet files")


def test_truncated_file(tmp_path, tables):
    path = tmp_path / "hits.parquet"
    pq.write_table(tables["hits"], path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    raises_input_error(lambda: read_table(tmp_path, HITS, name="hits"), str(path), "truncated")
    path.write_bytes(b"")
    raises_input_error(lambda: read_table(tmp_path, HITS, name="hits"), str(path), "empty (0 bytes)")


def test_corrupt_file_with_valid_magic(tmp_path, tables):
    path = tmp_path / "hits.parquet"
    pq.write_table(tables["hits"], path, compression="none")
    data = bytearray(path.read_bytes())
    data[4:-200] = b"\xff" * (len(data) - 204)  # destroy the pages, keep footer and magic
    path.write_bytes(bytes(data))
    raises_input_error(lambda: read_table(tmp_path, HITS, name="hits"), str(path))


def test_not_parquet(tmp_path):
    (tmp_path / "hits.parquet").write_text("event_id,hit_id\n0,0\n")
    raises_input_error(lambda: read_table(tmp_path, HITS, name="hits"), "hits.parquet", "not a Parquet file")


def test_bad_file_in_directory_is_named(tmp_path):
    hits = make_tables(6)["hits"]
    d = tmp_path / "hits"
    d.mkdir()
    pq.write_table(hits.slice(0, 27), d / "part-0.parquet")
    u = hits.column("u").to_numpy().copy()
    u[27 + 4] = np.nan
    pq.write_table(replace_column(hits, "u", u).slice(27), d / "part-1.parquet")
    read = lambda: read_table(tmp_path, HITS, name="hits")  # noqa: E731
    # the row number is within the part file that holds it
    raises_input_error(read, str(d / "part-1.parquet"), "column 'u': row 4 (event_id=3, hit_id=4) is NaN")
    (d / "part-1.parquet").write_text("not parquet")
    raises_input_error(read, str(d / "part-1.parquet"), "not a Parquet file")
    pq.write_table(hits.slice(27).drop_columns(["v"]), d / "part-1.parquet")
    raises_input_error(read, str(d / "part-1.parquet"), "column 'v' is missing")
    # events out of order across files
    pq.write_table(hits.slice(0, 27), d / "part-1.parquet")
    pq.write_table(hits.slice(27), d / "part-0.parquet")
    raises_input_error(read, str(d / "part-1.parquet"), "column 'event_id': row 0 (event_id=0, hit_id=0)", "sorted")
    # duplicates across files name the other file
    pq.write_table(hits.slice(0, 27), d / "part-0.parquet")
    pq.write_table(hits.slice(18, 9), d / "part-1.parquet")
    raises_input_error(read, str(d / "part-1.parquet"), "row 0 (event_id=2, hit_id=0) duplicates",
                       f"{d / 'part-0.parquet'} row 18")


def test_missing_and_ambiguous_table(tmp_path, tables):
    raises_input_error(lambda: read_table(tmp_path, HITS, name="hits"), str(tmp_path), "'hits' not found")
    pq.write_table(tables["hits"], tmp_path / "hits.parquet")
    (tmp_path / "hits").mkdir()
    raises_input_error(lambda: read_table(tmp_path, HITS, name="hits"), "ambiguous")


# ----------------------------------------------------------------------------- geometry checks


def test_unknown_layer(tables):
    hits = tables["hits"]
    for bad in (4, -1):
        layer = hits.column("layer").to_numpy().copy()
        layer[13] = bad
        raises_input_error(
            lambda: validate_hit_layers(
                replace_column(hits, "layer", layer), LAYER_Z, LAYER_KIND, source="ds/hits.parquet"
            ),
            "ds/hits.parquet: column 'layer': row 13 (event_id=1, hit_id=4)", f"is {bad}", "not a layer",
        )


def test_z_mismatch_via_open_dataset(tmp_path, tables):
    z = tables["hits"].column("z").to_numpy().copy()
    z[30] += 1e-5
    write_dataset(tmp_path / "ds", {"hits": replace_column(tables["hits"], "z", z)})
    raises_input_error(
        lambda: open_dataset(tmp_path / "ds", layer_z=LAYER_Z, layer_kind=LAYER_KIND),
        f"{tmp_path / 'ds' / 'hits.parquet'}: column 'z': row 30 (event_id=3, hit_id=3)", "layer 3 is at z = 30.0",
    )
    z[30] -= 0.99e-5  # within 1e-6 mm
    write_dataset(tmp_path / "ds", {"hits": replace_column(tables["hits"], "z", z)})
    open_dataset(tmp_path / "ds", layer_z=LAYER_Z, layer_kind=LAYER_KIND)


def test_strip_and_pixel_measurements(tables):
    hits = tables["hits"]
    v = hits.column("v").to_pylist()
    sigma_v = hits.column("sigma_v").to_pylist()
    v[2], sigma_v[2] = 1.0, 0.05  # layer 2 is a strip layer
    both = replace_column(replace_column(hits, "v", v), "sigma_v", sigma_v)
    raises_input_error(
        lambda: validate_hit_layers(both, LAYER_Z, LAYER_KIND),
        "hits: column 'v': row 2 (event_id=0, hit_id=2)", "strip layer",
    )
    v = hits.column("v").to_pylist()
    sigma_v = hits.column("sigma_v").to_pylist()
    sigma_v[1] = None  # layer 1 is a pixel layer
    raises_input_error(
        lambda: validate_hit_layers(replace_column(hits, "sigma_v", sigma_v), LAYER_Z, LAYER_KIND),
        "column 'sigma_v': row 1 (event_id=0, hit_id=1)", "pixel layer",
    )
    with pytest.raises(ValueError):
        validate_hit_layers(hits, LAYER_Z, LAYER_KIND[:3])


# ----------------------------------------------------------------------------- MC consistency


def test_mc_hit_without_hit(tmp_path, tables):
    write_dataset(tmp_path / "ds", {**tables, "hits": tables["hits"].filter(pa.array(np.arange(36) != 11))})
    raises_input_error(
        lambda: open_dataset(tmp_path / "ds"),
        f"{tmp_path / 'ds' / 'mc_hits.parquet'}: column 'hit_id': row 11 (event_id=1, hit_id=2)", "has no hit",
    )


def test_mc_hit_with_unknown_particle(tmp_path, tables):
    pid = tables["mc_hits"].column("particle_id").to_numpy().copy()
    pid[22] = 7
    write_dataset(tmp_path / "ds", {**tables, "mc_hits": replace_column(tables["mc_hits"], "particle_id", pid)})
    raises_input_error(
        lambda: open_dataset(tmp_path / "ds"),
        "mc_hits.parquet: column 'particle_id': row 22 (event_id=2, hit_id=4, particle_id=7)", "not a particle",
    )


def test_particle_with_unknown_parent(tmp_path, tables):
    parent = tables["particles"].column("parent_id").to_numpy().copy()
    parent[3] = 5
    write_dataset(tmp_path / "ds", {**tables, "particles": replace_column(tables["particles"], "parent_id", parent)})
    raises_input_error(
        lambda: open_dataset(tmp_path / "ds"),
        "particles.parquet: column 'parent_id': row 3 (event_id=1, particle_id=2, parent_id=5)",
    )


def test_consistency_with_huge_ids(tables):
    """Ids spanning the whole int64 range use the rank-encoding path."""
    big = 2**62
    hits = replace_column(tables["hits"], "hit_id", tables["hits"].column("hit_id").to_numpy() * big // 8 - big)
    mc = replace_column(tables["mc_hits"], "hit_id", hits.column("hit_id").to_numpy())
    validate_consistency(hits, None, mc.slice(3))
    bad = mc.column("hit_id").to_numpy().copy()
    bad[-1] += 1
    raises_input_error(
        lambda: validate_consistency(hits, None, replace_column(mc, "hit_id", bad).slice(1)),
        "mc_hits: column 'hit_id': row 34", "has no hit",
    )


# ----------------------------------------------------------------------------- meta and paths


def test_meta(tmp_path):
    raises_input_error(lambda: read_meta(tmp_path), "meta.json", "not found")
    (tmp_path / "meta.json").write_text("{bad json")
    raises_input_error(lambda: read_meta(tmp_path), str(tmp_path / "meta.json"), "not valid JSON", "line 1")
    (tmp_path / "meta.json").write_text("[1, 2]")
    raises_input_error(lambda: read_meta(tmp_path), "meta.json", "JSON object")
    (tmp_path / "meta.json").write_bytes(b"\xff\xfe")
    raises_input_error(lambda: read_meta(tmp_path), "meta.json", "not valid JSON")
    (tmp_path / "meta.json").write_text(json.dumps({"seed": 3}))
    assert read_meta(tmp_path) == {"seed": 3}


def test_open_dataset_bad_paths(tmp_path, dataset_dir):
    raises_input_error(lambda: open_dataset(tmp_path / "nope"), "nope", "does not exist")
    raises_input_error(lambda: open_dataset(dataset_dir / "meta.json"), "meta.json", "not a directory")
    (dataset_dir / "meta.json").unlink()
    raises_input_error(lambda: open_dataset(dataset_dir), "meta.json", "not found")


def test_open_dataset_validates_optional_tables(dataset_dir, tables):
    mc = tables["mc_hits"].drop_columns(["qop"])
    pq.write_table(mc, dataset_dir / "mc_hits.parquet")
    raises_input_error(lambda: open_dataset(dataset_dir), "mc_hits.parquet", "column 'qop' is missing")


def test_large_table_is_fast(tmp_path):
    """Validation is vectorised: 10^6 hits with shuffled hit ids within events."""
    n_events, per_event = 1000, 1000
    rng = np.random.default_rng(5)
    event_id = np.repeat(np.arange(n_events, dtype=np.int64), per_event)
    hit_id = np.concatenate([rng.permutation(per_event) for _ in range(n_events)]).astype(np.int64)
    layer = rng.integers(0, 2, size=event_id.size)
    hits = table_from_columns(HITS, {
        "event_id": event_id, "hit_id": hit_id, "layer": layer, "z": LAYER_Z[layer],
        "u": rng.normal(size=event_id.size), "v": rng.normal(size=event_id.size),
        "sigma_u": 0.0125, "sigma_v": 0.0125,
    })
    atomic_write_table(hits, tmp_path / "hits.parquet")
    back = read_table(tmp_path, HITS, name="hits")
    validate_hit_layers(back, LAYER_Z, LAYER_KIND)
    validate_consistency(back, None, back.select(["event_id", "hit_id"]))
