"""Issue 13, checks at the reader: errors and positions of hits against their layers' areas,
incomplete MC truth, hits without truth, particles without momentum, id ranges the MC
matching needs. Each message is one line naming the file, the column and the first bad row."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pyarrow as pa
import pytest
from io_helpers import LAYER_KIND, LAYER_Z, make_tables, raises_input_error, replace_column, write_dataset

from pkf.io import HITS, PARTICLES, open_dataset, read_table, validate_consistency
from pkf.io.reader import AREA_MARGIN_MM, AREA_TOLERANCE_SIGMAS, LayerArea, pair_keys, validate_hit_layers

#: Toy areas of the io_helpers layers: two pixel layers (the second covers only u ≤ 2, like
#: a VELO module's side), then two strip layers.
AREA = LayerArea(
    u_min=np.array([-10.0, -10.0, -12.0, -12.0]), u_max=np.array([10.0, 2.0, 12.0, 12.0]),
    v_min=np.array([-10.0, -10.0, np.nan, np.nan]), v_max=np.array([10.0, 10.0, np.nan, np.nan]),
    hole_radius=np.zeros(4), hole_half_u=np.zeros(4), hole_half_v=np.zeros(4),
)


def _set_rows(hits, column, rows, values):
    """``hits`` with ``column`` set at ``rows`` (null stays null in v, sigma_v)."""
    array = hits.column(column).to_numpy(zero_copy_only=False).copy()
    array[rows] = values
    i = hits.schema.get_field_index(column)
    return hits.set_column(i, hits.field(i), pa.array(array, type=pa.float64(), from_pandas=hits.field(i).nullable))


def _hits_with(**changes):
    hits = make_tables()["hits"]
    for column, (row, value) in changes.items():
        hits = _set_rows(hits, column, row, value)
    return hits


def _check(hits, area=AREA):
    validate_hit_layers(hits, LAYER_Z, LAYER_KIND, area=area, source="hits.parquet")


def _outside(sigma: float, n_sigma: float) -> float:
    """A distance [mm] outside an area edge: n_sigma of σ plus the margin."""
    return n_sigma * sigma + AREA_MARGIN_MM


def test_the_tables_of_the_helpers_are_inside():
    _check(make_tables()["hits"])


def test_hits_within_the_tolerance_pass_and_beyond_fail():
    # row 1: layer 1 (pixel, u ≤ 2 mm, σ 0.0125 mm); row 2: layer 2 (strip, |u| ≤ 12 mm, σ 0.05 mm)
    inside = AREA_TOLERANCE_SIGMAS - 0.5
    beyond = AREA_TOLERANCE_SIGMAS + 0.5
    _check(_hits_with(u=(1, 2.0 + _outside(0.0125, inside))))
    _check(_hits_with(u=(2, -12.0 - _outside(0.05, inside))))
    raises_input_error(lambda: _check(_hits_with(u=(1, 2.0 + _outside(0.0125, beyond)))),
                       "hits.parquet: column 'u': row 1 (event_id=0, hit_id=1, layer=1)",
                       "outside layer 1's active area [-10.0, 2.0] mm")
    raises_input_error(lambda: _check(_hits_with(u=(2, -12.0 - _outside(0.05, beyond)))),
                       "column 'u': row 2 (", "outside layer 2's active area")
    raises_input_error(lambda: _check(_hits_with(v=(4, 1e300))), "column 'v': row 4 (", "is 1e+300 mm")


def test_first_bad_row_over_all_columns():
    """The first bad row of all checks (as a streamed scan, batch by batch, finds it)."""
    raises_input_error(lambda: _check(_hits_with(v=(4, 50.0), u=(6, 50.0))), "column 'v': row 4 (")
    raises_input_error(lambda: _check(_hits_with(u=(6, 50.0), sigma_v=(9, 50.0))), "column 'u': row 6 (")
    raises_input_error(lambda: _check(_hits_with(u=(6, 50.0), sigma_u=(5, 50.0))), "column 'sigma_u': row 5 (")


@pytest.mark.parametrize("hole", ["round", "square"])
def test_hit_in_the_beam_hole(hole):
    sizes = np.array([0.0, 1.0, 0.0, 0.0])
    area = replace(AREA, hole_radius=sizes) if hole == "round" else replace(AREA, hole_half_u=sizes, hole_half_v=sizes)
    hits = make_tables()["hits"]
    hits = _set_rows(hits, "u", hits.column("layer").to_numpy() == 1, 1.5)  # beside the hole
    _check(hits, area)
    for u, v in ((0.3, -0.2), (-0.5, 0.4)):
        bad = _set_rows(_set_rows(hits, "u", 1, u), "v", 1, v)
        raises_input_error(lambda: _check(bad, area), "column 'u': row 1 (", "inside layer 1's beam hole")
    _check(_set_rows(_set_rows(hits, "u", 1, 0.95), "v", 1, 0.0), area)  # within the tolerance of the edge


def test_error_larger_than_the_layer():
    raises_input_error(lambda: _check(_hits_with(sigma_u=(2, 25.0))),
                       "column 'sigma_u': row 2 (", "larger than layer 2's extent (24.0 mm)")
    raises_input_error(lambda: _check(_hits_with(sigma_v=(0, 21.0))), "column 'sigma_v': row 0 (")
    _check(_hits_with(sigma_u=(2, 1.0)))


@pytest.mark.parametrize("value", [1e-300, 1e-7])
def test_error_below_a_nanometre(tmp_path, value):
    write_dataset(tmp_path, {"hits": _hits_with(sigma_u=(5, value))})
    raises_input_error(lambda: read_table(tmp_path, HITS, name="hits"),
                       "hits.parquet: column 'sigma_u': row 5 (event_id=0, hit_id=5)", ">= 1e-06")


@pytest.mark.parametrize("missing", ["particles", "mc_hits"])
def test_mc_truth_is_both_tables_or_neither(tmp_path, missing):
    tables = make_tables()
    del tables[missing]
    write_dataset(tmp_path / "ds", tables)
    raises_input_error(lambda: open_dataset(tmp_path / "ds"), f"{tmp_path / 'ds' / missing}.parquet: not found",
                       "MC truth needs both")


def test_hits_without_truth():
    tables = make_tables()
    mc = tables["mc_hits"]
    without = mc.filter(np.arange(mc.num_rows) != 11)  # event 1, hit 2
    raises_input_error(lambda: validate_consistency(tables["hits"], tables["particles"], without,
                                                    sources={"hits": "hits.parquet", "mc_hits": "mc_hits.parquet"}),
                       "hits.parquet: column 'hit_id': row 11 (event_id=1, hit_id=2) has no row in mc_hits.parquet")


@pytest.mark.parametrize("momentum", [0.0, 1e-200])  # 1e-200: p² underflows, p = 0
def test_particle_without_momentum(tmp_path, momentum):
    particles = make_tables()["particles"]
    for c in ("px", "py", "pz"):
        values = particles.column(c).to_numpy().copy()
        values[3] = momentum
        particles = replace_column(particles, c, values)
    write_dataset(tmp_path, {"particles": particles})
    raises_input_error(lambda: read_table(tmp_path, PARTICLES, name="particles"),
                       "particles.parquet: column 'px': row 3 (event_id=1, particle_id=2)", "of length 0")


def test_ids_the_matching_cannot_key(tmp_path):
    particles = make_tables()["particles"]
    pid = particles.column("particle_id").to_numpy().copy()
    pid[5] = 1 << 24
    write_dataset(tmp_path, {"particles": replace_column(particles, "particle_id", pid)})
    raises_input_error(lambda: read_table(tmp_path, PARTICLES, name="particles"),
                       "column 'particle_id': row 5 (", "must be <= 16777215")


def test_pair_keys_with_negative_ids():
    ev_a, id_a = np.array([-5, -5, -1, 0, 3]), np.array([-1, 2, 7, 7, 0])
    ev_b, id_b = np.array([-5, 0, 3, -1]), np.array([2, 7, 1, 7])
    ka, kb = pair_keys(ev_a, id_a, ev_b, id_b)
    assert np.isin(ka, kb).tolist() == [False, True, True, True, False]
    assert np.unique(ka).size == ka.size


def test_hit_truth_without_momentum(tmp_path):
    """q/p = 0 (infinite momentum) in mc_hits gave p_true = inf in the pulls."""
    from pkf.io import MC_HITS

    mc = make_tables()["mc_hits"]
    qop = mc.column("qop").to_numpy(zero_copy_only=False).copy()
    qop[5] = 0.0
    write_dataset(tmp_path, {"mc_hits": mc.set_column(8, mc.field(8), pa.array(qop, from_pandas=True))})
    raises_input_error(lambda: read_table(tmp_path, MC_HITS, name="mc_hits"),
                       "mc_hits.parquet: column 'qop': row 5 (event_id=0, hit_id=5) is 0.0, must not be 0")


def _with_garbage_under_nulls(rng, values, null, dtype):
    """An Arrow array of ``values`` with nulls where ``null``, random garbage in the values
    buffer under them (Arrow leaves those unspecified)."""
    values = np.array(values, dtype=dtype)
    values[null] = rng.normal(size=int(null.sum())) * 1e3 if dtype == np.float64 else rng.integers(0, 40, null.sum())
    arrow_type = pa.from_numpy_dtype(np.dtype(dtype))
    if not null.any():
        return pa.array(values, type=arrow_type)
    bitmap = np.packbits(~null, bitorder="little")
    return pa.Array.from_buffers(arrow_type, values.size, [pa.py_buffer(bitmap.tobytes()), pa.py_buffer(values.tobytes())],
                                 null_count=int(null.sum()))


def _split(rng, table):
    """The table in 1–4 record batches at random row boundaries, some of them slices."""
    cuts = np.sort(rng.integers(0, table.num_rows + 1, int(rng.integers(0, 4))))
    edges = [0, *cuts.tolist(), table.num_rows]
    return pa.Table.from_batches([b for lo, hi in zip(edges[:-1], edges[1:])
                                  for b in table.slice(lo, hi - lo).to_batches()], schema=table.schema)


def test_compiled_layer_checks_find_the_rows_of_the_numpy_form():
    """first_bad_layer_rows, reading the columns in place (nulls through the bitmaps, garbage
    under them, several record batches), against the numpy form it replaced (layer, z with NaN
    and nulls, v/sigma_v nulls)."""
    from pkf.io.area_kernel import first_bad_layer_rows, first_bad_rows

    rng = np.random.default_rng(13)
    layer_z, layer_kind = np.asarray(LAYER_Z, float), np.asarray(LAYER_KIND, np.int64)
    for trial in range(200):
        n = int(rng.integers(0, 60))
        layer = rng.integers(0, layer_z.size, n)
        z = layer_z[layer] + rng.choice([0.0, 0.0, 0.0, 5e-7, 2e-6, np.nan], n)
        layer[rng.random(n) < 0.02] = rng.choice([-1, layer_z.size, 99])
        layer_null = rng.random(n) < 0.02
        z_null = rng.random(n) < 0.02
        strip = layer_kind[np.clip(layer, 0, layer_z.size - 1)] == 1
        v_null = strip ^ (rng.random(n) < 0.02)
        sv_null = strip ^ (rng.random(n) < 0.02)
        layer_read = np.where(layer_null, -1, layer)
        z_read = np.where(z_null, np.nan, z)
        valid = (layer_read >= 0) & (layer_read < layer_z.size)
        index = np.where(valid, layer_read, 0)
        kind_strip = layer_kind[index] == 1
        expected = []
        for bad in (~valid, valid & ~(np.abs(z_read - layer_z[index]) <= 1e-6),
                    valid & (np.where(kind_strip, ~v_null, v_null) | np.where(kind_strip, ~sv_null, sv_null))):
            expected.append(int(np.argmax(bad)) if bad.any() else -1)
        table = pa.table({"layer": _with_garbage_under_nulls(rng, layer, layer_null, np.int16),
                          "z": _with_garbage_under_nulls(rng, z, z_null, np.float64),
                          "u": np.zeros(n), "sigma_u": np.ones(n),
                          "v": _with_garbage_under_nulls(rng, np.zeros(n), v_null, np.float64),
                          "sigma_v": _with_garbage_under_nulls(rng, np.ones(n), sv_null, np.float64)})
        first = first_bad_rows(_split(rng, table), first_bad_layer_rows, 3, layer_z, layer_kind, 1e-6)
        assert first.tolist() == expected, trial


def test_compiled_area_checks_read_nulls_as_nan():
    """first_bad_area_rows on columns read in place (nulls with garbage under them, several
    record batches) finds the rows it finds on the same columns converted to numpy with NaN for
    nulls and the layers widened, in one batch (the form it replaced)."""
    from pkf.io.area_kernel import AREA_CHECKS, first_bad_area_rows, first_bad_rows

    rng = np.random.default_rng(17)
    n_layers = 6
    bounds = [rng.uniform(-60.0, -20.0, n_layers), rng.uniform(20.0, 60.0, n_layers),
              rng.uniform(-60.0, -20.0, n_layers), rng.uniform(20.0, 60.0, n_layers),
              rng.choice([0.0, 5.0], n_layers), rng.choice([0.0, 4.0], n_layers), rng.choice([0.0, 4.0], n_layers)]
    found = np.zeros(len(AREA_CHECKS), int)
    for trial in range(300):
        n = int(rng.integers(0, 50))
        layer = rng.integers(-1, n_layers + 1, n)
        near_hole = rng.random(n) < 0.2
        u = np.where(near_hole, rng.normal(0.0, 3.0, n), rng.uniform(-80.0, 80.0, n))
        v = np.where(near_hole, rng.normal(0.0, 3.0, n), rng.uniform(-80.0, 80.0, n))
        sigma_u = rng.choice([0.01, 0.1, 500.0, np.nan], n, p=[0.6, 0.3, 0.05, 0.05])
        sigma_v = rng.choice([0.01, 0.1, 500.0], n, p=[0.6, 0.35, 0.05])
        nulls = {name: rng.random(n) < rate for name, rate in
                 (("layer", 0.03), ("u", 0.03), ("sigma_u", 0.03), ("v", 0.4), ("sigma_v", 0.4))}
        columns = {"layer": (layer, np.int16), "u": (u, np.float64), "sigma_u": (sigma_u, np.float64),
                   "v": (v, np.float64), "sigma_v": (sigma_v, np.float64)}
        in_place = pa.table({"z": np.zeros(n)} | {name: _with_garbage_under_nulls(rng, values, nulls[name], dtype)
                                                  for name, (values, dtype) in columns.items()})
        converted = pa.table({"z": np.zeros(n)} | {name: np.where(nulls[name], -1 if name == "layer" else np.nan,
                                                                   values).astype(np.int64 if name == "layer" else float)
                                                   for name, (values, _) in columns.items()})
        got = first_bad_rows(_split(rng, in_place), first_bad_area_rows, len(AREA_CHECKS), *bounds, 3.0, 0.1)
        expected = first_bad_rows(converted, first_bad_area_rows, len(AREA_CHECKS), *bounds, 3.0, 0.1)
        assert got.tolist() == expected.tolist(), trial
        found += expected >= 0
    assert np.all(found > 10), found  # every check finds rows
