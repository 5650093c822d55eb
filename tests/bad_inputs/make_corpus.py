"""Write the corpus of bad inputs (DESIGN §13) beside this file: one dataset directory per case.

Run `python tests/bad_inputs/make_corpus.py` to regenerate it. Every case derives from a
tiny valid dataset (3 gun events, 2 particles each, lhcb-like geometry) by one defect,
and `cases.json` records what the one-line error must name: the file (relative to the
case directory), the column and the first bad row (0-based within that file), or null
where the defect has no column or row (a file that is not Parquet at all).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

HERE = Path(__file__).resolve().parent


def _base(tmp: Path) -> Path:
    from pkf.pipeline.simulate import SimulationConfig, run_simulation

    out = tmp / "base"
    run_simulation(SimulationConfig(generator="gun", events=3, particles=2, seed=5), out, progress=False)
    return out


def _write(case: str, base: Path, tables: dict, params: dict | None = None, geometry: dict | None = None) -> Path:
    """Case directory with meta.json of the base and the given tables (name → Table, bytes or dir);
    ``geometry`` replaces meta.json's geometry record."""
    d = HERE / case
    if d.exists():
        shutil.rmtree(d)
    d.mkdir()
    meta = json.loads((base / "meta.json").read_text())
    meta["geometry"].pop("file", None)  # the built-in lhcb-like geometry, by name and hash
    if geometry is not None:
        meta["geometry"] = geometry
    (d / "meta.json").write_text(json.dumps(meta, indent=1, sort_keys=True) + "\n")
    for name, value in tables.items():
        path = d / name
        if isinstance(value, str):
            path.write_text(value)
        elif isinstance(value, bytes):
            path.write_bytes(value)
        elif isinstance(value, list):  # a table directory of several files
            path.mkdir()
            for i, part in enumerate(value):
                pq.write_table(part, path / f"part-{i}.parquet")
        else:
            pq.write_table(value, path)
    if params is not None:
        (d / "params.json").write_text(json.dumps(params))
    return d


