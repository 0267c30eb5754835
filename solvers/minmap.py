"""``minmap-newton``: semismooth Newton on the minimum map, matrix-free.

The second-order baseline of the method paper's section "Numerical Results" ->
"Comparison Methods" (Min-Map Newton, Anitescu 2006 / the authors' Num4LCP
routine ``minmap_newton_matfree.m`` after K. Erleben's Num4LCP, 2011): Newton's
method on

    H(x) = min(x, A x + b)        (componentwise; H = 0 exactly at a solution)

with the generalized Jacobian ``J`` whose rows are ``A[i, :]`` on the set
``S = {i : w_i < x_i}`` (where ``H_i = w_i``) and identity rows elsewhere, and a
projected Armijo backtracking line search on the merit ``f = 1/2 ||H||^2``.

Newton system
-------------
``krylov="gmres"`` (default, as the authors' code): GMRES on the full system
``J dx = -H``, one MVP per Krylov product (``J v`` needs ``A v``).
``krylov="cg"`` / ``"minres"``: the Schur-reduced system the authors' code
recommends in its comments: the identity rows give ``dx_F = -x_F``, so
``A_SS dx_S = -w_S + (A x_F)_S``, symmetric positive (semi)definite like A, solved
by conjugate gradients or MINRES; one MVP for ``A x_F`` plus one per Krylov
product (``A`` applied to a vector supported on ``S``). CG is meant for SPD
``A``: on a singular ``A_SS`` with an inconsistent right-hand side it stops at
the first non-positive curvature and the fallback has to rescue the step.

Regularisation (option, off by default)
---------------------------------------
``reg > 0`` replaces the active rows of ``J`` by ``A[S, :] + mu e_S'`` with
``mu = reg ||H||`` (a Levenberg-Marquardt step, which becomes the Newton step
as ``H -> 0``) in the Krylov solve only; the descent test and the line search
keep the true ``J``. The default ``reg = 0`` is the source's method. On our
small planted tests ``reg = 0.1`` needed fewer MVPs for SPD matrices and turned
stalls on rank-deficient PSD matrices into convergence in about ten iterations.

MVPs per Newton iteration
-------------------------
* the Krylov products (``info['krylov_mvps']``), plus for ``cg``/``minres`` one
  for ``A x_F`` (free when ``x_F = 0``);
* one for ``A dx`` (free for ``cg``: CG accumulates it from the products it
  already made; free when ``S`` is empty). ``A dx`` gives the exact directional
  derivative ``grad f . dx = H . (J dx)`` and makes line-search trials free when
  the projection does not clip (``w + tau A dx``);
* one per line-search trial whose projection ``max(0, x + tau dx)`` clips an
  entry (``info['ls_mvps']``; unprojected trials along the Newton direction are
  free); the accepted trial's ``w`` is reused by the next
  iteration, so unlike the authors' code ``A x + b`` is never recomputed (a
  free trial's ``w = w + tau A dx`` is a recurrence: exact up to rounding, and
  refreshed by the next clipped trial). Before a recurrence ``w`` is allowed
  to claim convergence it is confirmed by one counted product when the
  rounding drift could explain the claim (:class:`lcpbench.toolkit.confirm.ConfirmedReport`,
  ``info['confirmations']``; found necessary by ``benchmarks/fuzz.py`` on
  badly scaled ``b``).
* when the Newton direction is not a sufficient descent direction
  (``grad f . dx > -rho ||dx||^2`` with ``rho`` = machine epsilon, or
  ``max|dx| < eps``; the authors' code stops there and says "I am lazy here")
  or its line search fails, the steepest-descent direction ``-J'H`` of the merit
  is used instead (one MVP for ``A H_S``, then one per trial), counted in
  ``info['fallbacks']``.

Line search (``projection``)
----------------------------
The source projects every trial onto ``x >= 0``. Near the boundary the
projected path is not the Newton direction and its Armijo test can fail even for
tiny steps (on a 7-variable hard case the merit rises along the whole projected
path while ``x + tau dx`` descends), after which the source accepts a useless
step. lcpbench's default ``retry`` keeps the source's projected search and, only
when it fails, repeats the search without projection (``info['retries']``):
the merit ``1/2||min(x, w)||^2`` is defined for any ``x`` and penalises ``x < 0``,
so a solution found this way is still checked by the same residual.
On the hard-case families (n <= 50) ``krylov=cg, projection=never`` needed about
a quarter of the MVPs of the source's configuration and solved more instances;
the defaults stay with the source so the baseline is the paper's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Literal, Optional

import numpy as np
from scipy.sparse.linalg import LinearOperator, gmres, minres

from lcpbench import register_solver
from lcpbench.core.context import SolverContext
from lcpbench.core.result import SolveResult, Status
from lcpbench.core.specs import Bounds, CheckedParams
from lcpbench.toolkit.confirm import ConfirmedReport

__all__ = ["MinMapParams", "minmap_newton"]

_EPS = np.finfo(float).eps


@dataclass(frozen=True)
class MinMapParams(CheckedParams):
    """Parameters of minmap-newton.

    Parameters
    ----------
    krylov : str
        ``gmres`` (default, the authors' choice: full Newton system),
        ``cg`` or ``minres`` (Schur-reduced symmetric system on the active set).
    inner_tol : float
        Relative residual tolerance of the Krylov solve (default 1e-6: MATLAB's
        ``gmres`` default used by the authors' code).
    inner_max_iter : int
        Krylov products allowed per Newton solve (default 200: the authors'
        restart 20 times MATLAB's default of at most 10 restart cycles; GMRES
        also spends one product per restart on its true residual).
    restart : int
        GMRES restart length (default 20, as the authors' code; capped at n).
    alpha : float
        Step reduction factor of the backtracking line search (default 0.5, as the source).
    beta : float
        Sufficient-decrease constant of the Armijo test (default 1e-3, as the source).
    max_backtracks : int
        Step reductions before the line search gives up (default 47: the
        source's test ``tau^2 < 1e-28`` with ``alpha = 0.5``).
    reg : float
        Levenberg-Marquardt regularisation: the active rows of J become
        ``A[S, :] + mu e_S'`` with ``mu = reg ||H||`` (default 0: the source's
        unregularised Newton step). Helps when A is singular (J singular);
        ``mu`` is not scale-invariant (it mixes the units of ``H`` and ``A``), so
        tune ``reg`` to the scale of ``A`` and ``b``.
    projection : str
        Line-search trials along the Newton direction: ``always`` projects them
        onto ``x >= 0`` (the source's projected Armijo search); ``never`` does not
        (Armijo on the merit in R^n: trials cost no MVP); ``retry`` (default)
        projects first and, if that search fails, retries unprojected.
    """

    krylov: Literal["gmres", "cg", "minres"] = "gmres"
    inner_tol: Annotated[float, Bounds(gt=0, lt=1)] = 1e-6
    inner_max_iter: Annotated[int, Bounds(ge=1)] = 200
    restart: Annotated[int, Bounds(ge=1)] = 20
    alpha: Annotated[float, Bounds(gt=0, lt=1)] = 0.5
    beta: Annotated[float, Bounds(gt=0, lt=1)] = 1e-3
    max_backtracks: Annotated[int, Bounds(ge=0)] = 47
    reg: Annotated[float, Bounds(ge=0)] = 0.0
    projection: Literal["always", "retry", "never"] = "retry"


def _pad(v: np.ndarray, mask: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros(n)
    out[mask] = v
    return out


def _cg(apply_full: Callable[[np.ndarray], np.ndarray], S: np.ndarray, rhs: np.ndarray,
        rtol: float, maxiter: int, mu: float = 0.0) -> tuple[np.ndarray, np.ndarray, int]:
    """CG on ``(A_SS + mu I) y = rhs``.

    Returns ``y``, ``A pad(y)`` (accumulated from the products CG made: no extra
    MVP) and the number of products.
    """
    n = S.size
    y = np.zeros(rhs.size)
    Ay = np.zeros(n)
    r = rhs.copy()
    p = r.copy()
    rr = float(r @ r)
    stop = rtol * np.sqrt(rr)
    k = 0
    while k < maxiter and np.sqrt(rr) > stop and rr > 0:
        q_full = apply_full(_pad(p, S, n))
        k += 1
        q = q_full[S] + mu * p
        pq = float(p @ q)
        if not pq > 0:          # singular direction of a PSD A_SS: stop with what we have
            break
        a = rr / pq
        y += a * p
        Ay += a * q_full
        r -= a * q
        rr_new = float(r @ r)
        p = r + (rr_new / rr) * p
        rr = rr_new
    return y, Ay, k


@register_solver("minmap-newton", MinMapParams)
def minmap_newton(ctx: SolverContext, p: MinMapParams) -> SolveResult:
    """Min-map (semismooth) Newton with a Krylov inner solve and an Armijo line search.

    Comparison method of the method paper (section "Comparison Methods";
    Anitescu 2006; authors' ``minmap_newton_matfree.m``, after Erleben's Num4LCP).
    MVPs per iteration as in the module docstring; ``info`` holds
    ``newton_iterations``, ``krylov_mvps``, ``ls_mvps``, ``backtracks``,
    ``fallbacks``, ``ls_failures`` (searches that found no step) and ``retries``
    (unprojected retries after a failed projected search).
    """
    n = ctx.n
    A = ctx.A
    info = ctx.info
    for k in ("newton_iterations", "krylov_mvps", "ls_mvps", "backtracks", "fallbacks",
              "ls_failures", "retries"):
        info[k] = 0
    x = np.maximum(ctx.x0, 0.0)
    report = ConfirmedReport(ctx)
    w = report.exact(x)
    if report(x, w):
        return ctx.finish(x, w)

    def counted(v: np.ndarray) -> np.ndarray:
        c0 = A.count
        out = A @ v
        info["krylov_mvps"] += A.count - c0
        ctx.offer_direction(v, out)     # the Krylov products: evidence if there is no solution
        return out

    while True:
        H = np.minimum(x, w)
        f0 = 0.5 * float(H @ H)
        S = w < x
        F = ~S
        dx, Adx = _newton_direction(ctx, p, x, w, H, S, F, counted)
        info["newton_iterations"] += 1
        if dx is not None:
            # On a problem without a solution J is singular and the Krylov solve grows the
            # step along a null direction of A: evidence the framework can confirm.
            ctx.offer_direction(dx, Adx)
        step: Optional[tuple[np.ndarray, np.ndarray, bool]] = None
        if dx is not None:
            JdX = np.where(S, Adx, dx)
            gd = float(H @ JdX)
            if np.max(np.abs(dx)) >= _EPS and gd <= -_EPS * float(dx @ dx):
                step = None
                if p.projection in ("always", "retry"):
                    step = _line_search(ctx, p, x, w, dx, Adx, f0, gd, project=True)
                if step is None and p.projection in ("retry", "never"):
                    if p.projection == "retry":
                        info["retries"] += 1
                    step = _line_search(ctx, p, x, w, dx, Adx, f0, gd, project=False)
                if step is None:
                    info["ls_failures"] += 1
        if step is None:
            # Steepest descent of the merit: grad f = J'H = H on F + A (H on S).
            info["fallbacks"] += 1
            AHS = A @ _pad(H[S], S, n)
            g = np.where(F, H, 0.0) + AHS
            # -H_S (> 0 where x = 0) with its product: a null direction when J'H = 0 at H != 0
            ctx.offer_direction(-_pad(H[S], S, n), -AHS)
            gg = float(g @ g)
            if not gg > 0:
                return ctx.finish(x, w, Status.stagnated,
                                  "local minimum of the merit 1/2||min(x,w)||^2 (J'H = 0)")
            step = _line_search(ctx, p, x, w, -g, None, f0, -gg,
                                project=p.projection != "never")
            if step is None:
                info["ls_failures"] += 1
                return ctx.finish(x, w, Status.stagnated,
                                  "Armijo line search failed along the Newton and gradient "
                                  "directions")
        x, w, exact = step
        # a recurrence w = w + tau A dx inherits the rounding of A dx = A y - u (a difference
        # of two products that can cancel): a convergence claim on it is always confirmed
        if report(x, w, exact=exact, always=True):
            return ctx.finish(x, w)


def _newton_direction(ctx: SolverContext, p: MinMapParams, x, w, H, S, F, counted):
    """``(dx, A dx)`` solving ``J dx = -H`` approximately, or ``(None, None)``."""
    n = ctx.n
    A = ctx.A
    m = int(S.sum())
    mu = p.reg * float(np.linalg.norm(H))
    if m == 0:                      # J = I: dx = -x, A dx = -(w - b) exactly, no product
        return -x.copy(), -(w - ctx.b)
    if p.krylov == "gmres":
        def jv(v):
            out = np.array(v, dtype=np.float64).reshape(-1)
            Av = counted(out)
            out = out.copy()
            out[S] = Av[S] + mu * out[S]
            return out
        J = LinearOperator((n, n), matvec=jv, dtype=np.float64)
        restart = min(p.restart, n)
        cycles = max(1, int(np.ceil(p.inner_max_iter / restart)))
        dx, _ = gmres(J, -H, rtol=p.inner_tol, atol=0.0, restart=restart, maxiter=cycles)
        if not np.all(np.isfinite(dx)):
            return None, None
        return dx, A @ dx
    # Schur-reduced symmetric system on S: dx_F = -x_F, A_SS dx_S = -w_S + (A x_F)_S.
    xF = np.where(F, x, 0.0)
    u = A @ xF                       # free when x_F = 0
    rhs = -w[S] + u[S]
    if p.krylov == "cg":
        y, Ay, _ = _cg(counted, S, rhs, p.inner_tol, min(p.inner_max_iter, 10 * m), mu)
    else:
        def red_mv(v):
            v = np.ravel(v)
            return counted(_pad(v, S, n))[S] + mu * v
        red = LinearOperator((m, m), matvec=red_mv, dtype=np.float64)
        y, _ = minres(red, rhs, rtol=p.inner_tol, maxiter=p.inner_max_iter)
        if not np.all(np.isfinite(y)):
            return None, None
        Ay = A @ _pad(y, S, n)
    dx = -xF
    dx[S] = y
    return dx, Ay - u


def _line_search(ctx: SolverContext, p: MinMapParams, x, w, d, Ad, f0: float, gd: float, *,
                 project: bool = True) -> Optional[tuple[np.ndarray, np.ndarray, bool]]:
    """Armijo backtracking on ``1/2||min(x,w)||^2``; ``(x, w, exact)`` or None.

    Trials are ``max(0, x + tau d)`` when ``project`` (the source's projected
    search), else ``x + tau d``. A trial that is not clipped uses ``w + tau A d``
    (no product) when ``A d`` is known; otherwise it costs one MVP. ``exact``
    says whether the accepted ``w`` is a fresh product rather than a recurrence.
    """
    A, b = ctx.A, ctx.b
    tau = 1.0
    for k in range(p.max_backtracks + 1):
        z = x + tau * d
        exact = not (Ad is not None and (not project or np.all(z >= 0)))
        if not exact:
            wz = w + tau * Ad
        else:
            z = np.maximum(z, 0.0)
            c0 = A.count
            wz = A @ z + b
            ctx.info["ls_mvps"] += A.count - c0
        Hz = np.minimum(z, wz)
        fz = 0.5 * float(Hz @ Hz)
        if fz <= f0 + p.beta * tau * gd:
            ctx.info["backtracks"] += k
            return z, wz, exact
        tau *= p.alpha
    ctx.info["backtracks"] += p.max_backtracks
    return None
