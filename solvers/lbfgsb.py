"""``l-bfgs-b``: scipy's L-BFGS-B on the QP form of the LCP, every evaluation counted.

Baseline of the method paper's section "Numerical Results" -> "Comparison
Methods" (table comparisonMethods: first order, line search on the step size).
The method is Byrd, Lu, Nocedal & Zhu, "A limited memory algorithm for bound
constrained optimization", SIAM J. Sci. Comput. 16 (1995), run through
:func:`scipy.optimize.minimize` (``method="L-BFGS-B"``) on

    f(x) = 1/2 x'Ax + b'x,   grad f(x) = A x + b = w,   x >= 0.

MVPs
----
Every ``(f, grad f)`` evaluation scipy asks for is one counted product ``A x``
(line-search trials included): ``f`` follows from ``w`` without a product
(see below). A small cache of the last evaluated points makes sure
the same ``x`` is never multiplied twice (scipy's own first call at ``x0`` and
the monitor's look-ups hit it); ``A 0`` is free (cold start). So the MVP count
equals the number of *distinct* points evaluated, typically one per iteration
plus the extra line-search trials (``info['ls_extra']``).

Stopping
--------
scipy's own tests are switched off (``ftol = gtol = 0``) so the lcpbench stop
rule decides: the iteration callback reports the new iterate with the ``w`` of
that very point (taken from the cache) to ``ctx.report`` and raises
:class:`lcpbench.core.context.StopSolver` when it says stop. When scipy ends by
itself (e.g. ``ABNORMAL_TERMINATION_IN_LNSRCH``: the line search cannot make
progress at machine precision) the last point is reported and, unless the stop
rule is met there, the solve ends ``stagnated`` (or ``failed`` for an error
return, ``max_iter`` for scipy's iteration/evaluation caps) with scipy's message.

Precision and restarts (lcpbench's addition, not in the source)
----------------------------------------------------------------
L-BFGS-B works on the objective, and near the solution ``f - f* ~ ||x - x*||^2``
falls below the rounding of ``f`` itself (about ``eps |f|``): with the stop
tests off, plain scipy ends with ``CONVERGENCE: RELATIVE REDUCTION OF F <=
FACTR*EPSMCH`` (no decrease at all) or an abnormal line search at
``||min(x, w)||`` of roughly 1e-6 to 1e-8, short of the paper's 1e-8. The
objective is therefore handed to scipy as the exact difference
``f(x) - f(x_ref) = 1/2 (x - x_ref)'(w + w_ref)`` (no product: ``w_ref`` is
cached), and scipy is restarted from its last point with ``x_ref`` moved there
(``info['restarts']``, at most ``max_restarts``; the restart point is cached, so
a restart costs no MVP, only the L-BFGS memory) when it stalls before the stop
rule is met, or pre-emptively once an iteration decreases ``f - f(x_ref)`` by
less than ``rebase_rtol`` of its magnitude (the point where rounding of ``f``
starts to corrupt the line search). Near ``x_ref`` the differences are then
resolved to ``eps |f(x) - f(x_ref)|`` instead of ``eps |f|``. On the hard-case
families (tol 1e-8, paper rule, cond <= 1e7) this took the plain run from 20 to
41 of 41 instances solved. A restart that does not move, or running out of
restarts, ends the solve ``stagnated``.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from scipy.optimize import minimize

from lcpbench import register_solver
from lcpbench.core.context import SolverContext, StopSolver
from lcpbench.core.result import SolveResult, Status
from lcpbench.core.specs import Bounds, CheckedParams

__all__ = ["LBFGSBParams", "lbfgsb"]


@dataclass(frozen=True)
class LBFGSBParams(CheckedParams):
    """Parameters of l-bfgs-b.

    Parameters
    ----------
    memory : int
        Correction pairs kept (scipy's ``maxcor``). Default 20, the ``m`` of the
        paper authors' ``L_BFGS_B.m`` used for the paper's comparison.
    maxls : int
        Line-search trials per iteration (scipy's default 20); every trial is one MVP.
    cache : int
        Evaluated points remembered so that no ``x`` is multiplied twice (default 4).
    max_restarts : int
        Restarts of scipy from its last point, with the objective re-referenced
        there (default 10; 0: the plain scipy run).
    rebase_rtol : float
        Restart pre-emptively once an iteration decreases ``f - f(x_ref)`` by at
        most this fraction of its magnitude, before rounding stalls scipy
        (default 1e-6; 0: restart only after a stall).
    """

    memory: Annotated[int, Bounds(ge=1)] = 20
    maxls: Annotated[int, Bounds(ge=1)] = 20
    cache: Annotated[int, Bounds(ge=1)] = 4
    max_restarts: Annotated[int, Bounds(ge=0)] = 10
    rebase_rtol: Annotated[float, Bounds(ge=0, lt=1)] = 1e-6


class _Rebase(Exception):
    """Raised from the callback to restart scipy with the objective re-referenced."""


class _Evaluator:
    """``x -> (f, w)`` with one counted MVP per distinct ``x`` (small LRU cache)."""

    def __init__(self, ctx: SolverContext, size: int):
        self.ctx = ctx
        self.size = size
        self.store: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self.evaluations = 0       # distinct points multiplied (zero vectors included)
        self.calls = 0             # calls from scipy (cache hits included)
        self.x_ref = np.zeros(ctx.n)
        self.w_ref = np.array(ctx.b, dtype=np.float64)

    def w(self, x: np.ndarray) -> np.ndarray:
        key = np.ascontiguousarray(x, dtype=np.float64).tobytes()
        hit = self.store.get(key)
        if hit is not None:
            self.store.move_to_end(key)
            return hit
        w = self.ctx.A @ np.asarray(x, dtype=np.float64) + self.ctx.b
        self.evaluations += 1
        self.store[key] = w
        if len(self.store) > self.size:
            self.store.popitem(last=False)
        return w

    def fun(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """``f(x) - f(x_ref)`` as ``1/2 (x - x_ref)'(w + w_ref)`` (exact for a quadratic)."""
        self.calls += 1
        w = self.w(x)
        return 0.5 * float((x - self.x_ref) @ (w + self.w_ref)), w.copy()

    def rebase(self, x: np.ndarray, w: np.ndarray) -> None:
        self.x_ref, self.w_ref = x.copy(), w.copy()


@register_solver("l-bfgs-b", LBFGSBParams)
def lbfgsb(ctx: SolverContext, p: LBFGSBParams) -> SolveResult:
    """L-BFGS-B (Byrd, Lu, Nocedal & Zhu 1995) via scipy on min 1/2 x'Ax + b'x, x >= 0.

    Comparison method of the method paper (section "Comparison Methods"). One
    counted MVP per distinct point scipy evaluates (line-search trials
    included, repeated points cached); lcpbench's stop rule decides termination
    through the iteration callback; precision stalls restart scipy (module
    docstring). ``info``: ``nfev`` (scipy's evaluation calls), ``evaluations``
    (distinct points), ``nit``, ``ls_extra`` (evaluations beyond one per
    iteration), ``restarts``, ``scipy_message``.
    """
    ev = _Evaluator(ctx, p.cache)
    x0 = np.maximum(ctx.x0, 0.0)
    w0 = ev.w(x0)
    if ctx.report(x0, w0):
        return ctx.finish(x0, w0)
    nit = [0]
    ctx.info["restarts"] = 0
    prev_f: list = [None]

    def callback(intermediate_result) -> None:
        x = np.array(intermediate_result.x, dtype=np.float64)   # scipy reuses the buffer
        f = float(intermediate_result.fun)
        nit[0] += 1
        last = ctx.last
        if last is not None and np.array_equal(last[0], x):
            return                 # no move: not a new iterate
        w = ev.w(x)                # the last evaluated point: a cache hit, no product
        if ctx.report(x, w):
            raise StopSolver(ctx.message)
        fp, prev_f[0] = prev_f[0], f
        if p.rebase_rtol > 0 and fp is not None and ctx.info["restarts"] < p.max_restarts \
                and fp - f <= p.rebase_rtol * abs(f):
            raise _Rebase()

    x, w = x0, w0
    while True:
        ev.rebase(x, w)
        prev_f[0] = None
        opts = {"maxcor": p.memory, "maxls": p.maxls, "ftol": 0.0, "gtol": 0.0,
                "maxiter": max(ctx.budget.max_iter - ctx.iterations, 1) + 10,
                "maxfun": np.iinfo(np.int32).max}
        try:
            res = minimize(ev.fun, x, jac=True, method="L-BFGS-B",
                           bounds=[(0.0, None)] * ctx.n, callback=callback, options=opts)
        except StopSolver:
            _record(ctx, ev, nit[0], "stopped by lcpbench's stop rule")
            x, w = _last(ctx)
            return ctx.finish(x, w)
        except _Rebase:
            ctx.info["restarts"] += 1
            x, w = _last(ctx)
            continue
        msg = str(res.message)
        _record(ctx, ev, nit[0], msg)
        x_new = np.array(res.x, dtype=np.float64)
        w_new = ev.w(x_new)
        last = ctx.last
        if last is None or not np.array_equal(last[0], x_new):
            if ctx.report(x_new, w_new):
                return ctx.finish(x_new, w_new)
        if res.status == 1:
            return ctx.finish(x_new, w_new, Status.max_iter, f"scipy L-BFGS-B stopped: {msg}")
        if not (res.status == 0 or "ABNORMAL" in msg or "WARNING" in msg):
            return ctx.finish(x_new, w_new, Status.failed, f"scipy L-BFGS-B stopped: {msg}")
        moved = not np.array_equal(x_new, x)
        x, w = x_new, w_new
        if not moved or ctx.info["restarts"] >= p.max_restarts:
            why = "no progress since the last restart" if not moved else \
                f"{p.max_restarts} restarts used"
            return ctx.finish(x, w, Status.stagnated,
                              f"scipy L-BFGS-B stopped: {msg} ({why})")
        ctx.info["restarts"] += 1


def _last(ctx: SolverContext) -> tuple[np.ndarray, np.ndarray]:
    """The last reported ``(x, w)``: the stop rule and a rebase are only raised from the
    callback after a report, so there always is one."""
    last = ctx.last
    if last is None:
        raise RuntimeError("l-bfgs-b stopped before any iterate was reported")
    return last


def _record(ctx: SolverContext, ev: _Evaluator, nit: int, msg: str) -> None:
    ctx.info["nfev"] = ev.calls
    ctx.info["evaluations"] = ev.evaluations
    ctx.info["nit"] = nit
    ctx.info["ls_extra"] = max(ev.evaluations - 1 - nit, 0)
    ctx.info["scipy_message"] = msg
