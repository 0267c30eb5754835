"""``lcpbench.solve``: one solve, counted by the operators and verified by the framework."""

from __future__ import annotations

import copy
import dataclasses
import time
import traceback
import warnings
from collections.abc import Callable, Mapping
from typing import Any, Optional, Union

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from lcpbench.core.claims import check_infeasibility, confirm_convergence, verify_claim
from lcpbench.core.context import Budget, Monitor, SolverContext, StopSolver
from lcpbench.core.deadline import Deadline
from lcpbench.core.defaults import DEFAULT_SOLVER
from lcpbench.core.guards import dense_refusal
from lcpbench.core.lcp import LCP
from lcpbench.core.operator import (
    BudgetExhausted,
    NonFiniteProduct,
    Operator,
    apply_uncounted,
    dense_uncounted,
)
from lcpbench.core.registry import get_solver, solvers
from lcpbench.core.residuals import (
    StopRule,
    all_residuals,
    floor_message,
    kkt_abs,
    make_stop_rule,
    rounding_floor,
)
from lcpbench.core.result import SolveResult, Status
from lcpbench.core.specs import make_params, parse_spec

__all__ = ["solve", "run_solver", "requested_lows", "DEFAULT_SOLVER"]



#: Largest n of an explicit matrix whose iterates :func:`solve` verifies by default
#: (``verify_history``): beyond it the verified history costs about what the solve does.
VERIFY_HISTORY_MAX_N = 500


def requested_lows(params: dict, solver: Optional[str] = None) -> list[str]:
    """Low-fidelity operator names a solver's parameter values ask for.

    The registry says which parameters name low operators
    (:class:`~lcpbench.core.registry.LowOperators`, declared with
    ``register_solver(..., multifidelity=...)``). Without ``solver``, the parameters
    every registered solver declares are read. An empty single name (the only low
    operator) asks for no name in particular.
    """
    if solver is not None:
        return get_solver(solver).lows.requested(params)
    names: list[str] = []
    for declared in {info.lows for info in solvers().values()}:
        names += [n for n in declared.requested(params) if n not in names]
    return names


def _resolve_solver(solver: str, params: dict):
    name, raw = parse_spec(solver)
    info = get_solver(name)
    merged = dict(raw)
    for k, v in params.items():
        k2 = k.replace("-", "_")
        if k2 in merged:
            raise ValueError(f"parameter {k2!r} given both in {solver!r} and as a keyword")
        merged[k2] = v
    return info, make_params(name, info.params, merged)


