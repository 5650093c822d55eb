"""numba options shared by the compiled kernels, and the generated kernel source blocks.

`NO_REFCOUNT` compiles a function without numba's runtime reference counting (NRT). For
functions that only read and write arrays they are given — no allocation, no array
returned or stored — this is safe, and it matters: numba gives every array bound to a name
(a view such as ``a[j]``, each array argument of a helper inlined into a loop) an atomic
increment and decrement of its reference count. In the forward extension of the pattern
recognition those atomic operations were 40 % of all CPU samples (perf: two instructions,
the atomic add/sub of NRT_incref/NRT_decref; gdb on their return addresses located them);
compiled without NRT the same tracks come out 22 % faster (benchmarks/pattern_recognition.py).
The fit kernels (the Kalman core's pass, the GX2F's propagation and solve, the RK4
transport, the field map) are compiled this way too: reference and GX2F fits 0.60× the
CPU time, parametrized 0.68× (same tracks, same process, bitwise identical outputs).
numba compiles a helper with the flags of the first kernel that calls it, so the shared
hot helpers carry the option themselves (their speed does not depend on who came first).
numba refuses to compile an allocation (or a call to a function that allocates) in such a
kernel, so the option cannot leak memory. numba uses this option for its own
non-allocating helpers (e.g. its mergesort). It is a
private option (``_nrt``), so it is passed only if the installed numba knows it; otherwise
the kernels compile as usual, slower and with the same results.
"""

from __future__ import annotations

import math
from pathlib import Path

import numba as nb
from llvmlite import ir
from numba.core import cgutils, types
from numba.core import options as _numba_options
from numba.extending import intrinsic
from numba.np.arrayobj import make_array, populate_array

__all__ = ["NO_REFCOUNT", "fma", "prefetch_write", "stack_array"]

#: keyword arguments of ``numba.njit`` for non-allocating kernels (empty if unsupported)
NO_REFCOUNT: dict = {"_nrt": False} if hasattr(getattr(_numba_options, "DefaultOptions", None), "_nrt") else {}


@intrinsic
def stack_array(typingctx, shape):
    """A C-contiguous float64 array of the literal `shape` (a tuple of int literals) on the
    stack of the compiled function (one ``alloca`` in its entry block, uninitialised). It
    needs no reference counting, so `NO_REFCOUNT` kernels can create it, and it aliases no
    other array, so LLVM may keep its elements in registers and vectorise over them
    (`pkf.fit.kalman`'s lanes). It must not outlive the function: never return or store it."""
    if not isinstance(shape, types.BaseTuple) or not all(isinstance(n, types.IntegerLiteral) for n in shape):
        return None
    dims = tuple(n.literal_value for n in shape)
    array_type = types.Array(types.float64, len(dims), "C")

    def codegen(context, builder, signature, args):
        double = context.get_value_type(types.float64)
        intp = context.get_value_type(types.intp)
        data = cgutils.alloca_once(builder, ir.ArrayType(double, math.prod(dims)))
        strides = [8 * math.prod(dims[i + 1 :]) for i in range(len(dims))]
        array = make_array(array_type)(context, builder)
        populate_array(
            array,
            data=builder.bitcast(data, double.as_pointer()),
            shape=[ir.Constant(intp, n) for n in dims],
            strides=[ir.Constant(intp, s) for s in strides],
            itemsize=ir.Constant(intp, 8),
            meminfo=None,
        )
        return array._getvalue()

    return array_type(shape), codegen


