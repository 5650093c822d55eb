"""Reading run directories for a report: validated run tables, run.json and the fitters they hold.

A report (docs/formats.md#summaryjson) accepts one or more run directories (output of
``pkf reconstruct``, docs/formats.md), each with a label (``RUN:LABEL``; default: the run
folder's name). Each run table is one Parquet file (``chi2.parquet``) or, as `pkf reconstruct`
writes it, a directory of partition files (``chi2/part-FFFF-BBBBB.parquet``, read in order).
The report's entries are (label, fitter) pairs, ``LABEL/FITTER``: the same fitter may appear
in several runs (shipped against tuned parameters, two datasets, two pileups); labels must
differ. Every problem is a one-line :class:`~pkf.errors.InputError` raised before anything
is written.

A run of ``pkf reconstruct`` lists its partition files with their SHA-256 in
``run.json`` (``partitions[].files``); :func:`verify_run_files` refuses a run with a
listed file missing or changed, or with a table file that no partition lists
(docs/cli.md#exit-codes-and-messages), so a damaged run never gives a report of part of its tracks. Cost: SHA-256 of
every file, on a thread per core (hashlib releases the GIL); the files are then in the
page cache for the reading that follows.
"""

from __future__ import annotations

import json
import os
import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from pkf.errors import InputError
from pkf.io.reader import _list_parquet_files, find_table, read_table
from pkf.io.schemas import CHI2, PULLS, RUN_SCHEMAS, STATES
from pkf.io.stream import file_sha256

__all__ = ["RunInput", "load_run", "load_runs", "parse_run_spec", "verify_run_files", "REFERENCE_FITTER"]

#: The fitter that resolutions and speeds are compared with (the paper's "default Kalman").
REFERENCE_FITTER = "reference"

#: Tables every run directory must hold (``pulls`` only when the dataset had MC truth).
REQUIRED_TABLES = ("chi2", "states", "candidates")


@dataclass(frozen=True)
class RunInput:
    """One validated run directory (its run.json; the tables are read partition by partition).

    Attributes:
        path: the run directory.
        label: the run's name in the report (``RUN:LABEL``, default the folder's name).
        info: contents of ``run.json``.
        fitters: fitter names in the run, in the order of run.json ``config.fitters``.
        has_mc: whether the run was made with MC truth (run.json has ``pattern``,
            or a pulls table exists); without it ``is_ghost`` carries no information.
        has_pulls: whether the run has a ``pulls`` table.
    """

    path: Path
    info: dict
    fitters: tuple[str, ...]
    has_mc: bool
    has_pulls: bool
    label: str = ""

    def entry(self, fitter: str) -> str:
        """The report entry of one of the run's fitters: ``LABEL/FITTER``."""
        return f"{self.label}/{fitter}"

    @property
    def dataset_path(self) -> Path | None:
        """The dataset the run was reconstructed from (run.json ``input.path``, else ``config.dataset``)."""
        path = (self.info.get("input") or {}).get("path") or (self.info.get("config") or {}).get("dataset")
        return Path(path) if isinstance(path, str) and path else None

    def partitions(self) -> list[dict[str, Path]]:
        """The run's tables in parts of whole events, each a dict table name → file (or table):
        one part per partition file when ``chi2``, ``states`` (and ``pulls``) have the same
        file names (as `pkf reconstruct` writes them), else one part with each whole table."""
        names = ("chi2", "states", "pulls") if self.has_pulls else ("chi2", "states")
        locations = {name: find_table(self.path, name) for name in names}
        files = {name: (_list_parquet_files(loc) if loc.is_dir() else [loc]) for name, loc in locations.items()}
        shapes = {tuple(f.name for f in fs) for fs in files.values()}
        if len(shapes) == 1 and all(loc.is_dir() for loc in locations.values()):
            return [{name: files[name][k] for name in names} for k in range(len(files["chi2"]))]
        return [locations]

    def read_part(self, part: dict[str, Path]) -> tuple[pa.Table, pa.Table, pa.Table | None]:
        """(chi2, states, pulls or None) of one part of :meth:`partitions`, validated (one-line
        InputError naming the file, column and first bad row); fitters must be the run's."""
        chi2 = read_chi2(part["chi2"])
        states = read_table(part["states"], STATES, name="states")
        pulls = read_table(part["pulls"], PULLS, name="pulls") if "pulls" in part else None
        for name, table in (("chi2", chi2), ("states", states), ("pulls", pulls)):
            if table is None or table.num_rows == 0:
                continue
            unknown = set(pc.unique(table.column("fitter")).to_pylist()) - set(self.fitters)
            if unknown:
                raise InputError(f"{part[name]}: fitter {sorted(unknown)[0]!r} is not a fitter of the run "
                                 f"({', '.join(self.fitters)}: run.json config.fitters, else the chi2 table's)")
        return chi2, states, pulls

    def table(self, name: str) -> pa.Table:
        """A whole run table (``chi2``, ``states``, ``pulls``), validated: for small runs and
        tests; the report reads :meth:`partitions` one at a time."""
        if name == "chi2":
            return read_chi2(self.path)
        return read_table(self.path, {"states": STATES, "pulls": PULLS}[name], name=name)


