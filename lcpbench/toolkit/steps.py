"""Exact step lengths along a direction for the quadratic objective (no extra MVP).

For ``f(x) = 1/2 x'Ax + b'x`` and a direction ``p`` with the product ``A p``
already computed, ``f(x + eta p)`` is an exact parabola in ``eta``:
``f(x) + eta g'p + eta^2/2 p'Ap`` with ``g = A x + b``. Solvers then update the
gradient by the recurrence ``g + eta A p`` instead of a new product.
"""

from __future__ import annotations

import numpy as np

__all__ = ["exact_step", "feasible_step_bound", "cauchy_step"]


def exact_step(g: np.ndarray, p: np.ndarray, Ap: np.ndarray) -> float:
    """Unconstrained minimiser ``-g'p / p'Ap`` of ``f`` along ``p`` (the CG step).

    Returns ``inf`` when the curvature ``p'Ap`` is not positive and ``p``
    descends (the parabola is unbounded below along ``p``), and 0 when ``p``
    does not descend.
    """
    gp = float(g @ p)
    pAp = float(p @ Ap)
    if gp >= 0.0:
        return 0.0
    if pAp <= 0.0:
        return float("inf")
    return -gp / pAp


def feasible_step_bound(x: np.ndarray, p: np.ndarray) -> float:
    """Largest ``eta >= 0`` with ``x + eta p >= 0`` (``inf`` if ``p >= 0``)."""
    neg = p < 0
    if not np.any(neg):
        return float("inf")
    return float(np.min(-x[neg] / p[neg]))


def cauchy_step(w: np.ndarray, Aw: np.ndarray) -> float:
    """The Cauchy step ``w'w / w'Aw``: the exact minimiser along ``-w`` (1.0 if undefined).

    First step of the projected-gradient baselines when no secant pair is known
    (the product ``A w`` is the caller's, counted).
    """
    wAw = float(w @ Aw)
    tau = float(w @ w) / wAw if wAw > 0.0 else 1.0
    return tau if np.isfinite(tau) and tau > 0.0 else 1.0
