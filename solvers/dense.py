"""Dense-matrix solvers: ``pgs`` (projected Gauss-Seidel / SOR) and ``lemke``.

Both are registered with ``needs_dense=True``: they read the explicit matrix
``ctx.dense`` (formed once by the framework, uncounted), so they are **not**
MVP-only methods and their MVP counts are not comparable with those of the
matrix-free solvers (results carry ``mvp_only = False``). They are classic LCP
baselines for small problems (Cottle, Pang & Stone, *The Linear
Complementarity Problem*, 1992; Erleben's Num4LCP), outside the method paper's
comparison (section "Numerical Results" -> "Comparison Methods" lists only
matrix-free methods, because there A = D'MD is never formed).

Counting
--------
Products with ``ctx.dense`` are not counted by any operator. To keep the counts
honest and the reported ``w`` independent of the dense sweeps:

* ``pgs``: after every sweep (``n`` row updates, one pass over the matrix,
  about one MVP of work) ``w = A x + b`` is computed through the counted
  ``ctx.A``: **one counted MVP per sweep**, which also supplies the ``w``
  reported to the stop rule.
* ``lemke``: the pivoting itself uses ``ctx.dense``; the final ``w = A x + b``
  is computed through ``ctx.A``: **one counted MVP per solve** (none when
  ``b >= 0``: ``x = 0`` is the solution and ``A 0`` is free).

Threads
-------
Both run with BLAS on one thread (:func:`lcpbench.toolkit.blas.on_one_blas_thread`):
their products are single rows (pgs) or rank-one updates and small solves
(lemke), where a threaded BLAS only adds start-up and, on a loaded machine,
contention (docs/benchmarks.md, "One BLAS thread: the measurements behind it").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from lcpbench import register_solver
from lcpbench.core.context import SolverContext
from lcpbench.core.result import SolveResult, Status
from lcpbench.core.specs import Bounds, CheckedParams
from lcpbench.toolkit.blas import on_one_blas_thread

from .dense_kernels import PIVOT_LIMIT, RAY, ZERO_PIVOT, basis_matrix, lemke_solve, pgs_sweep

__all__ = ["PGSParams", "LemkeParams", "pgs", "lemke"]

@dataclass(frozen=True)
class PGSParams(CheckedParams):
    """Parameters of pgs.

    Parameters
    ----------
    omega : float
        Relaxation factor in (0, 2): 1 is projected Gauss-Seidel, other values
        projected SOR (default 1.0).
    """

    omega: Annotated[float, Bounds(gt=0, lt=2)] = 1.0


def _matrix(ctx: SolverContext) -> np.ndarray:
    """The explicit matrix the framework formed for this solve (``needs_dense=True``).

    Raises
    ------
    RuntimeError
        The framework formed none (the solver was run without ``needs_dense``).
    """
    if ctx.dense is None:
        raise RuntimeError("the dense solvers need the explicit matrix ctx.dense; they are "
                           "registered with needs_dense=True, so run them through "
                           "lcpbench.solve or run_solver")
    return ctx.dense


@register_solver("pgs", PGSParams, needs_dense=True)
@on_one_blas_thread
def pgs(ctx: SolverContext, p: PGSParams) -> SolveResult:
    """Projected Gauss-Seidel / SOR sweeps on the dense matrix (not MVP-only).

    Cottle, Pang & Stone (1992), section 5.2 (projected SOR); a dense baseline
    outside the method paper's matrix-free comparison ("Comparison Methods").
    One sweep updates ``x_i <- max(0, x_i - omega (A_i x + b_i) / A_ii)`` for
    ``i = 1..n`` in order (Gauss-Seidel: the updated entries are used at once).
    Rows with ``A_ii = 0`` (a zero row of a PSD matrix) get ``x_i = 0`` when
    ``b_i >= 0``; when ``b_i < 0`` the LCP has no solution and the row is left
    alone (the stop rule never accepts it). Each sweep costs one counted MVP:
    ``w = A x + b`` through ``ctx.A`` (see the module docstring); ``info['sweeps']``.
    """
    M = _matrix(ctx)
    b = ctx.b
    n = ctx.n
    x = np.maximum(ctx.x0, 0.0)
    w = ctx.A @ x + b
    ctx.info["sweeps"] = 0
    if ctx.report(x, w):
        return ctx.finish(x, w)
    diag = np.diag(M).copy()
    scale = max(float(np.max(np.abs(diag))), np.finfo(float).tiny)
    live = diag > 1e-14 * scale
    dead_zero = ~live & (b >= 0)
    rows = np.flatnonzero(live)
    inv = np.zeros(n)
    inv[live] = p.omega / diag[live]
    M = np.ascontiguousarray(M, dtype=np.float64)
    while True:
        x[dead_zero] = 0.0
        pgs_sweep(M, b, x, rows, inv)
        ctx.info["sweeps"] += 1
        w = ctx.A @ x + b
        if ctx.report(x, w):
            return ctx.finish(x, w)


@dataclass(frozen=True)
class LemkeParams(CheckedParams):
    """Parameters of lemke.

    Parameters
    ----------
    max_pivots : int
        Pivot limit (0: automatic, ``max(100, 50 n)``); reaching it ends the
        solve with status ``max_iter``.
    pivot_tol : float
        Entries ``d_i`` of the pivot column below this times the rounding
        scale ``max (|B^-1| |col|)`` of the column are treated as zero in the ratio test (default
        1e-9: a singular PSD A leaves rounding noise of about cond * eps in
        directions that are exactly zero, and pivoting on it derails the path).
    refactor_every : int
        Recompute the basis inverse from the basis columns every this many
        pivots, bounding the drift of the product-form updates (0: automatic,
        ``max(20, n)``: a recomputation costs about ``2 n^3``, so every ``n``
        pivots it costs what the pivots themselves cost, ``O(n^2)`` each; every 20
        pivots it made lcpbench's Lemke several times slower than the pivots alone
        at n = 200). The final solution is recomputed from the final basis in any
        case (refined to rounding level, or by a direct solve).
    """

    max_pivots: Annotated[int, Bounds(ge=0)] = 0
    pivot_tol: Annotated[float, Bounds(gt=0, lt=1)] = 1e-9
    refactor_every: Annotated[int, Bounds(ge=0)] = 0


def _offer_ray(ctx: SolverContext, basis: np.ndarray, d: np.ndarray, entering: int) -> None:
    """Offer the ``z`` part of Lemke's secondary ray, clipped to ``>= 0``, with its product.

    Along the ray the entering variable grows by ``t`` and the basic variable of row
    ``i`` by ``-t d_i``; for PSD A its ``z`` part is a direction ``d >= 0`` with
    ``A d = 0`` and ``b'd < 0``, which the framework checks (the product is the dense
    matrix's, free; the framework confirms it with a counted one).
    """
    n = ctx.n
    dz = np.zeros(n)
    for i, k in enumerate(basis):
        if n <= k < 2 * n:
            dz[k - n] = -d[i]
    if n <= entering < 2 * n:
        dz[entering - n] += 1.0
    dz = np.maximum(dz, 0.0)
    if np.any(dz > 0.0):
        ctx.offer_direction(dz, _matrix(ctx) @ dz)


def _least_squares_solution(M: np.ndarray, q: np.ndarray, basis: np.ndarray,
                            ctx: SolverContext, x: np.ndarray) -> np.ndarray:
    """``x`` from a numerically singular final basis by a least-squares solve (``x``, the
    compiled run's answer from its updated right-hand side, when that is not finite)."""
    ctx.info["final_basis"] = "singular: least-squares solve"
    sol = np.linalg.lstsq(basis_matrix(M, basis), q, rcond=None)[0]
    n = q.shape[0]
    if not np.all(np.isfinite(sol)):
        return x
    x = np.zeros(n)
    z = (basis >= n) & (basis < 2 * n)       # the basic z variables
    x[basis[z] - n] = np.maximum(sol[z], 0.0)
    return x


def _lemke_outcome(code: int, pivots: int, max_piv: int) -> tuple[Status | None, str]:
    """The status and message of how the pivots ended (None: a complementary basis)."""
    if code == RAY:
        return Status.infeasible, (
            f"Lemke: ray termination after {pivots} pivots (no solution for PSD A: "
            "the LCP is infeasible)")
    if code == ZERO_PIVOT:
        return Status.failed, "Lemke: zero pivot"
    if code == PIVOT_LIMIT:
        return Status.max_iter, f"Lemke: pivot limit {max_piv} reached"
    return None, ""             # z0 left: complementary basis found


@register_solver("lemke", LemkeParams, needs_dense=True)
@on_one_blas_thread
def lemke(ctx: SolverContext, p: LemkeParams) -> SolveResult:
    """Lemke's complementary pivoting with covering vector e = 1 (not MVP-only).

    Lemke, "Bimatrix equilibrium points and mathematical programming", Manag.
    Sci. 11 (1965); Cottle, Pang & Stone (1992), section 4.4 (scheme I with the
    lexicographic rule against degenerate cycling). A dense baseline for small
    n, outside the method paper's matrix-free comparison ("Comparison Methods").

    Works on ``w - A z - e z0 = b`` with the basis inverse updated by one
    elementary pivot per step (O(n^2)); the warm start is ignored. ``b >= 0``
    returns ``x = 0`` at once. For PSD A a secondary ray means the LCP has no
    solution: the solve claims ``infeasible`` and offers the ray's ``z`` part, which
    the framework must confirm (rounding in the pivots can end on a ray of a solvable
    problem; the claim is then returned as ``stagnated``). At termination the solution
    is recomputed with the final basis, removing the drift of the updated inverse:
    the inverse's solution refined until its componentwise backward error is at
    rounding level (``n eps``), else a direct solve with the basis columns, least
    squares when that basis is singular; then ``w = A x + b`` costs one counted MVP. The pivots and the final
    solution run as one compiled call (:func:`lcpbench.solvers.dense_kernels.lemke_solve`),
    so the Python work per solve is a few calls. ``info``: ``pivots``.
    """
    M = _matrix(ctx)
    b = ctx.b
    n = ctx.n
    ctx.info["pivots"] = 0
    if np.all(b >= 0):
        x = np.zeros(n)
        w = ctx.A @ x + b                # free: A 0 = 0
        ctx.report(x, w)
        return ctx.finish(x, w, Status.converged, "b >= 0: x = 0 solves the LCP")
    # Work on (A/s, b/s), s = max|A_ij|: same solution x, and the tableau's
    # columns (identity, -A/s, -e) are all of order 1, so one pivot tolerance fits.
    s = float(np.max(np.abs(M)))
    s = s if s > 0 else 1.0
    Ms = np.ascontiguousarray(M / s, dtype=np.float64)
    q = np.asarray(b / s, dtype=np.float64)
    max_piv = p.max_pivots or max(100, 50 * n)
    # the whole pivoting run and the final basic solution in one compiled call
    code, pivots, entering, basis, d, x, solved, singular = lemke_solve(
        Ms, q, max_piv, p.refactor_every or max(20, n), p.pivot_tol)
    if singular:
        ctx.info["singular_refactors"] = singular
    ctx.info["pivots"] = pivots
    status, message = _lemke_outcome(code, pivots, max_piv)
    if code == RAY:
        _offer_ray(ctx, basis, d, entering)    # the framework confirms the claim
    if not solved:
        x = _least_squares_solution(Ms, q, basis, ctx, x)
    w = ctx.A @ x + b
    if ctx.report(x, w) and status is None:
        return ctx.finish(x, w)
    if status is None:
        status, message = Status.stagnated, (
            f"Lemke reached a complementary basis after {pivots} pivots but the residual "
            "misses the tolerance (rounding in the pivots)")
    return ctx.finish(x, w, status, message)