def run_solver(lcp: LCP, solver: str = DEFAULT_SOLVER, *, stop: Union[str, StopRule] = "paper",
               tol: float = 1e-8, budget: Optional[Budget] = None,
               x0: Optional[np.ndarray] = None, state: Any = None,
               verify_history: Optional[bool] = None, callback: Optional[Callable] = None,
               params: Optional[dict] = None, force: bool = False,
               verify: bool = True) -> SolveResult:
    """Run one registered solver on ``lcp`` and verify the answer.

    Parameters
    ----------
    lcp : LCP
        The problem; its operators are copied with fresh counters, so the same
        instance can be solved repeatedly.
    solver : str
        ``name[:key=value,...]``.
    stop, tol : see :func:`lcpbench.core.residuals.make_stop_rule`.
    budget : Budget, optional
    x0 : ndarray, optional
        Warm start (overrides ``lcp.x0``); negative entries are projected to 0.
    state : object, optional
        State returned by a previous solve of the same solver (``result.state``),
        e.g. quasi-Newton memory for time stepping.
    verify_history : bool, optional
        Record the verified residual of every iterate (default: on for explicit
        matrices, off for matrix-free operators where it would cost a PDE solve).
    callback : callable, optional
        ``callback(row, x)`` after each iterate (``row``: the history row, with
        ``mvps``, ``emvps`` and ``kkt_abs``). Raising ``StopIteration`` in it ends
        the solve at that iterate, as in ``scipy.optimize``: status ``stopped``,
        the answer verified like any other.
    params : dict, optional
        Solver parameters (merged with those in the spec string).
    force : bool
        Form the dense A for a solver that needs it even past the dense-conversion
        limit of :mod:`lcpbench.core.guards` (never past the available memory).
    verify : bool
        Verify the answer (default; see :func:`solve`).

    Returns
    -------
    SolveResult
        With the solver's claim (a ``converged`` confirmed by a fresh counted
        product, see :mod:`lcpbench.core.claims`), the operator-counted MVPs and
        E-MVPs, the framework's verified residuals (one uncounted product, none
        when the operator is exact and its last product was at the returned ``x``)
        and ``framework_mvps``, every product the framework made beside the solver's.
        An exception from the solver or from a user operator gives a ``failed``
        result naming it; it never escapes. So does a dense A refused up front or
        out of memory.
    """
    info, p = _resolve_solver(solver, params or {})
    if isinstance(tol, np.floating):
        tol = float(tol)
    rule = make_stop_rule(stop, tol)
    budget = budget or Budget()
    run = lcp.fresh()
    if x0 is not None:
        if np.iscomplexobj(x0):
            raise TypeError("x0 has complex values; the LCP is real, pass a real warm start")
        x0 = np.asarray(x0, dtype=np.float64).reshape(-1)
        if x0.shape != (run.n,):
            raise ValueError(f"x0 has shape {x0.shape}; expected ({run.n},)")
        if not np.all(np.isfinite(x0)):
            raise ValueError("x0 has non-finite entries; pass a finite warm start")
        x0 = np.maximum(x0, 0.0)
    if verify_history is None:
        verify_history = run.A.explicit
    monitor = Monitor(verify=verify_history, callback=callback)
    refused = _dense_refused(run, info, force)
    ctx = SolverContext(run, rule, budget, monitor, x0=x0, state=state)
    ctx.info["stop_rule"] = rule.kind

    if refused:
        res = SolveResult(x=ctx.x0.copy(), w=np.full(run.n, np.nan), status=Status.failed,
                          message=refused)
    elif run.n == 0:
        z = np.zeros(0)
        ctx.start()
        ctx.report(z, z)
        res = ctx.finish(z, z, Status.converged, "empty problem (n = 0)")
    else:
        ctx.start()
        try:
            try:
                with Deadline(budget.max_seconds):
                    # the dense copy is part of the solve: inside its time budget
                    stopped = _form_dense(ctx, info)
                    res = stopped if stopped is not None else _call_solver(info, ctx, p)
            except BudgetExhausted as exc:    # the timer fired between the solver's return and here
                res = _close_at_last(ctx, Status.timeout, str(exc))
            res = _confirm(ctx, res)
        finally:
            ctx.detach()
        check_infeasibility(ctx, res)         # a solver's own 'infeasible' is checked too
    res.time_s = ctx.elapsed()
    ctx.verify_history()
    return _complete(res, run, ctx, info, p, verify)


def _dense_refused(run: LCP, info, force: bool) -> Optional[str]:
    """Why the explicit A of a solver registered ``needs_dense`` is not formed, or None.

    The size of the copy is estimated before anything is built
    (:func:`lcpbench.core.guards.dense_refusal`).
    """
    if not (info.needs_dense and run.n):
        return None
    return dense_refusal(info.name, run.n, matrix_free=not run.A.explicit, force=force)


#: Columns of the identity applied at once while forming the dense copy of a matrix-free A,
#: at most: the time budget is checked between blocks.
DENSE_BLOCK = 256


