"""Dense QP backends through qpsolvers: ``min 1/2 x'Ax + b'x  s.t.  x >= 0``.

Used by the registered reference solvers and by :func:`lcpbench.reference`.
qpsolvers was chosen because it gives one interface to the three independent
interior-point / ADMM / augmented-Lagrangian codes the suite uses as ground
truth (Clarabel, ProxQP, OSQP), so disagreements come from the methods and
not from glue code.
"""

from __future__ import annotations

import warnings
from typing import Optional

import numpy as np
import scipy.sparse as sp

__all__ = ["QP_BACKENDS", "solve_nonneg_qp", "polish_active_set"]

#: Backend name -> (qpsolvers name, tight tolerance options at ``tol``).
QP_BACKENDS = {
    "clarabel": ("clarabel", lambda tol: dict(tol_gap_abs=tol, tol_gap_rel=tol, tol_feas=tol,
                                             tol_ktratio=max(tol, 1e-10), max_iter=500)),
    "proxqp": ("proxqp", lambda tol: dict(eps_abs=tol, eps_rel=0.0, max_iter=100000)),
    "osqp": ("osqp", lambda tol: dict(eps_abs=tol, eps_rel=tol, max_iter=200000, polish=True,
                                     adaptive_rho=True)),
}


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
    with warnings.catch_warnings():
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
