"""The compiled inner loops of the dense classics: one projected Gauss-Seidel sweep and
a whole Lemke solve (pivots, refactorisations of the basis inverse, the final solve).

Both are numba kernels (numba is already a dependency of the boundary-integral backend)
doing the arithmetic of the loops they replace: the dot products (the pivot column
``B^-1 col`` among them) go through the same BLAS calls numpy makes and the pivot
update is the same element-wise ``a - d_i b_j``; only the rounding scale of the ratio
test is summed in any order (``fastmath``); the final basic solution
is the updated inverse's refined to rounding level, with an LU solve (LAPACK, as
numpy's) only when refinement does not get there. What they save is
Python's cost per row (PGS), per pivot and per solve (Lemke), which made lcpbench's
Lemke about 90 times slower than quantecon's compiled ``lcp_lemke`` on the shipped sets
(docs/benchmarks.md, "The framework's cost around a solve, and Lemke").
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["pgs_sweep", "lemke_run", "lemke_solve", "basis_matrix",
           "Z0_LEFT", "RAY", "ZERO_PIVOT", "PIVOT_LIMIT", "REFACTOR_DUE"]

#: What :func:`lemke_run` stopped on.
Z0_LEFT, RAY, ZERO_PIVOT, PIVOT_LIMIT, REFACTOR_DUE = 0, 1, 2, 3, 4


#: Refinement steps of the final basic solution before a fresh factorisation.
REFINEMENTS = 3


@njit(cache=True)
def pgs_sweep(M: np.ndarray, b: np.ndarray, x: np.ndarray, rows: np.ndarray,
              inv: np.ndarray) -> None:
    """One sweep ``x_i <- max(0, x_i - inv_i (M_i x + b_i))`` over ``rows`` in order, in place."""
    for i in rows:
        r = np.dot(M[i], x) + b[i]
        xi = x[i] - inv[i] * r
        x[i] = xi if xi > 0.0 else 0.0


@njit(cache=True, fastmath=True)
def _pivot_column(M: np.ndarray, Binv: np.ndarray, k: int, col: np.ndarray,
                  d: np.ndarray) -> float:
    """``d = B^-1 col`` for column ``k`` of the tableau ``[I, -M, -e]``; returns its
    rounding scale ``max_i sum_j |B^-1_ij| |col_j|``.

    The scale is summed in any order (``fastmath``, so that the sums vectorise);
    ``d`` is BLAS's, as numpy's, since a degenerate path follows its rounding. A column of the identity
    selects a column of ``B^-1`` and ``-e`` sums its rows.
    """
    n = M.shape[0]
    scale = 0.0
    if k < n:
        col[:] = 0.0
        col[k] = 1.0
        for i in range(n):
            d[i] = Binv[i, k]
            scale = max(scale, abs(d[i]))
        return scale
    if k < 2 * n:
        for i in range(n):
            col[i] = -M[i, k - n]
    else:
        col[:] = -1.0
    for i in range(n):
        a = 0.0
        for j in range(n):
            a += abs(Binv[i, j]) * abs(col[j])
        scale = max(scale, a)
    d[:] = np.dot(Binv, col)      # BLAS, as numpy: a degenerate path follows its rounding
    return scale


@njit(cache=True)
def basis_matrix(M: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """The basis columns of the tableau ``[I, -M, -e]`` as a matrix."""
    n = M.shape[0]
    B = np.zeros((n, n))
    for c in range(n):
        k = basis[c]
        if k < n:
            B[k, c] = 1.0
        elif k < 2 * n:
            for i in range(n):
                B[i, c] = -M[i, k - n]
        else:
            for i in range(n):
                B[i, c] = -1.0
    return B


@njit(cache=True)
def _lex_min_ratio(rhs: np.ndarray, Binv: np.ndarray, d: np.ndarray, scale: float,
                   tol: float) -> int:
    """The row of the lexicographic minimum ratio test, or -1 (a ray).

    ``d_i`` counts as positive only above ``tol`` times ``scale``, the rounding scale
    ``max_k (|B^-1| |col|)_k`` of ``d`` (see :class:`lcpbench.solvers.dense.LemkeParams`);
    ties within ``1e-12`` are broken on the rows of ``B^-1`` divided by the pivot entries.
    """
    n = d.shape[0]
    cut = tol * scale
    best = np.inf
    first = -1
    for i in range(n):                     # the minimum ratio, without temporaries
        if d[i] > cut:
            r = rhs[i] / d[i]
            if r < best:
                best, first = r, i
    if first < 0:
        return -1
    bound = best + 1e-12 * max(1.0, abs(best))
    ties = 0
    for i in range(n):
        if d[i] > cut and rhs[i] / d[i] <= bound:
            ties += 1
    if ties == 1:
        return first
    near = np.array([i for i in range(n) if d[i] > cut and rhs[i] / d[i] <= bound])
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
    prow = np.empty(n)
    while True:
        scale = _pivot_column(M, Binv, entering, col, d)
        if pivots == 0:
            row = first_row
        else:
            row = _lex_min_ratio(rhs, Binv, d, scale, pivot_tol)
            if row < 0:
                return RAY, entering, pivots
        piv = d[row]
        if piv == 0.0:
            return ZERO_PIVOT, entering, pivots
        for j in range(n):
            Binv[row, j] /= piv
            prow[j] = Binv[row, j]      # a row apart: the update below vectorises
        rhs[row] /= piv
        r = rhs[row]
        for i in range(n):
            di = d[i]
            if i != row and di != 0.0:
                for j in range(n):
                    Binv[i, j] -= di * prow[j]
                rhs[i] -= di * r
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


@njit(cache=True)
def _refactor(M: np.ndarray, q: np.ndarray, basis: np.ndarray, Binv: np.ndarray,
              rhs: np.ndarray) -> bool:
    """Recompute ``Binv`` from the basis columns and ``rhs = max(B^-1 q, 0)`` in place.

    Returns False, leaving both as they were (the product form carries on), when the
    basis is numerically singular.
    """
    try:
        fresh = np.linalg.inv(basis_matrix(M, basis))
    except Exception:  # noqa: BLE001 - numba raises a plain LinAlgError it cannot name
        return False
    Binv[:, :] = fresh
    rhs[:] = np.maximum(np.dot(fresh, q), 0.0)      # basic variables are >= 0
    return True


@njit(cache=True)
def _basic_residual(M: np.ndarray, q: np.ndarray, basis: np.ndarray, xb: np.ndarray,
                    r: np.ndarray, size: np.ndarray) -> None:
    """``r = q - B xb`` for the basis columns ``B`` of ``[I, -M, -e]``, and
    ``size = |q| + |B| |xb|`` (the scale of each row's rounding), in place."""
    n = M.shape[0]
    for i in range(n):
        r[i] = q[i]
        size[i] = abs(q[i])
    for c in range(n):
        k = basis[c]
        v = xb[c]
        if v == 0.0:
            continue
        if k < n:
            r[k] -= v
            size[k] += abs(v)
        elif k < 2 * n:
            for i in range(n):
                r[i] += M[i, k - n] * v
                size[i] += abs(M[i, k - n] * v)
        else:
            for i in range(n):
                r[i] += v
                size[i] += abs(v)


@njit(cache=True)
def _refined_basic_solution(M: np.ndarray, q: np.ndarray, basis: np.ndarray,
                            Binv: np.ndarray) -> np.ndarray:
    """The basic solution ``B^-1 q`` from the updated inverse, refined to rounding.

    ``xb = B^-1 q``, then at most :data:`REFINEMENTS` steps ``xb += B^-1 (q - B xb)``
    until every row's residual is within ``n eps`` of its scale ``(|q| + |B| |xb|)_i``
    (a componentwise backward error as small as an LU solve's). Each step is
    ``O(n^2)``, against ``n^3 / 3`` for a fresh factorisation. Returns an empty array
    when the drift of the inverse is too large for that (the caller factorises).
    """
    n = M.shape[0]
    xb = np.dot(Binv, q)
    r = np.empty(n)
    size = np.empty(n)
    tol = n * np.finfo(np.float64).eps
    for _ in range(REFINEMENTS + 1):
        if not np.all(np.isfinite(xb)):
            break
        _basic_residual(M, q, basis, xb, r, size)
        ok = True
        for i in range(n):
            if abs(r[i]) > tol * size[i]:
                ok = False
                break
        if ok:
            return xb
        xb = xb + np.dot(Binv, r)
    return np.empty(0)


@njit(cache=True)
def lemke_solve(M: np.ndarray, q: np.ndarray, max_pivots: int, refactor_every: int,
                pivot_tol: float
                ) -> tuple[int, int, int, np.ndarray, np.ndarray, np.ndarray, bool, int]:
    """A whole Lemke solve on ``w - M z - e z0 = q`` in one call (``M``, ``q`` already scaled).

    Scheme I from the basis of every ``w``: ``z0`` enters, the most negative ``q_i``
    leaves, then :func:`lemke_run`'s pivots, with the basis inverse recomputed from
    the basis columns every ``refactor_every`` pivots (:func:`_refactor`), and at the
    end the basic solution with the final basis: the updated inverse's, refined to a
    backward error at rounding level (:func:`_refined_basic_solution`), else a direct
    solve with the basis columns (LAPACK's LU, as numpy's ``solve``), so the drift of
    the updated inverse never reaches ``x``. Returns ``(code, pivots, entering, basis, d, x, solved,
    singular_refactors)``: ``x`` is the ``z`` part of the basic solution clipped at 0
    (from the updated right-hand side when the solve gives non-finite values or, with
    ``solved`` False, when the final basis is singular: the caller then tries least
    squares), ``d`` the last pivot column (the ray's on :data:`RAY`).
    """
    n = M.shape[0]
    basis = np.arange(n)
    Binv = np.eye(n)
    rhs = q.copy()
    d = np.zeros(n)
    first_row = int(np.argmin(q))
    entering, pivots, singular = 2 * n, 0, 0
    while True:
        code, entering, pivots = lemke_run(M, basis, Binv, rhs, d, entering, pivots,
                                           first_row, max_pivots, refactor_every, pivot_tol)
        if code != REFACTOR_DUE:
            break
        if not _refactor(M, q, basis, Binv, rhs):
            singular += 1
    solved = True
    xb = _refined_basic_solution(M, q, basis, Binv)
    if xb.size == 0:
        try:
            xb = np.linalg.solve(basis_matrix(M, basis), q)
        except Exception:  # noqa: BLE001 - numba raises a plain LinAlgError it cannot name
            solved, xb = False, rhs
    if not np.all(np.isfinite(xb)):
        xb = rhs                      # the updated right-hand side, drift and all
    x = np.zeros(n)
    for c in range(n):
        k = basis[c]
        if n <= k < 2 * n:
            x[k - n] = xb[c] if xb[c] > 0.0 else 0.0
    return code, pivots, entering, basis, d, x, solved, singular
