"""The documentation in docs/ matches the code: table columns, geometry keys, CLI options."""

from __future__ import annotations

import re
import tomllib
from importlib import resources
from pathlib import Path

import click
import pyarrow as pa
import pytest

from pkf.io import schemas

DOCS = Path(__file__).resolve().parents[1] / "docs"

#: Arrow's names of the types, as the docs write them.
_TYPE_NAMES = {"double": "float64", "float": "float32", "halffloat": "float16"}


def _sections(text: str) -> dict[str, str]:
    """Text of each ``## NAME`` section of a markdown page, by NAME."""
    parts = re.split(r"^## +(.+?)\s*$", text, flags=re.MULTILINE)
    return {parts[i].strip().strip("`"): parts[i + 1] for i in range(1, len(parts), 2)}


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def documented_columns(section: str) -> dict[str, tuple[str, bool]] | None:
    """Columns of the first ``| column | type | ...`` table of a section: name → (type, nullable).

    A row may name several columns (``x``, ``y``, ... separated by commas) of one type.
    """
    lines = section.splitlines()
    for start, line in enumerate(lines):
        if line.startswith("|") and _cells(line)[:2] == ["column", "type"]:
            break
    else:
        return None
    columns: dict[str, tuple[str, bool]] = {}
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = _cells(line)
        names = re.findall(r"`([^`]+)`", cells[0])
        kind = cells[1]
        nullable = "nullable" in kind
        type_name = kind.split(",")[0].strip()
        for name in names:
            assert name not in columns, f"column {name!r} documented twice"
            columns[name] = (type_name, nullable)
    return columns


def _schemas() -> dict[str, pa.Schema]:
    """Every table schema of pkf.io.schemas, by its ``pkf.table`` name."""
    found = {}
    for value in vars(schemas).values():
        if isinstance(value, pa.Schema) and value.metadata and b"pkf.table" in value.metadata:
            found[value.metadata[b"pkf.table"].decode()] = value
    return found


def _expected(schema: pa.Schema) -> dict[str, tuple[str, bool]]:
    return {f.name: (_TYPE_NAMES.get(str(f.type), str(f.type)), f.nullable) for f in schema}


FORMATS = _sections((DOCS / "formats.md").read_text(encoding="utf-8"))


def test_every_schema_is_found():
    names = set(_schemas())
    assert set(schemas.DATASET_SCHEMAS) | set(schemas.RUN_SCHEMAS) <= names
    assert {"hits", "particles", "mc_hits", "chi2", "candidates", "states", "pulls"} <= names


@pytest.mark.parametrize("table", sorted(_schemas()))
def test_formats_documents_every_column_of(table):
    """docs/formats.md has a section per table whose columns and types equal the schema's."""
    assert table in FORMATS, f"docs/formats.md has no '## {table}' section"
    documented = documented_columns(FORMATS[table])
    assert documented is not None, f"docs/formats.md '## {table}': no '| column | type |' table"
    expected = _expected(_schemas()[table])
    missing = sorted(set(expected) - set(documented))
    absent = sorted(set(documented) - set(expected))
    assert not missing, f"{table}: columns of the schema not documented: {missing}"
    assert not absent, f"{table}: documented columns not in the schema: {absent}"
    wrong = {n: (documented[n], expected[n]) for n in expected if documented[n] != expected[n]}
    assert not wrong, f"{table}: (documented, schema) type/nullable differ: {wrong}"


def test_documented_tables_without_schema_are_marked_as_being_built():
    """A documented Parquet table that has no schema yet (track_states) says so."""
    for name, text in FORMATS.items():
        if documented_columns(text) is not None and name not in _schemas():
            assert "being built" in text.lower(), f"'## {name}' documents a table pkf does not have"


def test_parser_sees_a_missing_column():
    """The check can fail: a column dropped from the doc is reported."""
    text = FORMATS["hits"].replace("| `sigma_v` |", "| `not_sigma_v` |")
    documented = documented_columns(text)
    assert "sigma_v" not in documented and "not_sigma_v" in documented
    assert set(documented) != set(_expected(schemas.HITS))


# --------------------------------------------------------------------------- geometry


def _documented_geometry_keys() -> dict[str, set[str]]:
    """Keys documented in docs/geometry.md: the first column of the first table of each
    ``## [table]`` / ``## [[table]]`` section, and of ``## Top-level keys`` (as "top")."""
    sections = _sections((DOCS / "geometry.md").read_text(encoding="utf-8"))
    keys: dict[str, set[str]] = {}
    for title, text in sections.items():
        match = re.match(r"\[+([a-z_]+)\]+", title)
        if not match and not title.startswith("Top-level keys"):
            continue
        table = match.group(1) if match else "top"
        rows = []
        for line in text.splitlines():
            if line.startswith("|"):
                rows.append(line)
            elif rows:
                break  # the end of the first table
        keys[table] = {name for line in rows[2:] for name in re.findall(r"`([a-z_0-9]+)`", _cells(line)[0])}
    return keys


