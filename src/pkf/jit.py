"""numba options shared by the compiled kernels.

`NO_REFCOUNT` compiles a function without numba's runtime reference counting (NRT). For
functions that only read and write arrays they are given — no allocation, no array
returned or stored — this is safe, and it matters: numba gives every array bound to a name
(a view such as ``a[j]``, each array argument of a helper inlined into a loop) an atomic
increment and decrement of its reference count. In the forward extension of the pattern
recognition those atomic operations were 40 % of all CPU samples (perf: two instructions,
the atomic add/sub of NRT_incref/NRT_decref; gdb on their return addresses located them);
compiled without NRT the same tracks come out 22 % faster (benchmarks/pattern_recognition.py).
numba uses this option for its own non-allocating helpers (e.g. its mergesort). It is a
private option (``_nrt``), so it is passed only if the installed numba knows it; otherwise
the kernels compile as usual, slower and with the same results.
"""

from __future__ import annotations

from numba.core import options as _numba_options

__all__ = ["NO_REFCOUNT"]

#: keyword arguments of ``numba.njit`` for non-allocating kernels (empty if unsupported)
NO_REFCOUNT: dict = {"_nrt": False} if hasattr(getattr(_numba_options, "DefaultOptions", None), "_nrt") else {}
