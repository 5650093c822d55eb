"""The `pkf validate` stage: the reader's checks on a dataset without reconstructing (docs/cli.md).

Every table is checked, and a failing table does not stop the others: the result is one
line per problem (the first bad row of each table, as `pkf reconstruct` would say it),
the warnings (ignored extra columns) and, when nothing is wrong, a one-line summary.
The tables are scanned batch by batch (:mod:`pkf.io.stream`), in bounded memory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pkf.errors import InputError
from pkf.io.reader import check_dataset_dir, find_table, find_truth_tables, read_meta, validate_hit_layers
from pkf.io.schemas import HITS, MC_HITS, PARTICLES
from pkf.io.stream import TableScan, scan_table
from pkf.pipeline.inputs import hit_layer_checks, option_geometry, resolve_geometry
from pkf.pipeline.plan import check_consistency, cut_partitions, table_warnings

#: Events whose MC truth is checked against the hits at a time (bounds memory, as in `pkf reconstruct`).
EVENTS_PER_CHECK = 50

__all__ = ["Validation", "validate_dataset"]


@dataclass
class Validation:
    """What `pkf validate` found: ``problems`` (one line each), ``warnings``, ``summary``."""

    path: Path
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    tables: dict[str, TableScan] = field(default_factory=dict)

    @property
    def valid(self) -> bool:
        return not self.problems

    def attempt(self, step: Callable[[], object]) -> object | None:
        """Run one check; record its InputError as a problem (and return None)."""
        try:
            return step()
        except InputError as exc:
            if str(exc) not in self.problems:  # e.g. an ambiguous table, found by two checks
                self.problems.append(str(exc))
            return None

    @property
    def summary(self) -> str:
        """``DATASET: N events, M hits, tables hits, ...: valid``."""
        hits = self.tables.get("hits")
        events = int(hits.events.size) if hits is not None else 0
        rows = hits.n_rows if hits is not None else 0
        return f"{self.path}: {events} events, {rows} hits, tables {', '.join(self.tables)}: valid"


def validate_dataset(path: str | Path, geometry: str | None = None) -> Validation:
    """Check the dataset at ``path`` as `pkf reconstruct` would (``geometry``: ``--geometry``),
    continuing past a failing table; see :class:`Validation`."""
    found = Validation(Path(path))
    if found.attempt(lambda: check_dataset_dir(path)) is None:
        return found
    path = Path(path)
    try:
        meta = read_meta(path, required=False)
    except InputError as exc:  # a broken meta.json: the tables are checked all the same
        found.problems.append(str(exc))
        detector = found.attempt(lambda: option_geometry(geometry)) if geometry else None
    else:
        detector = found.attempt(lambda: resolve_geometry(path, meta, geometry))
    layer_check = None
    if detector is not None:
        layer_checks = hit_layer_checks(detector)

        def layer_check(table, source):
            validate_hit_layers(table, **layer_checks, source=source)

    for name, schema in (("hits", HITS), ("particles", PARTICLES), ("mc_hits", MC_HITS)):
        check = layer_check if name == "hits" else None
        scan = found.attempt(lambda name=name, schema=schema, check=check: _scan(path, name, schema, check))
        if scan is not None:
            found.tables[name] = scan
    found.attempt(lambda: find_truth_tables(path))
    tables = found.tables
    if found.valid and len(tables) == 3:
        found.attempt(lambda: check_consistency(tables, cut_partitions(tables["hits"], EVENTS_PER_CHECK)))
    found.warnings = table_warnings(tables)
    return found


def _scan(path: Path, name: str, schema, check) -> TableScan | None:
    """Scan table ``name`` of the dataset (None if an optional table is absent)."""
    location = find_table(path, name)
    if location is None:
        if name == "hits":
            raise InputError(f"{path}: table 'hits' not found (expected hits.parquet or hits/)")
        return None
    return scan_table(location, schema, name, check)