def _form_dense(ctx: SolverContext, info) -> Optional[SolveResult]:
    """Form ``ctx.dense`` for a solver registered ``needs_dense``; a closing result if it fails.

    The copy is made on the clock of the solve: a matrix-free operator is applied to
    blocks of the identity and the time budget is checked between blocks (``timeout``).
    An operator that raises, returns non-finite values or runs out of memory gives a
    ``failed`` result saying so; nothing is raised.
    """
    if not (info.needs_dense and ctx.n):
        return None
    what = f"{info.name} needs A as a dense matrix"
    try:
        ctx.dense = _dense_within(ctx)
    except BudgetExhausted:
        raise
    except _DenseTimeout as exc:
        return SolveResult(x=ctx.x0.copy(), w=np.full(ctx.n, np.nan), status=Status.timeout,
                           message=f"{what}: {exc}")
    except MemoryError:
        message = (f"{what}: forming it (n = {ctx.n}) ran out of memory; use an MVP-only "
                   "solver")
        return SolveResult(x=ctx.x0.copy(), w=np.full(ctx.n, np.nan), status=Status.failed,
                           message=message)
    except Exception as exc:   # the user's operator raised on a column of the identity
        return SolveResult(x=ctx.x0.copy(), w=np.full(ctx.n, np.nan), status=Status.failed,
                           message=f"{what}: forming it failed: {type(exc).__name__}: {exc}")
    bad = ~np.isfinite(ctx.dense)
    if bad.any():
        j = int(np.argwhere(bad.any(axis=0))[0, 0])
        ctx.dense = None
        return SolveResult(x=ctx.x0.copy(), w=np.full(ctx.n, np.nan), status=Status.failed,
                           message=(f"operator returned non-finite values while the framework "
                                    f"formed the dense copy of A (column {j}) for {info.name}"))
    return None


class _DenseTimeout(Exception):
    """The time budget ran out between blocks of the dense copy."""


