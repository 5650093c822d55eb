"""The import floors of DESIGN §14: no module of `pkf` imports from a higher floor, no circle of modules.

Floors, top to bottom: cli → pipeline → report → seeding → fit → simulation → params → physics
→ geometry, io → errors, jit (`pkf/__init__.py` sits at the bottom with errors and jit). A module
may import from its own subpackage or from a lower floor: not from a higher one, nor from the
other part of its own floor (geometry ↔ io, errors ↔ jit); anything may import `pkf` itself. Every import statement counts,
including those deferred inside functions and relative ones (`from . import x`,
`from ..fit import y`). The graph is built from the source with `ast`, nothing is imported.

An edge goes to the module an import names: `from pkf.a import b` goes to `pkf.a.b` when that is
a module, else to `pkf.a`. The parent packages Python runs on the way (`pkf`, `pkf.a`) are not
edges: a package `__init__` that re-exports its own modules would otherwise make every module of
the package a circle with it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pkf

PACKAGE_ROOT = Path(pkf.__file__).resolve().parent

#: floor of each top-level part of pkf; higher numbers are higher floors (DESIGN §14)
FLOORS = {
    "cli": 9,
    "__main__": 10,  # the console script (`pkf`, `python -m pkf`): only imports pkf.cli
    "pipeline": 8,
    "report": 7,
    "seeding": 6,
    "fit": 5,
    "simulation": 4,
    "params": 3,
    "physics": 2,
    "geometry": 1,
    "io": 1,
    "errors": 0,
    "jit": 0,
    "": 0,  # pkf/__init__.py
}


def module_name(path: Path) -> str:
    """Dotted module name of a source file under PACKAGE_ROOT (`pkf.fit.kalman`, `pkf.io`, `pkf`)."""
    parts = list(path.relative_to(PACKAGE_ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(["pkf", *parts])


def is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def all_modules() -> dict[str, Path]:
    return {module_name(path): path for path in sorted(PACKAGE_ROOT.rglob("*.py"))}


def floor_of(module: str) -> tuple[str, int]:
    """(part, floor) of a module: `pkf.fit.kalman` → ("fit", 5)."""
    parts = module.split(".")
    part = parts[1] if len(parts) > 1 else ""
    if part not in FLOORS:
        raise AssertionError(f"{module}: part {part!r} has no floor in DESIGN §14; add it to FLOORS")
    return part, FLOORS[part]


def resolve_relative(module: str, package: bool, level: int, target: str | None) -> str:
    """Absolute name of `from <level dots><target> import ...` written in `module`."""
    base = module.split(".")
    if not package:
        base = base[:-1]  # a plain module's package
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, int]]:
    """(imported pkf module, line) for every import statement of a file, deferred ones included."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "pkf" or alias.name.startswith("pkf."):
                    found.append((alias.name, node.lineno))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                source = resolve_relative(module, is_package(path), node.level, node.module)
            else:
                source = node.module or ""
            if not (source == "pkf" or source.startswith("pkf.")):
                continue
            for alias in node.names:
                submodule = f"{source}.{alias.name}"
                found.append((submodule if submodule in modules else source, node.lineno))
    for name, line in found:
        assert name in modules, f"{module}:{line} imports {name}, which is no module of pkf"
    return found


def import_graph() -> tuple[dict[str, Path], dict[str, dict[str, int]]]:
    """All modules and the edges module → {imported module: first line}."""
    modules = all_modules()
    edges: dict[str, dict[str, int]] = {}
    for module, path in modules.items():
        targets: dict[str, int] = {}
        for target, line in imports_of(module, path, modules):
            if target != module:
                targets.setdefault(target, line)
        edges[module] = targets
    return modules, edges


