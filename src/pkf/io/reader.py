"""Validating readers of pkf datasets and run tables: every bad input becomes a one-line InputError.

A table ``NAME`` of a dataset (or run) directory ``DIR`` is either one Parquet file
``DIR/NAME.parquet`` or a directory ``DIR/NAME/`` of Parquet files with the same
schema (docs/formats.md). The reader checks, before any work is done (docs/cli.md#exit-codes-and-messages):
missing columns (extra ones are ignored, and listed), dtypes, nulls in non-nullable columns, NaN/inf in measured
values, errors below 1 nm, particles without momentum or with ids the MC matching
cannot key, sorting by ``event_id``, duplicate ids, empty hit tables, and truncated or
non-Parquet files. :func:`validate_hit_layers` checks hits against a geometry (layers,
z, and with a :class:`LayerArea` errors and positions against the layers' active
areas), :func:`find_truth_tables` that MC truth is both tables or neither, and
:func:`validate_consistency` the MC truth against the hits. Every message is one line
naming the file, the column and the first bad row over all checks of the table (so a
table read whole and the same table scanned batch by batch say the same), e.g.
``ds/hits.parquet: column 'u': row 17 (event_id=3, hit_id=5) is NaN``; row numbers are
0-based within the named file.

All checks are vectorised (numpy / pyarrow.compute): tables of 10^7 rows are fine.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from pkf.errors import InputError
from pkf.io.schemas import HITS, MC_HITS, PARTICLES, TableSpec, spec_for
from pkf.io.value_kernels import first_nonfinite, has_nan

__all__ = [
    "Dataset",
    "TableSource",
    "find_table",
    "read_table",
    "read_meta",
    "open_dataset",
    "check_dataset_dir",
    "validate_hit_layers",
    "validate_consistency",
    "validate_hit_area",
    "find_truth_tables",
    "extra_columns",
    "extra_columns_warning",
    "pair_keys",
    "LayerArea",
]

_MAGIC = b"PAR1"


# --------------------------------------------------------------------------- sources


@dataclass(frozen=True)
class TableSource:
    """Where the rows of a table were read from, to name file and row in error messages.

    Attributes:
        path: the table as found on disk (``DIR/NAME.parquet`` or ``DIR/NAME``).
        files: the Parquet files, in reading order.
        offsets: row index in the table of the first row of each file, plus the
            total number of rows (length ``len(files) + 1``).
    """

    path: Path
    files: tuple[Path, ...]
    offsets: tuple[int, ...]

    def locate(self, row: int) -> tuple[str, int]:
        """Return (file name for messages, 0-based row within that file) of a table row."""
        if len(self.files) <= 1:
            return str(self.files[0] if self.files else self.path), row
        k = int(np.searchsorted(np.asarray(self.offsets), row, side="right")) - 1
        k = min(max(k, 0), len(self.files) - 1)
        return str(self.files[k]), row - self.offsets[k]

    def __str__(self) -> str:
        return str(self.path)


Source = str | os.PathLike | TableSource


def _locate(source: Source, row: int) -> tuple[str, int]:
    if isinstance(source, TableSource):
        return source.locate(row)
    return os.fspath(source), row


def _one_line(text: object) -> str:
    lines = str(text).strip().splitlines()
    return lines[0].strip() if lines else type(text).__name__


def _format_value(value: object) -> str:
    if value is None:
        return "null"
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return repr(value)
    return str(value)


def _describe_row(table: pa.Table, row: int, key: Sequence[str]) -> str:
    parts = []
    for name in key:
        if name in table.column_names:
            try:
                value = table.column(name)[row].as_py()
            except (pa.ArrowException, ValueError, OverflowError):  # pragma: no cover - defensive
                continue
            parts.append(f"{name}={_format_value(value)}")
    return f" ({', '.join(parts)})" if parts else ""


def _row_error(source: Source, table: pa.Table, row: int, column: str, key: Sequence[str], problem: str) -> InputError:
    file, local = _locate(source, row)
    error = InputError(f"{file}: column {column!r}: row {local}{_describe_row(table, row, key)} {problem}")
    error.table_row = row  # for _raise_first
    return error


def _raise_first(checks: Sequence[Callable[[], None]]) -> None:
    """Run every check and raise the InputError of the earliest table row among those that
    failed (ties: the earlier check; an error without a row comes first).

    So a table checked in one piece and the same table checked batch by batch (the streamed
    scan) name the same first bad row, whichever checks the defects break.
    """
    first: tuple[int, InputError] | None = None
    for check in checks:
        try:
            check()
        except InputError as error:
            row = getattr(error, "table_row", -1)
            if first is None or row < first[0]:
                first = (row, error)
    if first is not None:
        raise first[1]


def _first_true(mask: pa.Array | pa.ChunkedArray | np.ndarray) -> int | None:
    """Index of the first True of a boolean mask (nulls count as False), or None."""
    if isinstance(mask, (pa.Array, pa.ChunkedArray)):
        if not pc.any(mask).as_py():  # none (nulls skipped): no conversion of the bit mask
            return None
        mask = pc.fill_null(mask, False).to_numpy(zero_copy_only=False)
    mask = np.asarray(mask, dtype=bool)
    if mask.size == 0:
        return None
    idx = int(np.argmax(mask))
    return idx if mask[idx] else None


def _default_key(table: pa.Table, spec: TableSpec | None) -> tuple[str, ...]:
    if spec is not None:
        return spec.unique_key
    return tuple(n for n in ("event_id", "hit_id") if n in table.column_names)


# --------------------------------------------------------------------------- files


def _natural_key(path: Path) -> list[object]:
    parts = re.split(r"(\d+)", path.as_posix())
    return [int(p) if i % 2 else p for i, p in enumerate(parts)]


def _list_parquet_files(directory: Path) -> list[Path]:
    """Files of a table directory, as pyarrow.dataset selects them (names starting
    with '.' or '_' are skipped, subdirectories are searched), in natural order."""
    found = []
    for root, dirs, files in os.walk(directory):
        dirs[:] = [d for d in dirs if not d.startswith((".", "_"))]
        for f in files:
            if not f.startswith((".", "_")):
                found.append(Path(root) / f)
    return sorted(found, key=lambda p: _natural_key(p.relative_to(directory)))


def find_table(path: str | os.PathLike, name: str) -> Path | None:
    """Locate table ``name`` in directory ``path``: ``path/NAME.parquet`` or ``path/NAME/``.

    ``path`` may also be the table itself (a Parquet file, or a directory named
    ``NAME`` or ``NAME.parquet`` that holds the part files).

    Returns:
        the table path, or None if the table does not exist.

    Raises:
        InputError: both ``NAME.parquet`` and ``NAME/`` exist.
    """
    path = Path(path)
    if path.is_file():
        return path
    as_file = path / f"{name}.parquet"
    as_dir = path / name
    if as_file.exists() and as_dir.exists():
        raise InputError(f"{path}: table {name!r} is ambiguous: both {as_file.name} and {as_dir.name}/ exist")
    if as_file.exists():
        return as_file
    if as_dir.is_dir():
        return as_dir
    if path.is_dir() and path.name in (name, f"{name}.parquet"):
        return path
    return None


def _castable(src: pa.DataType, dst: pa.DataType) -> bool:
    """Whether a column of type ``src`` may be converted to ``dst`` (values are checked later)."""
    if src.equals(dst) or pa.types.is_null(src):
        return True
    if pa.types.is_integer(dst):
        return pa.types.is_integer(src)
    if pa.types.is_floating(dst):
        return pa.types.is_floating(src) or pa.types.is_integer(src)
    if pa.types.is_string(dst):
        if pa.types.is_dictionary(src):
            src = src.value_type
        return pa.types.is_string(src) or pa.types.is_large_string(src) or pa.types.is_string_view(src)
    return False


def _check_magic(file: Path, shown: str) -> None:
    try:
        size = file.stat().st_size
        with open(file, "rb") as f:
            head = f.read(4)
            f.seek(max(size - 4, 0))
            tail = f.read(4)
    except OSError as exc:
        raise InputError(f"{shown}: cannot read file ({_one_line(exc.strerror or exc)})") from None
    if size == 0:
        raise InputError(f"{shown}: file is empty (0 bytes), not a Parquet file")
    if head != _MAGIC:
        raise InputError(f"{shown}: not a Parquet file (no 'PAR1' magic bytes at the start)")
    if size < 12 or tail != _MAGIC:
        raise InputError(f"{shown}: truncated Parquet file (no footer; was it written completely?)")


def extra_columns(file_schema: pa.Schema, schema: pa.Schema) -> list[str]:
    """Columns of a file that are not part of ``schema``: ignored by the readers (producers
    add columns such as times or cluster sizes), reported once per table as a warning."""
    return [n for n in file_schema.names if n not in schema.names]


def extra_columns_warning(location: object, table_name: str, names: Sequence[str]) -> str:
    """The one warning line about a table's ignored extra columns."""
    listed = ", ".join(repr(n) for n in names)
    plural = "s" if len(names) > 1 else ""
    return f"{location}: column{plural} {listed} not part of the {table_name} schema: ignored"


