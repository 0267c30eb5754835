"""The compiled inner loops of the dense classics: one projected Gauss-Seidel sweep and
a run of Lemke pivots.

Both are numba kernels (numba is already a dependency of the boundary-integral backend)
doing the same arithmetic, in the same order, as the loops they replace: the dot
products and the matrix-vector products of the pivot column go through the same BLAS
calls numpy makes, and the pivot update is the same element-wise ``a - d_i b_j``. What
they save is Python's cost per row (PGS) and per pivot (Lemke), which made lcpbench's
Lemke about 90 times slower than quantecon's compiled ``lcp_lemke`` on the shipped sets
(docs/benchmarks.md, "The framework's cost around a solve").
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["pgs_sweep", "lemke_run", "Z0_LEFT", "RAY", "ZERO_PIVOT", "PIVOT_LIMIT",
           "REFACTOR_DUE"]

#: What :func:`lemke_run` stopped on.
Z0_LEFT, RAY, ZERO_PIVOT, PIVOT_LIMIT, REFACTOR_DUE = 0, 1, 2, 3, 4


@njit(cache=True)
def pgs_sweep(M: np.ndarray, b: np.ndarray, x: np.ndarray, rows: np.ndarray,
              inv: np.ndarray) -> None:
    """One sweep ``x_i <- max(0, x_i - inv_i (M_i x + b_i))`` over ``rows`` in order, in place."""
    for i in rows:
        r = np.dot(M[i], x) + b[i]
        xi = x[i] - inv[i] * r
        x[i] = xi if xi > 0.0 else 0.0


@njit(cache=True)
def _column(M: np.ndarray, k: int, col: np.ndarray) -> None:
    """Column ``k`` of the tableau ``[I, -M, -e]`` into ``col``."""
    n = M.shape[0]
    if k < n:
        col[:] = 0.0
        col[k] = 1.0
    elif k < 2 * n:
        for i in range(n):
            col[i] = -M[i, k - n]
    else:
        col[:] = -1.0


@njit(cache=True)
def _lex_min_ratio(rhs: np.ndarray, Binv: np.ndarray, d: np.ndarray, col: np.ndarray,
                   tol: float) -> int:
    """The row of the lexicographic minimum ratio test, or -1 (a ray).

    ``d_i`` counts as positive only above ``tol max_k (|B^-1| |col|)_k`` (see
    :class:`lcpbench.solvers.dense.LemkeParams`); ties within ``1e-12`` are broken on the rows
    of ``B^-1`` divided by the pivot entries.
    """
    n = d.shape[0]
    scale = 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += abs(Binv[i, j]) * abs(col[j])
        if s > scale:
            scale = s
    cand = np.flatnonzero(d > tol * scale)
    if cand.size == 0:
        return -1
    ratios = rhs[cand] / d[cand]
    best = ratios.min()
    near = cand[ratios <= best + 1e-12 * max(1.0, abs(best))]
    j = 0
    while near.size > 1 and j < n:
        vals = Binv[near, j] / d[near]
        m = vals.min()
        near = near[vals <= m + 1e-12 * max(1.0, abs(m))]
        j += 1
    return int(near[0])


@njit(cache=True)
def lemke_run(M: np.ndarray, basis: np.ndarray, Binv: np.ndarray, rhs: np.ndarray,
              d: np.ndarray, entering: int, pivots: int, first_row: int, max_pivots: int,
              refactor_every: int, pivot_tol: float) -> tuple[int, int, int]:
    """Lemke's pivots on ``[I, -M, -e]`` until one of the stop codes; returns
    ``(code, entering, pivots)``.

    ``basis``, ``Binv`` and ``rhs`` are updated in place; on :data:`RAY` ``d`` holds the
    pivot column ``B^-1 col`` of the entering variable. :data:`REFACTOR_DUE` hands the
    solve back every ``refactor_every`` pivots so that the caller recomputes ``Binv``
    and calls again with the returned ``entering``. The first pivot (``pivots == 0``)
    is on ``first_row``, the most negative ``q_i``, and makes ``rhs >= 0``.
    """
    n = M.shape[0]
    col = np.empty(n)
    while True:
        _column(M, entering, col)
        d[:] = np.dot(Binv, col)
        if pivots == 0:
            row = first_row
        else:
            row = _lex_min_ratio(rhs, Binv, d, col, pivot_tol)
            if row < 0:
                return RAY, entering, pivots
        piv = d[row]
        if piv == 0.0:
            return ZERO_PIVOT, entering, pivots
        for j in range(n):
            Binv[row, j] /= piv
        rhs[row] /= piv
        for i in range(n):
            if i != row:
                di = d[i]
                for j in range(n):
                    Binv[i, j] -= di * Binv[row, j]
                rhs[i] -= di * rhs[row]
        leaving = int(basis[row])
        basis[row] = entering
        pivots += 1
        if pivots == 1:
            for i in range(n):
                if rhs[i] < 0.0:
                    rhs[i] = 0.0
        if leaving == 2 * n:
            return Z0_LEFT, entering, pivots
        if pivots >= max_pivots:
            return PIVOT_LIMIT, entering, pivots
        entering = leaving + n if leaving < n else leaving - n
        if pivots % refactor_every == 0:
            return REFACTOR_DUE, entering, pivots
