"""Consensus reference solutions from independent QP solvers."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from lcpbench.core.lcp import LCP
from lcpbench.core.residuals import kkt_abs, objective
from lcpbench.toolkit.qp import QPTimeout, solve_and_refine

__all__ = ["Reference", "reference", "AGREE_RTOL", "default_reference_seconds",
           "REFERENCE_BASE_SECONDS", "REFERENCE_SECONDS_PER_GIGAFLOP"]

#: Two backends agree when their w differ by at most this, relative to max(1, ||w||).
AGREE_RTOL = 1e-8

#: The default time limit of one reference backend is this many seconds ...
REFERENCE_BASE_SECONDS = 10.0
#: ... plus this many seconds per (n / 1000)^3: the backends' dense factorisations grow
#: as n^3. Measured on a loaded 2-core machine (SPD A, tolerance 1e-10): Clarabel, the
#: slowest, took 0.3 s at n = 300, 4.4 s at n = 1000 and 28 s at n = 2000, against
#: default limits of 10.5 s, 30 s and 170 s.
REFERENCE_SECONDS_PER_GIGAFLOP = 20.0


def default_reference_seconds(n: int) -> float:
    """The time limit of one reference backend on an ``n x n`` problem when none is given.

    ``REFERENCE_BASE_SECONDS + REFERENCE_SECONDS_PER_GIGAFLOP * (n / 1000)^3``:
    10 s for small problems (which take well under a second unless the backend
    is stuck), 30 s at n = 1000, 550 s at n = 3000 (the runner's largest
    consensus reference).
    """
    return REFERENCE_BASE_SECONDS + REFERENCE_SECONDS_PER_GIGAFLOP * (max(int(n), 0) / 1000) ** 3


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
        Per-backend message and residual.
    answers : dict
        Each answering backend's ``(x, w, kkt_abs)``: a backend scored as a solver is
        compared with the others' answers, not with a consensus it belongs to.
    """

    x: np.ndarray
    w: np.ndarray
    objective: float
    accepted: bool
    solvers: list
    kkt_abs: float
    disagreement: float
    details: dict = field(default_factory=dict)
    answers: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"x": self.x, "w": self.w, "objective": self.objective,
                "accepted": self.accepted, "solvers": list(self.solvers),
                "kkt_abs": self.kkt_abs, "disagreement": self.disagreement,
                "answers": dict(self.answers)}

    def without(self, name: str) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """``(x, w)`` of the best answer of the backends other than ``name``.

        The best is the lowest residual among the agreeing group less ``name`` (among
        all other answers if none of the group is left); ``None`` when no other backend
        answered.
        """
        return reference_without(self.as_dict(), name)


def reference_without(ref: dict, name: str) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """``(x, w)`` of the best answer in ``ref`` (a :meth:`Reference.as_dict`) not by ``name``.

    Used to score a reference backend against the others (leave one out) instead of
    against a consensus that contains its own answer.
    """
    answers = {k: v for k, v in ref.get("answers", {}).items() if k != name}
    if not answers:
        return None
    group = [k for k in ref.get("solvers", []) if k in answers] or list(answers)
    best = min(group, key=lambda k: answers[k][2])
    return answers[best][0], answers[best][1]


def _rel(w1: np.ndarray, w2: np.ndarray) -> float:
    scale = max(1.0, float(np.linalg.norm(w1)), float(np.linalg.norm(w2)))
    return float(np.linalg.norm(w1 - w2)) / scale


def _backend_answer(A: np.ndarray, b: np.ndarray, name: str, tol: float, polish: bool,
                    limit: Optional[float], sols: dict) -> dict:
    """One backend's answer, added to ``sols`` when it has one; its ``details`` entry."""
    timed_out = False
    try:
        x, msg, _ = solve_and_refine(A, b, name, tol, polish=polish,
                                     refine_steps=3 if polish else 0, max_seconds=limit)
    except QPTimeout as exc:
        x, msg, timed_out = None, str(exc), True
    if x is not None:
        w = A @ x + b
        sols[name] = (x, w, kkt_abs(x, w))
    return {"message": msg, "timeout": timed_out,
            "kkt_abs": sols[name][2] if name in sols else float("nan")}


def reference(lcp: LCP, backends: Sequence[str] = ("clarabel", "proxqp", "osqp"),
              tol: float = 1e-10, polish: bool = True, rtol: float = AGREE_RTOL, *,
              max_seconds: Optional[float] = None) -> Reference:
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

    Every backend is held to ``max_seconds`` (its retries together; default
    :func:`default_reference_seconds` of ``n``, ``math.inf`` for no limit): it
    runs in a forked child that is killed then
    (:func:`lcpbench.toolkit.qp.solve_nonneg_qp`), so a backend that never
    returns (ProxQP on some infeasible problems) costs at most that and the
    others still decide; ``details[name]["timeout"]`` is then True. The whole
    call takes at most about ``len(backends) * max_seconds`` plus the dense
    polish.

    Raises
    ------
    RuntimeError
        When no backend solved the problem (each backend's message included).
    """
    if max_seconds is None:
        max_seconds = default_reference_seconds(lcp.n)
    elif not max_seconds > 0:
        raise ValueError(f"max_seconds must be > 0 (math.inf: no limit), got {max_seconds!r}")
    A = lcp.dense()
    b = lcp.b
    n = lcp.n
    if n == 0:
        z = np.zeros(0)
        return Reference(z, z, 0.0, True, list(backends), 0.0, 0.0)
    sols: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}
    details: dict[str, Any] = {}
    if lcp.A.rtol is not None:
        scale = float(np.max(np.abs(A)))
        details["asymmetry"] = float(np.max(np.abs(A - A.T))) / scale if scale > 0 else 0.0
        details["operator_rtol"] = float(lcp.A.rtol)
        A = (A + A.T) / 2
    limit = None if math.isinf(max_seconds) else float(max_seconds)
    for name in backends:
        details[name] = _backend_answer(A, b, name, tol, polish, limit, sols)
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
                     details=details, answers=sols)
