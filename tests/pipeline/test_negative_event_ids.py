"""Issue 13 case 10: negative event ids are legitimate. A run on events with ids shifted to
negative (and across zero) gives the same tables and pattern metrics as the same events
with ids 0, 1, …; before the fix every track of a negative event was a ghost."""

import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from pkf.cli import main
from pkf.io.reader import read_table
from pkf.io.schemas import CANDIDATES, CHI2, PULLS, STATES
from pkf.pipeline.inputs import particle_key

SCHEMAS = {"candidates": CANDIDATES, "chi2": CHI2, "states": STATES, "pulls": PULLS}


def test_particle_keys_are_positive_and_unique_for_any_event_id():
    events = np.repeat(np.array([-(1 << 38), -3, -2, -1, 0, 1, 2, (1 << 38) - 1]), 3)
    particles = np.tile(np.array([1, 2, (1 << 24) - 1]), 8)
    keys = particle_key(events, particles)
    assert np.all(keys > 0)
    assert np.unique(keys).size == keys.size
    assert np.array_equal(keys % (1 << 24), particles)
    assert np.all(particle_key(events, np.zeros_like(particles)) == 0)  # noise


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("data") / "gun"
    assert main(["simulate", "--out", str(out), "--generator", "gun", "--events", "6", "--particles", "15",
                 "--seed", "13"]) == 0
    return out


def _shifted(dataset, out, offset):
    shutil.copytree(dataset, out)
    for name in ("hits", "particles", "mc_hits"):
        table = pq.read_table(dataset / f"{name}.parquet")
        i = table.column_names.index("event_id")
        shifted = pc.add(table.column("event_id"), pa.scalar(offset, pa.int64()))
        pq.write_table(table.set_column(i, table.field(i), shifted), out / f"{name}.parquet")
    return out


def _run(dataset, out):
    """The matching (where negative ids broke) does not depend on the pattern: truth is the fastest."""
    assert main(["reconstruct", str(dataset), "--out", str(out), "--pattern", "truth", "--fitter", "parametrized",
                 "--workers", "1", "--events-per-batch", "2"]) == 0
    return out


@pytest.fixture(scope="module")
def reference(dataset, tmp_path_factory):
    return _run(dataset, tmp_path_factory.mktemp("runs") / "run")


@pytest.mark.parametrize("offset", [-100, -3])  # all negative; across zero
def test_negative_event_ids_give_the_same_run(dataset, reference, tmp_path, offset):
    shifted = _run(_shifted(dataset, tmp_path / "shifted", offset), tmp_path / "run_shifted")
    pattern = json.loads((reference / "run.json").read_text())["pattern"]
    assert pattern["ghost_rate"] < 0.05 and pattern["efficiency"] > 0.9
    assert json.loads((shifted / "run.json").read_text())["pattern"] == pattern
    for name, schema in SCHEMAS.items():
        a, b = read_table(reference, schema, name=name), read_table(shifted, schema, name=name)
        assert a.num_rows == b.num_rows > 0, name
        for col in schema.names:
            x = a.column(col).to_numpy(zero_copy_only=False)
            y = b.column(col).to_numpy(zero_copy_only=False)
            if col == "event_id":
                y = y - offset
            if x.dtype.kind == "f":
                assert np.array_equal(x, y, equal_nan=True), (name, col)
            else:
                assert np.array_equal(x, y), (name, col)
