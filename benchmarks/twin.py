"""A second pkf in the same process: another checkout's package imported as ``pkf_base_<digest>`` (issue 18).

Speed differences of a few per cent cannot be measured by running two checkouts one after
the other on this machine: a virtual machine whose steal time moves a benchmark by ±30 %
between processes minutes apart. Timed side by side in one process, alternating, the two
versions see the same machine state. This module makes that possible: `load_twin` copies
``CHECKOUT/src/pkf`` (with its package data) to a cache directory as the package
``pkf_base_<digest>``, named by the content of the checkout's source, rewriting every
reference to ``pkf`` in it (imports, ``importlib.resources`` names), and imports it. Its
kernels, record types and registries are its own, so the benchmarks build the same objects
from both packages and time them alternately (``--against CHECKOUT`` of `fit_core.py` and
`parametrized_steps.py`, and `side_by_side.py`). The digest in the name keeps a twin's types
apart from another checkout's in numba's cache, where a kernel of this checkout compiled for
a twin's record type (`parametrized_steps.py --against`) is filed under that type's name.

The copy lives under $PKF_CACHE_DIR (or ~/.cache/pkf) in ``twins/<digest>``, with numba's
on-disk cache of its kernels beside it (reused between runs). A checkout whose pkf lacks a
function a benchmark calls fails with an ordinary AttributeError: compare checkouts of the
same API.

`side_by_side` times two such builds alternately. Placement in memory alone moves a
kernel's time by up to ±15 % between two copies of the same code (kalman_lanes'
docstring): compare against a null A/B, ``--against`` the current checkout itself, before
reading a ratio.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import pkgutil
import re
import shutil
import sys
import time
from pathlib import Path

TWIN_PREFIX = "pkf_base"
_REFERENCE = re.compile(r"\bpkf(?=[.\s'\"]|$)", re.MULTILINE)


def _source_root(checkout: Path) -> Path:
    root = Path(checkout).resolve() / "src" / "pkf"
    if not (root / "__init__.py").is_file():
        raise SystemExit(f"error: {checkout} is not a pkf checkout (no src/pkf/__init__.py)")
    return root


def _digest(root: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def rewrite_references(text: str, name: str = TWIN_PREFIX) -> str:
    """``pkf`` as a package reference (``pkf.x``, ``import pkf``, ``"pkf.params"``) → `name`;
    names that merely contain it (``pkf_x``, ``mypkf``) are left alone."""
    return _REFERENCE.sub(name, text)


def twin_directory(checkout: Path) -> tuple[Path, str]:
    """The directory holding the copy of `checkout`'s package (made if absent) and the copy's
    package name."""
    root = _source_root(checkout)
    digest = _digest(root)
    name = f"{TWIN_PREFIX}_{digest}"
    base = Path(os.environ.get("PKF_CACHE_DIR") or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
                / "pkf")
    target = base / "twins" / digest
    if not (target / name / "__init__.py").is_file():
        staging = target.with_name(target.name + f".tmp{os.getpid()}")
        shutil.rmtree(staging, ignore_errors=True)
        shutil.copytree(root, staging / name, ignore=shutil.ignore_patterns("__pycache__"))
        for path in (staging / name).rglob("*.py"):
            path.write_text(rewrite_references(path.read_text(), name))
        shutil.rmtree(target, ignore_errors=True)
        os.replace(staging, target)
    return target, name


def load_twin(checkout: Path):
    """Import `checkout`'s pkf as the package ``pkf_base_<digest>``, with all its modules, and
    return it (the one already imported if there is one). numba caches the copy's kernels beside it
    (their dispatchers read the cache directory when their module is imported, hence all
    modules at once); the process's cache directory is left as it was."""
    directory, name = twin_directory(checkout)
    if name in sys.modules:
        return sys.modules[name]
    import numba

    before = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = str(directory / "numba")
    sys.path.insert(0, str(directory))
    try:
        package = importlib.import_module(name)
        numba.config.CACHE_DIR = str(directory / "numba")  # its __init__ may have set its own
        for info in pkgutil.walk_packages(package.__path__, name + "."):
            if not info.name.endswith("__main__"):
                importlib.import_module(info.name)
        return package
    finally:
        sys.path.remove(str(directory))
        numba.config.CACHE_DIR = before


def submodule(package, name: str):
    """Module `name` (dotted, e.g. ``fit.kalman``) of `package`: pkf or a twin."""
    return importlib.import_module(f"{package.__name__}.{name}")


def best_of(run, repeat: int) -> float:
    """Minimum CPU seconds of `repeat` calls of `run`."""
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        run()
        times.append(time.process_time() - t0)
    return min(times)


def side_by_side(runs: dict, rounds: int, repeat: int) -> dict[str, list[float]]:
    """CPU seconds per round of each of runs["base"], runs["new"], alternating (base first in
    even rounds), after one warm-up call of each."""
    for run in runs.values():
        run()
    times = {"base": [], "new": []}
    for r in range(rounds):
        for side in ("base", "new") if r % 2 == 0 else ("new", "base"):
            times[side].append(best_of(runs[side], repeat))
    return times
