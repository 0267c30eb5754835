"""Confirm a recurrence-updated gradient with a counted product before claiming convergence."""

from __future__ import annotations

from typing import Optional

import numpy as np

from lcpbench.core.context import SolverContext
from lcpbench.core.result import Status

__all__ = ["ConfirmedReport"]


class ConfirmedReport:
    """``ctx.report`` that confirms a recurrence-updated gradient before it claims convergence.

    Solvers that update ``G = A x + b`` by a recurrence ``G + eta A p`` (the
    PQN levels, algorithm stepSize: one MVP per iteration; min-map Newton's
    unclipped line-search trials) let ``G`` drift from the exact
    gradient by rounding, by at most about ``eps sqrt(n) (||G_old|| + ||G_new||)``
    per step (the update and the product ``A p``); the bound is accumulated
    here (with a factor 8) since the last exact product. When
    ``||min(x, G)||`` meets the stop threshold but the accumulated drift could
    account for the difference (``claim + drift > threshold``), ``G`` is
    recomputed exactly, in place, with one counted MVP
    (``info['confirmations']``) before the iterate is reported. With a
    well-scaled ``b`` the drift is far below the tolerance and nothing is
    spent; with ``|b|`` near 1e6 and the paper's absolute 1e-8 it is not, and
    without this the solver could claim a residual the framework's
    verification does not reproduce (found by ``benchmarks/fuzz.py``). With an
    operator that declares a relative accuracy ``rtol``, each step's product
    adds ``rtol ||dG||`` to the bound. A report whose residual plus the bound
    meets the threshold is certified to the framework
    (:meth:`~lcpbench.core.context.SolverContext.certify`), which then accepts a
    ``converged`` at that iterate without a fresh product. After
    three confirmations that the exact residual refutes, the solve ends
    ``stagnated``: the tolerance is then below the attainable precision.

    An operator that declares no ``rtol`` is not assumed exact: the first time
    a claim meets the threshold, its accuracy is measured on the framework's
    uncounted path (:meth:`~lcpbench.core.context.SolverContext.operator_accuracy`:
    free for a float64 matrix). When its products are not float64-exact
    (single precision, an iterative solve at an undeclared tolerance) the
    drift bound does not hold: every claim is then confirmed by an exact
    product, nothing is certified, and the stagnation message says how
    accurate the operator is and to declare it.
    lcpbench's addition; not in the method paper or the solvers' sources.

    Call it as ``report(x, G)`` in place of ``ctx.report(x, G)``; ``G`` may be
    replaced in place by the exact gradient. ``exact(x)`` is the counted
    ``A x + b`` that also resets the drift bound.
    """

    def __init__(self, ctx: SolverContext):
        self.ctx = ctx
        self.drift = 0.0
        self.prev_norm: Optional[float] = None
        self.scale = 8.0 * np.finfo(float).eps * np.sqrt(max(ctx.n, 1))
        self.refuted = 0
        self.max_refuted = 3
        # The products themselves round at eps ||A|| ||z|| (cancellation inside A z is invisible
        # in the norms of G): ||A|| is estimated from the secant ratios ||dG|| / ||dz|| seen so
        # far, and eps sqrt(n) ||A|| ||z|| is the precision floor below which no recurrence
        # claim is trusted (benchmarks/fuzz.py: ||A|| = 4.6e5, ||x|| = 4e3, claim 3.7e-10,
        # exact 1.2e-7).
        self.norm_A = 0.0
        self.rtol = float(ctx.A.rtol or 0.0)
        self.path = 0.0
        # undeclared accuracy is not exactness: measured at the first claim (None: not yet)
        self.inexact: Optional[bool] = False if ctx.A.rtol is not None or ctx.A.explicit \
            else None
        self._prev: Optional[tuple[np.ndarray, np.ndarray]] = None
        ctx.info["confirmations"] = 0

    def exact(self, z: np.ndarray) -> np.ndarray:
        """``A z + b`` by a counted product; resets the drift bound."""
        self.drift, self.prev_norm, self.path = 0.0, None, 0.0
        return self.ctx.A @ z + self.ctx.b

    def __call__(self, z: np.ndarray, G: np.ndarray, *, exact: bool = False,
                 always: bool = False) -> bool:
        """Report ``(z, G)``; True means stop.

        ``exact=True`` says ``G`` was just computed as ``A z + b`` (nothing to
        confirm; the drift bound restarts). ``always=True`` says the caller's
        recurrence has rounding the norm-based bound does not see (e.g. ``A d``
        formed as a difference of two large products): a claim that meets the
        threshold is then always confirmed.
        """
        norm = float(np.linalg.norm(G))
        if exact:
            self.drift, self.path = 0.0, 0.0
        elif self.prev_norm is not None:
            self.drift += self.scale * (self.prev_norm + norm)
            if self.rtol and self._prev is not None:
                # an inexact product A p is off by up to rtol ||A p||, and A p is what the
                # recurrence added to G since the last report
                self.drift += self.rtol * float(np.linalg.norm(G - self._prev[1]))
        self.prev_norm = norm
        if self._prev is not None and np.all(np.isfinite(G)):
            dz = float(np.linalg.norm(z - self._prev[0]))
            if dz > 0.0:
                self.norm_A = max(self.norm_A, float(np.linalg.norm(G - self._prev[1])) / dz)
            self.path += dz
        self._prev = (np.array(z, dtype=float), np.array(G, dtype=float))
        # every product A p of a step p rounds at about eps sqrt(n) ||A|| ||p||: the steps
        # since the last exact product (the path length, which an excursion far out and back
        # makes large even when z is small again) bound what the recurrence lost
        floor = self.scale * self.norm_A * (float(np.linalg.norm(z)) + self.path)
        thr = self.ctx.threshold
        claim = float(np.linalg.norm(np.minimum(z, G)))
        confirmed = False
        if claim <= thr and not exact and self.inexact is None and self.drift > 0.0:
            # a recurrence has run since the last exact product: is the operator exact?
            self.inexact = not self.ctx.operator_accuracy().known
        always = always or bool(self.inexact)
        doubt = always or thr < claim + self.drift + floor
        if not exact and (self.drift > 0.0 or always) and claim <= thr and doubt \
                and np.all(np.isfinite(G)):
            G[...] = self.exact(z)
            self.prev_norm = float(np.linalg.norm(G))
            self._prev = (np.array(z, dtype=float), np.array(G, dtype=float))
            self.ctx.info["confirmations"] += 1
            confirmed = True
        if np.all(np.isfinite(G)):
            norm_A = max(self.norm_A, self.ctx.norm_A)
            bound = float(np.linalg.norm(np.minimum(z, G))) + self.drift \
                + self.scale * norm_A * (float(np.linalg.norm(z)) + self.path)
            if bound <= thr and not always:
                self.ctx.certify(z, bound)
        if self.ctx.report(z, G):
            return True
        if confirmed:
            self.refuted += 1
            if self.refuted >= self.max_refuted:
                residual = float(np.linalg.norm(np.minimum(z, G)))
                self.ctx.status = Status.stagnated
                self.ctx.message = (
                    f"the gradient recurrence met the threshold {thr:.3g} {self.refuted} times "
                    f"but the exact residual did not (last {residual:.3g}): the tolerance is below "
                    "the precision attainable for this b; loosen tol or use stop='kkt'"
                    + (self.ctx.accuracy_advice() if self.inexact else ""))
                return True
        return False
