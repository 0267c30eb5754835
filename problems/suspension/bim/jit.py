"""Compiled builds of one kernel that do not share numba's on-disk cache.

numba keys its cache file by the Python function's qualified name and source line, and an
entry in it by the argument types: not by ``parallel`` or ``fastmath``.  A serial and a
parallel build of one function would therefore share (and overwrite) one cache entry, and
either could be loaded for both (measured: the parallel build then ran on one thread).
:func:`variant` gives each build its own function object and name.
"""

from __future__ import annotations

import types
from collections.abc import Callable

from numba import njit

__all__ = ["variant", "parallel_and_serial"]


def variant(fn: Callable, suffix: str) -> Callable:
    """``fn`` under the qualified name ``fn.__qualname__ + "_" + suffix`` (same code).

    Parameters
    ----------
    fn : function
        A plain Python function (not yet compiled).
    suffix : str
        Name of the build, e.g. ``"serial"``; one per distinct set of compile options.
    """
    if not isinstance(fn, types.FunctionType):
        raise TypeError(f"variant() needs a plain Python function, got {type(fn).__name__}")
    copy = types.FunctionType(fn.__code__, fn.__globals__, f"{fn.__name__}_{suffix}",
                              fn.__defaults__, fn.__closure__)
    copy.__qualname__ = f"{fn.__qualname__}_{suffix}"
    copy.__doc__ = fn.__doc__
    copy.__module__ = fn.__module__
    return copy


def parallel_and_serial(fn: Callable) -> tuple[Callable, Callable]:
    """The parallel and the serial compiled build of ``fn`` (fastmath, cached on disk), the
    serial one under its own name (:func:`variant`)."""
    return (njit(parallel=True, fastmath=True, cache=True)(fn),
            njit(fastmath=True, cache=True)(variant(fn, "serial")))
