"""Atomic, deterministic writers: Parquet tables, JSON files and staged output directories.

A crashed or interrupted command must leave no file that looks complete
(docs/formats.md, docs/cli.md#exit-codes-and-messages): every file is written under a hidden temporary name in its final
directory and then renamed into place (``os.replace`` is atomic on POSIX), and
whole output directories are built in a hidden sibling directory that is renamed
into place only when the command succeeds (:func:`staged_output_dir`).

Parquet output is deterministic: the same table gives a byte-identical file
(fixed writer options, chunk layout normalised), for a given pyarrow version —
``created_by`` in the footer names that version.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pkf.errors import CtrlC, InputError

__all__ = [
    "PARQUET_WRITE_OPTIONS",
    "parquet_write_options",
    "atomic_write_table",
    "atomic_write_json",
    "check_output_apart",
    "check_output_dir",
    "staged_output_dir",
]

#: Fixed options of ``pyarrow.parquet.write_table`` for every pkf table. LZ4 (Parquet's LZ4_RAW;
#: issue 18.4): every table pkf writes is read at least as often as it is written (`pkf reconstruct`
#: decodes its inputs twice, for the validation and then by partition; `pkf report` reads the runs),
#: and LZ4 decodes them 2.2–2.6× faster than zstd at level 1, and writes them 1.6–1.8× faster, for
#: 5–10 % more bytes. Measured (one thread, CPU seconds to decode / to write, MB), a 1,000-event
#: minimum-bias dataset at ν = 7.6: hits 0.282 / 0.52 / 109.9 → 0.120 / 0.34 / 115.4, mc_hits
#: 0.629 / 1.01 / 339.0 → 0.265 / 0.58 / 354.7; the run of 400 such events with two fitters:
#: states 0.183 / 0.29 / 99.8 → 0.072 / 0.16 / 109.4, pulls 0.103 / 0.15 / 53.7 → 0.047 / 0.09 / 58.8.
#: (zstd at level 1 had replaced level 3: the same size, 0.84 instead of 1.11 s to write the four
#: run tables of 1,000 events.)
PARQUET_WRITE_OPTIONS: dict[str, object] = {
    "version": "2.6",
    "compression": "lz4",
    "use_dictionary": True,
    "write_statistics": True,
    "row_group_size": 1 << 20,
    "data_page_size": 1 << 20,
    "data_page_version": "1.0",
    "store_schema": True,
}


def dictionary_columns(schema: pa.Schema) -> list[str]:
    """The columns of ``schema`` worth dictionary-encoding: all but the floating-point ones.

    Measured (issue 18; 60 minimum-bias events at ν = 7.6, every output table of a four-fitter
    run, `benchmarks/parquet_write.py`): dictionary pages for float columns, whose values hardly
    repeat, made the writes 2.5× slower in CPU and the files 18 % larger; without them the tables
    read back equal. Nested float columns (lists of floats) count as floats.
    """
    names = []
    for f in schema:
        t = f.type
        while pa.types.is_list(t) or pa.types.is_large_list(t) or pa.types.is_fixed_size_list(t):
            t = t.value_type
        if not pa.types.is_floating(t):
            names.append(f.name)
    return names


def parquet_write_options(schema: pa.Schema) -> dict[str, object]:
    """:data:`PARQUET_WRITE_OPTIONS` with dictionary encoding for the non-float columns only
    (`dictionary_columns`)."""
    return {**PARQUET_WRITE_OPTIONS, "use_dictionary": dictionary_columns(schema)}


def _temp_sibling(path: Path) -> Path:
    """A hidden, unique name beside ``path`` (hidden so dataset readers skip it)."""
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_table(table: pa.Table, path: str | os.PathLike, *, schema: pa.Schema | None = None) -> Path:
    """Write ``table`` to the Parquet file ``path`` atomically and deterministically.

    The file is written under a hidden temporary name in the same directory,
    flushed to disk, then renamed over ``path``. The same table content always
    gives the same bytes (options `parquet_write_options`; chunks are
    combined first so the chunk layout of the input does not matter).

    Args:
        table: the data.
        path: destination file (its directory must exist).
        schema: if given, the table's columns are selected in schema order and cast
            to it exactly (a pkf schema from :mod:`pkf.io.schemas`).

    Returns:
        the destination path.

    Raises:
        ValueError: with ``schema``, a non-nullable column holds nulls (raised by
            ``Table.cast``; a bug in the caller: the reader would refuse the file).
    """
    path = Path(path)
    if schema is not None:
        table = table.select(schema.names).cast(schema)
    table = table.combine_chunks()
    tmp = _temp_sibling(path)
    try:
        pq.write_table(table, tmp, **parquet_write_options(table.schema))
        _fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise
    return path


def _jsonable(obj: object) -> object:
    """Convert numpy scalars/arrays, paths and tuples to JSON types; NaN/±inf become null."""
    if isinstance(obj, Mapping):
        out = {}
        for key, value in obj.items():
            if not isinstance(key, str):
                raise TypeError(f"JSON object keys must be str, got {key!r}")
            out[key] = _jsonable(value)
        return out
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if obj is None or isinstance(obj, str):
        return obj
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")


def atomic_write_json(obj: object, path: str | os.PathLike) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically (sorted keys, indent 2, trailing newline).

    numpy scalars and arrays, tuples and paths are converted; non-finite floats
    (NaN, ±inf) are written as ``null`` so the file is strict JSON.

    Returns:
        the destination path.
    """
    path = Path(path)
    text = json.dumps(_jsonable(obj), sort_keys=True, indent=2, allow_nan=False) + "\n"
    tmp = _temp_sibling(path)
    try:
        with open(tmp, "x", encoding="utf-8") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise
    return path


