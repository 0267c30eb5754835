"""Relaxed restarted GMRES of the boundary-integral mobility.

The boundary-integral product can be made at several accuracies ("rungs" of a tolerance
ladder); :func:`relaxed_gmres` runs GMRES one restart cycle at a time so that the accuracy
of every product is chosen before it is made, and so that every convergence decision uses a
full-accuracy residual.  The forward and the transposed solves of :class:`bim.BimMobility`
both use it.

A cycle (:func:`gmres_cycle`) is the Arnoldi process of ``scipy.sparse.linalg.gmres`` (the
same Givens rotations, LAPACK's ``lartg``, the same stopping and breakdown rules) with the
orthogonalisation done as block passes over the basis: classical Gram-Schmidt with one
reorthogonalisation when the first pass cancelled more than half of the vector ("twice is
enough", Giraud, Langou and Rozloznik 2005), two or four matrix-vector products over the
stored basis per direction instead of one dot product and one update per basis vector.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.linalg import get_lapack_funcs

from lcpbench.toolkit.blas import one_blas_thread

from .gram_schmidt import orthogonalise

__all__ = ["relaxed_gmres", "gmres_cycle"]


def relaxed_gmres(matvec, b: np.ndarray, x0: np.ndarray, rtol: float, restart: int,
                  maxiter: int, *, rungs: int = 1, step: float = 100.0,
                  relax: float = 1.0) -> tuple[np.ndarray, int, float]:
    """Restarted, optionally relaxed GMRES for ``A x = b``, one :func:`gmres_cycle` at a time.

    ``matvec(x, k)`` applies A with accuracy rung ``k`` (0 = full accuracy, rung k
    ``step**k`` times less accurate).  Relaxation (inexact Krylov; Bouras & Fraysse 2005,
    Simoncini & Szyld 2003): once the relative residual estimate has dropped to
    ``relax / step**k``, the product error can grow by ``step**k`` without spoiling the
    final residual, because later Krylov directions enter the solution with weights of
    the size of the residual.  Residuals at restarts and at the end are always measured
    with rung 0, so a relaxation that went too far only costs iterations.

    A cycle is run per restart (``restart`` capped by the iterations left, ``rtol``, from
    the current iterate, first the warm start), so that:

    * the rung of every product is known before it is made: a callback records the
      residual estimate after each inner iteration and the next product uses the rung
      that estimate allows;
    * every convergence decision here uses a full-accuracy residual: after each cycle
      ``b - A x`` is measured at rung 0, and the rung-0 product at the start of the next
      cycle is served from a cache of that product, so a restart costs no extra product.

    Stops when the full-accuracy relative residual ``||b - A x|| / ||b||`` is at most
    ``rtol`` or after ``maxiter`` inner iterations in total.  numpy's vector work runs
    with BLAS limited to one thread (threadpoolctl): threaded BLAS would compete with the
    parallel compiled kernels of the product on few cores.

    Returns
    -------
    x, iterations, relative residual ``||b - A x|| / ||b||`` of the returned x, measured
    with a full-accuracy (rung 0) product
    """
    b = np.asarray(b, dtype=float)
    n = b.size
    nb = float(np.linalg.norm(b))
    x = np.array(x0, dtype=float)
    if nb == 0.0:
        return np.zeros(n), 0, 0.0
    m = max(1, min(int(restart), n))
    # rung: accuracy of the next product; then: rung after it (set when that product is
    # the cycle's initial residual b - A x0); its / cycle: inner iterations, total and in cycle
    state: dict[str, Any] = {"rung": 0, "then": None, "its": 0, "cycle": 0, "restart": m}
    cache: dict = {}                        # last product: input copy, rung, output

    def product(v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=float).reshape(-1)
        rung = state["rung"]
        if state["then"] is not None:
            state["rung"], state["then"] = state["then"], None
        if rung == 0 and cache.get("rung") == 0 and np.array_equal(cache["x"], v):
            return cache["y"].copy()
        y = np.asarray(matvec(v, rung), dtype=float).reshape(-1)
        cache.update(x=v.copy(), rung=rung, y=y)
        return y.copy()

    def rung_for(est: float) -> int:
        k = 0
        while k + 1 < rungs and est * step ** (k + 1) <= relax:
            k += 1
        return k

    def callback(pr_norm: float) -> None:
        state["its"] += 1
        state["cycle"] += 1
        state["rung"] = rung_for(float(pr_norm))

    def residual(z: np.ndarray) -> float:
        state["rung"], state["then"] = 0, None
        return float(np.linalg.norm(b - product(z))) / nb

    with one_blas_thread():
        res = residual(x)
        while res > rtol and state["its"] < maxiter:
            state["cycle"] = 0
            state["restart"] = min(m, maxiter - state["its"])
            if x.any():                     # the cycle first forms b - A x0: rung 0 (cached)
                state["rung"], state["then"] = 0, rung_for(res)
            else:                           # the cycle starts from r = b, no product
                state["rung"], state["then"] = rung_for(res), None
            its_before = state["its"]
            x = gmres_cycle(product, b, x, rtol, state["restart"], callback)
            res = residual(x)
            if state["its"] == its_before:  # the cycle took no step: stop rather than loop
                break
    return x, state["its"], res


_LARTG = get_lapack_funcs("lartg", dtype=np.float64)
_EPS = float(np.finfo(np.float64).eps)


def gmres_cycle(matvec: Callable[[np.ndarray], np.ndarray], b: np.ndarray, x: np.ndarray,
                rtol: float, restart: int, callback: Callable[[float], None]) -> np.ndarray:
    """One restart cycle of GMRES for ``A x = b`` from ``x``; returns the new iterate.

    The cycle of ``scipy.sparse.linalg.gmres(..., restart=restart, maxiter=1, rtol=rtol,
    atol=0, callback_type="pr_norm")`` without a preconditioner: at most ``restart``
    Arnoldi steps, stopped when the residual estimate is at most ``rtol ||b||`` or on a
    breakdown (a new direction below machine precision of its image), ``callback`` called
    with the relative residual estimate after every step.  Unlike scipy it makes no product
    of the returned iterate (the caller measures its residual).  The orthogonalisation is
    :func:`.gram_schmidt.orthogonalise` over the whole basis at once.

    Parameters
    ----------
    matvec : callable
        ``matvec(v) -> A v``.
    b, x : ndarray
        Right-hand side and start (not modified).
    rtol : float
        Relative tolerance of the residual estimate.
    restart : int
        Most Arnoldi steps (>= 1).
    callback : callable
        Called with the residual estimate over ``||b||`` after every step.
    """
    n = b.size
    nb = float(np.linalg.norm(b))
    x = np.array(x, dtype=np.float64)
    if nb == 0.0:
        return np.zeros(n)
    ptol = nb * rtol
    r = b - matvec(x) if x.any() else b.copy()
    V = np.empty((restart + 1, n))
    R = np.zeros((restart, restart))              # R[:col+1, col]: rotated column col
    rotations: list[tuple[float, float]] = []
    beta = float(np.linalg.norm(r))
    V[0] = r / beta
    S = np.zeros(restart + 1)
    S[0] = beta
    col = 0
    for col in range(restart):
        w = np.array(matvec(V[col]), dtype=np.float64).reshape(-1)
        h, h0, h1 = orthogonalise(V[:col + 1], w)
        breakdown = h1 <= _EPS * h0
        V[col + 1] = w if breakdown else w * (1.0 / h1)
        hc = h.tolist()
        for k, (c, s) in enumerate(rotations):        # the past rotations, on floats
            n0, n1 = hc[k], hc[k + 1]
            hc[k], hc[k + 1] = c * n0 + s * n1, -s * n0 + c * n1
        c, s, mag = (float(t) for t in _LARTG(hc[col], 0.0 if breakdown else h1))
        rotations.append((c, s))
        hc[col] = mag
        R[:col + 1, col] = hc
        S[col], S[col + 1] = c * S[col], -s * S[col]
        presid = abs(S[col + 1])
        callback(presid / nb)
        if presid <= ptol or breakdown:
            break
    # back substitution on R[:col+1, :col+1], pseudo-solving a zero diagonal as scipy does
    if R[col, col] == 0:
        S[col] = 0
    y = S[:col + 1].copy()
    for k in range(col, 0, -1):
        if y[k] != 0:
            y[k] /= R[k, k]
            y[:k] -= y[k] * R[:k, k]
    if y[0] != 0:
        y[0] /= R[0, 0]
    x += y @ V[:col + 1]
    return x
