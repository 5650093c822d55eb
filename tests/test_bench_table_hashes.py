"""benchmarks/table_hashes.py's value-by-value comparison of two runs' tables (``--against``)."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from bench_helpers import load_benchmark


def _table_dir(path, rows):
    path.mkdir(parents=True)
    order = np.arange(len(rows["event_id"]))[::-1]  # written out of order: the comparison sorts by the keys
    table = pa.table({key: np.asarray(values)[order] for key, values in rows.items()})
    pq.write_table(table, path / "part-0.parquet")
    return path


def test_value_differences_reports_relative_and_rms_differences_and_refuses_other_rows(tmp_path):
    th = load_benchmark("table_hashes")
    rows = {"event_id": [0, 0, 1], "track_id": [0, 1, 0], "chi2": [10.0, 20.0, 30.0], "x": [1e-3, 2.0, -3.0]}
    a = _table_dir(tmp_path / "a", rows)
    same = _table_dir(tmp_path / "same", rows)
    assert th.value_differences(a, same) == (None, [])
    nudged = dict(rows, x=[1e-3 + 1e-15, 2.0, -3.0])
    reason, columns = th.value_differences(a, _table_dir(tmp_path / "nudged", nudged))
    assert reason is None and [c[0] for c in columns] == ["x"]
    _, relative, in_rms = columns[0]
    delta = nudged["x"][0] - rows["x"][0]  # 1e-15 as rounded
    rms = np.sqrt(np.mean(np.square(rows["x"])))
    np.testing.assert_allclose(relative, delta / nudged["x"][0], rtol=1e-12)
    np.testing.assert_allclose(in_rms, delta / rms, rtol=1e-12)
    other_track = dict(rows, track_id=[0, 2, 0])
    reason, _ = th.value_differences(a, _table_dir(tmp_path / "other", other_track))
    assert reason == "column track_id differs"
    reason, _ = th.value_differences(a, _table_dir(tmp_path / "short", {k: v[:2] for k, v in rows.items()}))
    assert reason.startswith("3 vs 2 rows")
