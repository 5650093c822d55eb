"""Run-table rows gathered as numpy columns, built into Arrow tables once per partition.

A partition is reconstructed in groups of a few events (`pkf.pipeline.executor.PROGRESS_HITS`),
and each group gives a few blocks of rows per run table (one per fitter and location).
Building an Arrow table per block and sorting each group's tables by their string
columns cost more than the numpy work behind the rows: on 1,000 minimum-bias events at
ν = 7.6 (parametrized fitter, 239 groups, 20 partitions) `table_from_columns` took 1.7 s
and the sorts 0.7 s of CPU. Here a block is a dict of numpy columns; string columns are
:class:`Coded` (codes into a few names); :meth:`RowBlocks.table` concatenates the blocks of
a table, orders the rows by integer keys (a string key by the rank of its names: the
byte order Arrow sorts strings in) and builds the table once. The sort is stable, as
Arrow's, so a table built from any split of the same blocks into groups is the same.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from pkf.io.schemas import table_from_columns

__all__ = ["Coded", "RowBlocks"]


@dataclass(frozen=True)
class Coded:
    """A column of strings ``names[codes]``: codes (any integer dtype) into a few names."""

    names: tuple[str, ...]
    codes: np.ndarray

    @classmethod
    def repeat(cls, name: str, n: int) -> Coded:
        """``name`` on each of ``n`` rows."""
        return cls((name,), np.zeros(n, np.int8))

    def __len__(self) -> int:
        return len(self.codes)


def _concat_coded(parts: Sequence[Coded]) -> Coded:
    """One :class:`Coded` of the rows of ``parts`` (names in order of first appearance)."""
    names = list(dict.fromkeys(name for part in parts for name in part.names))
    index = {name: i for i, name in enumerate(names)}
    codes = [np.array([index[n] for n in part.names], dtype=np.int32)[part.codes] for part in parts]
    return Coded(tuple(names), np.concatenate(codes) if len(codes) > 1 else codes[0])


def _concat(parts: list) -> np.ndarray | Coded:
    if isinstance(parts[0], Coded):
        return _concat_coded(parts)
    return np.concatenate(parts) if len(parts) > 1 else parts[0]


def _sort_key(values: np.ndarray | Coded) -> np.ndarray:
    """Integers in the order of ``values`` (strings: their byte order, as Arrow sorts them)."""
    if not isinstance(values, Coded):
        return values
    rank = np.empty(len(values.names), np.int64)
    rank[sorted(range(len(values.names)), key=lambda i: values.names[i].encode())] = np.arange(len(values.names))
    return rank[values.codes]


def _take(values: np.ndarray | Coded, order: np.ndarray | None):
    if order is None:
        return values
    if isinstance(values, Coded):
        return Coded(values.names, values.codes[order])
    return values[order]


def _arrow(values: np.ndarray | Coded, field: pa.Field):
    """Numpy columns as they are (`table_from_columns` converts them), Coded as Arrow strings."""
    if not isinstance(values, Coded):
        return values
    return pa.array(values.names, type=field.type).take(pa.array(values.codes))


class RowBlocks:
    """Blocks of rows per run table, in the order they were added."""

    def __init__(self) -> None:
        self.blocks: dict[str, list[dict]] = {}

    def add(self, table: str, columns: dict) -> None:
        """Add a block: column name → numpy array or :class:`Coded` (a str: the same on every row)."""
        n = next(len(v) for v in columns.values() if not isinstance(v, str))
        self.blocks.setdefault(table, []).append(
            {k: Coded.repeat(v, n) if isinstance(v, str) else v for k, v in columns.items()})

    def extend(self, other: RowBlocks) -> None:
        """Add the blocks of ``other`` after these."""
        for table, blocks in other.blocks.items():
            self.blocks.setdefault(table, []).extend(blocks)

    def table(self, name: str, schema: pa.Schema, sort_keys: Sequence[str] = ()) -> pa.Table:
        """The table ``name`` (``schema``): its blocks concatenated, then ordered by those of
        ``sort_keys`` that it has (stable); an empty table if it has no blocks."""
        blocks = self.blocks.get(name)
        if not blocks:
            return schema.empty_table()
        columns = {c: _concat([b[c] for b in blocks]) for c in schema.names}
        keys = [_sort_key(columns[k]) for k in sort_keys if k in columns]
        order = np.lexsort(keys[::-1]) if keys else None  # lexsort: the last key is the primary one
        return table_from_columns(schema, {c: _arrow(_take(v, order), schema.field(c)) for c, v in columns.items()})
