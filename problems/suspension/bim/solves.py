"""The Krylov side of :class:`~.operator.BimMobility`: recycled spaces, the solves' records,
the tolerance a solve stops at (``eps_gmres``, or a looser one on request) and the report of a
solve that missed it.

:class:`KrylovSolves` is a mixin: the operator provides ``setup``, ``recycle``, ``krylov``,
``eps_gmres``, ``maxiter``, ``on_failure``, ``M``, ``p``, ``apply_preconditioned`` and
``adjoint_pieces``.
"""

from __future__ import annotations

import contextlib
import warnings
import weakref
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from ..geometry import check_tolerance
from .gmres import relaxed_gmres
from .pairs import RELAX_STEP
from .recycle import KrylovBudget, RecycledGCR

if TYPE_CHECKING:
    from .adjoint import AdjointPieces
    from .setup import BimSetup

__all__ = ["KrylovSolves", "BimConvergenceWarning"]


class BimConvergenceWarning(RuntimeWarning):
    """GMRES stopped before reaching the requested tolerance."""


class KrylovSolves:
    """Recycled spaces, records and stopping tolerance of a boundary-integral mobility."""

    _relaxed: float | None = None     # a looser tolerance asked by at_accuracy
    _recycler: RecycledGCR | None
    _adj_recycler: RecycledGCR | None

    if TYPE_CHECKING:                 # what the operator provides
        setup: BimSetup
        recycle: int
        krylov: KrylovBudget
        eps_gmres: float
        maxiter: int
        on_failure: str

        @property
        def M(self) -> int: ...

        @property
        def p(self) -> int: ...

        @property
        def adjoint_pieces(self) -> AdjointPieces: ...

        def apply_preconditioned(self, y: np.ndarray, rung: int = 0) -> np.ndarray: ...

    def _new_recyclers(self) -> tuple[RecycledGCR | None, RecycledGCR | None]:
        """Empty recycled spaces for the forward and the transposed equation (None, None
        without recycling)."""
        n, cap = self.setup.unknowns, self.recycle
        if not cap:
            return None, None
        # the solvers reach this operator through a weak reference: a strong one would make
        # a reference cycle, and the blocks and kept directions of every configuration would
        # wait for Python's cyclic collector (docs/mobility.md, "Memory per time step")
        me = weakref.ref(self)

        def host() -> KrylovSolves:
            op = me()
            assert op is not None, "the operator of a recycled space was collected"
            return op

        return (RecycledGCR(lambda v: host().apply_preconditioned(v), n, cap, self.krylov),
                RecycledGCR(lambda v: host().adjoint_pieces.operator(v), n, cap, self.krylov))

    @contextlib.contextmanager
    def cold_products(self) -> Iterator[None]:
        """Products made inside start from empty recycled spaces, as the first product of
        a configuration does; the kept directions are put back afterwards.  For timing one
        product at its first-product cost (:func:`lcpbench.core.probes.measure_cost`):
        with recycling every later product needs fewer new directions."""
        saved = self._recycler, self._adj_recycler
        self._recycler, self._adj_recycler = self._new_recyclers()
        try:
            yield
        finally:
            self._recycler, self._adj_recycler = saved

    @property
    def solve_tol(self) -> float:
        """The tolerance the next solve stops at: ``eps_gmres``, or the looser one asked
        inside :meth:`at_accuracy`."""
        return self.eps_gmres if self._relaxed is None else self._relaxed

    @contextlib.contextmanager
    def at_accuracy(self, rtol: float) -> Iterator[None]:
        """Products made inside stop their solves at relative residual ``rtol`` instead of
        ``eps_gmres`` (never tighter: ``max(rtol, eps_gmres)``).

        For a solver that needs a product only to a known accuracy (inexact products,
        :class:`lcpbench.solvers.pqn.products.IterateProducts`): the solve stops earlier,
        the directions it adds to the recycled spaces are exact images, so later products
        at full accuracy lose nothing.  The quadrature stays that of ``eps_gmres``.

        Raises
        ------
        ValueError
            If ``rtol`` is not in (0, 1).
        """
        tol = max(check_tolerance(rtol), self.eps_gmres)
        saved, self._relaxed = self._relaxed, tol
        try:
            yield
        finally:
            self._relaxed = saved

    def work_counts(self) -> dict[str, int]:
        """Inner applications made so far: ``{"forward": .., "adjoint": ..}``, the sums of
        :attr:`gmres_iterations` and :attr:`adjoint_iterations` (GMRES/GCR products of the
        traction operator and of its transpose).  The ``work`` hook of the counted operator
        (:class:`lcpbench.Operator`), which charges each counted product the increase."""
        return {"forward": int(sum(self.gmres_iterations)),
                "adjoint": int(sum(self.adjoint_iterations))}

    def _fresh_solvers(self) -> None:
        """New (empty) recycled spaces and empty iteration and residual records."""
        self._recycler, self._adj_recycler = self._new_recyclers()
        self.gmres_iterations: list[int] = []
        self.residuals: list[float] = []
        self.adjoint_iterations: list[int] = []
        self.adjoint_residuals: list[float] = []

    def _solve(self, what: str, operator, b: np.ndarray, start: np.ndarray, rungs: int,
               records: tuple[list, list]) -> np.ndarray:
        """GMRES on ``operator(v, rung)`` from ``start`` to ``eps_gmres`` (restart 60,
        ``maxiter``); records the iterations and the full-accuracy residual in ``records``
        and reports non-convergence (:meth:`_report`)."""
        restart = max(1, min(b.size, 60, self.maxiter))
        x, its, res = relaxed_gmres(operator, b, start, self.solve_tol, restart, self.maxiter,
                                    rungs=rungs, step=RELAX_STEP)
        self._record(what, its, res, records)
        return x

    def _recycled_solve(self, what: str, solver: RecycledGCR, b: np.ndarray,
                        records: tuple[list, list], x0: np.ndarray | None = None
                        ) -> np.ndarray:
        """:meth:`RecycledGCR.solve` to ``eps_gmres`` within ``maxiter`` new directions
        (from the guess ``x0``); records the products made and the true residual, and
        reports non-convergence (:meth:`_report`)."""
        before = solver.products
        y, _new, res = solver.solve(b, self.solve_tol, self.maxiter, x0=x0)
        self._record(what, solver.products - before, res, records)
        return y

    def _record(self, what: str, its: int, res: float, records: tuple[list, list]) -> None:
        """Append a solve's products and residual to its lists and report non-convergence."""
        records[0].append(its)
        records[1].append(res)
        self._report(what, res, its)

    def _report(self, what: str, res: float, its: int) -> None:
        """Warn (or raise, ``on_failure="raise"``) when a solve's full-accuracy relative
        residual ``res`` missed ``eps_gmres``."""
        if res <= self.solve_tol:
            return
        msg = (f"{what} did not converge: relative residual {res:.3g} after {its} "
               f"iterations (eps_gmres = {self.solve_tol:g}, M = {self.M}, p = {self.p}); "
               "raise maxiter or eps_gmres, or check for near-contact spheres")
        if self.on_failure == "raise":
            raise RuntimeError(msg)
        warnings.warn(msg, BimConvergenceWarning, stacklevel=6)
