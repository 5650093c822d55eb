"""Shared fixtures: a private field-map cache so tests never touch the user's, and one numba
kernel cache for the test process, its xdist workers and every ``pkf`` subprocess they start."""

import os

import numba
import pytest

import pkf  # noqa: F401  (importing pkf points numba's cache at the directory of this source)

# A `pkf` subprocess (the CLI, the examples, Dask workers) would otherwise derive its numba cache
# from the private PKF_CACHE_DIR below and compile every kernel again (~30-90 s each on CI).
os.environ.setdefault("NUMBA_CACHE_DIR", numba.config.CACHE_DIR)


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory):
    cache = tmp_path_factory.mktemp("pkf-cache")
    old = os.environ.get("PKF_CACHE_DIR")
    os.environ["PKF_CACHE_DIR"] = str(cache)
    yield
    if old is None:
        os.environ.pop("PKF_CACHE_DIR", None)
    else:
        os.environ["PKF_CACHE_DIR"] = old