def _dense_within(ctx: SolverContext) -> np.ndarray:
    """The dense A, formed in blocks of columns with the time budget checked between them."""
    if ctx.A.explicit:
        return dense_uncounted(ctx.A)
    n, limit = ctx.n, ctx.budget.max_seconds
    D = np.empty((n, n))
    j, block = 0, 1
    while j < n:
        k = min(block, n - j)
        E = np.zeros((n, k))
        E[j + np.arange(k), np.arange(k)] = 1.0
        t0 = time.perf_counter()
        D[:, j:j + k] = apply_uncounted(ctx.A, E)
        j += k
        spent = time.perf_counter() - t0
        if limit is not None and j < n and ctx.elapsed() > limit:
            raise _DenseTimeout(f"the time budget of {limit:g} s ran out while forming it "
                                f"({j} of {n} columns done)")
        # about a fiftieth of the budget per block (a tenth of a second without one)
        room = 0.02 * limit if limit is not None else 0.1
        block = min(DENSE_BLOCK, 2 * k) if 2 * spent < room else max(1, k // 2)
    return D


def _call_solver(info, ctx: SolverContext, p) -> SolveResult:
    """The solver's result; budget, stop and exceptions closed at the last reported iterate."""
    try:
        res = info.func(ctx, p)
        if not isinstance(res, SolveResult):
            raise TypeError(f"solver {info.name!r} returned {type(res).__name__}, "
                            "expected a SolveResult (use ctx.finish(x, w))")
        # the framework's checks work on their own record: the solver's object stays as made
        mine = copy.copy(res)
        mine.info = dict(res.info)
        return mine
    except BudgetExhausted as exc:
        return _close_at_last(ctx, Status.timeout if exc.kind == "time" else Status.budget,
                              str(exc))
    except NonFiniteProduct as exc:    # a broken operator, not an infeasible problem
        return _close_at_last(ctx, Status.failed, str(exc))
    except StopSolver as exc:
        return _close_at_last(ctx, ctx.status or Status.max_iter, str(exc) or ctx.message)
    except SystemExit as exc:  # sys.exit() inside a solve ends the solve, not the sweep
        res = _close_at_last(ctx, Status.failed,
                             f"SystemExit: solver {info.name!r} called sys.exit({exc.code!r}); "
                             "a solver returns ctx.finish(x, w) and never exits the process")
        res.info["traceback"] = traceback.format_exc(limit=3)
        return res
    except Exception as exc:  # the sweep must never die for one solver
        tb = traceback.format_exc(limit=3)
        res = _close_at_last(ctx, Status.failed, f"{type(exc).__name__}: {exc}")
        res.info["traceback"] = tb
        return res


def _confirm(ctx: SolverContext, res: SolveResult) -> SolveResult:
    """:func:`confirm_convergence`, with an operator that raises recorded as ``failed``."""
    try:
        return confirm_convergence(ctx, res)
    except Exception as exc:  # the user's operator raised on the confirming product
        res.status = Status.failed
        res.message = f"confirming the convergence claim failed: {type(exc).__name__}: {exc}"
        return res


def _close_at_last(ctx: SolverContext, status: Status, message: str) -> SolveResult:
    if ctx.last is not None:
        x, w = ctx.last
    else:
        x, w = ctx.x0, np.full(ctx.n, np.nan)
    return SolveResult(x=x, w=w, status=status, message=message)


def _checked_answer(res: SolveResult, run: LCP, ctx: SolverContext) -> tuple[np.ndarray, Status, str]:
    """The solver's ``x`` with its status and message, held to shape, finiteness and the
    operators' non-finite products (which fail the solve even when the solver caught them)."""
    status, message = res.status, res.message
    x = np.asarray(res.x, dtype=np.float64).reshape(-1)
    if x.shape != (run.n,):
        status, message = Status.failed, f"solver returned x of shape {x.shape}"
        x = ctx.x0.copy()
    if not np.all(np.isfinite(x)) and status != Status.failed:
        status, message = Status.diverged, message or "non-finite solution"
    bad = [op for op in run.operators().values() if op.nonfinite_at is not None]
    if bad:
        status = Status.failed
        message = (f"operator returned non-finite values at product {bad[0].nonfinite_at}"
                   + ("" if bad[0].name == "high" else f" (operator {bad[0].name!r})"))
    return x, status, message


def _verified(ctx: SolverContext, run: LCP, x: np.ndarray, status: Status, message: str
              ) -> tuple[dict, Status, str]:
    """The framework's residuals at ``x`` and the claim held to them.

    One uncounted product, or none when the operator is exact and reproducible (a
    float64 matrix, or one that declares ``rtol=0``) and its last counted product was
    at exactly ``x``: that product is the operator's own answer at ``x``, kept by the
    operator, not the solver's ``w``.
    """
    if not np.all(np.isfinite(x)):
        return {"kkt_abs": float("nan")}, status, message
    verified = {"kkt_abs": float("nan")}
    try:
        Ax = run.A.last_product(x) if ctx.measured_exact() and run.n else None
        if Ax is not None:
            ctx.info["verified_by"] = "the operator's last product"
        w_verified = run.residual_w(x) if Ax is None else Ax + run.b
        verified = all_residuals(x, w_verified, run.b)
        # never 'converged' against the verification
        status, message = verify_claim(ctx, status, x, w_verified, message)
        floor = rounding_floor(w_verified - run.b, run.b)
        if ctx.threshold < floor:        # more digits asked for than float64 holds
            verified["float64_floor"] = floor            # and the run is not 'solved'
            if status == Status.converged:
                message = floor_message(ctx.threshold, floor) + \
                    (f" (solver: {message})" if message else "")
    except Exception as exc:  # the user's operator raised on the verifying product
        if status != Status.failed:       # an earlier failure keeps its own reason first
            message = (f"verification failed: {type(exc).__name__}: {exc}"
                       + (f" (solver: {message})" if message else ""))
        status = Status.failed
    return verified, status, message


def _complete(res: SolveResult, run: LCP, ctx: SolverContext, info, params,
              verify: bool = True) -> SolveResult:
    """The result of the solve: the solver's answer checked, counted and verified, built once.

    The solver's own ``SolveResult`` supplies ``x``, ``w``, the claim, ``time_s``,
    ``state`` and its ``info``; everything else is the framework's. Without
    ``verify`` the claim stands unverified (``info['unverified']``, ``solved`` False).
    """
    x, status, message = _checked_answer(res, run, ctx)
    try:
        emvps = float(run.emvps())
    except Exception as exc:  # an undeclared cost whose measuring product raised
        emvps = float("nan")
        status, message = Status.failed, f"E-MVPs: {type(exc).__name__}: {exc}"
    mvps = int(run.A.count)             # after emvps(): a cost calibration is counted too
    lofi_mvps = run.lofi_counts()
    mvp_time_s = float(sum(op.seconds for op in run.operators().values()))
    try:
        app_cost = float(run.app_cost())
    except Exception:  # high_cost() already failed above: emvps is nan and the status says why
        app_cost = float("nan")
    used = {k: op for k, op in run.operators().items() if op.count}
    work = {"applications": run.work_counts(),       # and what the products cost, per operator
            "operator_seconds": {k: float(op.seconds) for k, op in used.items()},
            "operator_cost": {k: op.cost for k, op in used.items()},
            "operator_steady_seconds": {k: op.steady_application_seconds
                                        for k, op in used.items()},
            "operator_cold_applications": {k: op.cold_applications for k, op in used.items()}}
    claimed = kkt_abs(x, res.w) if np.all(np.isfinite(res.w)) else float("nan")
    if verify:
        verified, status, message = _verified(ctx, run, x, status, message)
    else:
        verified = {"kkt_abs": float("nan")}
        ctx.info["unverified"] = True
    framework = int(sum(op.framework_products for op in run.operators().values()))
    ctx.info["history_mvps"] = int(run.A.history_products)
    return SolveResult(
        x=x, w=res.w, status=status, message=message, mvps=mvps, lofi_mvps=lofi_mvps,
        emvps=emvps, applications=run.A.applications, app_cost=app_cost,
        lofi_applications={k: op.applications for k, op in run.low.items()},
        iterations=ctx.iterations, time_s=res.time_s, mvp_time_s=mvp_time_s,
        framework_mvps=framework,
        history=ctx.monitor.frame, claimed_kkt_abs=claimed, verified=verified,
        solved=bool(verified["kkt_abs"] <= ctx.threshold and "float64_floor" not in verified),
        threshold=ctx.threshold,
        solver=info.name, params=dataclasses.asdict(params), mvp_only=info.mvp_only,
        info={**ctx.info, **res.info, **work}, state=res.state)


def solve(A_or_lcp, b=None, *, solver: str = DEFAULT_SOLVER, tol: float = 1e-8,
          stop: Union[str, StopRule] = "paper", x0=None, max_emvps: float = 5000.0,
          max_seconds: Optional[float] = None, max_iter: int = 5000, low: Optional[dict] = None,
          low_cost: Union[float, dict, None] = None, shape: Optional[tuple] = None,
          state: Any = None, callback: Optional[Callable] = None, force: bool = False,
          psd: bool = False, verify: bool = True, verify_history: Optional[bool] = None,
          **params) -> SolveResult:
    """Solve the LCP ``0 <= x _|_ A x + b >= 0``.

    Parameters
    ----------
    A_or_lcp : LCP, ndarray, sparse matrix, LinearOperator or Operator
        The matrix (symmetric positive semidefinite) or a ready :class:`LCP`.
    b : array_like, optional
        Required unless an LCP is given.
    solver : str
        Registered solver, optionally with parameters: ``"bi-pqn:low=p4"``.
        ``lcpbench list`` shows them all.
    tol : float
        Tolerance of the stop rule.
    stop : {"paper", "paper-code", "kkt"} or StopRule
        ``paper``: absolute or relative KKT error below tol (the paper's rule);
        ``paper-code``: ``||min(x, Ax+b)||^2 < tol`` (the authors' released code);
        ``kkt``: ``||min(x, Ax+b)|| <= tol (1 + ||b||)``.
    x0 : array_like, optional
        Warm start (e.g. the previous time step's forces).
    max_emvps, max_seconds, max_iter : budget of the solve.
    low : dict, optional
        Low-fidelity operators by name (only when ``A_or_lcp`` is a matrix).
    low_cost : float or dict, optional
        Cost of one low-fidelity product in high-fidelity products (``0.1``: ten low
        products cost one high product), one number for every low operator or a dict
        by name. E-MVPs are then ``high MVPs + sum(low_cost * low MVPs)``, the same on
        every run. Without it (and without ``lcpbench.Operator(..., cost=...)``) the
        costs are the measured wall time per product, which varies between runs; a
        warning says so when low-fidelity products were used.
    shape : tuple, optional
        ``(n, n)`` of a callable ``A`` (and callable low operators); default
        ``(len(b), len(b))``.
    state : object, optional
        ``result.state`` of the previous solve (quasi-Newton memory for time
        stepping; solvers that keep none ignore it).
    callback : callable, optional
        ``callback(row, x)`` after each iterate (``row``: the history row, with
        ``mvps``, ``emvps`` and ``kkt_abs``). Raising ``StopIteration`` in it ends
        the solve at that iterate, as in ``scipy.optimize``: status ``stopped``,
        the answer verified like any other.
    force : bool
        Let a solver that needs the explicit matrix form it past the dense-conversion
        limit (2 GiB, see :mod:`lcpbench.core.guards`); without it such a solve is
        ``failed`` with the estimate in its message.
    psd : bool
        Declare ``A`` positive semidefinite: the definiteness test of an explicit
        matrix (a Cholesky factorisation, about ``n^3 / 3`` operations, the cost of
        a whole solve at n = 1500) is skipped. Without it the test is made once per
        operator: wrap ``A`` once in :class:`lcpbench.Operator` and pass that to
        every solve to check it once.
    verify : bool
        Verify the answer (default). ``False`` returns the solver's claim as it
        stands, marked ``info['unverified'] = True``: no verifying product, the
        ``verified`` residuals nan and ``solved`` False (what a time stepper that
        trusts the solver's confirmed claim needs); the runner always verifies.
    verify_history : bool, optional
        Record the verified residual of every iterate (uncounted products, one block
        product after the solve). Default: for explicit matrices up to
        n = :data:`VERIFY_HISTORY_MAX_N`, where it costs little beside the solve;
        beyond, it would cost about as much as the solver's own products, so it is
        off unless asked for (``lcpbench run`` records it for every explicit matrix).
    **params
        Solver parameters (checked against the solver's parameter dataclass); a
        misspelt keyword of this function (``tolerance=``) is named as such.

    Returns
    -------
    SolveResult

    Examples
    --------
    >>> import numpy as np, lcpbench
    >>> A = np.array([[2.0, 1.0], [1.0, 2.0]]); b = np.array([-1.0, 1.0])
    >>> res = lcpbench.solve(A, b)                          # Mono-PQN
    >>> res.status.value, res.solved, np.round(res.x, 6).tolist()
    ('converged', True, [0.5, 0.0])

    The paper's stop rule also ends on a small relative change of the KKT
    error; the status then says so and the run does not count as solved:

    >>> res = lcpbench.solve(A, b, solver="bb-pgd")
    >>> res.status.value, res.solved
    ('stagnated', False)
    >>> lcpbench.solve(A, b, solver="bb-pgd", stop="kkt").solved
    True
    """
    _misspelt_keywords(solver, params)
    if isinstance(A_or_lcp, LCP):
        if b is not None or low is not None or low_cost is not None or shape is not None:
            raise ValueError("pass b, low and their costs inside the LCP, not beside it")
        lcp = A_or_lcp
    else:
        if b is None:
            raise ValueError("b is required when A is given as a matrix or operator")
        n = int(np.size(b))
        if low is not None and not isinstance(low, Mapping):
            raise TypeError(f"low= takes a dict of low-fidelity operators by name, got "
                            f"{type(low).__name__}; pass low={{'coarse': A_low}}")
        A, lows = _with_costs(_operator(A_or_lcp, "high", shape, n),
                              {k: _operator(v, k, shape, n) for k, v in (low or {}).items()},
                              low_cost)
        lcp = LCP(A, b, low=lows, psd_check=not psd)
    budget = Budget(max_emvps=max_emvps, max_seconds=max_seconds, max_iter=max_iter)
    if verify_history is None:
        verify_history = lcp.A.explicit and lcp.n <= VERIFY_HISTORY_MAX_N
    res = run_solver(lcp, solver, stop=stop, tol=tol, budget=budget, x0=x0, state=state,
                     verify_history=verify_history, callback=callback, params=params,
                     force=force, verify=verify)
    clocked = [name for name, op in [("high", lcp.A), *lcp.low.items()]
               if op.declared_cost is None]
    if clocked and any(res.lofi_mvps.values()):
        warnings.warn(f"E-MVPs are priced by the measured wall time per product of "
                      f"{', '.join(clocked)} (no declared cost), so they vary between "
                      "identical solves; pass low_cost= (or lcpbench.Operator(A, cost=...))",
                      UserWarning, stacklevel=2)
    return res


#: The keywords of :func:`solve` itself, offered for a misspelt one.
_SOLVE_KEYWORDS = ("solver", "tol", "stop", "x0", "max_emvps", "max_seconds", "max_iter", "low",
                   "low_cost", "shape", "state", "callback", "force", "psd", "verify",
                   "verify_history")
#: Other libraries' names of solve's keywords.
_SOLVE_ALIASES = {"tolerance": "tol", "eps": "tol", "atol": "tol", "rtol": "tol",
                  "maxiter": "max_iter", "max_iterations": "max_iter", "timeout": "max_seconds",
                  "time_limit": "max_seconds", "budget": "max_emvps", "warm_start": "x0"}


def _misspelt_keywords(solver: str, params: dict) -> None:
    """TypeError for a keyword that is no parameter of the solver but resembles one of solve's.

    ``tolerance=1e-6`` is a misspelt ``tol``, not an unknown solver parameter.
    """
    import dataclasses
    import difflib

    if not params or not isinstance(solver, str):
        return
    name = parse_spec(solver)[0]
    fields = [f.name for f in dataclasses.fields(get_solver(name).params)]
    for key in params:
        if key.replace("-", "_") in fields:
            continue
        close = ([_SOLVE_ALIASES[key]] if key in _SOLVE_ALIASES else
                 [k for k in _SOLVE_KEYWORDS if key.startswith(k) or k.startswith(key)][:1]
                 or difflib.get_close_matches(key, _SOLVE_KEYWORDS, n=1, cutoff=0.75))
        if close:
            raise TypeError(f"unknown keyword {key!r}. Did you mean {close[0]}? (lcpbench.solve "
                            f"takes {', '.join(_SOLVE_KEYWORDS)}; {name}'s own parameters: "
                            f"{', '.join(fields) or 'none'})")


def _operator(M, name: str, shape: Optional[tuple], n: int):
    """``M`` as given (a nested list as an array), or a counted :class:`Operator` when it is
    a bare callable."""
    if isinstance(M, (list, tuple)):
        M = np.asarray(M)
    if callable(M) and not isinstance(M, (LinearOperator, np.ndarray)) and not sp.issparse(M):
        return Operator(M, shape=tuple(shape) if shape is not None else (n, n), name=name)
    if shape is not None and tuple(getattr(M, "shape", ())) != tuple(shape):
        raise ValueError(f"shape={tuple(shape)} does not match {name} operator's shape "
                         f"{getattr(M, 'shape', None)}; shape= is for callables")
    return M


def _with_costs(A, lows: dict, low_cost) -> tuple:
    """Declare costs from ``low_cost`` (high = 1 unless ``A`` declares one)."""
    if low_cost is None:
        return A, lows
    if not lows:
        raise ValueError("low_cost= given without low= operators; pass low={'name': A_low}")
    costs = dict(low_cost) if isinstance(low_cost, dict) else {k: low_cost for k in lows}
    unknown, missing = sorted(set(costs) - set(lows)), sorted(set(lows) - set(costs))
    if unknown or missing:
        raise ValueError(f"low_cost names {unknown or missing} but low has {sorted(lows)}; "
                         "give one cost per low operator, or one number for all")
    for k, c in costs.items():
        if not (isinstance(c, (int, float, np.floating, np.integer)) and np.isfinite(c)
                and c > 0):
            raise ValueError(f"low_cost[{k!r}] = {c!r}: a cost must be a positive number "
                             "(low products per high product, e.g. 0.1)")
    high = A.declared_cost if isinstance(A, Operator) and A.declared_cost else 1.0
    A = Operator(A, cost=high, name="high")
    return A, {k: Operator(v, cost=float(costs[k]) * high, name=k) for k, v in lows.items()}
