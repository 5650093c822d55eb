"""Compile-time dispatch on the NamedTuple class of a compiled function's first argument.

The fitters' shared kernels (the propagator's plane loop, the outlier driver) call
functions such as ``interact(actor, ext, k, direction)`` whose body depends on what the
first argument is: a NamedTuple of arrays and numbers. `dispatched` makes such a
function: each NamedTuple class registers its njit implementation, and numba resolves
the call to it, inlined, when it compiles the caller, so one compiled kernel per type
is built (and cached on disk) with no Python object inside. This is the mechanism of
`pkf.fit.extrapolator.extrapolate`, made reusable.
"""

from __future__ import annotations

import numba as nb
from numba.extending import overload

_TEMPLATE = """
def function({params}):
    return registry[type({first})]({params})


def resolve({params}):
    if not isinstance({first}, nb.types.BaseNamedTuple):
        return None
    implementation = registry.get({first}.instance_class)
    if implementation is None:
        return None

    def call({params}):
        return implementation({params})

    return call
"""


def dispatched(name: str, params: str, doc: str):
    """A function ``name(params)`` (params: its argument names, comma-separated) that
    calls the njit implementation registered for the NamedTuple class of its first
    argument: ``function.register(cls, implementation)`` (which may be ``inline="always"``;
    the overload itself is not inlined: numba's inliner miscompiled the GX2F with it). The
    Python body (NUMBA_DISABLE_JIT=1) looks the implementation up the same way."""
    registry: dict[type, object] = {}
    namespace = {"registry": registry, "nb": nb}
    # named arguments (not *args): numba inlines an implementation only into a fixed argument list
    exec(_TEMPLATE.format(params=params, first=params.split(",")[0]), namespace)  # noqa: S102
    function = namespace["function"]
    function.__name__ = function.__qualname__ = name
    function.__doc__ = doc
    function.register = registry.__setitem__
    overload(function)(namespace["resolve"])
    return function