def _set(table: pa.Table, column: str, row: int, value) -> pa.Table:
    values = table.column(column).to_pylist()
    values[row] = value
    i = table.column_names.index(column)
    field = table.field(i).with_nullable(True)  # as another program might write it
    return table.set_column(i, field, pa.array(values, type=field.type))


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        base = _base(Path(tmp))
        hits = pq.read_table(base / "hits.parquet")
        mc_hits = pq.read_table(base / "mc_hits.parquet")
        particles = pq.read_table(base / "particles.parquet")
        strip_row = int(np.flatnonzero(pa.compute.is_null(hits.column("v")).to_numpy(zero_copy_only=False))[0])
        n = hits.num_rows
        cases = {}

        def add(case, tables, file, column, row, args=(), params=None, geometry=None):
            _write(case, base, tables, params, geometry)
            cases[case] = {"file": file, "column": column, "row": row, "args": list(args)}

        add("missing_column", {"hits.parquet": hits.drop_columns(["sigma_u"])}, "hits.parquet", "sigma_u", None)
        # issue 16: extra columns are ignored with one warning line; a valid dataset, not a case of cases.json
        _write("extra_column", base, {"hits.parquet": hits.append_column("charge", pa.array(np.ones(n, np.int8)))})
        add("wrong_dtype", {"hits.parquet": hits.set_column(4, "u", pa.array([str(x) for x in hits.column("u").to_pylist()]))},
            "hits.parquet", "u", None)
        add("nan_value", {"hits.parquet": _set(hits, "u", 17, float("nan"))}, "hits.parquet", "u", 17)
        add("inf_value", {"hits.parquet": _set(hits, "sigma_u", 23, float("inf"))}, "hits.parquet", "sigma_u", 23)
        add("negative_error", {"hits.parquet": _set(hits, "sigma_u", 29, -0.01)}, "hits.parquet", "sigma_u", 29)
        add("null_value", {"hits.parquet": _set(hits, "hit_id", 31, None)}, "hits.parquet", "hit_id", 31)
        add("unknown_layer", {"hits.parquet": _set(hits, "layer", 11, 99)}, "hits.parquet", "layer", 11)
        add("wrong_layer_z", {"hits.parquet": _set(hits, "z", 13, 12345.0)}, "hits.parquet", "z", 13)
        strip_v = _set(_set(hits, "v", strip_row, 1.0), "sigma_v", strip_row, 0.01)
        add("strip_with_v", {"hits.parquet": strip_v}, "hits.parquet", "v", strip_row)
        dup = _set(hits, "hit_id", 41, hits.column("hit_id")[40].as_py())
        add("duplicate_hit", {"hits.parquet": dup}, "hits.parquet", "hit_id", 41)
        ev = hits.column("event_id").to_numpy()
        first1 = int(np.flatnonzero(ev == 1)[0])
        swapped = pa.concat_tables([hits.filter(pa.compute.equal(hits.column("event_id"), 1)),
                                    hits.filter(pa.compute.not_equal(hits.column("event_id"), 1))])
        n1 = int(np.sum(ev == 1))
        add("unsorted_events", {"hits.parquet": swapped}, "hits.parquet", "event_id", n1)
        add("empty_dataset", {"hits.parquet": hits.slice(0, 0)}, "hits.parquet", None, None)
        data = (base / "hits.parquet").read_bytes()
        add("truncated_file", {"hits.parquet": data[: len(data) // 2]}, "hits.parquet", None, None)
        add("not_parquet", {"hits.parquet": b"event_id,hit_id,layer\n0,1,2\n"}, "hits.parquet", None, None)
        add("empty_file", {"hits.parquet": b""}, "hits.parquet", None, None)
        # a table directory: the bad row is in the second file, counted within that file
        parts = [hits.slice(0, first1), _set(hits.slice(first1), "u", 5, float("nan"))]
        add("bad_row_in_second_file", {"hits": parts}, "hits/part-1.parquet", "u", 5)
        # MC truth that does not match the hits
        bad_mc = _set(mc_hits, "hit_id", 7, 10**9)
        add("mc_hit_without_hit", {"hits.parquet": hits, "mc_hits.parquet": bad_mc, "particles.parquet": particles},
            "mc_hits.parquet", "hit_id", 7)
        # a parameter file tuned for another geometry
        from pkf.geometry import load_geometry
        from pkf.params.parameter_set import shipped_parameters

        params = shipped_parameters(load_geometry("lhcb-like")).to_json_dict()
        params["ut_to_scifi"] = None  # keeps the file small; the geometry check comes first
        params["geometry"] = {"name": "telescope", "hash": load_geometry("telescope").content_hash}
        add("params_other_geometry", {"hits.parquet": hits}, "params.json", None, None,
            args=["--params", "{case}/params.json"], params=params)
        add_issue_13_cases(add, hits, mc_hits, particles, params)
        add_issue_16_cases(add, hits, mc_hits, particles)
        (HERE / "cases.json").write_text(json.dumps(cases, indent=1, sort_keys=True) + "\n")


def add_issue_13_cases(add, hits: pa.Table, mc_hits: pa.Table, particles: pa.Table, params: dict) -> None:
    """Cases of issue 13: values out of their physical range, incomplete MC truth, broken
    geometry and parameter files."""
    from pkf.geometry import load_geometry

    layer = hits.column("layer").to_numpy()
    v_null = pa.compute.is_null(hits.column("v")).to_numpy(zero_copy_only=False)
    velo_row = int(np.flatnonzero((layer < 52) & ~v_null)[7])
    strip_row = int(np.flatnonzero(v_null)[3])
    # measurement errors out of range (case 4): 1e-300 mm overflowed 1/σ² in the pattern
    add("sigma_too_small", {"hits.parquet": _set(hits, "sigma_u", 19, 1e-300)}, "hits.parquet", "sigma_u", 19)
    add("sigma_larger_than_layer", {"hits.parquet": _set(hits, "sigma_v", velo_row, 500.0)},
        "hits.parquet", "sigma_v", velo_row)
    # hits far outside their layer's active area (case 13)
    add("hit_outside_area", {"hits.parquet": _set(hits, "u", velo_row, 1e5)}, "hits.parquet", "u", velo_row)
    add("hit_at_1e300", {"hits.parquet": _set(hits, "u", strip_row, 1e300)}, "hits.parquet", "u", strip_row)
    in_hole = _set(_set(hits, "u", velo_row, 0.5), "v", velo_row, -0.5)
    add("hit_in_beam_hole", {"hits.parquet": in_hole}, "hits.parquet", "u", velo_row)
    # MC truth: one table without the other (case 5), hits without truth (case 15)
    add("mc_hits_without_particles", {"hits.parquet": hits, "mc_hits.parquet": mc_hits},
        "particles.parquet", None, None)
    add("particles_without_mc_hits", {"hits.parquet": hits, "particles.parquet": particles},
        "mc_hits.parquet", None, None)
    hit_of_mc = {(e, h): i for i, (e, h) in enumerate(zip(hits.column("event_id").to_pylist(),
                                                          hits.column("hit_id").to_pylist()))}
    dropped = mc_hits.slice(0, 100).to_pylist()
    first_without = min(hit_of_mc[(r["event_id"], r["hit_id"])] for r in dropped)
    add("hits_without_truth", {"hits.parquet": hits, "mc_hits.parquet": mc_hits.slice(100),
                               "particles.parquet": particles}, "hits.parquet", "hit_id", first_without)
    # a particle without momentum (case 14)
    zero_p = _set(_set(_set(particles, "px", 3, 0.0), "py", 3, 0.0), "pz", 3, 0.0)
    add("zero_momentum", {"hits.parquet": hits, "mc_hits.parquet": mc_hits, "particles.parquet": zero_p},
        "particles.parquet", "px", 3)
    # ids the MC matching cannot key (case 10's encoding): particle_id ≥ 2^24
    big = 1 << 24
    pid = particles.column("particle_id")[2].as_py()
    big_id = _set(particles, "particle_id", 2, big)
    mc_pid = [big if p == pid and e == particles.column("event_id")[2].as_py() else p
              for p, e in zip(mc_hits.column("particle_id").to_pylist(), mc_hits.column("event_id").to_pylist())]
    big_mc = mc_hits.set_column(2, "particle_id", pa.array(mc_pid, pa.int64()))
    add("particle_id_too_large", {"hits.parquet": hits, "mc_hits.parquet": big_mc, "particles.parquet": big_id},
        "particles.parquet", "particle_id", 2)
    # geometry files (cases 6, 16)
    lhcb = load_geometry("lhcb-like")
    custom = lhcb.text.replace('name = "lhcb-like"', 'name = "lhcb-scifi100"')
    add("geometry_toml_missing", {"hits.parquet": hits},
        "geometry.toml", None, None, geometry={"name": "lhcb-scifi100", "file": "geometry.toml"})
    add("geometry_string_number", {"hits.parquet": hits, "geometry.toml": custom.replace("sigma = 0.055", 'sigma = "fine"')},
        "geometry.toml", None, None, geometry={"name": "lhcb-scifi100", "file": "geometry.toml"})
    # parameter files with bad coefficients (case 11); no UT→SciFi table: the slots are checked first
    def params_with(change):
        bad = json.loads(json.dumps(params))
        bad["geometry"] = {"name": "lhcb-like", "hash": lhcb.content_hash}
        change(bad)
        return bad

    args = ["--params", "{case}/params.json"]
    add("params_nan_coefficient", {"hits.parquet": hits}, "params.json", None, None, args=args,
        params=params_with(lambda p: p["slots"][60]["extrapolation"].__setitem__(2, float("nan"))))
    add("params_missing_slots", {"hits.parquet": hits}, "params.json", None, None, args=args,
        params=params_with(lambda p: p.__setitem__("slots", p["slots"][:10])))
    add("params_short_coefficients", {"hits.parquet": hits}, "params.json", None, None, args=args,
        params=params_with(lambda p: p["slots"][60].__setitem__("extrapolation", p["slots"][60]["extrapolation"][:5])))


def add_issue_16_cases(add, hits: pa.Table, mc_hits: pa.Table, particles: pa.Table) -> None:
    """Issue 16: missing truth is accepted on noise rows of mc_hits (particle_id 0) only."""
    particle_rows = np.flatnonzero(mc_hits.column("particle_id").to_numpy() != 0)
    tables = {"hits.parquet": hits, "particles.parquet": particles}
    row = int(particle_rows[11])
    add("null_truth_on_particle_row", tables | {"mc_hits.parquet": _set(mc_hits, "tx", row, None)},
        "mc_hits.parquet", "tx", row)
    row = int(particle_rows[13])
    add("nan_truth_on_particle_row", tables | {"mc_hits.parquet": _set(mc_hits, "qop", row, float("nan"))},
        "mc_hits.parquet", "qop", row)


if __name__ == "__main__":
    main()
