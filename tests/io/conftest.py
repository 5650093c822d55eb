"""Fixtures for the pkf.io tests."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pytest
from io_helpers import make_tables

from pkf.io import atomic_write_json, atomic_write_table


@pytest.fixture
def tables() -> dict[str, pa.Table]:
    return make_tables()


@pytest.fixture
def dataset_dir(tmp_path: Path, tables) -> Path:
    ds = tmp_path / "ds"
    ds.mkdir()
    for name, table in tables.items():
        atomic_write_table(table, ds / f"{name}.parquet")
    atomic_write_json({"geometry": "toy", "seed": 1}, ds / "meta.json")
    return ds
