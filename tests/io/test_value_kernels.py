"""pkf.io.value_kernels: the compiled finite and NaN scans answer as pyarrow's kernels do."""

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pytest

from pkf.io.value_kernels import BLOCK, first_nonfinite, has_nan


def _pyarrow_first_nonfinite(column):
    bad = pc.fill_null(pc.invert(pc.is_finite(column)), False).to_numpy(zero_copy_only=False)
    return int(np.argmax(bad)) if bad.any() else None


def _pyarrow_has_nan(column):
    return bool(pc.any(pc.is_nan(column)).as_py())


def _columns(seed: int, count: int):
    """Random float columns: NaN and ±inf anywhere (also under nulls), nulls at several
    densities, sliced (offsets inside the validity bitmap's bytes) and in several chunks."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        n = int(rng.integers(1, 3 * BLOCK))
        values = rng.normal(size=n)
        for _ in range(int(rng.integers(0, 4))):
            values[rng.integers(0, n)] = rng.choice([np.nan, np.inf, -np.inf])
        mask = rng.random(n) < rng.choice([0.0, 0.01, 0.5, 1.0])
        array = pa.array(values, mask=mask)
        if rng.random() < 0.5:
            lo = int(rng.integers(0, n))
            array = array.slice(lo, int(rng.integers(0, n - lo + 1)))
        cut = int(rng.integers(0, len(array) + 1))
        yield pa.chunked_array([array.slice(0, cut), array.slice(cut)], type=pa.float64())


def test_agree_with_pyarrow_on_random_columns():
    found = 0
    for column in _columns(seed=5, count=1500):
        assert first_nonfinite(column) == _pyarrow_first_nonfinite(column)
        assert has_nan(column) == _pyarrow_has_nan(column)
        found += first_nonfinite(column) is not None
    assert 300 < found < 1400  # both answers occur


def test_a_nan_under_a_null_is_no_nan():
    values = np.zeros(2 * BLOCK)
    values[BLOCK + 7] = np.nan  # under a null: Arrow leaves such values unspecified
    mask = np.zeros(values.size, dtype=bool)
    mask[BLOCK + 7] = True
    column = pa.array(values, mask=mask)
    assert first_nonfinite(column) is None and not has_nan(column)
    values[BLOCK + 9] = -np.inf
    column = pa.array(values, mask=mask)
    assert first_nonfinite(column) == BLOCK + 9 and not has_nan(column)


@pytest.mark.parametrize("type_", [pa.float32(), pa.float16()])
def test_other_float_types(type_):
    values = np.array([1.0, 2.0, np.inf, np.nan], dtype=np.float32)
    column = pa.array(values).cast(type_)
    assert first_nonfinite(column) == 2 and has_nan(column)
    assert first_nonfinite(column.slice(3)) == 0 and first_nonfinite(column.slice(0, 2)) is None
