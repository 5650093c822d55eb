"""Reading run directories for a report: validated run tables, run.json and the fitters they hold.

A report (DESIGN §11) accepts one or more run directories (output of
``pkf reconstruct``, DESIGN §6), each with a label (``RUN:LABEL``; default: the run
folder's name). Each run table is one Parquet file (``chi2.parquet``) or, as `pkf reconstruct`
writes it, a directory of partition files (``chi2/part-FFFF-BBBBB.parquet``, read in order).
The report's entries are (label, fitter) pairs, ``LABEL/FITTER``: the same fitter may appear
in several runs (shipped against tuned parameters, two datasets, two pileups); labels must
differ. Every problem is a one-line :class:`~pkf.errors.InputError` raised before anything
is written.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from pkf.errors import InputError
from pkf.io.reader import find_table, read_table
from pkf.io.schemas import CHI2, PULLS, STATES

__all__ = ["RunInput", "load_run", "load_runs", "parse_run_spec", "REFERENCE_FITTER"]

#: The fitter that resolutions and speeds are compared with (the paper's "default Kalman").
REFERENCE_FITTER = "reference"

#: Tables every run directory must hold (``pulls`` only when the dataset had MC truth).
REQUIRED_TABLES = ("chi2", "states", "candidates")


@dataclass(frozen=True)
class RunInput:
    """One validated run directory.

    Attributes:
        path: the run directory.
        label: the run's name in the report (``RUN:LABEL``, default the folder's name).
        info: contents of ``run.json``.
        fitters: fitter names in the run, in the order of run.json ``config.fitters``.
        chi2: the ``chi2`` table (:data:`~pkf.io.schemas.CHI2`).
        states: the ``states`` table (:data:`~pkf.io.schemas.STATES`).
        pulls: the ``pulls`` table, or None when the run has no MC truth.
        has_mc: whether the run was made with MC truth (run.json has ``pattern``,
            or a pulls table exists); without it ``is_ghost`` carries no information.
    """

    path: Path
    info: dict
    fitters: tuple[str, ...]
    chi2: pa.Table
    states: pa.Table
    pulls: pa.Table | None
    has_mc: bool
    label: str = ""

    def entry(self, fitter: str) -> str:
        """The report entry of one of the run's fitters: ``LABEL/FITTER``."""
        return f"{self.label}/{fitter}"

    @property
    def dataset_path(self) -> Path | None:
        """The dataset the run was reconstructed from (run.json ``input.path``, else ``config.dataset``)."""
        path = (self.info.get("input") or {}).get("path") or (self.info.get("config") or {}).get("dataset")
        return Path(path) if isinstance(path, str) and path else None


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
            is missing, or any table is malformed (one line naming file and column).
    """
    shown = os.fspath(path)
    path = Path(path)
    if not path.exists():
        raise InputError(f"{shown}: run directory does not exist")
    if not path.is_dir():
        raise InputError(f"{shown}: not a directory (a run is a directory written by `pkf reconstruct`)")
    info = _read_run_json(path)
    for name in REQUIRED_TABLES:
        if find_table(path, name) is None:
            raise InputError(f"{path}: table {name!r} not found (expected {name}/ or {name}.parquet; incomplete run directory)")
    chi2 = read_table(path, CHI2, name="chi2")
    states = read_table(path, STATES, name="states")
    pulls = read_table(path, PULLS, name="pulls") if find_table(path, "pulls") is not None else None
    has_mc = "pattern" in info or pulls is not None

    in_table = list(dict.fromkeys(chi2.column("fitter").to_pylist()))
    configured = (info.get("config") or {}).get("fitters")
    if isinstance(configured, list) and all(isinstance(f, str) for f in configured):
        extra = [f for f in in_table if f not in configured]
        if extra:
            raise InputError(f"{find_table(path, 'chi2')}: fitter {extra[0]!r} is not in run.json config.fitters")
        fitters = tuple(configured)
    else:
        fitters = tuple(in_table)
    if not fitters:
        raise InputError(f"{path}: the run names no fitter (empty chi2 table and no config.fitters)")
    for name, table in (("states", states), ("pulls", pulls)):
        if table is None or table.num_rows == 0:
            continue
        unknown = set(table.column("fitter").to_pylist()) - set(fitters)
        if unknown:
            raise InputError(f"{path}: table {name!r} has fitter {sorted(unknown)[0]!r} that chi2 does not have")
    label = Path(os.path.abspath(path)).name if label is None else label
    return RunInput(path, info, fitters, chi2, states, pulls, has_mc, label)


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
