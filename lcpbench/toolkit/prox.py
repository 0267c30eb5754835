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
matrix is ever needed. :func:`compact_prox` takes the factors as coefficients
over the rows of a matrix ``W`` (``U = W'P``, ``V = W'N``, the PQN models'
compact form) and builds the Newton system from Gram matrices of ``W``: one
pass over ``W`` per Newton step, the active set's Gram matrix updated by the
rows that changed (and kept from one evaluation to the next, :class:`ActiveGram`),
no ``n x r`` copy. Safeguards: a step that does not reduce ``||L||`` is
damped by halving; if Newton has not converged after ``max_iter`` steps, the
n-dimensional QP is solved instead by an accelerated projected gradient method
in the metric's own O(n r) products (reported as a fallback). For ``r = 0`` the
prox is the closed form ``max(y, 0)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from lcpbench.toolkit.blas import one_blas_thread

__all__ = ["weighted_prox", "compact_prox", "shifted_point", "ActiveGram", "ProxInfo",
           "FALLBACK_ITERS"]

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
    predictor_rejected : int
        Steps taken with the previous evaluation's active set that did not reduce the
        residual (each one pass over ``W`` spent; :meth:`_NewtonSystem._predicted`).
    fallback : bool
        True when Newton did not converge and the projected-gradient fallback
        produced the answer.
    residual : float
        ``||L||`` at the returned root (NaN for the closed form / fallback).
    """

    newton_iters: int = 0
    damped: int = 0
    predictor_rejected: int = 0
    fallback: bool = False
    residual: float = float("nan")


def weighted_prox(y: np.ndarray, d: np.ndarray, U: np.ndarray, V: np.ndarray, *,
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
    y = np.asarray(y, dtype=np.float64)
    n = y.shape[0]
    U = np.asarray(U, dtype=np.float64).reshape(n, -1)
    V = np.asarray(V, dtype=np.float64).reshape(n, -1)
    r1, r2 = U.shape[1], V.shape[1]
    W = np.vstack([U.T, V.T])
    eye = np.eye(r1 + r2)
    with one_blas_thread():       # rank-sized systems: threads cost more than they give
        return compact_prox(y, d, W, eye[:, :r1], eye[:, r1:], tol=tol, max_iter=max_iter,
                            fallback_iters=fallback_iters)


def compact_prox(y: np.ndarray, d, W: np.ndarray, P: np.ndarray, N: np.ndarray,
                 gram: Optional[np.ndarray] = None, *, active: Optional[ActiveGram] = None,
                 shift: Optional[np.ndarray] = None, tol: float = 1e-12, max_iter: int = 100,
                 fallback_iters: int = FALLBACK_ITERS) -> tuple[np.ndarray, ProxInfo]:
    """:func:`weighted_prox` for factors given by coefficients: ``U = W' P``, ``V = W' N``.

    The semi-smooth Newton iteration works on the ``m x m`` Gram matrices of
    ``W`` only: ``L`` and its Jacobian depend on the active set ``Lam`` through
    ``W Lam D^-1 W'`` and ``W Lam y``, which are updated by the rows whose
    activity changed from one Newton step to the next. A Newton step (and
    each damping trial) costs one pass over ``W`` (``t = y + D^-1 W' c``) plus
    ``O(k m^2 + m^3)`` for ``k`` changed rows; no ``n x m`` array is copied.
    With ``active`` the first step is taken with the previous evaluation's
    active set (an active-set predictor, lcpbench's addition: the root problem
    is piecewise linear, so once the set is right one step lands on the root,
    and consecutive proxes of a solve mostly share it); it is kept when it
    reduces the residual, else the iteration starts from 0. The root is the
    same; on the shipped sets the Newton passes fell by 15-55%
    (docs/benchmarks.md, "The weighted prox's active-set predictor").
    BLAS threads are the caller's business (:mod:`lcpbench.toolkit.blas`).

    Parameters
    ----------
    y : ndarray, shape (n,)
        Point to project.
    d : float or ndarray, shape (n,)
        Positive diagonal of ``D``.
    W : ndarray, shape (m, n)
        Rows spanning the factors.
    P, N : ndarray, shape (m, r1), (m, r2)
        Coefficients of ``U`` and ``V``.
    gram : ndarray, shape (m, m), optional
        ``W W'`` if known (else computed: ``O(n m^2)``).
    active : ActiveGram, optional
        The active set and its Gram matrix of the previous evaluation with the
        same ``W`` (scalar ``d`` only); updated in place to this evaluation's.
    shift : ndarray, shape (m,), optional
        The point to project is ``y + D^-1 W' shift`` (a quasi-Newton step ``z - H g``
        whose ``W'`` part is still in coefficients). It is formed in the same sweep over
        ``W`` that computes ``W y`` and ``W Lam y`` for the Newton system, so the step
        costs no sweep of its own.
    tol, max_iter, fallback_iters
        As for :func:`weighted_prox`.

    Returns
    -------
    z : ndarray
    info : ProxInfo
    """
    y = np.asarray(y, dtype=np.float64)
    info = ProxInfo()
    r1, r2 = P.shape[1], N.shape[1]
    products = None
    if shift is not None and W.shape[0]:
        y, products = shifted_point(y, d, W, shift)
    if r1 + r2 == 0 or np.all(y >= 0):
        # Closed form: a diagonal metric separates; y >= 0 is its own prox.
        return np.maximum(y, 0.0), info
    newton = _NewtonSystem(y, d, W, P, N, gram)
    t, converged = newton.solve(tol, max_iter, info, active, products)
    if converged:
        return np.maximum(t, 0.0), info
    info.fallback = True
    n = y.shape[0]
    dv = np.broadcast_to(np.asarray(d, dtype=np.float64), (n,)).copy()
    return _prox_fallback(y, dv, W.T @ P, W.T @ N, fallback_iters, tol), info


#: Columns of ``W`` handled at a time (active-set Gram matrices, :func:`row_products`).
_BLOCK = 8192


def row_products(W: np.ndarray, vectors) -> np.ndarray:
    """``[W v_1, ..., W v_k]`` (shape ``(m, k)``) reading ``W`` once.

    ``vectors``: a sequence of vectors (length ``n``) or of ``(j, n)`` arrays of
    ``j`` vectors each (rows of an existing array: no copy is made). One matrix
    product per array and block of columns small enough to stay in cache
    (:func:`_gemm_columns`): on 106 x 1e5 pairs and five vectors it took 7.7 ms of CPU
    against 11.9 ms for five matrix-vector products per 8192-column block and 14 ms for
    BLAS's product of the whole arrays (docs/benchmarks.md, "PQN work outside products:
    the second round").
    """
    m, n = W.shape
    groups = [np.asarray(v, dtype=np.float64).reshape(-1, n) for v in vectors]
    cols = np.cumsum([0] + [g.shape[0] for g in groups])
    out = np.zeros((m, int(cols[-1])))
    step = _gemm_columns(m)
    for j in range(0, n, step):
        Wb = W[:, j:j + step]
        for g, a, b in zip(groups, cols[:-1], cols[1:]):
            out[:, a:b] += Wb @ g[:, j:j + step].T
    return out


def _gemm_columns(m: int) -> int:
    """Columns of an ``m``-row array that make about 1 MB (a core's L2 cache)."""
    return int(min(_BLOCK, max(512, (1 << 17) // max(m, 1))))


def shifted_point(y0: np.ndarray, d, W: np.ndarray, c0: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``y = y0 + D^-1 W' c0`` with ``[W y, W y_+]`` (shape ``(m, 2)``), in one sweep over ``W``.

    Each block of columns of ``W`` is read from memory once and used three times while
    it is in cache: for ``y`` on the block, then its products with ``y`` and with
    ``max(y, 0)`` (the Newton system's ``W y`` and ``W Lam y`` at the start point, whose
    active set is ``y > 0``).
    """
    n = y0.shape[0]
    y = np.empty(n)
    out = np.zeros((W.shape[0], 2))
    scalar = np.ndim(d) == 0
    dv = d if scalar else np.broadcast_to(np.asarray(d, dtype=np.float64), (n,))
    step = _gemm_columns(W.shape[0])
    pair = np.empty((2, step))
    for j in range(0, n, step):
        Wb = W[:, j:j + step]
        k = Wb.shape[1]
        yb = pair[0, :k]
        np.add(y0[j:j + step], (c0 @ Wb) / (dv if scalar else dv[j:j + step]), out=yb)
        np.maximum(yb, 0.0, out=pair[1, :k])
        out += Wb @ pair[:, :k].T
        y[j:j + step] = yb
    return y, out


@dataclass
class ActiveGram:
    """``W Lam W'`` of an active set, kept between prox evaluations of one model.

    Consecutive proxes of a solve have nearly the same active set, so the Newton
    system of the next one starts from this Gram matrix and the rows that
    changed (``O(k m^2)``) instead of all active rows (``O(n m^2)``). The owner
    extends ``gram`` when ``W`` gains rows. It is recomputed from scratch once
    the rows changed since then exceed ``n``, which bounds the rounding that
    adding and removing rows accumulates.

    Attributes
    ----------
    mask : ndarray of bool, shape (n,)
        The active set (``x > 0``).
    gram : ndarray, shape (m, m)
        ``W diag(mask) W'`` over the rows of ``W``.
    flips : int
        Rows added or removed since ``gram`` was computed from scratch.
    """

    mask: np.ndarray
    gram: np.ndarray
    flips: int = 0


class _NewtonSystem:
    """The root problem ``L(a, at) = 0`` of the weighted prox in Gram-matrix form.

    With ``c = Qc at - P a`` (``D^-1 W' Qc = C^-1 V``, ``C = D + U U'``) the point
    is ``t = y + D^-1 W' c`` and ``x = Lam t``; ``W x = h + M c`` with
    ``M = W Lam D^-1 W'`` and ``h = W Lam y``, so ``L`` and its Jacobian are
    small once ``(M, h)`` of the active set is known. For a scalar ``d`` the
    Gram matrices are kept without the factor ``1/d`` (``inv``).
    """

    def __init__(self, y, d, W, P, N, gram):
        self.y, self.W, self.P, self.N = y, W, P, N
        self.r1 = P.shape[1]
        self.scalar = np.ndim(d) == 0
        self.d = float(d) if self.scalar else np.broadcast_to(
            np.asarray(d, dtype=np.float64), y.shape)
        if self.scalar:
            self.G = W @ W.T if gram is None else gram
            self.inv = 1.0 / self.d
        else:
            self.G = (W / self.d) @ W.T
            self.inv = 1.0
        self.Wy = None                     # with the first active set's (start)
        Gd = self.inv * self.G
        if self.r1:
            K = np.eye(self.r1) + P.T @ Gd @ P
            self.Qc = N - P @ np.linalg.solve(K, P.T @ (Gd @ N))
        else:
            self.Qc = N.copy()
        self.GdQc = Gd @ self.Qc

    # ------------------------------------------------------------------ active set
    def _rows(self, idx):
        """``W_idx D_idx^-1 W_idx'`` over the columns ``idx``, gathered in blocks of
        :data:`_BLOCK` columns so memory stays ``O(_BLOCK m)``."""
        m = self.W.shape[0]
        M = np.zeros((m, m))
        for j in range(0, idx.size, _BLOCK):
            cols = idx[j:j + _BLOCK]
            Wi = self.W[:, cols]
            M += (Wi if self.scalar else Wi / self.d[cols]) @ Wi.T
        return M

    def _gram_of(self, mask, prev, flips):
        """``(W Lam W', flips)`` of ``mask``, from ``prev = (mask, gram)`` when cheaper."""
        n = mask.size
        act = np.flatnonzero(mask)
        if prev is not None:
            flip = np.flatnonzero(mask != prev[0])
            if flip.size <= min(act.size, n - act.size) and flips + flip.size <= n:
                M = prev[1].copy()
                on, off = flip[mask[flip]], flip[~mask[flip]]
                if on.size:
                    M += self._rows(on)
                if off.size:
                    M -= self._rows(off)
                return M, flips + flip.size
        if 2 * act.size <= n:
            return self._rows(act), 0
        return self.G - self._rows(np.flatnonzero(~mask)), 0

    def start(self, mask, cache: Optional[ActiveGram], products=None):
        """``(mask, M, h, flips)`` at the start, from the cached active set if it fits;
        ``products`` is ``[W y, W Lam y]`` if already known (:func:`shifted_point`)."""
        if cache is not None and cache.gram.shape == self.G.shape:
            M, flips = self._gram_of(mask, (cache.mask, cache.gram), cache.flips)
        else:
            M, flips = self._gram_of(mask, None, 0)
        Wy = products if products is not None else \
            row_products(self.W, (self.y, np.where(mask, self.y, 0.0)))
        self.Wy = Wy[:, 0]
        return mask, M, Wy[:, 1], flips

    def masked(self, mask, prev):
        """``(mask, M, h, flips)`` of ``mask``, updated from the state ``prev``."""
        flip = np.flatnonzero(mask != prev[0])
        if not flip.size:
            return prev
        M, flips = self._gram_of(mask, prev[:2], prev[3])
        if flips:
            h = self._flipped_h(prev[2], mask, flip)
        else:
            h = self.W @ np.where(mask, self.y, 0.0)
        return mask, M, h, flips

    def _flipped_h(self, h, mask, flip):
        """``W Lam y`` for the set ``mask`` from ``h`` of a set differing in the rows ``flip``."""
        on, off = flip[mask[flip]], flip[~mask[flip]]
        return h + self.W[:, on] @ self.y[on] - self.W[:, off] @ self.y[off]

    def point(self, a):
        """``t`` at ``a`` (one pass over ``W``)."""
        c = self.Qc @ a[self.r1:] - self.P @ a[:self.r1]
        if self.scalar:          # scale the m coefficients, not the n entries
            t = (c / self.d) @ self.W
        else:
            t = (c @ self.W) / self.d
        t += self.y
        return t, c

    def residual(self, a, c, act):
        M, h = act[1], act[2]
        rest = self.Wy - h - self.inv * (M @ c)
        L1 = self.P.T @ (rest + self.GdQc @ a[self.r1:]) + a[:self.r1]
        L2 = self.N.T @ rest + a[self.r1:]
        return np.concatenate([L1, L2])

    def jacobian(self, act):
        M = self.inv * act[1]
        P, Qc, r1 = self.P, self.Qc, self.r1
        MP, MQ = M @ P, M @ Qc
        J = np.eye(r1 + Qc.shape[1])
        J[:r1, :r1] += P.T @ MP
        J[:r1, r1:] += P.T @ (self.GdQc - MQ)
        J[r1:, :r1] += self.N.T @ MP
        J[r1:, r1:] -= self.N.T @ MQ
        return J

    # ------------------------------------------------------------------ Newton
    def _predicted(self, a, res, act, cache: ActiveGram, info: ProxInfo):
        """The Newton step taken with the previous evaluation's active set ``mask`` instead
        of the one at ``a = 0`` (an active-set predictor).

        The root problem is piecewise linear: with its final active set known, one
        Newton step from anywhere lands on the root. Consecutive proxes of a PQN solve
        mostly share that set, so the step is taken with it first; it is kept when its
        true residual (at the point it reaches, with that point's own active set)
        decreases as the damped Newton iteration requires, else the iteration starts
        from ``a = 0`` as without it (one pass over ``W`` spent, counted in
        ``newton_iters``). The root, hence the prox point, is the same either way.
        Returns ``(step length, a, L, t, res, act)`` for an accepted step, else None.
        """
        mask, cache_gram, cache_flips = cache.mask, cache.gram, cache.flips
        flip = np.flatnonzero(mask != act[0])
        if not flip.size:
            return None                 # the same set as at a = 0: the plain Newton step
        # the cached set's own Gram matrix; W Lam y from the one at a = 0 by the flipped rows
        guess = (mask, cache_gram, self._flipped_h(act[2], mask, flip), cache_flips)
        Lg = self.residual(a, np.zeros(self.W.shape[0]), guess)
        J = self.jacobian(guess)
        try:
            step = -np.linalg.solve(J, Lg)
        except np.linalg.LinAlgError:
            return None
        info.newton_iters += 1
        a_new = a + step
        t_new, c = self.point(a_new)
        act_new = self.masked(t_new > 0, guess)
        L_new = self.residual(a_new, c, act_new)
        r_new = np.linalg.norm(L_new)
        if not r_new <= (1 - 1e-4) * res:
            info.predictor_rejected += 1
            return None
        return float(np.linalg.norm(step)), a_new, L_new, t_new, r_new, act_new

    def solve(self, tol: float, max_iter: int, info: ProxInfo,
              cache: Optional[ActiveGram] = None, products: Optional[np.ndarray] = None):
        """Semi-smooth Newton from 0 with halving; ``(t, converged)`` at the last root.

        ``cache`` (scalar ``d`` only) starts the active-set Gram matrix and
        receives the last one; its active set also gives the first step
        (:meth:`_predicted`), when that step reduces the residual.
        """
        y = self.y
        a = np.zeros(self.r1 + self.Qc.shape[1])
        t = y
        act = self.start(t > 0, cache if self.scalar else None, products)
        Lv = self.residual(a, np.zeros(self.W.shape[0]), act)
        scale = 1.0 + np.linalg.norm(y)
        res = np.linalg.norm(Lv)
        converged = done = res <= tol * scale
        if not done and cache is not None and self.scalar and \
                cache.gram.shape == self.G.shape and cache.mask.shape == y.shape:
            guess = self._predicted(a, res, act, cache, info)
            if guess is not None:
                delta, a, Lv, t, res, act = guess
                done = res <= tol * scale or delta <= tol * (1.0 + np.linalg.norm(a))
                converged = done and res <= np.sqrt(tol) * scale
        while not done and info.newton_iters < max_iter:
            info.newton_iters += 1
            J = self.jacobian(act)
            try:
                step = -np.linalg.solve(J, Lv)
            except np.linalg.LinAlgError:
                step = -np.linalg.lstsq(J, Lv, rcond=None)[0]
            lam = 1.0
            while True:
                a_new = a + lam * step
                t_new, c = self.point(a_new)
                act_new = self.masked(t_new > 0, act)
                L_new = self.residual(a_new, c, act_new)
                r_new = np.linalg.norm(L_new)
                if r_new <= (1 - 1e-4 * lam) * res or lam < 1e-10:
                    break
                lam *= 0.5
            if lam < 1.0:
                info.damped += 1
            delta = np.linalg.norm(a_new - a)
            a, Lv, t, res, act = a_new, L_new, t_new, r_new, act_new
            if res <= tol * scale or delta <= tol * (1.0 + np.linalg.norm(a)):
                converged = res <= np.sqrt(tol) * scale
                break
        info.residual = float(res)
        if cache is not None and self.scalar:
            cache.mask, cache.gram, cache.flips = act[0], act[1], act[3]
        return t, converged


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
