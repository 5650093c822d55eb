"""`benchmarks/forward_ut_stage.py`: its compiled loop runs step 1 of the forward extension as
the kernel does (the UT leaves of the search, the candidates of their refits), and the script
writes its table."""

import json

import pytest
from bench_helpers import load_benchmark


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("forward_ut_stage")


def test_the_ut_stage_parts_find_what_step_1_finds(bench):
    from pkf.geometry import load_geometry
    from pkf.params.parameter_set import shipped_parameters

    geometry = load_geometry("lhcb-like")
    ext = shipped_parameters(geometry).extrapolator(geometry)
    stage = bench.Stage(geometry, ext, bench._sample(geometry, 3, 1.0, 7)["h"])
    leaves = bench._ut_parts(*stage.args, 2)
    candidates = bench._ut_parts(*stage.args, 3)
    # most VELO tracks of minimum bias cross the UT: a search without its start (or with the
    # wrong rules) finds none; the refits and the χ² cut only remove leaves
    assert stage.n_tracks > 100
    assert 0.7 * stage.n_tracks < candidates <= leaves <= 2 * stage.n_tracks


def test_the_script_writes_its_table(bench, tmp_path, monkeypatch):
    out = tmp_path / "ut.json"
    monkeypatch.setattr("sys.argv", ["forward_ut_stage.py", "--pileups", "1", "--events", "2", "--repeat", "1",
                                     "--json", str(out)])
    bench.main()
    result = json.loads(out.read_text())
    (row,) = result["rows"]
    us = row["cpu_us_per_velo_track"]
    assert set(us) == {*bench.PARTS, "forward"} and row["velo_tracks_per_event"] > 30
    assert all(v > 0 for v in us.values())