def check_output_apart(output: str | os.PathLike, inputs: Iterable[str | os.PathLike | None],
                       option: str = "--out") -> None:
    """Refuse an output that equals, contains or sits inside one of the inputs (docs/cli.md#exit-codes-and-messages).

    With ``--overwrite`` an output directory is deleted and replaced, so an output that
    contains an input would delete it, and one that sits inside an input would change the
    input (a run inside a dataset is read back as part of it). Paths are compared after
    resolving symbolic links and ``..``, so no spelling of the same place gets through;
    ``None`` inputs (an option not given) are skipped.

    Raises:
        InputError: one line naming the option, the output and the input.
    """
    shown = os.fspath(output)
    out = Path(os.path.realpath(output))
    for given in inputs:
        if given is None:
            continue
        inp = Path(os.path.realpath(given))
        if out == inp:
            relation = "is"
        elif out in inp.parents:
            relation = "contains"
        elif inp in out.parents:
            relation = "is inside"
        else:
            continue
        raise InputError(f"{option} {shown}: {relation} the input {os.fspath(given)}; "
                         "an output must lie outside every input")


def check_output_dir(final_path: str | os.PathLike, overwrite: bool,
                     inputs: Iterable[str | os.PathLike | None] = ()) -> Path:
    """Check that the output directory ``final_path`` can be created; return it as an absolute path.

    Raises:
        InputError: ``final_path`` equals, contains or sits inside one of ``inputs``
            (:func:`check_output_apart`, whatever ``overwrite`` says), the parent
            directory does not exist or is not writable, ``final_path`` is an existing
            file, or it is a non-empty directory and ``overwrite`` is False.
    """
    check_output_apart(final_path, inputs)
    shown = os.fspath(final_path)
    final = Path(os.path.abspath(final_path))
    parent = final.parent
    if final == parent:
        raise InputError(f"{shown}: cannot use the filesystem root as output directory")
    if not parent.is_dir():
        raise InputError(f"{shown}: cannot create output directory: parent directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{shown}: cannot create output directory: parent directory {parent} is not writable")
    if final.exists() or final.is_symlink():
        if not final.is_dir() or final.is_symlink():
            raise InputError(f"{shown}: output path exists and is not a directory")
        if not overwrite and any(final.iterdir()):
            raise InputError(f"{shown}: output directory exists and is not empty (use --overwrite to replace it)")
    return final


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def staged_output_dir(final_path: str | os.PathLike, overwrite: bool,
                      inputs: Iterable[str | os.PathLike | None] = ()) -> Iterator[Path]:
    """Build an output directory in a temporary sibling and move it into place on success.

    On entry, checks that ``final_path`` can be created and lies apart from every one of
    ``inputs`` (:func:`check_output_dir`), so the caller gets the one-line :class:`~pkf.errors.InputError` before doing
    any work. Yields a new, empty hidden directory beside ``final_path`` to write
    into. When the ``with`` block ends normally, the directory is renamed to
    ``final_path``; a previous ``final_path`` (an empty directory, or any directory
    when ``overwrite`` is True) is first renamed out of the way and deleted after
    the new one is in place. If the block raises (including KeyboardInterrupt), the
    temporary directory is deleted and any previous output is left untouched.

    Example::

        with staged_output_dir(out, overwrite=opts.overwrite) as tmp:
            atomic_write_table(hits, tmp / "hits.parquet", schema=HITS)
            atomic_write_json(meta, tmp / "meta.json")
    """
    inputs = tuple(inputs)
    final = check_output_dir(final_path, overwrite, inputs)
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".staging", dir=final.parent))
    except OSError as exc:
        raise InputError(f"{final}: cannot create the output directory here: {exc.strerror}") from None
    try:
        os.chmod(staging, 0o777 & ~_umask())
        yield staging
        CtrlC.check()  # a Ctrl-C that a library swallowed on the way must not commit the output
        # Re-check: another process may have created the output meanwhile.
        check_output_dir(final, overwrite, inputs)
        if final.exists():
            old = final.with_name(f".{final.name}.{os.getpid()}.{secrets.token_hex(4)}.old")
            os.replace(final, old)
            try:
                os.replace(staging, final)
            except BaseException:
                os.replace(old, final)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(staging, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
