"""Dense QP backends through qpsolvers: ``min 1/2 x'Ax + b'x  s.t.  x >= 0``.

Used by the registered reference solvers and by :func:`lcpbench.reference`.
qpsolvers was chosen because it gives one interface to the three independent
interior-point / ADMM / augmented-Lagrangian codes the suite uses as ground
truth (Clarabel, ProxQP, OSQP), so disagreements come from the methods and
not from glue code.
"""

from __future__ import annotations

import contextlib
import os
import sys
import warnings
from typing import Optional

import numpy as np
import scipy.sparse as sp

__all__ = ["QP_BACKENDS", "solve_nonneg_qp", "polish_active_set", "refine_active_set",
           "solve_and_refine"]

#: Backend name -> (qpsolvers name, tight tolerance options at ``tol``).
QP_BACKENDS = {
    "clarabel": ("clarabel", lambda tol: dict(tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol,
                                             tol_ktratio=max(tol, 1e-10), max_iter=500)),
    "proxqp": ("proxqp", lambda tol: dict(eps_abs=tol, eps_rel=0.0, max_iter=100000)),
    "osqp": ("osqp", lambda tol: dict(eps_abs=tol, eps_rel=tol, max_iter=200000, polish=True,
                                     adaptive_rho=True)),
}


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
                    x0: Optional[np.ndarray] = None) -> tuple[Optional[np.ndarray], str]:
    """Solve the non-negative QP with one backend.

    Returns
    -------
    x : ndarray or None
        None when the backend reports failure.
    message : str
        The backend's status.
    """
    from qpsolvers import Problem, solve_problem

    if backend not in QP_BACKENDS:
        raise KeyError(f"unknown QP backend {backend!r}; use one of {', '.join(QP_BACKENDS)}")
    name, opts = QP_BACKENDS[backend]
    n = A.shape[0]
    P = sp.csc_matrix(A) if name in ("clarabel", "osqp") else A
    prob = Problem(P=P, q=np.asarray(b, dtype=np.float64), lb=np.zeros(n))
    with warnings.catch_warnings(), _c_stdout_silenced():
        warnings.simplefilter("ignore")
        sol = solve_problem(prob, solver=name, initvals=x0, verbose=False, **opts(tol))
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
                     retries: int = 2, polish: bool = True, refine_steps: int = 3
                     ) -> tuple[Optional[np.ndarray], str, float]:
    """One backend at ``tol`` (looser by 100x per retry on failure), then polish and refine.

    Returns
    -------
    x : ndarray or None
        None when every attempt failed.
    message : str
    tol_used : float
        The tolerance of the attempt that succeeded (or the last tried).
    """
    for attempt in range(retries + 1):
        try:
            x, message = solve_nonneg_qp(A, b, backend, tol)
        except Exception as exc:  # a backend crash is a failed solve, not a crash
            x, message = None, f"{backend}: {type(exc).__name__}: {exc}"
        if x is not None or attempt == retries or tol * 100 >= 1:
            break
        tol *= 100
    if x is not None:
        if polish:
            x = polish_active_set(A, b, x)
        if refine_steps:
            x = refine_active_set(A, b, x, refine_steps)
    return x, message, tol