def open_checked(file: Path, schema: pa.Schema, table_name: str, **options) -> pq.ParquetFile:
    """Open one Parquet file after checking magic bytes, required column names and dtypes (not
    values); columns beyond ``schema`` are allowed (see :func:`extra_columns`).

    ``options`` go to ``pyarrow.parquet.ParquetFile``. The caller closes the returned file.
    Raises InputError (one line naming the file).
    """
    shown = str(file)
    _check_magic(file, shown)
    try:
        pf = pq.ParquetFile(file, **options)
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{shown}: corrupt or truncated Parquet file ({_one_line(exc)})") from None
    try:
        file_schema = pf.schema_arrow
        names = file_schema.names
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise InputError(f"{shown}: column {dupes[0]!r} appears more than once")
        missing = [n for n in schema.names if n not in names]
        if missing:
            more = f" (also missing: {', '.join(missing[1:])})" if len(missing) > 1 else ""
            raise InputError(f"{shown}: column {missing[0]!r} is missing{more}")
        for fld in schema:
            src = file_schema.field(fld.name).type
            if not _castable(src, fld.type):
                raise InputError(f"{shown}: column {fld.name!r}: wrong dtype {src}, expected {fld.type}")
    except BaseException:
        pf.close()
        raise
    return pf


def convert_to_schema(raw: pa.Table, schema: pa.Schema, source: Source, key: Sequence[str],
                      spec: TableSpec | None = None) -> pa.Table:
    """Convert a table read from a file to ``schema`` (integer widths checked value by value);
    NaN truth on noise rows becomes null (:func:`noise_truth_as_null`, with the rules ``spec``
    of the table, default: those of ``schema``).

    Raises InputError naming the file, column and first row whose value does not fit.
    """
    columns = []
    for fld in schema:
        col = raw.column(fld.name)
        src = col.type
        if not src.equals(fld.type):
            if pa.types.is_integer(fld.type) and pa.types.is_integer(src):
                info = np.iinfo(fld.type.to_pandas_dtype())
                values = pc.fill_null(col, 0).to_numpy()
                row = _first_true((values < info.min) | (values > info.max))
                if row is not None:
                    raise _row_error(
                        source, raw, row, fld.name, key, f"is {values[row]}, which does not fit in {fld.type}"
                    )
                col = col.cast(fld.type)
            elif pa.types.is_floating(fld.type):
                col = col.cast(fld.type, safe=False)
            else:
                col = col.cast(fld.type)
        columns.append(col)
    return noise_truth_as_null(pa.Table.from_arrays(columns, schema=schema), spec or spec_for(schema))


