"""Dense QP backends through qpsolvers: ``min 1/2 x'Ax + b'x  s.t.  x >= 0``.

Used by the registered reference solvers and by :func:`lcpbench.reference`.
qpsolvers was chosen because it gives one interface to the three independent
interior-point / ADMM / augmented-Lagrangian codes the suite uses as ground
truth (Clarabel, ProxQP, OSQP), so disagreements come from the methods and
not from glue code.

Time limits: a backend is a compiled loop that Python's signal handlers cannot
interrupt (ProxQP has no time limit of its own and, on some infeasible
problems, runs its 10^5 outer iterations for many minutes). Given
``max_seconds``, :func:`solve_nonneg_qp` therefore hands the backend its own
limit where it has one (Clarabel's and OSQP's ``time_limit``) and runs the call
in a forked child that is killed at ``max_seconds``
(:func:`lcpbench.core.forked.call_with_deadline`, the runner's own
mechanism); either way the caller gets :class:`QPTimeout`.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import time
import warnings
from typing import Optional

import numpy as np
import scipy.sparse as sp

from lcpbench.core.forked import call_with_deadline
from lcpbench.core.operator import BudgetExhausted

__all__ = ["QP_BACKENDS", "TIME_LIMIT_OPTION", "QPTimeout", "solve_nonneg_qp",
           "polish_active_set", "refine_active_set", "solve_and_refine"]

#: Backend name -> (qpsolvers name, tight tolerance options at ``tol``).
QP_BACKENDS = {
    "clarabel": ("clarabel", lambda tol: dict(tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol,
                                             tol_ktratio=max(tol, 1e-10), max_iter=500)),
    "proxqp": ("proxqp", lambda tol: dict(eps_abs=tol, eps_rel=0.0, max_iter=100000)),
    "osqp": ("osqp", lambda tol: dict(eps_abs=tol, eps_rel=tol, max_iter=200000, polish=True,
                                     adaptive_rho=True)),
}

#: Backend -> the name of its own wall-time option (None: it has none, only the kill).
TIME_LIMIT_OPTION = {"clarabel": "time_limit", "proxqp": None, "osqp": "time_limit"}

#: Share of ``max_seconds`` handed to a backend's own time limit, so that it stops
#: cleanly before the child running it is killed at ``max_seconds``.
OWN_LIMIT_SHARE = 0.9


#: A forked backend call ends itself this many seconds after its limit if its parent,
#: which kills it at the limit, is gone.
ORPHAN_SLACK_S = 1.0


class QPTimeout(TimeoutError):
    """A backend did not answer within its ``max_seconds``.

    Attributes
    ----------
    tol : float
        The tolerance of the last attempt.
    """

    def __init__(self, message: str, tol: float = float("nan")):
        super().__init__(message)
        self.tol = tol


@contextlib.contextmanager
def _c_stdout_silenced():
    """Send file descriptor 1 to /dev/null: OSQP's C code prints even with verbose off."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError):          # no real stdout (e.g. captured): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def solve_nonneg_qp(A: np.ndarray, b: np.ndarray, backend: str, tol: float = 1e-12,
                    x0: Optional[np.ndarray] = None, *, max_seconds: Optional[float] = None
                    ) -> tuple[Optional[np.ndarray], str]:
    """Solve the non-negative QP with one backend.

    Parameters
    ----------
    A, b : ndarray
        The QP ``min 1/2 x'Ax + b'x, x >= 0`` (A dense, symmetric).
    backend : str
        A key of :data:`QP_BACKENDS`.
    tol : float
        The backend's tolerance.
    x0 : ndarray, optional
        Warm start handed to the backend.
    max_seconds : float, optional
        Wall-time limit. The backend gets its own limit (where it has one) at
        :data:`OWN_LIMIT_SHARE` of it, and runs in a forked child killed at
        ``max_seconds``. None (or infinity): no limit, the call runs in this
        process.

    Returns
    -------
    x : ndarray or None
        None when the backend reports failure (or its child dies).
    message : str
        The backend's status.

    Raises
    ------
    QPTimeout
        When the child was killed at ``max_seconds``.
    """
    if backend not in QP_BACKENDS:
        raise KeyError(f"unknown QP backend {backend!r}; use one of {', '.join(QP_BACKENDS)}")
    if max_seconds is None or math.isinf(max_seconds):
        return _solve_here(A, b, backend, tol, x0, None)
    if not max_seconds > 0:
        raise QPTimeout(f"{backend}: no time left (max_seconds = {max_seconds:g})", tol)
    if not hasattr(os, "fork"):            # no fork on this platform: the backend's own limit
        return _solve_here(A, b, backend, tol, x0, max_seconds)
    import qpsolvers  # noqa: F401 - imported before the fork, so no child imports it again

    kind, value = call_with_deadline(_solve_in_child, (A, b, backend, tol, x0, max_seconds),
                                     max_seconds)
    if kind == "ok":
        return value
    if kind == "timeout":
        raise QPTimeout(f"{backend}: killed at its time limit of {max_seconds:.3g} s", tol)
    return None, f"{backend}: {value}"


