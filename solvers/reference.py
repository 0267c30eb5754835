"""Reference QP solvers: Clarabel, ProxQP and OSQP on the dense matrix.

The symmetric LCP ``0 <= x _|_ A x + b >= 0`` is the KKT system of the QP
``min 1/2 x'Ax + b'x  s.t.  x >= 0`` (method paper, section "Collision
Resolution" -> "The LCP as an Optimization Problem", eq. qp). These solvers hand that QP to an independent dense QP
code through qpsolvers (:func:`lcpbench.toolkit.qp.solve_nonneg_qp`) at a tight
tolerance. They are *ground truth*, not MVP-only methods: they need the
explicit matrix (``needs_dense=True``, formed once and uncounted by the
framework) and are registered with ``reference=True`` so that reports keep them
apart from the benchmarked solvers.

MVPs: exactly one counted product per solve, ``w = A x + b`` through
``ctx.A`` at the returned ``x``, so that the solver's claimed ``w`` is computed
the same way as for every other solver (zero if ``x = 0``: a zero product is
free).

Default tolerances, measured on every family of ``lcpbench.problems.hard``
and ``lcpbench.problems.random`` (default parameters, n <= 300): at 1e-12
Clarabel reports failure on all ``planted`` and 3/10 ``spd-cond`` instances,
ProxQP on 2/10 ``spd-cond`` and all ``bad-scale`` instances (after ~4 s each),
OSQP on all ``all-inactive`` instances; at 1e-10 all three succeed on every
default-parameter instance, so 1e-10 is the default of all three (ProxQP's
absolute tolerance can still fail on other ``bad-scale`` draws: ``retries``
loosens it). The backends' answers at
1e-10 have ``||min(x, w)||`` up to ~1e-4 (Clarabel on ``bad-scale``), which
is why the active-set polish and refinement are on by default: with them the
verified residual is below 1e-9 on every instance except OSQP on the
``spd-cond`` instance with condition number 1e10 (wrong active set).

Time: the backend runs in a forked child killed at the solve's ``max_seconds``
(what the budget has left), or, when the budget sets none, at
:func:`lcpbench.core.reference.default_reference_seconds` of ``n`` (10 s for
small problems), so a backend that never returns (ProxQP runs for many minutes
on some 2 x 2 infeasible problems) ends the solve as ``timeout`` at the start.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from lcpbench import register_solver
from lcpbench.core.context import SolverContext
from lcpbench.core.reference import default_reference_seconds
from lcpbench.core.result import SolveResult, Status
from lcpbench.toolkit.qp import QPTimeout, solve_and_refine

__all__ = ["DEFAULT_TOLERANCES", "make_reference_solver"]

#: Backend -> default tolerance of the registered reference solver.
DEFAULT_TOLERANCES = {"clarabel": 1e-10, "proxqp": 1e-10, "osqp": 1e-10}

_PARAM_DOC = """Parameters of the {name} reference solver.

    Parameters
    ----------
    tol : float
        Tolerance handed to {name} (absolute and, where the backend has one,
        relative; default {tol:g}, the tightest at which {name} reliably
        reports success). Must be in (0, 1).
    polish : bool
        After the backend returns, try one active-set refinement
        (:func:`lcpbench.toolkit.qp.polish_active_set`: solve ``A_FF x_F = -b_F`` on the
        support of ``x``), kept only if it is feasible and lowers
        ``||min(x, Ax+b)||`` (default True). Dense algebra, no counted MVP.
    retries : int
        When the backend reports failure at ``tol``, retry up to this many
        times, each at 100 times the previous tolerance (default 2: at most
        ``1e4 * tol``); the polish and refinement then restore the accuracy.
        Needed for absolute tolerances on badly scaled ``b`` (ProxQP's
        ``eps_abs`` at 1e-10 with entries of b near 1e6). The tolerance that
        succeeded is recorded in ``info["tol_used"]``.
    refine_steps : int
        Then up to this many correction steps of :func:`lcpbench.toolkit.qp.refine_active_set`
        (default 3; 0 disables). They rescue singular ``A_FF`` (redundant
        contacts) and tiny negative entries on degenerate indices, where the
        polish above is rejected. Dense algebra, no counted MVP.
    """


def _validate(self) -> None:
    if not (isinstance(self.tol, (int, float)) and 0 < self.tol < 1):
        raise ValueError(f"tol must be in (0, 1), got {self.tol!r}")
    if not (isinstance(self.retries, int) and self.retries >= 0):
        raise ValueError(f"retries must be an integer >= 0, got {self.retries!r}")
    if not (isinstance(self.refine_steps, int) and self.refine_steps >= 0):
        raise ValueError(f"refine_steps must be an integer >= 0, got {self.refine_steps!r}")


def _time_limit(ctx: SolverContext) -> tuple[float, str]:
    """Seconds the backend may take, and where the limit comes from (for the message)."""
    if ctx.budget.max_seconds is not None:
        return ctx.budget.max_seconds - ctx.elapsed(), \
            f"time budget of {ctx.budget.max_seconds:g} s"
    seconds = default_reference_seconds(ctx.n)
    return seconds, (f"the reference solvers' default limit of {seconds:g} s at n = {ctx.n}; "
                     "set max_seconds (--timeout) to change it")


def _report_start(ctx: SolverContext):
    """The start reported as the answer: free at x0 = 0, one MVP for a warm start."""
    x0 = ctx.x0
    w0 = ctx.A @ x0 + ctx.b
    ctx.report(x0, w0)
    return x0, w0


def make_reference_solver(backend: str, default_tol: float) -> Callable:
    """Register the reference solver ``backend`` (a key of :data:`lcpbench.toolkit.qp.QP_BACKENDS`).

    Builds its frozen parameter dataclass (``tol``, ``polish``) and the solver
    function, and registers both with ``needs_dense=True, reference=True``.

    Returns
    -------
    callable
        The registered solver function ``func(ctx, params) -> SolveResult``.
    """
    cls_name = f"{backend.capitalize()}Params"
    params = dataclasses.make_dataclass(
        cls_name, [("tol", float, dataclasses.field(default=default_tol)),
                   ("polish", bool, dataclasses.field(default=True)),
                   ("retries", int, dataclasses.field(default=2)),
                   ("refine_steps", int, dataclasses.field(default=3))],
        frozen=True, namespace={"__post_init__": _validate})
    params.__doc__ = _PARAM_DOC.format(name=backend, tol=default_tol)
    params.__module__ = __name__
    params.__qualname__ = cls_name

    def solve(ctx: SolverContext, p) -> SolveResult:
        seconds, why = _time_limit(ctx)
        try:
            if ctx.dense is None:
                raise RuntimeError(f"{backend}: the framework formed no explicit matrix "
                                   "(the reference solvers are registered with needs_dense)")
            x, message, tol = solve_and_refine(ctx.dense, ctx.b, backend, p.tol,
                                               retries=p.retries, polish=p.polish,
                                               refine_steps=p.refine_steps, max_seconds=seconds)
        except QPTimeout as exc:
            ctx.info["tol_used"] = exc.tol
            x0, w0 = _report_start(ctx)
            return ctx.finish(x0, w0, Status.timeout, f"{exc} ({why})")
        ctx.info["tol_used"] = tol
        if x is None:
            x0, w0 = _report_start(ctx)
            return ctx.finish(x0, w0, Status.failed,
                              f"{message} (tolerances {p.tol:g} to {tol:g} tried)")
        w = ctx.A @ x + ctx.b
        ctx.info["backend_message"] = message
        if ctx.report(x, w):
            return ctx.finish(x, w)
        return ctx.finish(x, w, Status.stagnated,
                          f"{message}; backend answer does not meet the stop rule")

    solve.__name__ = solve.__qualname__ = f"{backend}_reference"
    solve.__doc__ = (
        f"Reference solver: the non-negative QP by {backend} on the dense matrix.\n\n"
        f"    Not an MVP-only method (method paper, section \"Numerical Results\": the\n"
        f"    ground truth the baselines of \"Comparison Methods\" are checked against).\n"
        f"    Solves ``min 1/2 x'Ax + b'x, x >= 0`` with qpsolvers' {backend} backend at\n"
        f"    ``tol`` (options in :data:`lcpbench.toolkit.qp.QP_BACKENDS`), optionally polishes\n"
        f"    and refines the active set on the dense matrix (uncounted dense algebra,\n"
        f"    like the backend itself), then computes ``w = A x + b`` with one counted\n"
        f"    MVP: 1 MVP per solve in total.\n"
        f"    One iterate is reported (the answer); the warm start is not used by the\n"
        f"    backends. A backend failure (after ``retries`` looser tolerances) ends\n"
        f"    the solve as ``failed`` with the backend's message, at the starting point;\n"
        f"    a backend still running at the time limit (the budget's ``max_seconds``,\n"
        f"    else the default of :func:`lcpbench.core.reference.default_reference_seconds`)\n"
        f"    is killed and the solve ends as ``timeout`` at the starting point.\n")
    solve.__module__ = __name__
    return register_solver(backend, params, needs_dense=True, reference=True)(solve)


clarabel_reference = make_reference_solver("clarabel", DEFAULT_TOLERANCES["clarabel"])
proxqp_reference = make_reference_solver("proxqp", DEFAULT_TOLERANCES["proxqp"])
osqp_reference = make_reference_solver("osqp", DEFAULT_TOLERANCES["osqp"])
