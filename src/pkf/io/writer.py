"""Streaming Parquet writer: one table written batch by batch, deterministically.

Used by stages that produce more rows than should sit in memory at once. The file
goes to a hidden temporary name and is renamed to its final name by `close()`; meant
to be used inside `staged_output_dir`, which makes the whole output atomic.
"""

from __future__ import annotations

import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from pkf.io.atomic import parquet_write_options


class StreamingTableWriter:
    """Append tables of one schema to a Parquet file; each `write` is one row group.

    The same sequence of batches gives byte-identical files. The file appears under
    its final name only when `close()` succeeds.
    """

    def __init__(self, path: str | os.PathLike, schema: pa.Schema):
        self.path = Path(path)
        self.schema = schema
        self._tmp = self.path.with_name(f".{self.path.name}.partial")
        options = {k: v for k, v in parquet_write_options(schema).items() if k != "row_group_size"}
        self._writer = pq.ParquetWriter(self._tmp, schema, **options)
        self.rows = 0

    def write(self, table: pa.Table) -> None:
        """Append `table` (cast to the schema, columns in schema order)."""
        table = table.select(self.schema.names).cast(self.schema).combine_chunks()
        self._writer.write_table(table, row_group_size=max(table.num_rows, 1))
        self.rows += table.num_rows

    def close(self) -> Path:
        """Finish the file and move it to its final name."""
        self._writer.close()
        os.replace(self._tmp, self.path)
        return self.path
