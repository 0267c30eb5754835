"""Consensus reference solutions from independent QP solvers."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lcpbench.core.lcp import LCP
from lcpbench.core.residuals import kkt_abs, objective
from lcpbench.toolkit.qp import solve_and_refine

__all__ = ["Reference", "reference", "AGREE_RTOL"]

#: Two backends agree when their w differ by at most this, relative to max(1, ||w||).
AGREE_RTOL = 1e-8


@dataclass
class Reference:
    """A reference solution of an LCP.

    Attributes
    ----------
    x, w : ndarray
        Solution and ``A x + b`` of the most accurate agreeing backend.
    objective : float
    accepted : bool
        True when at least two backends agree on ``w`` to :data:`AGREE_RTOL`.
    solvers : list of str
        Backends in the agreeing group (or all that returned, if none agree).
    kkt_abs : float
        ``||min(x, w)||`` of the returned solution.
    disagreement : float
        Largest relative difference of ``w`` among the agreeing group, or the
        smallest pairwise difference when no two agree.
    details : dict
        Per-backend message, residual and w.
    """

    x: np.ndarray
    w: np.ndarray
    objective: float
    accepted: bool
    solvers: list
    kkt_abs: float
    disagreement: float
    details: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"x": self.x, "w": self.w, "objective": self.objective,
                "accepted": self.accepted, "solvers": list(self.solvers),
                "kkt_abs": self.kkt_abs, "disagreement": self.disagreement}


def _rel(w1: np.ndarray, w2: np.ndarray) -> float:
    scale = max(1.0, float(np.linalg.norm(w1)), float(np.linalg.norm(w2)))
    return float(np.linalg.norm(w1 - w2)) / scale


def reference(lcp: LCP, backends: Sequence[str] = ("clarabel", "proxqp", "osqp"),
              tol: float = 1e-10, polish: bool = True, rtol: float = AGREE_RTOL) -> Reference:
    """Ground truth for ``lcp`` from the reference QP solvers.

    Each backend solves ``min 1/2 x'Ax + b'x, x >= 0`` on the dense matrix
    (formed once, uncounted) at tolerance ``tol`` (retried up to 100x and
    10^4 x looser if the backend reports failure: at 1e-12 Clarabel fails on
    most planted instances and ProxQP on badly scaled b); each answer is then
    refined on the dense matrix by the active-set polish and correction steps
    of :func:`lcpbench.toolkit.qp.solve_and_refine`, each kept only when it lowers the
    residual. The reference is *accepted* when at least two
    backends agree on ``w`` (compared rather than ``x``, which is not unique
    when A is singular) to ``rtol`` relative; otherwise the disagreement is
    recorded and ``accepted`` is False.

    An operator that declares a relative accuracy (``Operator(..., rtol=)``, e.g.
    products that are iterative solves) gives a dense matrix symmetric only to
    about that accuracy; it is symmetrised before the backends see it (each
    backend reads a different triangle of an asymmetric matrix) and its
    asymmetry ``max|A - A'| / max|A|`` is recorded in ``details['asymmetry']``
    beside ``details['operator_rtol']``. The reference then solves the
    symmetrised matrix; its residual for a fresh product of the operator is
    within the operator's accuracy of ``kkt_abs``.
    """
    A = lcp.dense()
    b = lcp.b
    n = lcp.n
    if n == 0:
        z = np.zeros(0)
        return Reference(z, z, 0.0, True, list(backends), 0.0, 0.0)
    sols = {}
    details: dict[str, Any] = {}
    if lcp.A.rtol is not None:
        scale = float(np.max(np.abs(A)))
        details["asymmetry"] = float(np.max(np.abs(A - A.T))) / scale if scale > 0 else 0.0
        details["operator_rtol"] = float(lcp.A.rtol)
        A = (A + A.T) / 2
    for name in backends:
        x, msg, _ = solve_and_refine(A, b, name, tol, polish=polish,
                                     refine_steps=3 if polish else 0)
        if x is not None:
            w = A @ x + b
            sols[name] = (x, w, kkt_abs(x, w))
        details[name] = {"message": msg,
                         "kkt_abs": sols[name][2] if name in sols else float("nan")}
    if not sols:
        raise RuntimeError(f"no reference backend solved {lcp.name!r}: "
                           + "; ".join(details[nm]["message"] for nm in backends))
    names = list(sols)
    best_group, best_spread = [names[0]], float("inf")
    for a in names:
        group = [a] + [c for c in names if c != a and _rel(sols[a][1], sols[c][1]) <= rtol]
        spread = max((_rel(sols[p][1], sols[q][1]) for p in group for q in group if p < q),
                     default=float("inf"))
        if len(group) > len(best_group) or (len(group) == len(best_group) and spread < best_spread):
            best_group, best_spread = group, spread
    accepted = len(best_group) >= 2
    if not accepted:
        pair = [(_rel(sols[p][1], sols[q][1])) for p in names for q in names if p < q]
        best_spread = min(pair) if pair else float("inf")
        best_group = names
    pick = min(best_group, key=lambda k: sols[k][2])
    x, w, res = sols[pick]
    return Reference(x=x, w=w, objective=objective(x, w, b), accepted=accepted,
                     solvers=sorted(best_group), kkt_abs=res, disagreement=best_spread,
                     details=details)
