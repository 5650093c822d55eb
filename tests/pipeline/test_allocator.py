"""pkf.pipeline.allocator: with glibc, the arrays of one batch reuse the memory the previous batch freed.

Without the setting, glibc (2.36) faults the pages of ten 10 MB arrays in again for every batch
(4,255 faults per batch after the first); with it, none after the first batch.
"""

import os
import resource

import numpy as np
import pytest

from pkf.pipeline.allocator import keep_freed_memory


def _page_faults_of_a_batch() -> int:
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    arrays = [np.ones(1_250_000 + 1000 * k) for k in range(10)]  # ~100 MB, every page written
    after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    del arrays
    return after - before


def test_a_batch_reuses_the_memory_the_previous_one_freed():
    if not keep_freed_memory():
        pytest.skip("not glibc")
    assert keep_freed_memory()  # once per process, then a no-op
    _page_faults_of_a_batch()  # the heap grows once
    assert max(_page_faults_of_a_batch() for _ in range(3)) < 100


def test_arrow_allocates_through_the_same_malloc(tmp_path):
    """Arrow's decoded pages go through malloc too (its default pool was mimalloc, which returns
    freed pages to the kernel: 2.3–3.5 s of system CPU on 1,000 minimum-bias events)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    if not keep_freed_memory():
        pytest.skip("not glibc")
    if "ARROW_DEFAULT_MEMORY_POOL" in os.environ:
        pytest.skip("the user chose Arrow's pool")
    assert pa.default_memory_pool().backend_name == "system"
    pq.write_table(pa.table({"x": np.arange(100_000.0)}), tmp_path / "x.parquet")
    before = pa.system_memory_pool().bytes_allocated()
    decoded = pq.read_table(tmp_path / "x.parquet")
    assert pa.system_memory_pool().bytes_allocated() - before >= 800_000  # the decoded column, by malloc
    assert decoded.column("x").to_numpy()[-1] == 99_999.0
