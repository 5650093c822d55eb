"""The symbol map of `benchmarks/kernel_profile.py` (perf itself is not needed): numba's mangled
names made readable, and each kernel's perf-map entry at the address numba runs it from."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"

_CHILD = """
import sys
sys.path.insert(0, {bench!r})
import kernel_profile
kernel_profile.keep_object_code()
import numpy as np
from pkf.io.row_order import group_sort_order
group_sort_order(np.zeros(3, dtype=np.int64), np.zeros(3), 1)
cres = next(iter(group_sort_order.overloads.values()))
address = cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name)
entries = {{line.split()[2]: int(line.split()[0], 16) for line in kernel_profile.perf_map_lines()}}
assert entries[cres.fndesc.llvm_func_name] == address, "entry point not at its address"
names = {{kernel_profile.readable_name(name) for name in entries}}
assert "pkf.io.row_order.group_sort_order" in names, sorted(names)[:5]
print("ok")
"""


def test_readable_names():
    sys.path.insert(0, str(BENCH))
    try:
        from kernel_profile import readable_name
    finally:
        sys.path.remove(str(BENCH))
    mangled = "_ZN3pkf7seeding7forward5scifi12scifi_searchB4v184B36c8tJTIeFIjxB2IKSgI4CrvQCltYEAA_3d_3dE8Transport"
    assert readable_name(mangled) == "pkf.seeding.forward.scifi.scifi_search"
    assert readable_name("_ZN7cpython3pkf2io9row_order16group_sort_orderB2v1E5Array") == (
        "cpython:pkf.io.row_order.group_sort_order"
    )
    assert readable_name("cfunc._ZN3pkf3fit6kalman9_fit_onceB2v1E") == "cfunc:pkf.fit.kalman._fit_once"
    assert readable_name("__memmove_avx512_unaligned_erms") == "__memmove_avx512_unaligned_erms"


@pytest.mark.skipif(shutil.which("nm") is None, reason="needs binutils' nm")
def test_perf_map_has_each_kernel_at_its_entry_point():
    out = subprocess.run([sys.executable, "-c", _CHILD.format(bench=str(BENCH))], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "ok"
