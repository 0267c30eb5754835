"""Weighted proximal operator of the non-negative orthant for diagonal-plus-low-rank metrics.

Computes ``prox^B(y) = argmin_{z >= 0} 1/2 ||z - y||_B^2`` for
``B = D + U U' - V V'`` (``D`` positive diagonal, ``B`` positive definite) by
the method paper's proposition on the weighted non-negative prox (after
Becker, Fadili & Ochs 2018, Corollary 3.6): with ``C = D + U U'``,

    prox^B(y) = (y + C^{-1} V at - D^{-1} U a)_+

where ``(a, at)`` in R^{2r} is the unique root of the monotone piecewise-linear map

    L(a, at) = [ U'(y + C^{-1} V at - x(a, at)) + a ;  V'(y - x(a, at)) + at ],
    x(a, at) = (y + C^{-1} V at - D^{-1} U a)_+ .

(The "+ a, + at" terms are printed in the paper's generalized Jacobian,
``J_L = [...] + I``, and belong in ``L``; without them the stated Jacobian is not
the Jacobian of ``L``. The root of this ``L`` reproduces the QP solution, which
the tests check against Clarabel.) The root is found by the semi-smooth Newton
method of appendix "Numerical Approximation via Semi-Smooth Newton" (algorithm
semiSmoothNewton) with the generalized Jacobian

    J_L = I + [[U' Lam D^{-1} U,   U'(I - Lam) C^{-1} V],
               [V' Lam D^{-1} U,  -V' Lam C^{-1} V     ]],   Lam = diag(x > 0),

started at 0. Each Newton step costs O(n r + r^3): no product with the LCP
matrix is ever needed. Safeguards: a step that does not reduce ``||L||`` is
damped by halving; if Newton has not converged after ``max_iter`` steps, the
n-dimensional QP is solved instead by an accelerated projected gradient method
in the metric's own O(n r) products (reported as a fallback). For ``r = 0`` the
prox is the closed form ``max(y, 0)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

import numpy as np

from lcpbench.toolkit.blas import one_blas_thread

__all__ = ["weighted_prox", "ProxInfo", "FALLBACK_ITERS"]

#: Steps of the projected-gradient fallback (each O(n r)): a cost cap of about 500 n r
#: (with the momentum restart it converges in a few hundred steps where plain
#: acceleration took thousands).
FALLBACK_ITERS = 500


@dataclass
class ProxInfo:
    """How a prox evaluation went.

    Attributes
    ----------
    newton_iters : int
        Semi-smooth Newton iterations.
    damped : int
        Newton steps that had to be damped.
    fallback : bool
        True when Newton did not converge and the projected-gradient fallback
        produced the answer.
    residual : float
        ``||L||`` at the returned root (NaN for the closed form / fallback).
    """

    newton_iters: int = 0
    damped: int = 0
    fallback: bool = False
    residual: float = float("nan")


def _c_inverse(d: np.ndarray, U: np.ndarray):
    """``v -> (D + U U')^{-1} v`` by the Woodbury identity, O(n r) per column."""
    DiU = U / d[:, None]
    r = U.shape[1]
    if r == 0:
        return lambda X: X / (d[:, None] if X.ndim == 2 else d)
    K = np.eye(r) + U.T @ DiU
    cho = np.linalg.cholesky(K)

    def apply(X):
        Dx = X / (d[:, None] if X.ndim == 2 else d)
        t = np.linalg.solve(cho.T, np.linalg.solve(cho, U.T @ Dx))
        return Dx - DiU @ t

    return apply


def weighted_prox(y: np.ndarray, d: Union[float, np.ndarray], U: np.ndarray, V: np.ndarray, *,
                  tol: float = 1e-12, max_iter: int = 100,
                  fallback_iters: int = FALLBACK_ITERS) -> tuple[np.ndarray, ProxInfo]:
    """``argmin_{z >= 0} 1/2 (z - y)' (D + U U' - V V') (z - y)``.

    Parameters
    ----------
    y : ndarray, shape (n,)
        Point to project.
    d : ndarray, shape (n,) or float
        Positive diagonal of ``D``.
    U, V : ndarray, shape (n, r1), (n, r2)
        Low-rank factors (either may have zero columns).
    tol : float
        Newton stops when the root's update is below ``tol * (1 + ||root||)`` or
        ``||L|| <= tol * (1 + ||y||)``.
    max_iter : int
        Newton iteration cap before the fallback.
    fallback_iters : int
        Iteration cap of the projected-gradient fallback (default
        :data:`FALLBACK_ITERS`: its cost stays a fixed multiple of ``n r``, the
        order of one Newton prox, so fallbacks cannot dominate a solve's time).

    Returns
    -------
    z : ndarray
    info : ProxInfo
    """
    with one_blas_thread():       # rank-sized systems: threads cost more than they give
        return _weighted_prox(y, np.asarray(d, dtype=np.float64), U, V, tol=tol, max_iter=max_iter,
                              fallback_iters=fallback_iters)


def _weighted_prox(y: np.ndarray, d: np.ndarray, U: np.ndarray, V: np.ndarray, *,
                   tol: float, max_iter: int, fallback_iters: int) -> tuple[np.ndarray, ProxInfo]:
    y = np.asarray(y, dtype=np.float64)
    n = y.shape[0]
    d = np.broadcast_to(np.asarray(d, dtype=np.float64), (n,)).copy()
    U = np.asarray(U, dtype=np.float64).reshape(n, -1)
    V = np.asarray(V, dtype=np.float64).reshape(n, -1)
    info = ProxInfo()
    r1, r2 = U.shape[1], V.shape[1]
    if r1 + r2 == 0 or np.all(y >= 0):
        # Closed form: a diagonal metric separates; y >= 0 is its own prox.
        return np.maximum(y, 0.0), info
    DiU = U / d[:, None]
    Cinv = _c_inverse(d, U)
    CiV = Cinv(V) if r2 else np.zeros((n, 0))
    y_c = y
    scale = 1.0 + np.linalg.norm(y)

    def L_of(a):
        al, at = a[:r1], a[r1:]
        t = y_c - DiU @ al + CiV @ at
        x = np.maximum(t, 0.0)
        L1 = U.T @ (y_c + CiV @ at - x) + al
        L2 = V.T @ (y_c - x) + at
        return np.concatenate([L1, L2]), t

    a = np.zeros(r1 + r2)
    Lv, t = L_of(a)
    res = np.linalg.norm(Lv)
    converged = res <= tol * scale
    while not converged and info.newton_iters < max_iter:
        info.newton_iters += 1
        m = t > 0
        J = np.eye(r1 + r2)
        Um, Vm = U[m], V[m]
        J[:r1, :r1] += Um.T @ DiU[m]
        J[:r1, r1:] += U[~m].T @ CiV[~m]
        J[r1:, :r1] += Vm.T @ DiU[m]
        J[r1:, r1:] -= Vm.T @ CiV[m]
        try:
            step = -np.linalg.solve(J, Lv)
        except np.linalg.LinAlgError:
            step = -np.linalg.lstsq(J, Lv, rcond=None)[0]
        lam = 1.0
        while True:
            a_new = a + lam * step
            L_new, t_new = L_of(a_new)
            r_new = np.linalg.norm(L_new)
            if r_new <= (1 - 1e-4 * lam) * res or lam < 1e-10:
                break
            lam *= 0.5
        if lam < 1.0:
            info.damped += 1
        delta = np.linalg.norm(a_new - a)
        a, Lv, t, res = a_new, L_new, t_new, r_new
        if res <= tol * scale or delta <= tol * (1.0 + np.linalg.norm(a)):
            converged = res <= np.sqrt(tol) * scale
            break
    info.residual = float(res)
    if converged:
        return np.maximum(t, 0.0), info
    info.fallback = True
    return _prox_fallback(y, d, U, V, fallback_iters, tol), info


def _prox_fallback(y, d, U, V, iters, tol):
    """Accelerated projected gradient on the n-dimensional prox QP (O(n r) per step).

    The momentum restarts whenever the gradient points against the last step
    (O'Donoghue and Candes' gradient restart), which restores fast linear
    convergence on the strongly convex prox QP.
    """
    def Bv(v):
        return d * v + U @ (U.T @ v) - V @ (V.T @ v)

    # ||B|| <= max(d) + ||U||_2^2 bounds the Lipschitz constant of the gradient.
    Lc = float(np.max(d) + (np.linalg.norm(U, 2) ** 2 if U.size else 0.0))
    z = np.maximum(y, 0.0)
    zk, tk = z.copy(), 1.0
    for _ in range(iters):
        g = Bv(z - y)
        z_new = np.maximum(z - g / Lc, 0.0)
        if float(g @ (z_new - zk)) > 0.0:      # gradient restart of the momentum
            tk = 1.0
        t_new = 0.5 * (1 + np.sqrt(1 + 4 * tk * tk))
        zk_prev = zk
        zk = z_new
        z = zk + ((tk - 1) / t_new) * (zk - zk_prev)
        tk = t_new
        gk = Bv(zk - y)
        if np.linalg.norm(np.minimum(zk, gk)) <= tol * (1 + np.linalg.norm(y)):
            break
    return zk
