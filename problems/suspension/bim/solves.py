"""The Krylov side of :class:`~.operator.BimMobility`: recycled spaces, the solves' records,
the tolerance a solve stops at (``eps_gmres``, or a looser one on request) and the report of a
solve that missed it.

:class:`KrylovSolves` is a part of the operator (``BimMobility.solves``), not a base class:
its recycled spaces reach the operator's products through a weak reference
(:class:`SolvedOperator` says which), and the operator shows its records and contexts under
the same names.
"""

from __future__ import annotations

import contextlib
import warnings
import weakref
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..geometry import check_tolerance
from .gmres import relaxed_gmres
from .pairs import RELAX_STEP
from .recycle import KrylovBudget, RecycledGCR

if TYPE_CHECKING:
    from .adjoint import AdjointPieces

__all__ = ["KrylovSolves", "BimConvergenceWarning", "SolvedOperator"]


class BimConvergenceWarning(RuntimeWarning):
    """GMRES stopped before reaching the requested tolerance."""


class SolvedOperator(Protocol):
    """What the solves need of their operator: the preconditioned traction operator and the
    transposed pieces."""

    def apply_preconditioned(self, y: np.ndarray, rung: int = 0) -> np.ndarray: ...

    @property
    def adjoint_pieces(self) -> AdjointPieces: ...


class KrylovSolves:
    """Recycled spaces, records and stopping tolerance of the solves of one operator.

    Parameters
    ----------
    operator : SolvedOperator
        The operator whose equations are solved.  Only its recycled spaces reach it, through
        a weak reference: a strong one would make a reference cycle, and the blocks and kept
        directions of every configuration would wait for Python's cyclic collector
        (docs/mobility.md, "Memory per time step").
    unknowns : int
        Length of the densities.
    eps_gmres, maxiter, on_failure, recycle, krylov
        As in :class:`~.operator.BimMobility`.
    label : str
        What a convergence report says of the operator (its M and p).

    Attributes
    ----------
    gmres_iterations, residuals, adjoint_iterations, adjoint_residuals : list
        Products and final relative residual of every forward and transposed solve.
    forward_space, adjoint_space : RecycledGCR or None
        The recycled spaces of the two equations (None without recycling).
    """

    def __init__(self, operator: SolvedOperator, *, unknowns: int, eps_gmres: float,
                 maxiter: int, on_failure: str, recycle: int, krylov: KrylovBudget,
                 label: str) -> None:
        self.unknowns = int(unknowns)
        self.eps_gmres = float(eps_gmres)
        self.maxiter, self.on_failure = int(maxiter), on_failure
        self.recycle = max(int(recycle), 0)
        self.krylov = krylov
        self.label = label
        self._relaxed: float | None = None     # a looser tolerance asked by at_accuracy
        self.forward_space: RecycledGCR | None = None
        self.adjoint_space: RecycledGCR | None = None
        self.fresh(operator)

    def _new_spaces(self, operator: SolvedOperator
                    ) -> tuple[RecycledGCR | None, RecycledGCR | None]:
        """Empty recycled spaces for the forward and the transposed equation of ``operator``
        (None, None without recycling)."""
        n, cap = self.unknowns, self.recycle
        if not cap:
            return None, None
        ref = weakref.ref(operator)     # weak: the spaces must not keep the operator alive

        def host() -> SolvedOperator:
            op = ref()
            assert op is not None, "the operator of these solves was collected"
            return op

        return (RecycledGCR(lambda v: host().apply_preconditioned(v), n, cap, self.krylov),
                RecycledGCR(lambda v: host().adjoint_pieces.operator(v), n, cap, self.krylov))

    @contextlib.contextmanager
    def cold_products(self, operator: SolvedOperator) -> Iterator[None]:
        """Products made inside start from empty recycled spaces, as the first product of
        a configuration does; the kept directions are put back afterwards.  For timing one
        product at its first-product cost (:func:`lcpbench.core.probes.measure_cost`):
        with recycling every later product needs fewer new directions."""
        saved = self.forward_space, self.adjoint_space
        self.forward_space, self.adjoint_space = self._new_spaces(operator)
        try:
            yield
        finally:
            self.forward_space, self.adjoint_space = saved

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

    def fresh(self, operator: SolvedOperator) -> None:
        """New (empty) recycled spaces for ``operator`` and empty iteration and residual
        records."""
        self.forward_space, self.adjoint_space = self._new_spaces(operator)
        self.gmres_iterations: list[int] = []
        self.residuals: list[float] = []
        self.adjoint_iterations: list[int] = []
        self.adjoint_residuals: list[float] = []

    def solve(self, what: str, operator: Callable, b: np.ndarray, start: np.ndarray, rungs: int,
               records: tuple[list, list]) -> np.ndarray:
        """GMRES on ``operator(v, rung)`` from ``start`` to ``eps_gmres`` (restart 60,
        ``maxiter``); records the iterations and the full-accuracy residual in ``records``
        and reports non-convergence (:meth:`report`)."""
        restart = max(1, min(b.size, 60, self.maxiter))
        x, its, res = relaxed_gmres(operator, b, start, self.solve_tol, restart, self.maxiter,
                                    rungs=rungs, step=RELAX_STEP)
        self.record(what, its, res, records)
        return x

    def recycled_solve(self, what: str, solver: RecycledGCR, b: np.ndarray,
                        records: tuple[list, list], x0: np.ndarray | None = None
                        ) -> np.ndarray:
        """:meth:`RecycledGCR.solve` to ``eps_gmres`` within ``maxiter`` new directions
        (from the guess ``x0``); records the products made and the true residual, and
        reports non-convergence (:meth:`report`)."""
        before = solver.products
        y, _new, res = solver.solve(b, self.solve_tol, self.maxiter, x0=x0)
        self.record(what, solver.products - before, res, records)
        return y

    def record(self, what: str, its: int, res: float, records: tuple[list, list]) -> None:
        """Append a solve's products and residual to its lists and report non-convergence."""
        records[0].append(its)
        records[1].append(res)
        self.report(what, res, its)

    def report(self, what: str, res: float, its: int) -> None:
        """Warn (or raise, ``on_failure="raise"``) when a solve's full-accuracy relative
        residual ``res`` missed ``eps_gmres``."""
        if res <= self.solve_tol:
            return
        msg = (f"{what} did not converge: relative residual {res:.3g} after {its} "
               f"iterations (eps_gmres = {self.solve_tol:g}, {self.label}); "
               "raise maxiter or eps_gmres, or check for near-contact spheres")
        if self.on_failure == "raise":
            raise RuntimeError(msg)
        warnings.warn(msg, BimConvergenceWarning, stacklevel=6)
