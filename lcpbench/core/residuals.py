"""Residuals of an LCP iterate and the stop rules built on them.

All functions take the iterate ``x`` and ``w = A x + b`` (as computed by whoever
calls them: the solver's own ``w`` for its claim, one uncounted product for the
framework's verification), so none of them performs a product.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

__all__ = [
    "kkt_abs", "kkt_abs_inf", "kkt_rel", "complementarity_gap", "infeasibility_x",
    "infeasibility_w", "fischer_burmeister", "objective", "all_residuals", "StopRule",
    "make_stop_rule", "STOP_RULES",
]

#: Names of the stop rules :func:`make_stop_rule` builds.
STOP_RULES = ("paper", "paper-code", "kkt")


def _norm(v: np.ndarray, ord=2) -> float:
    if not v.size:
        return 0.0
    if ord == 2 and v.ndim == 1:            # what numpy's norm computes, without its dispatch
        return math.sqrt(float(np.dot(v, v)))
    return float(np.linalg.norm(v, ord))


def kkt_abs(x: np.ndarray, w: np.ndarray) -> float:
    """``||min(x, w)||_2``: zero exactly at a solution (eq. kkt-error, absolute)."""
    return _norm(np.minimum(x, w))


def kkt_abs_inf(x: np.ndarray, w: np.ndarray) -> float:
    """``||min(x, w)||_inf``."""
    return _norm(np.minimum(x, w), np.inf)


def kkt_rel(current: float, previous: Optional[float]) -> float:
    """The paper's relative stagnation measure (eq. kkt-error).

    ``|e_k - e_{k-1}| / max(e_k, e_{k-1})`` with ``e = kkt_abs``; NaN at the first
    iterate, 0 when both are zero.
    """
    if previous is None or not np.isfinite(previous):
        return float("nan")
    den = max(current, previous)
    if den == 0.0:
        return 0.0
    return abs(current - previous) / den


def complementarity_gap(x: np.ndarray, w: np.ndarray) -> float:
    """``x . w`` (the paper's algorithmic stopping test in algorithm pqn)."""
    return float(x @ w) if x.size else 0.0


def infeasibility_x(x: np.ndarray) -> float:
    """``||min(x, 0)||_2``."""
    return _norm(np.minimum(x, 0.0))


def infeasibility_w(w: np.ndarray) -> float:
    """``||min(w, 0)||_2``."""
    return _norm(np.minimum(w, 0.0))


def fischer_burmeister(x: np.ndarray, w: np.ndarray) -> float:
    """``||phi_FB(x, w)||_2`` with ``phi(a, b) = sqrt(a^2 + b^2) - a - b``."""
    return _norm(np.hypot(x, w) - x - w)


def objective(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> float:
    """QP objective ``1/2 x'Ax + b'x`` computed from ``w = Ax + b`` without a product.

    ``1/2 x'(Ax) + b'x = 1/2 x'(w - b) + b'x = 1/2 x'(w + b)``.
    """
    return 0.5 * float(x @ (w + b)) if x.size else 0.0


def all_residuals(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> dict:
    """Every residual of the iterate in one dict (keys are the run-store columns)."""
    return {
        "kkt_abs": kkt_abs(x, w),
        "kkt_abs_inf": kkt_abs_inf(x, w),
        "comp_gap": complementarity_gap(x, w),
        "infeas_x": infeasibility_x(x),
        "infeas_w": infeasibility_w(w),
        "fischer_burmeister": fischer_burmeister(x, w),
        "objective": objective(x, w, b),
    }


def rounding_floor(Ax: np.ndarray, b: np.ndarray) -> float:
    """``eps (||A x|| + ||b||)``: the smallest residual ``||min(x, A x + b)||`` that float64
    resolves at ``x``, since forming ``A x + b`` rounds each entry by about ``eps`` times
    its terms. ``||A x||`` stands for ``||A|| ||x||`` (a lower bound of it, so a tolerance
    flagged as below the floor is certainly below it)."""
    with np.errstate(over="ignore"):
        return float(np.finfo(np.float64).eps * (_norm(Ax) + _norm(b)))


def floor_message(threshold: float, floor: float) -> str:
    """The message of a claim whose stop rule asks for more digits than float64 holds."""
    return (f"reached the float64 floor, not the tolerance: the stop rule asks for "
            f"||min(x, w)|| <= {threshold:.3g}, below eps (||A x|| + ||b||) = {floor:.3g}, "
            "so float64 cannot show the residual meets it; scale the problem or loosen tol")


@dataclass(frozen=True)
class StopRule:
    """When an iterate counts as converged.

    Parameters
    ----------
    kind : {"paper", "paper-code", "kkt"}
        ``paper``: stop when ``kkt_abs < tol`` or ``kkt_rel < tol`` (eq. kkt-error,
        tol 1e-8 in the paper). Stopping on the relative measure alone is
        reported as ``stagnated``, not ``converged``: the paper counts both as
        convergence, lcpbench keeps them apart so that no "converged" is false.
        ``paper-code``: stop when ``kkt_abs ** 2 < tol``, the test of the
        authors' released solvers (their ``norm(min(x, Ax+b))^2 < tol``), so
        the paper's tol 1e-8 is 1e-4 on the norm; no relative test.
        ``kkt``: stop when ``kkt_abs <= atol + rtol * ||b||`` (absolute test only).
    tol : float
        Tolerance of the paper rule.
    atol, rtol : float
        Tolerances of the kkt rule.
    """

    kind: str = "paper"
    tol: float = 1e-8
    atol: float = 1e-8
    rtol: float = 1e-8

    def __post_init__(self) -> None:
        if self.kind not in STOP_RULES:
            raise ValueError(f"unknown stop rule {self.kind!r}; use one of {', '.join(STOP_RULES)}")
        for k in ("tol", "atol", "rtol"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"stop rule {k} must be a finite number >= 0, got {v!r}")

    def threshold(self, b: np.ndarray) -> float:
        """The absolute bound on ``kkt_abs`` that this rule accepts."""
        if self.kind == "paper":
            return self.tol
        if self.kind == "paper-code":
            return float(np.sqrt(self.tol))
        return self.atol + self.rtol * _norm(b)

    def check(self, abs_err: float, rel_err: float, b: np.ndarray) -> Optional[str]:
        """``"converged"``, ``"stagnated"`` or None (keep going)."""
        if abs_err <= self.threshold(b):
            return "converged"
        if self.kind == "paper" and np.isfinite(rel_err) and rel_err < self.tol:
            return "stagnated"
        return None


def make_stop_rule(stop: Union[str, StopRule], tol: float) -> StopRule:
    """Build a :class:`StopRule` from ``"paper"``/``"paper-code"``/``"kkt"`` and ``tol``."""
    if isinstance(stop, StopRule):
        return stop
    if not isinstance(tol, (int, float)) or isinstance(tol, bool) or not np.isfinite(tol) or tol <= 0:
        raise ValueError(f"tol must be a positive finite number, got {tol!r}")
    if stop == "paper":
        return StopRule("paper", tol=float(tol))
    if stop == "paper-code":
        return StopRule("paper-code", tol=float(tol))
    if stop == "kkt":
        return StopRule("kkt", tol=float(tol), atol=float(tol), rtol=float(tol))
    raise ValueError(f"unknown stop rule {stop!r}; use 'paper' (abs or relative KKT below tol, "
                     "the paper's KKT error), 'paper-code' (||min(x,w)||^2 < tol, the authors' code) "
                     "or 'kkt' (||min(x,w)|| <= tol (1 + ||b||))")