def _used_keys(config: dict) -> dict[str, set[str]]:
    used: dict[str, set[str]] = {"top": set(config)}
    for key, value in config.items():
        items = value if isinstance(value, list) else [value]
        for item in items:
            if isinstance(item, dict):
                used.setdefault(key, set()).update(item)
    return used


@pytest.mark.parametrize("name", ["lhcb-like", "telescope"])
def test_builtin_geometry_uses_documented_keys(name):
    text = resources.files("pkf.geometry").joinpath("data", f"{name}.toml").read_text()
    documented = _documented_geometry_keys()
    for table, keys in _used_keys(tomllib.loads(text)).items():
        assert table in documented, f"docs/geometry.md has no section for [{table}]"
        undocumented = keys - documented[table]
        assert not undocumented, f"{name}.toml [{table}]: keys not in docs/geometry.md: {sorted(undocumented)}"


def test_geometry_doc_lists_every_accepted_key():
    """Every key the geometry loader accepts is documented (and no other)."""
    from pkf.geometry import detector

    documented = _documented_geometry_keys()
    assert documented["layers"] == detector._LAYER_KEYS
    assert documented["passive"] == detector._PASSIVE_KEYS
    assert documented["top"] == detector._TOP_KEYS
    assert documented["envelope"] == {"half_width", "max_slope", "min_momentum"}
    assert documented["steps"] == {"from", "to", "type"}
    assert documented["field_map"] == {"spacing", "x_range", "y_range", "z_range"}
    assert documented["field"] == {"model", "b0", "z1", "z2", "edge_length", "k", "length_scale", "bx", "by", "bz"}


# --------------------------------------------------------------------------- CLI


def _commands():
    from pkf.cli import cli

    return cli.commands


def test_cli_doc_lists_every_command_and_option():
    text = (DOCS / "cli.md").read_text(encoding="utf-8")
    sections = _sections(text)
    for name, command in _commands().items():
        title = f"pkf {name}"
        assert title in sections, f"docs/cli.md has no '## pkf {name}' section"
        for param in command.params:
            if isinstance(param, click.Option):
                for opt in param.opts:
                    if opt.startswith("--") and opt != "--help":
                        assert f"`{opt}" in sections[title], f"docs/cli.md '## {title}': option {opt} not documented"
            else:
                assert param.human_readable_name.upper().split("[")[0].rstrip(".") in sections[title].upper()


# --------------------------------------------------------------------------- links


def _anchors(page: Path) -> set[str]:
    """GitHub's anchors of the headings of a markdown page."""
    titles = re.findall(r"^#+ +(.+?)\s*$", page.read_text(encoding="utf-8"), flags=re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", t.lower()).replace(" ", "-") for t in titles}


def _citations():
    """(where, page, anchor) of every docs citation in the sources, the docs and the README."""
    root = DOCS.parent
    sources = [*root.joinpath("src").rglob("*.py"), *root.joinpath("src").rglob("*.toml"), root / "README.md"]
    for path in sources:
        for page, anchor in re.findall(r"docs/([\w-]+\.md)(?:#([\w-]+))?", path.read_text(encoding="utf-8")):
            yield path.relative_to(root), page, anchor
    for path in DOCS.glob("*.md"):
        for page, anchor in re.findall(r"\]\(([\w-]+\.md)?(?:#([\w-]+))?\)", path.read_text(encoding="utf-8")):
            yield path.relative_to(root), page or path.name, anchor


def test_every_docs_citation_resolves():
    """Citations such as docs/formats.md#chi2 in code, docs and README name an existing page and heading."""
    bad = []
    for where, page, anchor in _citations():
        target = DOCS / page
        if not target.is_file() or (anchor and anchor not in _anchors(target)):
            bad.append(f"{where}: docs/{page}#{anchor}")
    assert not bad, f"citations that do not resolve: {bad}"


def test_anchor_rule_matches_github():
    page = DOCS / "physics.md"
    assert "the-gaussian-sum-filter-gsf-and-the-bethe-heitler-mixture" in _anchors(page)
    assert "the-reference-fitter-two-passes" in _anchors(page)
    assert "summaryjson" in _anchors(DOCS / "formats.md")


def test_formats_pyarrow_example_writes_valid_hits(tmp_path, monkeypatch):
    """The plain-pyarrow example of docs/formats.md writes a hits table the reader accepts."""
    from pkf.geometry import load_geometry
    from pkf.io.reader import read_table, validate_hit_layers

    code = re.search(r"```python\n(.*?)```", FORMATS["hits"], flags=re.DOTALL).group(1)
    (tmp_path / "DATASET").mkdir()
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "docs/formats.md", "exec"), {})
    hits = read_table(tmp_path / "DATASET", schemas.HITS, name="hits")
    geometry = load_geometry("lhcb-like")
    validate_hit_layers(hits, geometry.layer_z, geometry.layer_kind)
    assert hits.num_rows == 2