def noise_truth_as_null(table: pa.Table, spec: TableSpec | None) -> pa.Table:
    """The table with NaN replaced by null in the truth columns of noise rows (``spec.noise_truth``:
    rows whose particle column is 0); unchanged without such a rule or without those columns."""
    if spec is None or spec.noise_truth is None:
        return table
    columns, particle = spec.noise_truth
    if particle not in table.column_names or table.num_rows == 0:
        return table
    noise = None
    for name in columns:
        if name not in table.column_names:
            continue
        col = table.column(name)
        if not has_nan(col):  # no NaN at all (pkf simulate writes null): nothing to replace
            continue
        noise = pc.equal(table.column(particle), 0) if noise is None else noise
        nan = pc.fill_null(pc.and_(noise, pc.is_nan(col)), False)
        if pc.any(nan).as_py():
            i = table.column_names.index(name)
            table = table.set_column(i, table.field(i), pc.if_else(nan, pa.scalar(None, col.type), col))
    return table


def _read_file(file: Path, schema: pa.Schema, table_name: str, key: Sequence[str]) -> tuple[pa.Table, list[str]]:
    """Read one Parquet file and convert it to ``schema`` (columns, dtypes, integer ranges);
    also return the file's extra columns (not read)."""
    shown = str(file)
    pf = open_checked(file, schema, table_name)
    try:
        extra = extra_columns(pf.schema_arrow, schema)
        raw = pf.read(columns=schema.names, use_threads=True)
    except (pa.ArrowException, OSError) as exc:
        raise InputError(f"{shown}: corrupt or truncated Parquet file ({_one_line(exc)})") from None
    finally:
        pf.close()
    return convert_to_schema(raw, schema, shown, key), extra


def _read_with_source(path: str | os.PathLike, schema: pa.Schema, name: str,
                      check: Callable[[pa.Table, Source], None] | None = None
                      ) -> tuple[pa.Table, TableSource, tuple[str, ...]]:
    """Read, convert and validate a table; ``check(table, source)`` is an extra check whose
    problems compete with the value rules for the first bad row. Also returns the extra
    columns of its files (ignored), in order of first appearance."""
    spec = spec_for(schema)
    key = spec.unique_key if spec is not None else tuple(n for n in ("event_id", "hit_id") if n in schema.names)
    location = find_table(path, name)
    if location is None:
        raise InputError(f"{os.fspath(path)}: table {name!r} not found (expected {name}.parquet or {name}/)")
    if location.is_dir():
        files = _list_parquet_files(location)
        if not files and spec is not None and not spec.allow_empty:
            raise InputError(f"{location}: directory contains no Parquet files ({name} must not be empty)")
    else:
        files = [location]
    read = [_read_file(f, schema, name, key) for f in files]
    tables = [table for table, _ in read]
    ignored = tuple(dict.fromkeys(n for _, extra in read for n in extra))
    offsets = tuple(int(x) for x in np.cumsum([0] + [t.num_rows for t in tables]))
    source = TableSource(location, tuple(files), offsets)
    if not tables:
        table = schema.empty_table()
    elif len(tables) == 1:
        table = tables[0]
    else:
        table = pa.concat_tables(tables)
    extra = [lambda: check(table, source)] if check is not None else []
    _validate_values(table, schema, spec, source, extra)
    return table, source, ignored


# --------------------------------------------------------------------------- value checks


def _key_codes(column: pa.ChunkedArray) -> np.ndarray:
    """int64 codes with the same equality as the column's values (strings → dictionary codes)."""
    if pa.types.is_boolean(column.type):
        return pc.fill_null(column, False).to_numpy().astype(np.int64)
    if pa.types.is_integer(column.type):
        if column.null_count:
            column = pc.fill_null(column, 0)  # a null is reported as null
        return column.to_numpy().astype(np.int64, copy=False)
    return pc.dictionary_encode(column.combine_chunks()).indices.to_numpy().astype(np.int64, copy=False)


