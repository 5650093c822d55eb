"""`pkf.io.row_order.group_sort_order` is np.lexsort((key, group)) exactly, with the group bounds."""

from __future__ import annotations

import numpy as np
import pytest

from pkf.io.row_order import INSERTION_MAX, group_sort_order


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("key_kind", ["int", "float"])
def test_equals_lexsort_with_ties_empty_and_large_groups(seed, key_kind):
    rng = np.random.default_rng(seed)
    n_groups = 40
    # group sizes from empty to beyond the insertion-sort limit, rows of groups interleaved
    sizes = rng.integers(0, 3 * INSERTION_MAX, n_groups)
    sizes[:3] = (0, 1, INSERTION_MAX + 1)
    group = rng.permutation(np.repeat(np.arange(n_groups), sizes))
    key = rng.integers(0, 8, group.size)  # few values: many ties, which keep their row order
    if key_kind == "float":
        key = key * 0.5 - 1.0
    order, bounds = group_sort_order(group, key, n_groups)
    np.testing.assert_array_equal(order, np.lexsort((key, group)))
    np.testing.assert_array_equal(bounds, np.concatenate([[0], np.cumsum(sizes)]))


def test_no_rows():
    order, bounds = group_sort_order(np.zeros(0, dtype=np.int64), np.zeros(0), 3)
    assert order.size == 0
    np.testing.assert_array_equal(bounds, np.zeros(4, dtype=np.int64))
