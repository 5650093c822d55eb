"""`pkf reconstruct --track-states` (issue 14.5): the track_states table of docs/formats.md,
written per partition beside the other tables, which it leaves byte-identical."""

import numpy as np
import pyarrow.compute as pc
import pytest

from pkf.cli import main
from pkf.io.reader import read_table
from pkf.io.schemas import COV_COLUMNS, STATE_COLUMNS, STATES, TRACK_STATES
from pkf.io.stream import file_sha256

FITTERS = ("parametrized", "reference", "gx2f", "gsf")
ARGS = ["--pattern", "truth", "--workers", "1", "--events-per-batch", "6",
        *[a for f in FITTERS for a in ("--fitter", f)]]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A pion gun reconstructed by every fitter without and with --track-states."""
    root = tmp_path_factory.mktemp("track_states")
    data = root / "gun"
    assert main(["simulate", "--out", str(data), "--generator", "gun", "--events", "12", "--seed", "6"]) == 0
    assert main(["reconstruct", str(data), "--out", str(root / "plain"), *ARGS]) == 0
    assert main(["reconstruct", str(data), "--out", str(root / "with"), "--track-states", *ARGS]) == 0
    return root / "plain", root / "with"


def files(run):
    return {p.relative_to(run).as_posix(): file_sha256(p) for p in sorted(run.glob("*/part-*.parquet"))}


def test_other_tables_are_byte_identical_and_no_table_without_the_option(runs):
    plain, with_states = runs
    assert not (plain / "track_states").exists()
    before, after = files(plain), files(with_states)
    states_files = {k for k in after if k.startswith("track_states/")}
    assert len(states_files) == 2  # one per partition, like the other tables
    assert {k: v for k, v in after.items() if k not in states_files} == before


def table(run, name="track_states", schema=TRACK_STATES):
    return read_table(run, schema, name=name)


def column(t, name):
    return t.column(name).to_numpy(zero_copy_only=False)


def test_rows_stages_and_unique_key(runs):
    t = table(runs[1])
    stages = {f: set(column(t.filter(pc.equal(t["fitter"], f)), "stage")) for f in FITTERS}
    assert stages["gx2f"] == {"smoothed"}
    assert all(stages[f] == {"predicted", "filtered", "smoothed"} for f in ("parametrized", "reference", "gsf"))
    key = np.rec.fromarrays([column(t, c) for c in ("event_id", "track_id", "fitter", "node", "stage")])
    assert np.unique(key).size == t.num_rows
    assert np.all(np.diff(column(t, "event_id")) >= 0)
    strip = np.isnan(column(t, "res_v"))
    assert np.array_equal(strip, np.isnan(column(t, "var_res_v")))
    assert 0 < strip.sum() < t.num_rows  # UT and SciFi strips, VELO pixels


def test_smoothed_first_node_is_the_first_hit_state(runs):
    t = table(runs[1])
    first = t.filter(pc.and_(pc.equal(t["stage"], "smoothed"), pc.equal(t["node"], 0)))
    states = table(runs[1], "states", STATES)
    first_hit = states.filter(pc.equal(states["location"], "first_hit"))
    joined = first_hit.join(first, ["event_id", "track_id", "fitter"], right_suffix="_node")
    for fitter in ("parametrized", "reference", "gx2f"):
        rows = joined.filter(pc.equal(joined["fitter"], fitter))
        assert rows.num_rows == pc.sum(pc.equal(first_hit["fitter"], fitter)).as_py() > 50
        for c in ("z", *STATE_COLUMNS, *COV_COLUMNS):
            assert np.array_equal(column(rows, c), column(rows, f"{c}_node")), (fitter, c)


def test_an_outlier_row_has_filtered_equal_to_predicted(runs):
    t = table(runs[1])
    outliers = t.filter(t["is_outlier"])
    for fitter in ("parametrized", "reference", "gsf"):
        rows = outliers.filter(pc.equal(outliers["fitter"], fitter))
        predicted = rows.filter(pc.equal(rows["stage"], "predicted"))
        filtered = rows.filter(pc.equal(rows["stage"], "filtered"))
        assert predicted.num_rows == filtered.num_rows > 0, fitter
        for c in (*STATE_COLUMNS, *COV_COLUMNS, "res_u", "var_res_u", "chi2"):
            assert np.array_equal(column(predicted, c), column(filtered, c), equal_nan=True), (fitter, c)


def test_smoothed_residual_variance_is_positive_for_active_nodes(runs):
    t = table(runs[1])
    rows = t.filter(pc.and_(pc.equal(t["stage"], "smoothed"), pc.invert(t["is_outlier"])))
    for c in ("var_res_u", "var_res_v"):
        var = column(rows, c)
        assert np.all(var[~np.isnan(var)] > 0), c
