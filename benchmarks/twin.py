"""A second pkf in the same process: another checkout's package imported as ``pkf_base`` (issue 18).

Speed differences of a few per cent cannot be measured by running two checkouts one after
the other on this machine: a virtual machine whose steal time moves a benchmark by ±30 %
between processes minutes apart. Timed side by side in one process, alternating, the two
versions see the same machine state. This module makes that possible: `load_twin` copies
``CHECKOUT/src/pkf`` (with its package data) to a cache directory as the package
``pkf_base``, rewriting every reference to ``pkf`` in it (imports, ``importlib.resources``
names), and imports it. Its kernels, record types and registries are its own, so the
benchmarks can build the same objects from both packages and time them alternately
(``--against CHECKOUT`` of `fit_core.py` and `parametrized_steps.py`).

The copy lives under $PKF_CACHE_DIR (or ~/.cache/pkf) in ``twins/<digest>``, named by the
content of the checkout's source, with numba's on-disk cache of its kernels beside it
(reused between runs). A checkout whose pkf has not the functions a benchmark calls fails with an
ordinary AttributeError: compare checkouts of the same API (the benchmarks name the
functions they need).

Placement in memory alone moves a kernel's time by up to ±15 % between two copies of the
same code (kalman_lanes' docstring): compare against a null A/B, ``--against`` the
current checkout itself, before reading a ratio.
"""

from __future__ import annotations

import hashlib
import importlib
import os
import pkgutil
import re
import shutil
import sys
from pathlib import Path

TWIN_NAME = "pkf_base"
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


def rewrite_references(text: str) -> str:
    """``pkf`` as a package reference (``pkf.x``, ``import pkf``, ``"pkf.params"``) → ``pkf_base``;
    names that merely contain it (``pkf_x``, ``mypkf``) are left alone."""
    return _REFERENCE.sub(TWIN_NAME, text)


def twin_directory(checkout: Path) -> Path:
    """The directory holding the ``pkf_base`` copy of `checkout`'s package (made if absent)."""
    root = _source_root(checkout)
    base = Path(os.environ.get("PKF_CACHE_DIR") or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
                / "pkf")
    target = base / "twins" / _digest(root)
    package = target / TWIN_NAME
    if not (package / "__init__.py").is_file():
        staging = target.with_name(target.name + f".tmp{os.getpid()}")
        shutil.rmtree(staging, ignore_errors=True)
        shutil.copytree(root, staging / TWIN_NAME, ignore=shutil.ignore_patterns("__pycache__"))
        for path in (staging / TWIN_NAME).rglob("*.py"):
            path.write_text(rewrite_references(path.read_text()))
        shutil.rmtree(target, ignore_errors=True)
        os.replace(staging, target)
    return target


def load_twin(checkout: Path):
    """Import `checkout`'s pkf as the package ``pkf_base``, with all its modules, and return it
    (the one already imported if there is one). numba caches the copy's kernels beside it
    (their dispatchers read the cache directory when their module is imported, hence all
    modules at once); the process's cache directory is left as it was."""
    if TWIN_NAME in sys.modules:
        return sys.modules[TWIN_NAME]
    directory = twin_directory(checkout)
    import numba

    before = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = str(directory / "numba")
    sys.path.insert(0, str(directory))
    try:
        package = importlib.import_module(TWIN_NAME)
        numba.config.CACHE_DIR = str(directory / "numba")  # its __init__ may have set its own
        for info in pkgutil.walk_packages(package.__path__, TWIN_NAME + "."):
            if not info.name.endswith("__main__"):
                importlib.import_module(info.name)
        return package
    finally:
        sys.path.remove(str(directory))
        numba.config.CACHE_DIR = before
