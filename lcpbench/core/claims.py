"""What a result may claim: convergence confirmed by a fresh product, infeasibility from evidence.

Both checks run in the framework after the solver returns, once for every
solver family, and both use counted products of the high-fidelity operator:

* :func:`confirm_convergence`: a ``converged`` status is a claim about
  ``A x + b`` at the returned ``x``. Solvers that update ``w`` by a recurrence
  (``w + t A d``) can drift from it by rounding, or by the accuracy of an
  inexact operator, and on problems without a solution the drift can be
  catastrophic. The claim is therefore accepted only when a bound that covers
  the recurrence's drift (rounding and the operator's declared accuracy) was
  certified for exactly that ``x`` by the solver's shared confirmation, or the
  operator's own last product was taken at exactly that ``x`` (both free), or
  one fresh counted product confirms it; a claim the fresh product refutes
  becomes ``stagnated``, never ``converged``.
* :func:`infeasibility_evidence`: for a solve that ended without converging,
  a direction ``d >= 0`` with ``A d ~ 0`` and ``b'd < 0`` proves by Farkas'
  lemma that every feasible point is far away: ``d'(A z + b) >= 0`` for
  feasible ``z`` gives ``||z|| >= -b'd / ||(A d)_+||``. Candidates are the
  iterate, the last step, and the best non-negative combination of the
  directions whose products are already known (the recent iterates and their
  differences, and the directions a solver offered with
  :meth:`~lcpbench.core.context.SolverContext.offer_direction`). When the
  known products suggest such a direction, one counted product ``A d``
  (allowed past the budget: the solve is over) confirms it, and the status
  becomes ``infeasible`` with the bound in the message.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from lcpbench.core.context import SolverContext
from lcpbench.core.operator import BudgetExhausted
from lcpbench.core.residuals import kkt_abs
from lcpbench.core.result import SolveResult, Status

__all__ = ["confirm_convergence", "infeasibility_evidence", "NULL_RTOL"]

#: A direction counts as a null direction when ``||(A d)_+|| <= NULL_RTOL ||A||``:
#: every feasible point then has a norm of at least ``|b'd| / (NULL_RTOL ||A||)``.
NULL_RTOL = 1e-10
#: When the returned iterate is nearly feasible, ``infeasible`` needs the proven bound on
#: feasible points beyond this many times its norm (see :func:`infeasibility_evidence`).
BOUND_MARGIN = 10.0
#: Known directions below this fraction of the largest singular value of their
#: (unit-column) matrix are dropped from the span searched by :func:`_span_candidate`.
SPAN_RCOND = 1e-12


def confirm_convergence(ctx: SolverContext, res: SolveResult) -> SolveResult:
    """Confirm ``res``'s ``converged`` at its ``x`` by a counted product (or refute it).

    Called by the framework while the budget still applies; a product the
    budget refuses ends the solve as ``budget`` (or ``timeout``) instead of an
    unconfirmed ``converged``. Records ``info['confirmation_mvps']`` and
    ``info['confirmed_kkt_abs']``.
    """
    if res.status != Status.converged or ctx.n == 0:
        return res
    x = np.asarray(res.x, dtype=np.float64).reshape(-1)
    if x.shape != (ctx.n,) or not np.all(np.isfinite(x)):
        return res                          # the framework's checks fail it later
    bound = ctx.certified(x)
    if bound is not None and bound <= ctx.threshold:
        ctx.info["confirmed_by"] = "drift bound"
        return res
    Ax = ctx.A.last_product(x)
    if Ax is None:
        before = ctx.A.count
        try:
            Ax = ctx.A @ x                  # free for x = 0 (a zero vector is never counted)
        except BudgetExhausted as exc:
            res.status = Status.timeout if exc.kind == "time" else Status.budget
            res.message = (f"{exc} before the convergence claim at the returned x could be "
                           "confirmed by a fresh product")
            return res
        if ctx.A.count > before:
            ctx.info["confirmation_mvps"] = ctx.info.get("confirmation_mvps", 0) + 1
    fresh = kkt_abs(x, Ax + ctx.b)
    ctx.info["confirmed_kkt_abs"] = fresh
    if fresh <= ctx.threshold:
        return res
    res.status = Status.stagnated
    res.message = (f"convergence refuted: the solver's w gave {kkt_abs(x, res.w):.3g} but a fresh "
                   f"product at the returned x gives ||min(x, Ax+b)|| = {fresh:.3g} > "
                   f"{ctx.threshold:.3g} (the solver's recurrence drifted from A x + b)")
    ctx.info["refuted_convergence"] = True
    return res


def _candidates(ctx: SolverContext, x: np.ndarray, w: np.ndarray, D: np.ndarray,
                Y: np.ndarray, norm_A: float):
    """Unit directions ``d`` with the solver's own estimate of ``A d`` (no product).

    The iterate itself (when ``x >= 0``), the last step (when it is non-negative),
    then the best non-negative combination of the known directions
    (:func:`_span_candidate`). A candidate may have entries slightly below 0;
    the caller clips them before the confirming product.
    """
    nx = float(np.linalg.norm(x))
    if nx > 0.0 and np.all(x >= 0.0):
        yield x / nx, (w - ctx.b) / nx
    prev = ctx.previous
    if prev is not None and ctx.last is not None:
        dx = ctx.last[0] - prev[0]
        if np.all(dx >= 0.0):
            nd = float(np.linalg.norm(dx))
            if nd > 0.0:
                yield dx / nd, (ctx.last[1] - prev[1]) / nd
    span = _span_candidate(ctx, D, Y, norm_A)
    if span is not None:
        yield span


def _known_directions(ctx: SolverContext) -> tuple[np.ndarray, np.ndarray]:
    """Unit columns ``D`` and their products ``Y = A D`` known without a product.

    The differences of consecutive recent iterates (``A (x_k - x_j) = w_k - w_j``),
    the last iterate itself (``A x = w - b``) and the directions the solver
    offered with their products.
    """
    pairs = [(x1 - x0, w1 - w0) for (x0, w0), (x1, w1) in zip(ctx.recent, ctx.recent[1:])]
    pairs += [(x, w - ctx.b) for x, w in ctx.recent[-1:]]
    pairs += ctx.offered
    D, Y = [], []
    for d, Ad in pairs:
        nd = float(np.linalg.norm(d))
        if nd > 0.0:
            D.append(d / nd)
            Y.append(Ad / nd)
    if not D:
        return np.zeros((ctx.n, 0)), np.zeros((ctx.n, 0))
    return np.array(D).T, np.array(Y).T


def _span_candidate(ctx: SolverContext, D: np.ndarray, Y: np.ndarray,
                    norm_A: float) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """The best unit ``d >= 0`` with ``b'd < 0`` in the span of the known directions.

    A slowly diverging method (a first-order method with a fixed step, Newton
    steps on a singular system) never moves far enough for its iterate or its
    last step alone to be a null direction to ``NULL_RTOL``, but the span of
    its recent steps contains one: the steps differ by components that decay,
    and a combination cancels them (as minimal-polynomial extrapolation does).
    In an orthonormal basis ``U`` of the known directions, with ``A U`` from
    their known products, the right singular vectors of ``A U`` with singular
    values within ``NULL_RTOL ||A||`` span the near-null directions (the
    smallest one when none is); a linear program then picks the combination
    that is non-negative with the largest margin on the rows the iterates
    touched, normalised by ``b'd = -1``. Returns ``(d, A d)`` (the product
    predicted, not applied) or None.
    """
    if D.shape[1] == 0:
        return None
    U, s, Vt = np.linalg.svd(D, full_matrices=False)
    keep = s > SPAN_RCOND * s[0]
    U, Z = U[:, keep], (Y @ Vt[keep].T) / s[keep]            # Z = A U
    _, sz, Qt = np.linalg.svd(Z, full_matrices=False)
    near = sz <= NULL_RTOL * norm_A
    Q = Qt[near].T if near.any() else Qt[-1:].T
    N = U @ Q
    if Q.shape[1] == 1:
        y: Optional[np.ndarray] = np.array([-1.0 if float(ctx.b @ N[:, 0]) > 0.0 else 1.0])
    else:
        y = _nonnegative_combination(N, ctx.b, np.any(D != 0.0, axis=1))
        if y is None:
            return None
    d, Ad = N @ y, Z @ (Q @ y)
    nd = float(np.linalg.norm(d))
    if not nd > 0.0:
        return None
    return d / nd, Ad / nd


def _nonnegative_combination(N: np.ndarray, b: np.ndarray,
                             rows: np.ndarray) -> Optional[np.ndarray]:
    """``y`` maximising ``t <= 1`` with ``(N y)_i >= t`` on ``rows`` and ``b'N y = -1``, or None."""
    from scipy.optimize import linprog

    k = N.shape[1]
    c = np.zeros(k + 1)
    c[-1] = -1.0
    A_ub = np.hstack([-N[rows], np.ones((int(rows.sum()), 1))])
    A_eq = np.append(b @ N, 0.0)[None, :]
    try:
        sol = linprog(c, A_ub=A_ub, b_ub=np.zeros(A_ub.shape[0]), A_eq=A_eq, b_eq=[-1.0],
                      bounds=[(-1e6, 1e6)] * k + [(None, 1.0)], method="highs")
    except ValueError:
        return None
    if sol.status != 0:
        return None
    y = sol.x[:k]
    # The LP meets its constraints to about 1e-7: entries it leaves at ~0 could be slightly
    # negative, and clipping them would spoil A d ~ 0. Project y so that they are 0 to rounding.
    d = N @ y
    zero = rows & (d <= 1e-6 * float(np.max(np.abs(d))))
    C = np.vstack([N[zero], (b @ N)[None, :]])
    rhs = np.append(np.zeros(int(zero.sum())), -1.0)
    return y - np.linalg.lstsq(C, C @ y - rhs, rcond=None)[0]