def _first_duplicate(keys: list[np.ndarray]) -> tuple[int, int] | None:
    """(row, earlier row with the same key) for the first row whose key repeats, or None.

    Assumes the first key is non-decreasing (the table is sorted by event_id).
    """
    n = keys[0].size
    if n < 2:
        return None
    same_prefix = np.ones(n - 1, dtype=bool)
    for k in keys[:-1]:
        same_prefix &= k[1:] == k[:-1]
    last = keys[-1]
    if not np.any(same_prefix & (last[1:] <= last[:-1])):
        return None  # fast path: within each group of leading keys the last key increases
    order = np.lexsort(keys[::-1])  # stable: equal keys keep their row order
    equal = np.ones(n - 1, dtype=bool)
    for k in keys:
        ks = k[order]
        equal &= ks[1:] == ks[:-1]
    if not np.any(equal):
        return None
    later = order[1:][equal]
    earlier = order[:-1][equal]
    i = int(np.argmin(later))
    return int(later[i]), int(earlier[i])


def _outside(column: pa.ChunkedArray, lowest: float | None, highest: float | None) -> np.ndarray:
    """Mask of the values below ``lowest`` or above ``highest`` (None: no bound; nulls are inside)."""
    values = column.to_numpy(zero_copy_only=False)
    bad = np.zeros(values.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        if lowest is not None:
            bad |= values < lowest
        if highest is not None:
            bad |= values > highest
    return bad


def _range_text(lowest: float | None, highest: float | None) -> str:
    if highest is None:
        return f">= {lowest!r}"
    if lowest is None:
        return f"<= {highest!r}"
    return f"in [{lowest!r}, {highest!r}]"


def _validate_values(table: pa.Table, schema: pa.Schema, spec: TableSpec | None, source: TableSource,
                     extra: Sequence[Callable[[], None]] = ()) -> None:
    """Every value rule of the table (and the ``extra`` checks, e.g. hits against the
    geometry's layers); raises the InputError of the first bad row over all of them."""
    key = _default_key(table, spec)
    if table.num_rows == 0:
        if spec is not None and not spec.allow_empty:
            raise InputError(f"{source.path}: table is empty (no rows)")
        return
    checks: list[Callable[[], None]] = []

    def check(mask_of, column: str, problem_of, first_row_of=None) -> None:
        """Add a check: rows where ``mask_of()`` is true are bad (or the row ``first_row_of()``
        gives), ``problem_of(row)`` says why."""
        def run():
            row = first_row_of() if first_row_of is not None else _first_true(mask_of())
            if row is not None:
                raise _row_error(source, table, row, column, key, problem_of(row))
        checks.append(run)

    def value(name: str, row: int) -> str:
        return _format_value(table.column(name)[row].as_py())

    for fld in schema:
        if not fld.nullable and table.column(fld.name).null_count:
            check(lambda c=fld.name: pc.is_null(table.column(c)), fld.name, lambda row: "is null")
    if spec is not None:
        for name in spec.finite:  # one compiled pass over the values (pkf.io.value_kernels)
            check(None, name, lambda row, c=name: f"is {value(c, row)}",
                  first_row_of=lambda c=name: first_nonfinite(table.column(c)))
        for name in spec.positive:
            check(lambda c=name: pc.less_equal(table.column(c), 0), name,
                  lambda row, c=name: f"is {value(c, row)}, must be > 0")
        for name in spec.non_negative:
            check(lambda c=name: pc.less(table.column(c), 0), name,
                  lambda row, c=name: f"is {value(c, row)}, must be >= 0")
        for name, lowest, highest, why in spec.ranges:
            check(lambda c=name, lo=lowest, hi=highest: _outside(table.column(c), lo, hi), name,
                  lambda row, c=name, lo=lowest, hi=highest, why=why:
                  f"is {value(c, row)}, must be {_range_text(lo, hi)} ({why})")
        for group, why in spec.nonzero_vectors:
            def zero_length(group=group):
                # the sum of squares is 0 (also where they underflow) in any order of the terms: as
                # sqrt(sum) == 0, without stacking the columns (mc_hits qop: 0.1 s per 1,000 events)
                total = None
                for c in group:
                    x = table.column(c).to_numpy(zero_copy_only=False)
                    total = x * x if total is None else np.add(total, x * x, out=total)
                return total == 0

            if len(group) == 1:
                check(zero_length, group[0],
                      lambda row, c=group[0], why=why: f"is {value(c, row)}, must not be 0 ({why})")
            else:
                check(zero_length, group[0], lambda row, group=group, why=why:
                      f"is part of ({', '.join(group)}) = ({', '.join(value(c, row) for c in group)}), "
                      f"of length 0: must be > 0 ({why})")
        if spec.noise_truth is not None:  # before null_together: the clearer message for a particle's row
            truth_columns, particle = spec.noise_truth
            for name in (c for c in truth_columns if table.column(c).null_count):  # no null: no bad row
                check(lambda c=name: pc.and_(pc.not_equal(table.column(particle), 0), pc.is_null(table.column(c))),
                      name,
                      lambda row, p=particle: f"is null on a particle's hit ({p}={value(p, row)}): only noise "
                                              f"hits ({p} 0) may lack truth")
        for group in spec.null_together:
            def nulls_of(group=group):
                return [pc.is_null(table.column(c)).to_numpy(zero_copy_only=False) for c in group]

            def partly_null(group=group):
                """Rows where some column of the group is null and another is not (bitmaps, not arrays)."""
                if not any(table.column(c).null_count for c in group):
                    return np.zeros(0, dtype=bool)
                first = pc.is_null(table.column(group[0]))
                mask = None
                for c in group[1:]:
                    differs = pc.not_equal(pc.is_null(table.column(c)), first)
                    mask = differs if mask is None else pc.or_(mask, differs)
                return mask if mask is not None else np.zeros(0, dtype=bool)

            def not_together(row, group=group):
                nulls = nulls_of(group)
                set_cols = [c for c, m in zip(group, nulls) if not m[row]]
                return (f"is null but {', '.join(repr(c) for c in set_cols)} is not "
                        f"({', '.join(group)} must be null together)")

            checks.append(lambda group=group, partly_null=partly_null, not_together=not_together:
                          _raise_partly_null(source, table, key, group, partly_null(), not_together))

    if "event_id" in table.column_names:
        events = table.column("event_id")
        events = (pc.fill_null(events, 0) if events.null_count else events).to_numpy()  # a null is reported as null
        check(lambda: np.r_[False, events[1:] < events[:-1]], "event_id",
              lambda row: f"comes after event_id={events[row - 1]}: rows must be sorted by event_id")

    if spec is not None and spec.unique_key:
        def duplicates():
            dup = _first_duplicate([_key_codes(table.column(c)) for c in spec.unique_key])
            if dup is not None:
                row, earlier = dup
                file, _ = _locate(source, row)
                other_file, other_row = _locate(source, earlier)
                other = f"row {other_row}" if other_file == file else f"{other_file} row {other_row}"
                raise _row_error(source, table, row, spec.unique_key[-1], key,
                                 f"duplicates {other}: ({', '.join(spec.unique_key)}) must be unique")
        checks.append(duplicates)
    _raise_first(checks + list(extra))


def _raise_partly_null(source, table, key, group, partly_null: np.ndarray, problem_of) -> None:
    row = _first_true(partly_null)
    if row is not None:
        nulls = [pc.is_null(table.column(c))[row].as_py() for c in group]
        column = next(c for c, n in zip(group, nulls) if n)
        raise _row_error(source, table, row, column, key, problem_of(row))


# --------------------------------------------------------------------------- public readers


def read_table(path: str | os.PathLike, schema: pa.Schema, *, name: str) -> pa.Table:
    """Read and validate table ``name`` of the directory ``path``.

    The table is ``path/NAME.parquet`` or a directory ``path/NAME/`` of Parquet
    files (read in natural order of their names, e.g. part-2 before part-10, and
    concatenated); ``path`` may also be the table file or directory itself.

    Columns may come in any order; integer columns of another integer width are
    converted when every value fits, float columns are converted from other floats
    or integers, string columns from large/dictionary strings; any other dtype is
    an error, as are missing columns (extra columns are ignored). For the pkf schemas
    (:mod:`pkf.io.schemas`) the rules of :data:`~pkf.io.schemas.TABLE_SPECS` are
    applied (finite measured values, errors > 0, sorted by event_id, unique ids,
    non-empty hits); for another schema, only dtypes, nulls and event_id order.

    Returns:
        the table, with exactly ``schema``.

    Raises:
        InputError: one line naming the file, column and first bad row.
    """
    table, _, _ = _read_with_source(path, schema, name)
    return table


#: Hits may lie this many of their own σ outside their layer's active area (docs/cli.md#exit-codes-and-messages) ...
AREA_TOLERANCE_SIGMAS = 5.0
#: ... plus this margin [mm], for a producer whose placement of the layers differs from the
#: nominal geometry by a fraction of a millimetre (real modules are aligned to better).
AREA_MARGIN_MM = 0.1


@dataclass(frozen=True)
class LayerArea:
    """Where each layer can measure (per layer, indexed by ``layer``; lengths in mm).

    The measured coordinates of a hit of layer ``k`` on its active area lie in
    ``[u_min[k], u_max[k]]`` and, for pixel layers, ``[v_min[k], v_max[k]]``: for a strip
    layer these are the bounds of u = x·cos α + y·sin α over the whole area (the strip's
    unmeasured coordinate may lie anywhere on it). A pixel hit must also lie outside the
    beam hole: r ≥ ``hole_radius`` and not (|u| < ``hole_half_u`` and |v| < ``hole_half_v``)
    (0 where a layer has no such hole; strips: 0, a hole does not exclude any u).
    """

    u_min: np.ndarray
    u_max: np.ndarray
    v_min: np.ndarray
    v_max: np.ndarray
    hole_radius: np.ndarray
    hole_half_u: np.ndarray
    hole_half_v: np.ndarray


def validate_hit_layers(
    table: pa.Table,
    layer_z: Sequence[float] | np.ndarray,
    layer_kind: Sequence[int] | np.ndarray,
    *,
    source: Source = "hits",
    z_tolerance: float = 1e-6,
    area: LayerArea | None = None,
) -> None:
    """Check hits against a geometry's layers.

    Args:
        table: a ``hits`` table (:data:`~pkf.io.schemas.HITS`).
        layer_z: z of each geometry layer [mm], indexed by ``layer``.
        layer_kind: kind of each layer: 0 = pixel (measures u and v), 1 = strip (u only).
        source: file name (or :class:`TableSource`) to name in messages.
        z_tolerance: allowed |z − layer_z[layer]| [mm].
        area: the layers' active areas; if given, also checks errors and positions
            (:func:`validate_hit_area`).

    Raises:
        InputError: ``layer`` outside [0, n_layers); ``z`` not the layer's z; ``v`` or
            ``sigma_v`` set on a strip layer or missing on a pixel layer; with ``area``,
            an error larger than the layer or a hit outside its layer's area.
        ValueError: ``layer_z`` and ``layer_kind`` differ in length or a kind is not 0/1.
    """
    layer_z = np.asarray(layer_z, dtype=np.float64)
    layer_kind = np.asarray(layer_kind, dtype=np.int64)
    if layer_z.shape != layer_kind.shape or layer_z.ndim != 1:
        raise ValueError("layer_z and layer_kind must be 1-d arrays of the same length")
    if not np.all((layer_kind == 0) | (layer_kind == 1)):
        raise ValueError("layer_kind values must be 0 (pixel) or 1 (strip)")
    from pkf.io.area_kernel import LAYER_CHECKS, first_bad_layer_rows, first_bad_rows

    n_layers = layer_z.size
    key = ("event_id", "hit_id")
    first = first_bad_rows(table, first_bad_layer_rows, len(LAYER_CHECKS), layer_z, layer_kind, float(z_tolerance))

    def layers():
        row = int(first[0])
        if row >= 0:
            raise _row_error(source, table, row, "layer", key,
                             f"is {_layer_at(table, row)}, not a layer of the geometry (valid: 0 to {n_layers - 1})")

    def z_values():
        row = int(first[1])
        if row >= 0:
            layer = _layer_at(table, row)
            raise _row_error(source, table, row, "z", key,
                             f"is {_float_at(table, 'z', row)!r} mm but layer {layer} is at "
                             f"z = {float(layer_z[layer])!r} mm")

    def measured_coordinates():
        row = int(first[2])
        if row >= 0:
            layer = _layer_at(table, row)
            strip = layer_kind[layer] == 1
            column = "v" if (not table.column("v")[row].is_valid) != strip else "sigma_v"
            if strip:
                problem = f"is not null but layer {layer} is a strip layer (v, sigma_v must be null)"
            else:
                problem = f"is null but layer {layer} is a pixel layer (v, sigma_v are required)"
            raise _row_error(source, table, row, column, key, problem)

    checks = [layers, z_values, measured_coordinates]
    if area is not None:
        checks.append(lambda: validate_hit_area(table, area, source=source))
    _raise_first(checks)


def validate_hit_area(table: pa.Table, area: LayerArea, *, source: Source = "hits") -> None:
    """Check the errors and positions of hits (with valid layers) against their layers' areas.

    - ``sigma_u`` (``sigma_v``) at most the layer's extent in u (v): a larger error says
      nothing about where the particle passed and only hides a unit or column mix-up.
      (The lower bound, :data:`~pkf.io.schemas.MIN_SIGMA_MM`, needs no geometry and is a
      rule of the hits table.)
    - u (v) at most ``AREA_TOLERANCE_SIGMAS`` of the hit's own σ plus ``AREA_MARGIN_MM``
      outside the layer's area: a simulated hit lies within a few σ of the area (the
      smearing of a particle that crossed it near an edge) and noise hits lie on it.

    Raises:
        InputError: one line naming the file, the column and the first bad row.
    """
    from pkf.io.area_kernel import AREA_CHECKS, first_bad_area_rows, first_bad_rows

    key = ("event_id", "hit_id", "layer")
    first = first_bad_rows(table, first_bad_area_rows, len(AREA_CHECKS), area.u_min, area.u_max, area.v_min,
                           area.v_max, area.hole_radius, area.hole_half_u, area.hole_half_v, AREA_TOLERANCE_SIGMAS,
                           AREA_MARGIN_MM)
    found = [(int(row), k) for k, row in enumerate(first) if row >= 0]
    if not found:
        return
    row, k = min(found)  # the first bad row of all; of one row, the first check
    lay = _layer_at(table, row)
    beyond = f"by more than {AREA_TOLERANCE_SIGMAS:g} σ + {AREA_MARGIN_MM:g} mm"
    extent = {"u": area.u_max[lay] - area.u_min[lay], "v": area.v_max[lay] - area.v_min[lay]}
    bounds = {"u": (area.u_min[lay], area.u_max[lay]), "v": (area.v_min[lay], area.v_max[lay])}
    check = AREA_CHECKS[k]
    if check.startswith("sigma"):
        column = check
        problem = (f"is {_float_at(table, check, row)!r} mm, larger than layer {lay}'s extent "
                   f"({float(extent[check[-1]])!r} mm): not a measurement error")
    elif check == "hole":
        column = "u"
        problem = (f"is {_float_at(table, 'u', row)!r} mm with v = {_float_at(table, 'v', row)!r} mm: "
                   f"inside layer {lay}'s beam hole {beyond}")
    else:
        column = check
        lo, hi = bounds[check]
        problem = (f"is {_float_at(table, check, row)!r} mm, outside layer {lay}'s active area "
                   f"[{float(lo)!r}, {float(hi)!r}] mm {beyond}")
    raise _row_error(source, table, row, column, key, problem)


def _layer_at(table: pa.Table, row: int) -> int:
    """The ``layer`` of a row (−1 where null: reported as null by the schema's rules)."""
    value = table.column("layer")[row].as_py()
    return -1 if value is None else int(value)


def _float_at(table: pa.Table, name: str, row: int) -> float:
    """A float column's value at a row (NaN where null)."""
    value = table.column(name)[row].as_py()
    return math.nan if value is None else float(value)


def pair_keys(
    ev_a: np.ndarray, id_a: np.ndarray, ev_b: np.ndarray, id_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Encode (event, id) pairs of two tables as int64 keys that are equal iff the pairs are
    (for any int64 values, negative ones included)."""
    if ev_a.size == 0 or ev_b.size == 0:
        return np.zeros(ev_a.size, np.int64), np.zeros(ev_b.size, np.int64)
    ev_lo = min(int(ev_a.min()), int(ev_b.min()))
    ev_hi = max(int(ev_a.max()), int(ev_b.max()))
    id_lo = min(int(id_a.min()), int(id_b.min()))
    id_hi = max(int(id_a.max()), int(id_b.max()))
    span = id_hi - id_lo + 1
    if (ev_hi - ev_lo + 1) * span < 2**62:
        return (ev_a - ev_lo) * span + (id_a - id_lo), (ev_b - ev_lo) * span + (id_b - id_lo)
    # Wide id ranges: replace values by their ranks first.
    _, ev_inv = np.unique(np.concatenate([ev_a, ev_b]), return_inverse=True)
    id_uni, id_inv = np.unique(np.concatenate([id_a, id_b]), return_inverse=True)
    keys = ev_inv.astype(np.int64) * id_uni.size + id_inv.astype(np.int64)
    return keys[: ev_a.size], keys[ev_a.size :]


def _missing_pairs(
    ev: np.ndarray, ids: np.ndarray, ref_ev: np.ndarray, ref_ids: np.ndarray, check: np.ndarray | None = None
) -> int | None:
    """First row whose (event, id) is not among the reference pairs (only rows where ``check``)."""
    if ev.size == ref_ev.size and np.array_equal(ev, ref_ev) and np.array_equal(ids, ref_ids):
        return None
    keys, ref_keys = pair_keys(ev, ids, ref_ev, ref_ids)
    found = np.isin(keys, ref_keys)
    bad = ~found if check is None else check & ~found
    return _first_true(bad)


def validate_consistency(
    hits: pa.Table,
    particles: pa.Table | None,
    mc_hits: pa.Table | None,
    *,
    sources: Mapping[str, Source] | None = None,
) -> None:
    """Check that the MC truth refers to existing hits and particles.

    - every ``mc_hits`` row has a ``hits`` row with the same (event_id, hit_id), and
      every ``hits`` row an ``mc_hits`` row (a hit without truth would shift the
      efficiency silently; noise hits have a row with particle_id 0);
    - every non-zero ``mc_hits.particle_id`` exists in ``particles`` for that event;
    - every ``particles.parent_id`` is 0 or a particle of the same event.

    Checks involving a missing table (None) are skipped.

    Args:
        sources: file names (or :class:`TableSource`) per table name ("hits",
            "particles", "mc_hits") for messages; default: the table names.

    Raises:
        InputError: one line naming the file, column and first bad row.
    """
    sources = dict(sources or {})
    src_mc = sources.get("mc_hits", "mc_hits")
    src_particles = sources.get("particles", "particles")
    if mc_hits is not None:
        key = ("event_id", "hit_id")
        mc_ev = mc_hits.column("event_id").to_numpy()
        row = _missing_pairs(
            mc_ev,
            mc_hits.column("hit_id").to_numpy(),
            hits.column("event_id").to_numpy(),
            hits.column("hit_id").to_numpy(),
        )
        if row is not None:
            hits_name = str(sources.get("hits", "hits"))
            raise _row_error(
                src_mc, mc_hits, row, "hit_id", key, f"has no hit with the same event_id, hit_id in {hits_name}"
            )
        hits_ev = hits.column("event_id").to_numpy()
        row = _missing_pairs(hits_ev, hits.column("hit_id").to_numpy(), mc_ev, mc_hits.column("hit_id").to_numpy())
        if row is not None:
            raise _row_error(
                sources.get("hits", "hits"), hits, row, "hit_id", key,
                f"has no row in {src_mc}: with MC truth every hit needs one (noise hits: particle_id 0)",
            )
        if particles is not None:
            pid = mc_hits.column("particle_id").to_numpy()
            row = _missing_pairs(
                mc_ev,
                pid,
                particles.column("event_id").to_numpy(),
                particles.column("particle_id").to_numpy(),
                check=pid != 0,
            )
            if row is not None:
                raise _row_error(
                    src_mc,
                    mc_hits,
                    row,
                    "particle_id",
                    key + ("particle_id",),
                    f"is not a particle of this event in {src_particles}",
                )
    if particles is not None:
        ev = particles.column("event_id").to_numpy()
        parent = particles.column("parent_id").to_numpy()
        has_parent = parent != 0
        if np.any(has_parent):
            row = _missing_pairs(ev, parent, ev, particles.column("particle_id").to_numpy(), check=has_parent)
            if row is not None:
                raise _row_error(
                    src_particles,
                    particles,
                    row,
                    "parent_id",
                    ("event_id", "particle_id", "parent_id"),
                    "is not 0 and not a particle of this event",
                )


def read_meta(dataset_dir: str | os.PathLike, required: bool = True) -> dict | None:
    """Read ``meta.json`` of a dataset (geometry name and hash, generator, seed, pkf version).

    Args:
        required: if False, a missing file gives None (a dataset of another producer,
            whose geometry is given on the command line).

    Raises:
        InputError: the file is missing (and required), unreadable, not valid JSON or not
            a JSON object.
    """
    path = Path(dataset_dir) / "meta.json"
    if not path.is_file():
        if not required and not path.exists():
            return None
        raise InputError(f"{path}: file not found (every dataset has a meta.json)")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not valid JSON (not UTF-8 text: {_one_line(exc)})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read file ({_one_line(exc.strerror or exc)})") from None
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path}: must hold a JSON object, found {type(meta).__name__}")
    return meta


def find_truth_tables(dataset_dir: str | os.PathLike) -> dict[str, Path | None]:
    """Locate the MC truth tables ``particles`` and ``mc_hits`` of a dataset (None if absent).

    MC truth is both tables or neither. One without the other is an incomplete dataset
    (a lost or half-copied file), not a dataset without MC: ``mc_hits`` alone gives no
    production momentum for the efficiency bins, the q/p pulls and the beamline truth,
    ``particles`` alone cannot be matched to any hit; skipping the MC silently would
    give a run that looks complete but is not. So it is an error naming the missing table.

    Raises:
        InputError: exactly one of the two tables exists.
    """
    path = Path(dataset_dir)
    found = {name: find_table(path, name) for name in ("particles", "mc_hits")}
    for missing, present in (("particles", "mc_hits"), ("mc_hits", "particles")):
        if found[missing] is None and found[present] is not None:
            raise InputError(
                f"{path / missing}.parquet: not found (nor {missing}/), but {found[present]} is present: "
                f"MC truth needs both particles and mc_hits"
            )
    return found


@dataclass(frozen=True)
class Dataset:
    """A validated dataset directory (docs/formats.md).

    Attributes:
        path: the dataset directory.
        meta: contents of ``meta.json``.
        hits: the ``hits`` table (:data:`~pkf.io.schemas.HITS`).
        particles: the ``particles`` table, or None if the dataset has none.
        mc_hits: the ``mc_hits`` table, or None if the dataset has none.
        sources: per table name, where its rows came from (for error messages).
        ignored_columns: per table name, its extra columns (not read), if any.
    """

    path: Path
    meta: dict
    hits: pa.Table
    particles: pa.Table | None
    mc_hits: pa.Table | None
    sources: dict[str, TableSource] = field(default_factory=dict, repr=False, compare=False)
    ignored_columns: dict[str, tuple[str, ...]] = field(default_factory=dict, repr=False, compare=False)

    @property
    def has_mc(self) -> bool:
        """Whether the dataset carries MC truth (both ``particles`` and ``mc_hits``)."""
        return self.particles is not None and self.mc_hits is not None


def check_dataset_dir(dataset_dir: str | os.PathLike) -> Path:
    """The dataset directory as a Path; InputError if it does not exist or is not a directory."""
    shown = os.fspath(dataset_dir)
    path = Path(dataset_dir)
    if not path.exists():
        raise InputError(f"{shown}: dataset directory does not exist")
    if not path.is_dir():
        raise InputError(f"{shown}: not a directory (a dataset is a directory with meta.json and hits)")
    return path


def open_dataset(
    dataset_dir: str | os.PathLike,
    *,
    layer_z: Sequence[float] | np.ndarray | None = None,
    layer_kind: Sequence[int] | np.ndarray | None = None,
    area: LayerArea | None = None,
    meta: dict | None = None,
) -> Dataset:
    """Open and validate a dataset directory: ``meta.json``, ``hits`` and, if present,
    ``particles`` and ``mc_hits``, plus their consistency (:func:`validate_consistency`).

    Args:
        dataset_dir: the dataset directory.
        meta: the dataset's record if already read (``{}`` for a dataset without
            ``meta.json``); default: read ``meta.json`` (required).
        layer_z, layer_kind: if both are given, the hits are also checked against
            these geometry layers (:func:`validate_hit_layers`).
        area: with them, the layers' active areas (errors and positions of the hits).

    Raises:
        InputError: one line naming the file, column and first bad row.
    """
    path = check_dataset_dir(dataset_dir)
    if meta is None:
        meta = read_meta(path)
    truth = find_truth_tables(path)
    if (layer_z is None) != (layer_kind is None):
        raise ValueError("give both layer_z and layer_kind, or neither")
    check_layers = None
    if layer_z is not None:
        def check_layers(table, source):
            validate_hit_layers(table, layer_z, layer_kind, source=source, area=area)
    hits, hits_src, hits_extra = _read_with_source(path, HITS, "hits", check_layers)
    sources = {"hits": hits_src}
    ignored = {"hits": hits_extra}
    tables: dict[str, pa.Table | None] = {}
    for name, schema in (("particles", PARTICLES), ("mc_hits", MC_HITS)):
        if truth[name] is None:
            tables[name] = None
            continue
        tables[name], sources[name], ignored[name] = _read_with_source(path, schema, name)
    validate_consistency(hits, tables["particles"], tables["mc_hits"], sources=sources)
    return Dataset(path, meta, hits, tables["particles"], tables["mc_hits"], sources,
                   {name: extra for name, extra in ignored.items() if extra})
