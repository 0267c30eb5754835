"""BLAS on one thread for the small dense algebra inside a solve.

Solvers and operators here make many small dense products and solves (prox systems of the
secant rank, per-sphere blocks of the boundary-integral backend).  A threaded BLAS spends
more time starting threads than computing on such sizes, and on a loaded machine far more
(docs/benchmarks.md, "One BLAS thread: the measurements behind it").  threadpoolctl sets
the limit; its scan of the loaded libraries is done once.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from functools import cache

from threadpoolctl import ThreadpoolController

__all__ = ["one_blas_thread", "on_one_blas_thread", "with_current_blas_threads"]


@cache
def _threadpools() -> ThreadpoolController:
    """threadpoolctl's view of the loaded thread pools, scanned once (a scan takes
    milliseconds; entering a limit afterwards about 10 microseconds)."""
    return ThreadpoolController()


@cache
def _blas_pools() -> ThreadpoolController:
    """The BLAS libraries among the loaded thread pools, selected once."""
    return _threadpools().select(user_api="blas")


def one_blas_thread() -> AbstractContextManager:
    """A context in which BLAS runs on one thread (the previous limits come back on exit).

    When every BLAS library already runs on one thread (``OPENBLAS_NUM_THREADS=1``, or
    inside another such context) nothing is entered: reading the thread counts costs
    microseconds, entering and leaving a limit tens of them, which a small compiled solve
    (lcpbench's Lemke at n = 50) would otherwise pay several times over.
    """
    if all(lib.num_threads == 1 for lib in _blas_pools().lib_controllers):
        return nullcontext()
    return _threadpools().limit(limits=1, user_api="blas")


def on_one_blas_thread(method: Callable) -> Callable:
    """Decorate a method so that it runs with BLAS on one thread.

    Used on the products of the boundary-integral mobility: their dense per-sphere products
    are small, and beside the parallel compiled kernels a threaded BLAS is many times
    slower on a loaded machine (docs/benchmarks.md, "One BLAS thread: the measurements
    behind it"), while entering the limit costs next to nothing.
    """
    @functools.wraps(method)
    def wrapped(*args, **kwargs):
        with one_blas_thread():
            return method(*args, **kwargs)
    return wrapped


def with_current_blas_threads(func: Callable) -> Callable:
    """``func`` run with the BLAS thread counts in force now, whatever limit is active later.

    A solver runs its own small dense algebra inside one :func:`one_blas_thread`
    context entered once per solve (entering a limit costs tens of microseconds,
    too much per prox evaluation); the products it hands out of that context
    (the LCP's operators) are wrapped here, so an operator that gains from
    threads keeps them.  Each call enters one limit (microseconds beside a
    product).
    """
    pools = _threadpools().select(user_api="blas")
    counts = {lib.prefix: lib.num_threads for lib in pools.lib_controllers}
    if not counts or all(c == 1 for c in counts.values()):
        return func

    @functools.wraps(func)
    def wrapped(*args, **kwargs):
        with _threadpools().limit(limits=counts):
            return func(*args, **kwargs)
    return wrapped