@intrinsic
def fma(typingctx, a, b, c):
    """a·b + c rounded once (IEEE 754 fusedMultiplyAdd, LLVM's ``llvm.fma.f64``: one FMA
    instruction on x86-64 with FMA3, a correctly rounded library call without it), float64.

    The fit's multiply–add chains use it (issue 18.1): `pkf.physics.linalg` (its generated
    lane kernels too), the Kalman updates, solves and combination of `pkf.fit.kalman` and
    `pkf.fit.kalman_lanes`, the beamline's straight-line step, the layer steps' monomial sums
    and the step noise of `pkf.params`. Unlike numba's ``fastmath={"contract"}``, which lets
    LLVM decide per optimised module which a·b + c it fuses — so code loaded from numba's
    cache and the same code compiled in the process gave different last bits (branch
    fma-contract: the Dask and resumed-run tests, tables of two processes not identical) —
    an explicit fma is one rounding wherever it is compiled or inlined, and every other
    operation keeps its own IEEE rounding: results are determined by the source
    (tests/test_jit_fma.py forbids fastmath in the fit's kernels).

    Measured (benchmarks/fit_core.py --sample minbias, 257,055 nodes, old and new code
    alternating in separate processes, 5 rounds): reference fit 1,932–2,767 → 1,783–2,126
    ns/node, GX2F 1,992–2,016 → 1,766–1,844 (2 rounds), parametrized 297–303 → 289–303
    (×0.98, within the noise; likely because an accumulation s = fma(a, b, s) waits for
    the FMA's latency, 4 cycles per term on this Zen 4, where s += a·b waits 3 for the add:
    the chains of the parametrized fit gain nothing, the reference's wider products do); GSF-12 unchanged (2.55–2.61 →
    2.52–2.57 ms per track). Outputs (benchmarks/table_hashes.py --against): candidates
    bitwise the same, χ² within 4e-10 relative, states and pulls within 6e-9 of each
    column's RMS; against a 50-digit evaluation (benchmarks/smoother_precision.py, 1,000
    minimum-bias tracks, median / 99 % / max per node) states 1.9e-11 / 1.5e-9 / 2.9e-7 →
    1.7e-11 / 1.2e-9 / 4.7e-7 σ, covariances 3.5e-12 / 2.2e-10 / 9.0e-9 → 3.2e-12 /
    2.0e-10 / 1.2e-8."""
    if not all(isinstance(t, (types.Float, types.Integer)) for t in (a, b, c)):
        return None

    def codegen(context, builder, signature, args):
        double = types.float64
        x, y, z = (context.cast(builder, v, t, double) for v, t in zip(args, signature.args))
        return builder.fma(x, y, z)

    return types.float64(a, b, c), codegen


def _prefetch_codegen(write: int):
    def codegen(context, builder, signature, args):
        data = make_array(signature.args[0])(context, builder, args[0]).data
        i8p = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        offset = context.cast(builder, args[1], signature.args[1], types.intp)
        address = builder.gep(builder.bitcast(data, i8p), [offset])
        function_type = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        # declare_intrinsic mangles the pointer type as this llvmlite does ("p0i8"; LLVM remangles
        # it where pointers are opaque): a fixed "llvm.prefetch.p0" fails LLVM 14's verifier (numba 0.58)
        prefetch = builder.module.declare_intrinsic("llvm.prefetch", [i8p], function_type)
        builder.call(prefetch, [address, i32(write), i32(3), i32(1)])  # keep in all levels, data
        return context.get_dummy_value()

    return codegen


@intrinsic
def prefetch_write(typingctx, array, byte_offset):
    """Hint the cache to fetch, for writing, the line at `byte_offset` bytes from the start
    of `array`'s data (LLVM's prefetch intrinsic, x86 ``prefetchw``). A hint only: no
    effect on any value, no fault for an address outside the array. The Kalman
    combination issues it for the output rows of its next block of nodes, so that their
    write-allocate misses overlap its arithmetic instead of stalling the stores."""
    if not isinstance(array, types.Array) or not isinstance(byte_offset, types.Integer):
        return None
    return types.void(array, byte_offset), _prefetch_codegen(1)


@nb.njit(cache=True, inline="always")
def prefetch_write_rows(array, lo, hi):
    """`prefetch_write` of every cache line of rows lo:hi of the C-contiguous `array`
    (none if hi ≤ lo): the output rows a Kalman combination writes next."""
    if hi <= lo:
        return
    row = array.strides[0]
    for byte in range(lo * row, hi * row, 64):
        prefetch_write(array, byte)
    prefetch_write(array, hi * row - 1)  # the last line, where the rows end inside it


# ----------------------------------------------------------------------------------
# Generated kernel source: straight-line code that LLVM vectorises or unrolls, written into
# a source file between a BEGIN and an END marker line by a generator module and checked by
# a test to be exactly what it writes (`pkf.physics.lanes_codegen`)
# ----------------------------------------------------------------------------------


def generated_block_in(path: Path, begin: str, end: str) -> str:
    """The block of `path` from the line `begin` through the line `end`, markers included."""
    text = path.read_text()
    return text[text.index(begin) : text.index(end) + len(end)] + "\n"


def replace_generated_block(path: Path, begin: str, end: str, block: str) -> None:
    """Replace the block of `path` between `begin` and `end` (markers included) by `block`."""
    path.write_text(path.read_text().replace(generated_block_in(path, begin, end), block))