def _solve_in_child(A: np.ndarray, b: np.ndarray, backend: str, tol: float,
                    x0: Optional[np.ndarray], max_seconds: float
                    ) -> tuple[Optional[np.ndarray], str]:
    """:func:`_solve_here` in the forked child, which ends itself if its parent cannot.

    The parent kills the child at ``max_seconds``; should the parent be killed
    first (``kill -9`` of the runner, or of a run's own child), the child's
    ``SIGALRM`` at its default action ends it :data:`ORPHAN_SLACK_S` later,
    inside compiled code too, so no backend outlives its limit.
    """
    signal.signal(signal.SIGALRM, signal.SIG_DFL)
    signal.setitimer(signal.ITIMER_REAL, max_seconds + ORPHAN_SLACK_S)
    try:
        return _solve_here(A, b, backend, tol, x0, max_seconds)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)


def _solve_here(A: np.ndarray, b: np.ndarray, backend: str, tol: float,
                x0: Optional[np.ndarray], max_seconds: Optional[float]
                ) -> tuple[Optional[np.ndarray], str]:
    """:func:`solve_nonneg_qp` in this process, with the backend's own time limit if any."""
    from qpsolvers import Problem, solve_problem

    name, opts = QP_BACKENDS[backend]
    options = opts(tol)
    own = TIME_LIMIT_OPTION[backend]
    if max_seconds is not None and own is not None:
        options[own] = OWN_LIMIT_SHARE * max_seconds
    n = A.shape[0]
    P = sp.csc_matrix(A) if name in ("clarabel", "osqp") else A
    prob = Problem(P=P, q=np.asarray(b, dtype=np.float64), lb=np.zeros(n))
    with warnings.catch_warnings(), _c_stdout_silenced():
        warnings.simplefilter("ignore")
        sol = solve_problem(prob, solver=name, initvals=x0, verbose=False, **options)
    status = ""
    if sol.extras:
        st = sol.extras.get("status") or sol.extras.get("info")
        status = str(getattr(st, "status", st)) if st is not None else ""
    if not sol.found or sol.x is None or not np.all(np.isfinite(sol.x)):
        return None, f"{backend}: no solution ({status or 'not found'})"
    return np.maximum(np.asarray(sol.x, dtype=np.float64), 0.0), f"{backend}: {status or 'found'}"


def polish_active_set(A: np.ndarray, b: np.ndarray, x: np.ndarray) -> np.ndarray:
    """One active-set refinement: solve ``A_FF x_F = -b_F`` on the support of ``x``.

    The support ``F`` is where ``x_i > w_i`` (the min-map's choice). The polished
    point is returned only if it is feasible and lowers ``||min(x, Ax+b)||``;
    otherwise ``x`` is returned unchanged. (Least squares handles singular A_FF.)
    """
    w = A @ x + b
    F = x > w
    if not F.any():
        cand = np.zeros_like(x)
    else:
        cand = np.zeros_like(x)
        sol, *_ = np.linalg.lstsq(A[np.ix_(F, F)], -b[F], rcond=None)
        cand[F] = sol
    if np.any(cand < 0):
        return x
    wc = A @ cand + b
    if np.linalg.norm(np.minimum(cand, wc)) < np.linalg.norm(np.minimum(x, w)):
        return cand
    return x


