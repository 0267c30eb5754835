"""Relaxed restarted GMRES of the boundary-integral mobility, by ``scipy.sparse.linalg.gmres``.

The boundary-integral product can be made at several accuracies ("rungs" of a tolerance
ladder); :func:`relaxed_gmres` drives scipy's GMRES one restart cycle at a time so that
the accuracy of every product is chosen before it is made, and so that every convergence
decision uses a full-accuracy residual.  The forward and the transposed solves of
:class:`bim.BimMobility` both use it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.sparse.linalg import LinearOperator, gmres

from lcpbench.toolkit.blas import one_blas_thread

__all__ = ["relaxed_gmres"]


def relaxed_gmres(matvec, b: np.ndarray, x0: np.ndarray, rtol: float, restart: int,
                  maxiter: int, *, rungs: int = 1, step: float = 100.0,
                  relax: float = 1.0) -> tuple[np.ndarray, int, float]:
    """Restarted, optionally relaxed GMRES for ``A x = b`` by ``scipy.sparse.linalg.gmres``.

    ``matvec(x, k)`` applies A with accuracy rung ``k`` (0 = full accuracy, rung k
    ``step**k`` times less accurate).  Relaxation (inexact Krylov; Bouras & Fraysse 2005,
    Simoncini & Szyld 2003): once the relative residual estimate has dropped to
    ``relax / step**k``, the product error can grow by ``step**k`` without spoiling the
    final residual, because later Krylov directions enter the solution with weights of
    the size of the residual.  Residuals at restarts and at the end are always measured
    with rung 0, so a relaxation that went too far only costs iterations.

    scipy is called once per restart cycle (``maxiter=1``, ``restart`` capped by the
    iterations left, ``rtol``, ``atol=0``, ``x0`` = the current iterate, first the warm
    start), so that:

    * the rung of every product is known before it is made: a ``callback_type="pr_norm"``
      callback records the residual estimate after each inner iteration and the next
      product uses the rung that estimate allows; when the callback shows that the cycle
      ends (estimate at most ``rtol`` or ``restart`` inner iterations) the next product,
      scipy's residual ``b - A x`` at the end of the cycle, is made at rung 0;
    * every convergence decision here uses a full-accuracy residual: the last product of
      the cycle is reused when it was a rung-0 product of the returned iterate (the
      usual case), otherwise (e.g. an unforeseen Arnoldi breakdown) ``b - A x`` is
      recomputed at rung 0.  The rung-0 product at the start of the next scipy call is
      served from the same cache, so a restart costs no extra product.

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
    # scipy's initial residual b - A x0); its / cycle: inner iterations, total and in cycle
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
        ends = pr_norm <= rtol * (1 + 1e-8) or state["cycle"] >= state["restart"]
        state["rung"] = 0 if ends else rung_for(float(pr_norm))

    def residual(z: np.ndarray) -> float:
        state["rung"], state["then"] = 0, None
        return float(np.linalg.norm(b - product(z))) / nb

    op = LinearOperator((n, n), matvec=product, dtype=np.float64)
    with one_blas_thread():
        res = residual(x)
        while res > rtol and state["its"] < maxiter:
            state["cycle"] = 0
            state["restart"] = min(m, maxiter - state["its"])
            if x.any():                     # scipy first forms b - A x0: rung 0 (cached)
                state["rung"], state["then"] = 0, rung_for(res)
            else:                           # scipy starts from r = b, no product
                state["rung"], state["then"] = rung_for(res), None
            its_before = state["its"]
            x, _ = gmres(op, b, x0=x.copy(), rtol=rtol, atol=0.0, restart=state["restart"],
                         maxiter=1, callback=callback, callback_type="pr_norm")
            x = np.asarray(x, dtype=float).reshape(-1)
            res = residual(x)
            if state["its"] == its_before:  # scipy took no step: stop rather than loop
                break
    return x, state["its"], res