def infeasibility_evidence(ctx: SolverContext, res: SolveResult) -> Optional[float]:
    """Set ``res`` to ``infeasible`` when a null direction with ``b'd < 0`` is confirmed.

    Returns the proven lower bound on the norm of any feasible point, or None
    when there is no such evidence. ``||A||`` is the largest ratio
    ``||A v|| / ||v||`` among the known products (the context's secant estimate
    and the offered directions: a lower bound, so the test errs towards not
    declaring). The candidates are tried in the order of :func:`_candidates`;
    the first whose known products pass the test is confirmed. When the
    returned iterate is nearly feasible (``||(A x + b)_-|| < |b'd| / 2``) the
    proven bound must also exceed :data:`BOUND_MARGIN` times its norm: by
    ``-||w_-|| <= d'w = x'A d + b'd <= ||x|| ||(A d)_+|| + b'd`` such an
    iterate is itself about as far out as the bound, so the evidence could
    come from a solvable problem whose solution is large (badly scaled ``A``);
    the bound is then kept in ``info['infeasibility_bound_within_reach']``. At
    most one counted product, recorded in ``info['infeasibility_mvps']``.
    """
    if res.status in (Status.converged, Status.failed, Status.infeasible) or ctx.n == 0:
        return None
    x = np.asarray(res.x, dtype=np.float64).reshape(-1)
    w = np.asarray(res.w, dtype=np.float64).reshape(-1)
    if x.shape != (ctx.n,) or w.shape != (ctx.n,) or not (np.all(np.isfinite(x))
                                                         and np.all(np.isfinite(w))):
        return None
    D, Y = _known_directions(ctx)
    # a lower bound on ||A|| from the known products: the iterates' and the unit directions'
    norm_A = max(ctx.norm_A, float(np.max(np.linalg.norm(Y, axis=0))) if Y.shape[1] else 0.0)
    tol = NULL_RTOL * norm_A
    best = None
    for d, Ad in _candidates(ctx, x, w, D, Y, norm_A):
        d = np.maximum(d, 0.0)                 # a combination may dip below 0 by rounding
        nd = float(np.linalg.norm(d))
        if not nd > 0.0:
            continue
        d = d / nd
        bd = float(ctx.b @ d)
        if bd < 0.0 and float(np.linalg.norm(np.maximum(Ad, 0.0))) <= tol * nd:
            best = (d, bd)
            break
    if best is None:
        return None
    d, bd = best
    ctx.detach()                               # the solve is over: this product is evidence
    try:
        Ad = ctx.A @ d                         # d != 0: one counted product
    except Exception as exc:                   # an operator failure here is not the solver's
        ctx.info["infeasibility_check_error"] = f"{type(exc).__name__}: {exc}"
        return None
    ctx.info["infeasibility_mvps"] = ctx.info.get("infeasibility_mvps", 0) + 1
    pos = float(np.linalg.norm(np.maximum(Ad, 0.0)))
    if pos > tol:
        return None
    bound = float("inf") if pos == 0.0 else -bd / pos
    # For any x >= 0, -||(A x + b)_-|| <= d'(A x + b) <= ||x|| ||(A d)_+|| + b'd: an iterate
    # with a small negative part of w reaches the bound's region itself. There the "far
    # away" feasible points may be where the solver already is (badly scaled A, a large
    # solution), so the evidence must reach beyond it.
    near = float(np.linalg.norm(np.minimum(w, 0.0))) < 0.5 * -bd
    if near and not bound > BOUND_MARGIN * float(np.linalg.norm(x)):
        ctx.info["infeasibility_bound_within_reach"] = bound
        return None
    res.status = Status.infeasible
    res.message = (f"no solution: d >= 0 with b'd = {bd:.3g} and ||(A d)_+|| = {pos:.3g} "
                   f"(<= {NULL_RTOL:g} ||A||, ||A|| >= {norm_A:.3g}), so every feasible "
                   f"point has ||x|| >= {bound:.3g}; ended as: {res.message}")
    return bound
