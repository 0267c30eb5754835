"""Measurements of a counted operator made on the framework's uncounted path: the seconds a
product takes (:func:`measure_cost`) and how accurate its products are
(:func:`measure_accuracy`), with the overflow-safe norm they and the claim checks use."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional

import numpy as np

from lcpbench.core.operator import Operator, apply_uncounted

__all__ = ["measure_cost", "Accuracy", "measure_accuracy", "safe_norm", "safe_column_norms", "ACCURACY_PROBES"]


def measure_cost(op: Operator, min_seconds: float = 0.02, max_reps: int = 50,
                 cold: Optional[Callable[[], contextlib.AbstractContextManager]] = None) -> float:
    """Seconds per product of ``op``, timed on uncounted products with positive vectors.

    Repeats cheap products until ``min_seconds`` of products have passed (or ``max_reps``),
    so microsecond operators get a stable estimate; an expensive one is timed once.  Every
    repetition applies a different vector (``linspace(1, 2, n)`` rotated and scaled),
    so that an operator that remembers its last products does not serve a repetition from
    memory.

    Parameters
    ----------
    op : Operator
    min_seconds, max_reps : float, int
        When to stop repeating.
    cold : callable, optional
        For an operator that gets cheaper as it is used (a mobility that recycles its Krylov
        directions: every later product needs fewer new ones): ``cold()`` returns a context
        manager inside which a product costs what the first product of the configuration
        costs (:meth:`BimMobility.cold_products`).  Every timed product runs inside a fresh
        one; only the products are timed.  Without it a repetition would time the cheaper
        later products (measured: a p = 3 boundary-integral low timed 5x below its first
        product on a 27-sphere configuration).
    """
    n = op.shape[1]
    v = np.linspace(1.0, 2.0, n)
    reps, el = 0, 0.0
    while True:
        vk = np.roll(v, reps) * (1.0 + 1e-3 * reps)
        with (cold() if cold is not None else contextlib.nullcontext()):
            t0 = time.perf_counter()
            apply_uncounted(op, vk)
            el += time.perf_counter() - t0
        reps += 1
        if el >= min_seconds or reps >= max_reps:
            return max(el / reps, 1e-9)


#: Between these, a sum of squares is far from float64's overflow and from the subnormals,
#: so ``sqrt(v . v)`` (one pass) is the norm to rounding and the scaled passes (three, about
#: three times the time at n = 100) are not needed.
_SQUARE_SAFE_LOW, _SQUARE_SAFE_HIGH = 1e-200, 1e200


def safe_norm(v: np.ndarray) -> float:
    """``||v||_2`` without overflow or underflow: entries of 1e300 give 1e300 sqrt(n), not inf.

    inf only when an entry is infinite, nan when one is nan.
    """
    v = np.asarray(v, dtype=np.float64).reshape(-1)
    if v.size == 0:
        return 0.0
    with np.errstate(over="ignore", under="ignore"):    # out of range: the scaled passes
        sq = float(np.dot(v, v))
    if _SQUARE_SAFE_LOW < sq < _SQUARE_SAFE_HIGH:
        return float(np.sqrt(sq))
    return float(safe_column_norms(v[:, None])[0])


def safe_column_norms(X: np.ndarray) -> np.ndarray:
    """The 2-norms of the columns of ``X`` without overflow or underflow (each column
    scaled by its largest entry); 0 for a zero column, inf or nan for a column with one."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        m = np.max(np.abs(X), axis=0) if X.shape[0] else np.zeros(X.shape[1])
        scale = np.where((m > 0) & np.isfinite(m), m, 1.0)
        return np.where(np.isfinite(m) & (m > 0), scale * np.linalg.norm(X / scale, axis=0), m)


#: A probe defect (see :func:`measure_accuracy`) at or below ``EXACT_ULPS eps n`` (capped at
#: :data:`EXACT_CAP`) is float64 rounding: the operator counts as exact.
EXACT_ULPS = 16.0
#: Uncounted products one accuracy probe takes (:func:`measure_accuracy`).
ACCURACY_PROBES = 4
EXACT_CAP = 1e-10


@dataclass(frozen=True)
class Accuracy:
    """The relative accuracy of an operator's products, and where it comes from.

    Attributes
    ----------
    rtol : float
        Relative error of a product: 0 for products exact to float64 rounding,
        nan when it could not be measured (the probe raised or gave non-finite values).
    source : str
        ``"declared"`` (``Operator(rtol=)``), ``"explicit"`` (a float64 matrix) or
        ``"measured"`` (:func:`measure_accuracy`).
    detail : str
        What was found, in words (for messages and ``info``).
    """

    rtol: float
    source: str
    detail: str

    @property
    def exact(self) -> bool:
        """True when products are exact to float64 rounding."""
        return self.rtol == 0.0

    @property
    def known(self) -> bool:
        """True when the accuracy is declared, or measured exact: a drift bound on it holds."""
        return self.source == "declared" or self.exact


def measure_accuracy(op: Operator, seed: int = 0) -> Accuracy:
    """How accurate ``op``'s products are, from four uncounted products (framework only).

    A declared ``rtol`` and an explicit float64 matrix need no product. Otherwise
    ``A u``, ``A v``, ``A (u + v)`` and ``A u`` again are applied to seeded
    Gaussian vectors: an operator exact to float64 rounding is linear and
    reproducible to about ``eps n`` of the products' size; an operator that
    computes in single precision, or solves to a tolerance (GMRES, CG), is not.
    The relative defect, or the epsilon of a narrower output dtype, is the
    measured accuracy. Products that raise or are not finite give ``rtol = nan``.
    """
    if op.rtol is not None:
        return Accuracy(float(op.rtol), "declared", f"declared rtol={op.rtol:g}")
    if op.explicit:
        return Accuracy(0.0, "explicit", "explicit float64 matrix")
    n = int(op.shape[1])
    rng = np.random.default_rng(seed)
    u, v = rng.standard_normal(n), rng.standard_normal(n)
    try:
        Au, Av, Auv, Au2 = (np.asarray(apply_uncounted(op, z), dtype=np.float64)
                            for z in (u, v, u + v, u))
    except Exception as exc:  # the operator's own failure: unknown accuracy
        return Accuracy(float("nan"), "measured", f"the accuracy probe raised "
                                                   f"{type(exc).__name__}: {exc}")
    scale = safe_norm(Au) + safe_norm(Av) + safe_norm(Auv)
    if not np.isfinite(scale):
        return Accuracy(float("nan"), "measured", "the accuracy probe gave non-finite products")
    linear = safe_norm(Auv - Au - Av) / scale if scale > 0 else 0.0
    repeat = safe_norm(Au2 - Au) / scale if scale > 0 else 0.0
    level = min(EXACT_ULPS * float(np.finfo(np.float64).eps) * max(n, 1), EXACT_CAP)
    rel = max(linear, repeat, op.output_eps)
    if rel <= level:
        return Accuracy(0.0, "measured", "products linear and reproducible to float64 rounding")
    what = []
    if op.output_eps:
        what.append(f"products returned in a {op.output_eps:.1e}-epsilon (narrower than "
                    "float64) dtype")
    if linear > level:
        what.append(f"A(u+v) - Au - Av = {linear:.1e} of the products")
    if repeat > level:
        what.append(f"the same product twice differs by {repeat:.1e}")
    return Accuracy(float(rel), "measured", "; ".join(what))