#: ``chi2`` as pkf wrote it before the ``track_type`` column: such runs are still read; the
#: report then takes each track's type from its hit counts (`pkf.report.metrics.track_types`).
CHI2_WITHOUT_TRACK_TYPE = pa.schema([f for f in CHI2 if f.name != "track_type"])


def read_chi2(path: Path) -> pa.Table:
    """The validated ``chi2`` table at `path` (a run, its table directory or file), with or
    without the ``track_type`` column (runs written before it have none)."""
    schema = CHI2
    location = find_table(path, "chi2")
    files = [] if location is None else [location] if location.is_file() else _list_parquet_files(location)
    try:
        if files and "track_type" not in pq.read_schema(files[0]).names:
            schema = CHI2_WITHOUT_TRACK_TYPE
    except (OSError, pa.ArrowInvalid):
        pass  # read_table says what is wrong with the file
    return read_table(path, schema, name="chi2")


def _read_run_json(path: Path) -> dict:
    file = path / "run.json"
    if not file.is_file():
        raise InputError(f"{file}: file not found (not a complete run directory of `pkf reconstruct`)")
    try:
        info = json.loads(file.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"{file}: not valid JSON (not UTF-8 text)") from None
    except json.JSONDecodeError as exc:
        raise InputError(f"{file}: not valid JSON: {exc.msg} at line {exc.lineno} column {exc.colno}") from None
    except OSError as exc:
        raise InputError(f"{file}: cannot read file ({exc.strerror})") from None
    if not isinstance(info, dict):
        raise InputError(f"{file}: must hold a JSON object, found {type(info).__name__}")
    kind = info.get("kind", "run")
    if kind != "run":
        raise InputError(f"{file}: describes a {kind!r}, not a run of `pkf reconstruct`")
    for key in ("config", "timing"):
        if not isinstance(info.get(key), dict):
            raise InputError(f"{file}: key {key!r} is missing or not an object (not a run.json of pkf reconstruct)")
    return info


_SHA256 = re.compile(r"[0-9a-f]{64}")


def _listed_files(path: Path, info: dict) -> dict[Path, str] | None:
    """The table files run.json ``partitions`` lists, with their SHA-256 (None: no list)."""
    records = info.get("partitions")
    if records is None:
        return None  # a run written by other means: nothing to check against
    source = path / "run.json"
    if not isinstance(records, list):
        raise InputError(f"{source}: key 'partitions' must be a list, found {type(records).__name__}")
    listed: dict[Path, str] = {}
    for i, record in enumerate(records):
        files = record.get("files") if isinstance(record, dict) else None
        if not isinstance(files, dict):
            raise InputError(f"{source}: partitions[{i}] has no 'files' object")
        for table, entry in files.items():
            rel = entry.get("path") if isinstance(entry, dict) else None
            sha = entry.get("sha256") if isinstance(entry, dict) else None
            parts = Path(rel).parts if isinstance(rel, str) else ()
            if (len(parts) != 2 or parts[0] != table or Path(rel).is_absolute() or ".." in parts
                    or not isinstance(sha, str) or not _SHA256.fullmatch(sha)):
                raise InputError(f"{source}: partitions[{i}].files.{table} must hold a path TABLE/FILE "
                                 f"inside the run and a SHA-256, found {entry!r}")
            listed[path / rel] = sha
    return listed


def _table_files(path: Path, tables) -> list[Path]:
    """Every file the readers would read for these tables: ``NAME.parquet`` and the files of
    ``NAME/`` (as pyarrow.dataset selects them: names starting with '.' or '_' skipped)."""
    found = []
    for name in tables:
        as_file = path / f"{name}.parquet"
        if as_file.exists():
            found.append(as_file)
        for root, dirs, files in os.walk(path / name):
            dirs[:] = [d for d in dirs if not d.startswith((".", "_"))]
            found.extend(Path(root) / f for f in files if not f.startswith((".", "_")))
    return sorted(found)


def verify_run_files(path: str | os.PathLike, info: dict) -> None:
    """Refuse a damaged run: a file run.json lists is missing or has another SHA-256, or a
    run table holds a file that no partition lists (docs/cli.md#exit-codes-and-messages).

    A run.json without ``partitions`` (a run not written by `pkf reconstruct`) is not
    checked. Cost: reading and hashing every listed file once (SHA-256, ~0.3–1 GB/s per
    core; the files are hashed in parallel threads).

    Raises:
        InputError: one line naming the first bad file.
    """
    path = Path(path)
    listed = _listed_files(path, info)
    if listed is None:
        return
    for file in listed:
        if not file.is_file():
            raise InputError(f"{file}: missing, but run.json lists it (damaged run; "
                             "rerun `pkf reconstruct` with --overwrite)")
    tables = set(RUN_SCHEMAS) | {file.parent.name for file in listed}
    for file in _table_files(path, sorted(tables)):
        if file not in listed:
            raise InputError(f"{file}: not listed in run.json partitions (a stray file in the run; "
                             "remove it or rerun `pkf reconstruct` with --overwrite)")
    files = sorted(listed)
    with ThreadPoolExecutor(max_workers=min(len(files), os.cpu_count() or 1) or 1) as pool:
        digests = list(pool.map(_sha256_or_none, files))
    for file, digest in zip(files, digests):
        if digest != listed[file]:
            why = "cannot be read" if digest is None else "changed since the run (SHA-256 differs from run.json)"
            raise InputError(f"{file}: {why}; damaged run, rerun `pkf reconstruct` with --overwrite")