def refine_active_set(A: np.ndarray, b: np.ndarray, x: np.ndarray, steps: int = 3) -> np.ndarray:
    """Active-set correction steps on the dense matrix, each kept only if it helps.

    Each step takes ``F = {x_i > w_i}`` (the min-map's choice), zeroes ``x``
    off ``F``, solves the correction ``A_FF d = -(A x + b)_F`` by least
    squares (the minimum-norm correction, so for singular ``A_FF`` the point
    stays near the backend's answer instead of jumping to the minimum-norm
    solution), clips ``x_F + d`` at 0, and keeps the candidate only if it
    lowers ``||min(x, Ax+b)||``; it stops at the first step that does not.

    Parameters
    ----------
    A : ndarray, shape (n, n)
    b : ndarray, shape (n,)
    x : ndarray, shape (n,)
        A non-negative approximate solution.
    steps : int
        Maximum number of steps.

    Returns
    -------
    ndarray
        The refined point (``x`` itself when no step helps).
    """
    best = _kkt(A, b, x)
    for _ in range(steps):
        if best == 0.0:
            break
        F = x > A @ x + b
        cand = np.where(F, x, 0.0)
        if F.any():
            r = (A @ cand + b)[F]
            d, *_ = np.linalg.lstsq(A[np.ix_(F, F)], -r, rcond=None)
            cand[F] = np.maximum(cand[F] + d, 0.0)
        res = _kkt(A, b, cand)
        if not res < best:
            break
        x, best = cand, res
    return x


def _kkt(A: np.ndarray, b: np.ndarray, x: np.ndarray) -> float:
    return float(np.linalg.norm(np.minimum(x, A @ x + b)))


def solve_and_refine(A: np.ndarray, b: np.ndarray, backend: str, tol: float = 1e-10, *,
                     retries: int = 2, polish: bool = True, refine_steps: int = 3,
                     max_seconds: Optional[float] = None
                     ) -> tuple[Optional[np.ndarray], str, float]:
    """One backend at ``tol`` (looser by 100x per retry on failure), then polish and refine.

    Parameters
    ----------
    max_seconds : float, optional
        Wall-time limit of the backend's attempts together (each retry gets
        what is left; see :func:`solve_nonneg_qp`). The polish and refinement
        after a success are dense algebra of bounded cost and are not limited.

    Returns
    -------
    x : ndarray or None
        None when every attempt failed.
    message : str
    tol_used : float
        The tolerance of the attempt that succeeded (or the last tried).

    Raises
    ------
    QPTimeout
        When ``max_seconds`` ran out before an attempt succeeded.
    """
    deadline = None if max_seconds is None else time.monotonic() + max_seconds
    for attempt in range(retries + 1):
        limit = None if deadline is None else deadline - time.monotonic()
        try:
            x, message = solve_nonneg_qp(A, b, backend, tol, max_seconds=limit)
        except (QPTimeout, BudgetExhausted):   # out of time: no retry, the caller decides
            raise
        except Exception as exc:  # a backend crash is a failed solve, not a crash
            x, message = None, f"{backend}: {type(exc).__name__}: {exc}"
        if x is None and deadline is not None and time.monotonic() >= deadline:
            raise QPTimeout(f"{message}; time limit of {max_seconds:.3g} s reached", tol)
        if x is not None or attempt == retries or tol * 100 >= 1:
            break
        tol *= 100
    if x is not None:
        if polish:
            x = polish_active_set(A, b, x)
        if refine_steps:
            x = refine_active_set(A, b, x, refine_steps)
    return x, message, tol