def strongly_connected_components(edges: dict[str, dict[str, int]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative; components of more than one module only."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components = []
    counter = 0
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, successors = work[-1]
            advanced = False
            for successor in successors:
                if successor not in index:
                    index[successor] = low[successor] = counter
                    counter += 1
                    stack.append(successor)
                    on_stack.add(successor)
                    work.append((successor, iter(sorted(edges[successor]))))
                    advanced = True
                    break
                if successor in on_stack:
                    low[node] = min(low[node], index[successor])
            if advanced:
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    components.append(sorted(component))
    return components


def upward_edges(modules, edges) -> list[str]:
    """Imports from a higher floor or from another part of the same floor, as lines to print."""
    bad = []
    for module, targets in edges.items():
        part, floor = floor_of(module)
        for target, line in targets.items():
            target_part, target_floor = floor_of(target)
            if target_part != part and target_floor >= floor and target_part != "":
                bad.append(
                    f"{modules[module].relative_to(PACKAGE_ROOT.parent)}:{line}: {module} ({part}, floor {floor})"
                    f" imports {target} ({target_part}, floor {target_floor})"
                )
    return sorted(bad)


def circle_edges(modules, edges) -> list[str]:
    bad = []
    for component in strongly_connected_components(edges):
        members = set(component)
        lines = [
            f"  {modules[module].relative_to(PACKAGE_ROOT.parent)}:{line}: {module} imports {target}"
            for module in component
            for target, line in sorted(edges[module].items())
            if target in members
        ]
        bad.append(f"circle of {len(component)} modules: {', '.join(component)}\n" + "\n".join(lines))
    return bad


def test_no_import_from_a_higher_floor():
    modules, edges = import_graph()
    bad = upward_edges(modules, edges)
    assert not bad, "imports from a higher floor or a sibling part (DESIGN §14):\n" + "\n".join(bad)


def test_no_circle_of_modules():
    modules, edges = import_graph()
    bad = circle_edges(modules, edges)
    assert not bad, "circles of modules (DESIGN §14, deferred imports included):\n" + "\n".join(bad)


# --- the checker itself, on small made-up graphs -------------------------------------------------


def test_checker_finds_a_circle_through_a_deferred_import(tmp_path):
    source = tmp_path / "a.py"
    source.write_text("def f():\n    from pkf.pipeline import b\n")
    modules = {"pkf.pipeline.a": source, "pkf.pipeline.b": source}
    found = imports_of("pkf.pipeline.a", source, modules)
    assert found == [("pkf.pipeline.b", 2)]
    edges = {"pkf.pipeline.a": {"pkf.pipeline.b": 2}, "pkf.pipeline.b": {"pkf.pipeline.a": 1}}
    assert strongly_connected_components(edges) == [["pkf.pipeline.a", "pkf.pipeline.b"]]


def test_checker_resolves_relative_imports_and_flags_upward_ones(tmp_path):
    source = tmp_path / "tuning.py"
    source.write_text("from ..fit.parametrized import STEP_UT\nfrom . import formulas\n")
    modules = {
        "pkf.params.tuning": source,
        "pkf.params.formulas": source,
        "pkf.fit.parametrized": source,
        "pkf.fit": source,
        "pkf.params": source,
    }
    found = imports_of("pkf.params.tuning", source, modules)
    assert found == [("pkf.fit.parametrized", 1), ("pkf.params.formulas", 2)]
    edges = {name: {} for name in modules}
    edges["pkf.params.tuning"] = dict(found)
    (bad,) = upward_edges({name: PACKAGE_ROOT / "x.py" for name in modules}, edges)
    assert "pkf.params.tuning (params, floor 3) imports pkf.fit.parametrized (fit, floor 5)" in bad


def test_checker_flags_a_sibling_part_of_the_same_floor():
    edges = {"pkf.io.reader": {"pkf.geometry.detector": 3, "pkf.errors": 2, "pkf": 1},
             "pkf.geometry.detector": {}, "pkf.errors": {}, "pkf": {}}
    (bad,) = upward_edges({name: PACKAGE_ROOT / "x.py" for name in edges}, edges)
    assert "pkf.io.reader (io, floor 1) imports pkf.geometry.detector (geometry, floor 1)" in bad
