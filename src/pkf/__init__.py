"""pkf: track reconstruction with hit triplets and the LHCb parametrized Kalman filter.

Units everywhere: mm, MeV (c = 1), tesla, rad (docs/formats.md#conventions).
"""

import hashlib
import os
import sys
from pathlib import Path

__all__ = ["__version__"]


def __getattr__(name: str) -> str:
    """``pkf.__version__``, read from the installed metadata on first use: importing
    `importlib.metadata` takes ~65 ms, and until `pkf.__main__` runs, Ctrl-C at start-up
    would print a traceback."""
    if name != "__version__":
        raise AttributeError(f"module 'pkf' has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("pkf")
    except PackageNotFoundError:  # running from a source tree that is not installed
        value = "0.0.0+unknown"
    globals()["__version__"] = value
    return value


def _configure_numba_cache() -> None:
    """Keep numba's on-disk cache per version of pkf's source.

    numba invalidates a cached kernel only when *its own* file changes, not when a
    function it calls from another module does; a kernel compiled against an older
    extrapolation formula would silently survive an upgrade. So the cache lives in a
    directory named by a hash of all of pkf's source files (content, not time), under
    $PKF_CACHE_DIR or ~/.cache/pkf. Setting NUMBA_CACHE_DIR yourself overrides this.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    base = Path(os.environ.get("PKF_CACHE_DIR") or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pkf")
    cache_dir = str(base / "numba" / digest.hexdigest()[:16])
    numba = sys.modules.get("numba")
    if numba is None:  # numba reads it when imported; not importing it here keeps `pkf --help` and Ctrl-C at start-up quick
        os.environ["NUMBA_CACHE_DIR"] = cache_dir
    else:
        numba.config.CACHE_DIR = cache_dir


_configure_numba_cache()
