"""Cottle's fundamental quantity ``c(A)``: a multi-start estimate with bounds.

``c(A) = min_{||z||_inf = 1} max_i z_i (A z)_i``. When a low-fidelity matrix lies
within ``c(A)`` of ``A`` in the induced infinity norm, the solution map of the LCP is
locally Lipschitz there (Cottle's lemma in the method paper); the fidelity study
(:mod:`lcpbench.workflows.fidelity`) reports the share of instances where that holds.
The estimate follows the paper's appendix "Computing c(A)".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lcpbench.toolkit.blas import one_blas_thread

__all__ = ["CottleBounds", "cottle_bounds", "cottle_c"]


@dataclass(frozen=True)
class CottleBounds:
    """Bounds on Cottle's fundamental quantity ``c(A)``.

    Attributes
    ----------
    estimate : float
        ``h(z)`` at the best feasible ``z`` found: an upper bound of ``c(A)``.
    z : ndarray
        That ``z`` (``||z||_inf = 1``).
    lower : float
        ``lambda_min((A + A') / 2) / n``, a lower bound of ``c(A)`` (valid for any
        square ``A``; informative when the symmetric part is positive definite).
    lambda_min : float
        Smallest eigenvalue of the symmetric part of ``A``. For symmetric ``A`` it is an
        upper bound of ``c(A)``, so ``lower <= c(A) <= estimate <= lambda_min``.
    starts : int
        Number of local optimisations run.
    """

    estimate: float
    z: np.ndarray
    lower: float
    lambda_min: float
    starts: int


def _h(A: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """``h(z) = max_j z_j (A z)_j`` for each column of ``Z``."""
    return np.max(Z * (A @ Z), axis=0)


def _smoothed(A: np.ndarray, Z: np.ndarray, mu: float):
    """Log-sum-exp smoothing of ``h`` with temperature ``mu`` and its gradient, per column."""
    AZ = A @ Z
    Q = Z * AZ
    qmax = Q.max(axis=0)
    E = np.exp((Q - qmax) / mu)
    S = E.sum(axis=0)
    P = E / S
    val = qmax + mu * np.log(S)
    grad = P * AZ + A.T @ (P * Z)
    return val, grad


def _project(Z: np.ndarray, idx: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Clip to the box ``[-1, 1]`` and fix ``z_i = sigma`` in each column."""
    Z = np.clip(Z, -1.0, 1.0)
    Z[idx, np.arange(Z.shape[1])] = sigma
    return Z


def _local_descent(A: np.ndarray, Z: np.ndarray, idx: np.ndarray, sigma: np.ndarray,
                   iters: int) -> tuple[np.ndarray, np.ndarray]:
    """Projected gradient with backtracking on the smoothed ``h``, all starts at once.

    Returns the best feasible iterate of each column and its true ``h``.
    """
    scale = max(float(np.abs(A).sum(axis=1).max()), np.finfo(float).tiny)
    S = Z.shape[1]
    best_Z = Z.copy()
    best_h = _h(A, Z)
    step = np.full(S, 1.0 / scale)
    stages = [1e-1, 1e-2, 1e-3, 1e-4, 1e-6]
    per_stage = max(iters // len(stages), 1)
    for rel_mu in stages:
        mu = rel_mu * scale
        val, grad = _smoothed(A, Z, mu)
        for _ in range(per_stage):
            active = np.ones(S, dtype=bool)
            new_Z = Z.copy()
            new_val = val.copy()
            t = np.minimum(step * 4.0, 10.0 / scale)
            for _bt in range(30):
                cols = np.flatnonzero(active)
                if cols.size == 0:
                    break
                trial = _project(Z[:, cols] - t[cols] * grad[:, cols], idx[cols], sigma[cols])
                tv, _ = _smoothed(A, trial, mu)
                d = trial - Z[:, cols]
                ok = tv <= val[cols] + 1e-4 * np.sum(grad[:, cols] * d, axis=0)
                good = cols[ok]
                new_Z[:, good] = trial[:, ok]
                new_val[good] = tv[ok]
                step[good] = t[good]
                active[good] = False
                t[cols[~ok]] *= 0.5
            moved = np.max(np.abs(new_Z - Z), axis=0)
            Z = new_Z
            val, grad = _smoothed(A, Z, mu)
            hz = _h(A, Z)
            better = hz < best_h
            best_h[better] = hz[better]
            best_Z[:, better] = Z[:, better]
            if np.all(moved <= 1e-12):
                break
    return best_Z, best_h


def _polish(A: np.ndarray, z: np.ndarray, i: int, sigma: float) -> np.ndarray:
    """SLSQP on the epigraph form ``min t s.t. z_j (A z)_j <= t, |z| <= 1, z_i = sigma``."""
    from scipy.optimize import minimize

    n = A.shape[0]

    def cons(v):
        zz = v[:n]
        return v[n] - zz * (A @ zz)

    def cons_jac(v):
        zz = v[:n]
        J = np.empty((n, n + 1))
        J[:, :n] = -(zz[:, None] * A)
        J[np.arange(n), np.arange(n)] -= A @ zz
        J[:, n] = 1.0
        return J

    bounds = [(-1.0, 1.0)] * n + [(None, None)]
    bounds[i] = (sigma, sigma)
    v0 = np.concatenate([z, [float(np.max(z * (A @ z)))]])
    res = minimize(lambda v: v[n], v0, jac=lambda v: np.eye(1, n + 1, n).ravel(),
                   method="SLSQP", bounds=bounds,
                   constraints=[{"type": "ineq", "fun": cons, "jac": cons_jac}],
                   options={"maxiter": 200, "ftol": 1e-14})
    out = np.clip(np.asarray(res.x[:n], dtype=float), -1.0, 1.0)
    out[i] = sigma
    return out


def cottle_bounds(A, *, starts: int | None = 32, random_starts: int = 8, seed: int = 0,
                  iters: int = 150, polish: int | None = None,
                  polish_max_n: int = 250) -> CottleBounds:
    """Estimate Cottle's fundamental quantity ``c(A)`` with bounds.

    ``c(A) = min_{||z||_inf = 1} max_i z_i (A z)_i`` (Cottle's lemma). The problem is
    nonconvex and nonsmooth; following the paper's appendix "Computing c(A)", it is split
    into ``min over (i, sigma)`` of ``min h(z)`` subject to ``-1 <= z <= 1`` and
    ``z_i = sigma``, each solved by local optimisation started from the eigenvector of the
    smallest eigenvalue, scaled so that ``z_i = sigma`` and clipped to the box.

    Starts: ``h(-z) = h(z)``, so ``sigma = -1`` repeats ``sigma = +1`` and only ``sigma = +1``
    is run. ``starts`` indices ``i`` are used (the ``starts`` indices with the largest
    eigenvector entries; all ``n``, the appendix's full loop, when ``n <= starts`` or
    ``starts=None``; default 32), plus
    ``random_starts`` uniform random points of the box (seeded by ``seed``), each with a
    random fixed index: ``min(starts, n) + random_starts`` local optimisations in all.

    Local optimisation: projected gradient with Armijo backtracking (as the appendix) on a
    log-sum-exp smoothing of the max whose temperature decreases from ``0.1 ||A||_inf`` to
    ``1e-6 ||A||_inf`` (``iters`` iterations in all), keeping the iterate of smallest true
    ``h``; then the ``polish`` best candidates are refined by SLSQP on the epigraph form
    (for ``n <= polish_max_n``; by default all of them up to ``n = 60``, then fewer as
    ``40 (60 / n)^3``, at least 2, since the landscape has many local minima and the
    refinement is what finds the good ones). BLAS runs on one thread meanwhile.

    The estimate is ``h(z)`` at a feasible ``z`` (``||z||_inf = 1`` exactly), so it is an
    **upper bound** of the true ``c(A)``: any feasible ``z`` bounds the minimum from
    above; a local method may miss the global minimum. The rigorous lower bound
    ``lambda_min(sym A) / n`` (Cottle, Pang and Stone 2009) is returned beside it.

    Parameters
    ----------
    A : (n, n) array_like
    starts : int or None
        Number of eigenvector starts (fixed indices); None for all ``n``.
    random_starts : int
        Extra random starts.
    seed : int
        Seed of the random starts.
    iters : int
        Projected-gradient iterations per start.
    polish : int or None
        Number of best candidates refined by SLSQP (0 to skip; None: the default rule
        above).
    polish_max_n : int
        Skip SLSQP above this size (its dense QP subproblems cost ``O(n^3)`` each).

    Returns
    -------
    CottleBounds

    Raises
    ------
    ValueError
        If ``A`` is not a finite square matrix, or a count is negative.
    """
    A = np.asarray(A, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] == 0:
        raise ValueError(f"cottle_c: A must be a non-empty square matrix, got shape {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError("cottle_c: A has non-finite entries; c(A) needs a finite matrix")
    if (starts is not None and starts < 1) or random_starts < 0 or iters < 1 or (
            polish is not None and polish < 0):
        raise ValueError("cottle_c: starts must be >= 1 (or None for all n), random_starts, "
                         "polish >= 0 and iters >= 1")
    with one_blas_thread():
        return _cottle_bounds(A, starts, random_starts, seed, iters, polish, polish_max_n)


def _cottle_bounds(A: np.ndarray, starts, random_starts, seed, iters, polish,
                   polish_max_n) -> CottleBounds:
    n = A.shape[0]
    sym = 0.5 * (A + A.T)
    lam, vecs = np.linalg.eigh(sym)
    lam_min = float(lam[0])
    lower = lam_min / n
    if n == 1:
        z = np.ones(1)
        return CottleBounds(float(A[0, 0]), z, lower, lam_min, 1)
    v = vecs[:, 0]
    order = np.argsort(-np.abs(v), kind="stable")
    k = n if starts is None else min(int(starts), n)
    idx = order[:k]
    Z0 = []
    for i in idx:
        if abs(v[i]) > 0:
            Z0.append(v * (np.sign(v[i]) / abs(v[i])))
        else:
            e = np.zeros(n)
            e[i] = 1.0
            Z0.append(e)
    rng = np.random.default_rng(seed)
    ridx = rng.integers(0, n, size=random_starts)
    for _ in ridx:
        Z0.append(rng.uniform(-1.0, 1.0, size=n))
    all_idx = np.concatenate([idx, ridx]).astype(int)
    sigma = np.ones(all_idx.size)
    Z = _project(np.column_stack(Z0), all_idx, sigma)
    best_Z, best_h = _local_descent(A, Z, all_idx, sigma, iters)
    if polish is None:
        polish = max(2, int(40 * (60.0 / n) ** 3))
    if polish and n <= polish_max_n:
        for c in np.argsort(best_h, kind="stable")[:polish]:
            try:
                z = _polish(A, best_Z[:, c], int(all_idx[c]), 1.0)
            except (ValueError, np.linalg.LinAlgError):
                continue
            hz = float(np.max(z * (A @ z)))
            if hz < best_h[c]:
                best_h[c] = hz
                best_Z[:, c] = z
    c = int(np.argmin(best_h))
    return CottleBounds(float(best_h[c]), best_Z[:, c].copy(), lower, lam_min, int(all_idx.size))


def cottle_c(A, *, starts: int | None = 32, random_starts: int = 8, seed: int = 0) -> float:
    """An upper-bound estimate of Cottle's ``c(A) = min_{||z||_inf=1} max_i z_i (A z)_i``.

    Multi-start local optimisation as the paper's appendix "Computing c(A)": by default
    ``min(n, 32)`` eigenvector starts (one per fixed index ``z_i = 1``; ``z_i = -1`` is the
    same problem since ``h(-z) = h(z)``) plus ``random_starts = 8`` random ones, the best
    results refined by SLSQP (all 40 for ``n <= 60``, fewer above, none above ``n = 250``).
    Since every candidate is feasible, the value is an upper bound of the true minimum. See
    :func:`cottle_bounds` for the method, the lower bound ``lambda_min / n`` and the
    upper bound ``lambda_min`` (symmetric ``A``).

    Parameters
    ----------
    A : (n, n) array_like
    starts : int or None
        Eigenvector starts; None for all ``n``.
    random_starts : int
        Extra random starts.
    seed : int
        Seed of the random starts.

    Returns
    -------
    float
    """
    return cottle_bounds(A, starts=starts, random_starts=random_starts, seed=seed).estimate
