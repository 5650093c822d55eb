"""Shared fixtures: a private field-map cache so tests never touch the user's."""

import os

import pytest


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