def _sha256_or_none(file: Path) -> str | None:
    try:
        return file_sha256(file)
    except OSError:
        return None


def parse_run_spec(spec: str | os.PathLike | tuple) -> tuple[Path, str]:
    """``RUN[:LABEL]`` (or a path, or a (path, label) pair) → (run directory, label).

    A text that names an existing path is a path, even if it holds a colon; otherwise the
    label follows the last colon. The default label is the run folder's name. Labels may
    not hold ``/`` (it separates label and fitter in entry names) and may not be empty.

    Raises:
        InputError: an empty label or one with ``/``.
    """
    if isinstance(spec, tuple):
        path, label = Path(spec[0]), str(spec[1])
    else:
        text = os.fspath(spec)
        if ":" in text and not Path(text).exists():
            path_text, label = text.rsplit(":", 1)
            path = Path(path_text)
        else:
            path, label = Path(text), Path(os.path.abspath(text)).name
    if not label or "/" in label:
        raise InputError(f"{os.fspath(spec) if not isinstance(spec, tuple) else spec[0]}: run label {label!r} "
                         "must be non-empty and without '/' (RUN:LABEL)")
    return path, label


def load_run(path: str | os.PathLike, label: str | None = None) -> RunInput:
    """Read and validate one run directory.

    Raises:
        InputError: the directory does not exist, ``run.json`` or a required table
            is missing, a partition file does not match run.json
            (:func:`verify_run_files`), or any table is malformed (one line naming file
            and column).
    """
    shown = os.fspath(path)
    path = Path(path)
    if not path.exists():
        raise InputError(f"{shown}: run directory does not exist")
    if not path.is_dir():
        raise InputError(f"{shown}: not a directory (a run is a directory written by `pkf reconstruct`)")
    info = _read_run_json(path)
    verify_run_files(path, info)
    for name in REQUIRED_TABLES:
        if find_table(path, name) is None:
            raise InputError(f"{path}: table {name!r} not found (expected {name}/ or {name}.parquet; incomplete run directory)")
    has_pulls = find_table(path, "pulls") is not None
    has_mc = "pattern" in info or has_pulls
    configured = (info.get("config") or {}).get("fitters")
    if isinstance(configured, list) and all(isinstance(f, str) for f in configured):
        fitters = tuple(configured)
    else:
        fitters = _fitters_in_chi2(find_table(path, "chi2"))
    if not fitters:
        raise InputError(f"{path}: the run names no fitter (empty chi2 table and no config.fitters)")
    label = Path(os.path.abspath(path)).name if label is None else label
    return RunInput(path, info, fitters, has_mc, has_pulls, label)


def _fitters_in_chi2(location: Path) -> tuple[str, ...]:
    """The fitters of a chi2 table in order of appearance (its ``fitter`` column only)."""
    import pyarrow.parquet as pq

    files = _list_parquet_files(location) if location.is_dir() else [location]
    found: dict[str, None] = {}
    for file in files:
        try:
            column = pq.read_table(file, columns=["fitter"]).column("fitter")
        except (OSError, KeyError, pa.ArrowException) as exc:
            raise InputError(f"{file}: cannot read column 'fitter' ({str(exc).splitlines()[0]})") from None
        found.update(dict.fromkeys(str(f) for f in column.to_pylist()))
    return tuple(found)


def load_runs(specs) -> list[RunInput]:
    """Read several run directories, each given as ``RUN[:LABEL]`` (:func:`parse_run_spec`).

    The same fitter may appear in several runs; the labels tell them apart.

    Raises:
        InputError: no run given, a bad run directory (:func:`load_run`), or two runs
            with the same label (e.g. two folders both called ``run``: label them).
    """
    parsed = [parse_run_spec(s) for s in specs]
    if not parsed:
        raise InputError("report: give at least one run directory")
    runs = []
    owner: dict[str, Path] = {}
    for path, label in parsed:
        if label in owner:
            raise InputError(f"{path}: label {label!r} is also the label of {owner[label]}; "
                             "give each run its own label as RUN:LABEL")
        owner[label] = path
        runs.append(load_run(path, label))
    return runs


def column(table: pa.Table, name: str, dtype=np.float64) -> np.ndarray:
    """A table column as a numpy array of ``dtype``."""
    return table.column(name).to_numpy(zero_copy_only=False).astype(dtype, copy=False)


def rows_of(table: pa.Table, fitter: str, location: str | None = None) -> pa.Table:
    """The rows of one fitter (and location, for states/pulls)."""
    import pyarrow.compute as pc

    mask = pc.equal(table.column("fitter"), fitter)
    if location is not None:
        mask = pc.and_(mask, pc.equal(table.column("location"), location))
    return table.filter(mask)
