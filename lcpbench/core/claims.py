"""What a result may claim: convergence confirmed by a fresh product, infeasibility from evidence.

The checks run in the framework after the solver returns, once for every
solver family; the confirmations use counted products of the high-fidelity operator:

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
  :meth:`~lcpbench.core.context.SolverContext.offer_direction`). The one the
  known products show nearest to null is confirmed with a counted product
  (allowed past the budget: the solve is over), and the status becomes
  ``infeasible`` only when ``A d`` vanishes to the rounding of A along ``d``
  (:func:`_certificate`), not merely relative to ``||A||``.
* :func:`check_infeasibility`: a solver's own ``infeasible`` is held to the
  same certificate; unconfirmed, it becomes ``stagnated``.
* :func:`verify_claim`: the framework's verifying product has the last word
  on ``converged``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
import scipy.sparse as sp

from lcpbench.core.context import SolverContext
from lcpbench.core.operator import BudgetExhausted, apply_uncounted
from lcpbench.core.probes import safe_norm
from lcpbench.core.residuals import kkt_abs
from lcpbench.core.result import SolveResult, Status

__all__ = ["confirm_convergence", "verify_claim", "check_infeasibility", "infeasibility_evidence",
           "NULL_RTOL"]

#: A direction counts as a null direction when ``||(A d)_+|| <= NULL_RTOL ||A||``:
#: every feasible point then has a norm of at least ``|b'd| / (NULL_RTOL ||A||)``.
NULL_RTOL = 1e-10
#: The certificate for a matrix-free operator: ``||(A d)_+|| <= NULL_ULPS eps n ||A (d1 - d2)||``,
#: the rounding of the product along ``d`` (see :func:`_certificate`).
NULL_ULPS = 16.0
#: Entries of a candidate below this fraction of its largest are dropped first (see
#: :func:`_sparsified`).
SPARSE_REL = 1e-6
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
    Ax = ctx.A.last_product(x) if np.any(x) else np.zeros(ctx.n)     # free: A 0 = 0
    # a drift bound assumes products as accurate as declared, or float64-exact: an operator
    # that declares nothing is measured first (uncounted), unless a free product is at hand
    if bound is not None and bound <= ctx.threshold and (
            ctx.measured_exact() or ctx.A.rtol is not None
            or (Ax is None and ctx.operator_accuracy().known)):
        ctx.info["confirmed_by"] = "drift bound"
        return res
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
            ctx.A.framework_products += 1
    fresh = kkt_abs(x, Ax + ctx.b)
    ctx.info["confirmed_kkt_abs"] = fresh
    if fresh <= ctx.threshold:
        return res
    res.status = Status.stagnated
    res.message = (f"convergence refuted: the solver's w gave {kkt_abs(x, res.w):.3g} but a fresh "
                   f"product at the returned x gives ||min(x, Ax+b)|| = {fresh:.3g} > "
                   f"{ctx.threshold:.3g} (the solver's recurrence drifted from A x + b)"
                   + ctx.accuracy_advice())
    ctx.info["refuted_convergence"] = True
    return res


def verify_claim(ctx: SolverContext, status: Status, x: np.ndarray, w: np.ndarray,
                 message: str) -> tuple[Status, str]:
    """Hold a ``converged`` claim at ``x`` to the framework's verification ``w = A x + b``.

    The last word on a convergence claim: whatever confirmed it before (a drift
    bound, the operator's last product, a fresh product), a status is never
    ``converged`` when the verifying product refutes it. For an operator that
    is not known to be float64-exact (see
    :meth:`~lcpbench.core.context.SolverContext.operator_accuracy`) the point is
    verified twice (a second uncounted product; not for a matrix, nor for an
    operator already measured exact) and both must meet the threshold, so that
    a product that is not reproducible cannot pass by chance. A refuted claim
    becomes ``stagnated``, with a message that says how accurate the operator
    is when it declared nothing, and
    ``info['refuted_by_verification']``. Returns the status and message that stand.
    """
    if status != Status.converged or ctx.n == 0:
        return status, message
    worst = kkt_abs(x, w)
    if worst <= ctx.threshold and not ctx.A.explicit and not ctx.measured_exact():
        worst = max(worst, kkt_abs(x, apply_uncounted(ctx.A, x) + ctx.b))
    if worst <= ctx.threshold:
        return status, message
    ctx.info["refuted_by_verification"] = worst
    return Status.stagnated, (
        f"convergence refuted by the framework's verification: at the returned x "
        f"||min(x, Ax+b)|| = {worst:.3g} > {ctx.threshold:.3g} (the solver said: "
        f"{message})" + ctx.accuracy_advice())


def _candidates(ctx: SolverContext, x: np.ndarray, w: np.ndarray, D: np.ndarray,
                Y: np.ndarray, norm_A: float):
    """Unit directions ``d`` with the solver's own estimate of ``A d`` (no product).

    The iterate itself (when ``x >= 0``), the last step (when it is non-negative),
    then the best non-negative combination of the known directions
    (:func:`_span_candidate`). A candidate may have entries slightly below 0;
    the caller clips them before the confirming product.
    """
    nx = safe_norm(x)
    if nx > 0.0 and np.all(x >= 0.0):
        yield x / nx, (w - ctx.b) / nx
    prev = ctx.previous
    if prev is not None and ctx.last is not None:
        dx = ctx.last[0] - prev[0]
        if np.all(dx >= 0.0):
            nd = safe_norm(dx)
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
        nd = safe_norm(d)
        if np.isfinite(nd) and nd > 0.0:
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


def check_infeasibility(ctx: SolverContext, res: SolveResult) -> Optional[float]:
    """The framework's evidence of no solution, for every solve that did not converge.

    A solver's own ``infeasible`` (Lemke's ray termination, a quadratic
    unbounded along a search direction) is a claim like ``converged``: it is
    taken back to ``stagnated`` and stands only if
    :func:`infeasibility_evidence` certifies a direction (the solver may offer
    its ray with :meth:`~lcpbench.core.context.SolverContext.offer_direction`).
    An unconfirmed claim stays ``stagnated`` with the reason and
    ``info['refuted_infeasibility']``. Returns the proven bound, or None.
    """
    claimed = res.status == Status.infeasible
    said = res.message
    if claimed:
        res.status = Status.stagnated
        ctx.info["solver_claimed_infeasible"] = said
    bound = infeasibility_evidence(ctx, res)
    if not claimed:
        return bound
    if bound is not None:
        return bound
    why = ctx.info.get("infeasibility_rejected", "no direction d >= 0 with A d ~ 0 and b'd < 0 "
                                                 "among the known products")
    res.message = (f"the solver's claim of no solution was not confirmed by the framework "
                   f"({why}); the solver said: {said}")
    ctx.info["refuted_infeasibility"] = True
    return None


def infeasibility_evidence(ctx: SolverContext, res: SolveResult) -> Optional[float]:
    """Set ``res`` to ``infeasible`` when a null direction with ``b'd < 0`` is certified.

    Returns the proven lower bound on the norm of any feasible point, or None
    when there is no such evidence. Candidates (:func:`_candidates`) are
    screened with the known products against ``NULL_RTOL ||A||`` (``||A||``
    the largest ratio ``||A v|| / ||v||`` among the known products, a lower
    bound); the one nearest to null is confirmed with one counted product ``A d``
    (``info['infeasibility_mvps']``) and then must pass :func:`_certificate`:
    ``A d`` vanishes to the rounding of A along ``d`` (not of ``||A||``: a
    positive definite A with eigenvalues 0.1 ... 3.4e10 is not singular along
    its 0.1 eigenvector), ``b'd < 0`` beyond the rounding of the dot product,
    and, when the returned iterate is nearly feasible (``||(A x + b)_-|| <
    |b'd| / 2``), a bound beyond :data:`BOUND_MARGIN` times its norm (such an
    iterate is itself about as far out as the bound, by ``-||w_-|| <= d'w <=
    ||x|| ||(A d)_+|| + b'd``). A rejected confirmation is recorded in
    ``info['infeasibility_rejected']`` (and the bound in
    ``info['infeasibility_bound_within_reach']`` for the last case). Norms are
    overflow-safe: a warm start of 1e300 proves nothing by overflowing.
    """
    if res.status in (Status.converged, Status.failed, Status.infeasible) or ctx.n == 0:
        return None
    x = np.asarray(res.x, dtype=np.float64).reshape(-1)
    w = np.asarray(res.w, dtype=np.float64).reshape(-1)
    if x.shape != (ctx.n,) or w.shape != (ctx.n,) or not (np.all(np.isfinite(x))
                                                         and np.all(np.isfinite(w))):
        return None
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        best = _screened(ctx, x, w)
    if best is None:
        return None
    d, bd = best
    ctx.detach()                               # the solve is over: this product is evidence
    verdict = "no candidate"
    for cand in _sparsified(d):
        try:
            Ad = np.asarray(ctx.A @ cand, dtype=np.float64)   # cand != 0: a counted product
        except Exception as exc:               # an operator failure here is not the solver's
            ctx.info["infeasibility_check_error"] = f"{type(exc).__name__}: {exc}"
            return None
        ctx.info["infeasibility_mvps"] = ctx.info.get("infeasibility_mvps", 0) + 1
        ctx.A.framework_products += 1
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            verdict = _certificate(ctx, cand, Ad, x, w)
        if not isinstance(verdict, str):
            d, bd = cand, float(ctx.b @ cand)
            break
    if isinstance(verdict, str):
        ctx.info["infeasibility_rejected"] = verdict
        return None
    bound, pos, scale = verdict
    res.status = Status.infeasible
    res.message = (f"no solution: d >= 0 with b'd = {bd:.3g} and ||(A d)_+|| = {pos:.3g}, zero to "
                   f"the rounding of A along d (scale {scale:.3g}), so every feasible "
                   f"point has ||x|| >= {bound:.3g}; ended as: {res.message}")
    return bound


def _screened(ctx: SolverContext, x: np.ndarray,
              w: np.ndarray) -> Optional[tuple[np.ndarray, float]]:
    """The candidate whose known product is nearest to null, within ``NULL_RTOL ||A||``.

    As ``(d, b'd)``, or None. Only one candidate is confirmed (a counted product), so
    the one with the smallest predicted ``||(A d)_+||`` is taken.
    """
    D, Y = _known_directions(ctx)
    # a lower bound on ||A|| from the known products: the iterates' and the unit directions'
    col = [safe_norm(Y[:, j]) for j in range(Y.shape[1])]
    norm_A = max([ctx.norm_A] + [c for c in col if np.isfinite(c)])
    if not np.isfinite(norm_A):
        return None
    tol = NULL_RTOL * norm_A
    best, least = None, np.inf
    for d, Ad in _candidates(ctx, x, w, D, Y, norm_A):
        d = np.maximum(d, 0.0)                 # a combination may dip below 0 by rounding
        nd = safe_norm(d)
        if not (np.isfinite(nd) and nd > 0.0) or not np.all(np.isfinite(Ad)):
            continue
        d = d / nd
        bd = float(ctx.b @ d)
        pos = safe_norm(np.maximum(Ad, 0.0)) / nd
        if bd < 0.0 and pos <= tol and pos < least:
            best, least = (d, bd), pos
    return best


def _sparsified(d: np.ndarray) -> list[np.ndarray]:
    """``d`` without its entries below ``SPARSE_REL max(d)`` (when it has any and ``b'd`` stays
    negative), then ``d`` itself: the directions to confirm, in turn.

    A solver walking out along a null direction ``e_j`` carries the rest of its
    iterate along, ``x / ||x|| = e_j + O(1 / ||x||)``; the small entries are what
    keeps it from being null to rounding, and dropping them recovers ``e_j``.
    """
    keep = d >= SPARSE_REL * float(np.max(d))
    if keep.all():
        return [d]
    short = np.where(keep, d, 0.0)
    return [short / safe_norm(short), d]


def _certificate(ctx: SolverContext, d: np.ndarray, Ad: np.ndarray, x: np.ndarray,
                 w: np.ndarray):
    """``(bound, ||(A d)_+||, scale)`` when the confirmed product certifies ``d``, else the reason.

    A certificate must be conclusive: a product that merely cannot be told
    from zero by a loose rounding estimate is no proof that ``A d = 0``. The
    checks, in turn:

    * the Farkas argument needs ``A' d``: a matrix-free operator must be
      symmetric (declared with an attribute ``symmetric = True`` on the wrapped
      operator, else checked with two uncounted products, :func:`_symmetry_defect`),
      and an explicit matrix is applied transposed as well (uncounted), the
      larger positive part counting;
    * ``A d`` must vanish to the rounding of that very product, :data:`NULL_ULPS`
      ``eps n`` times a scale of A along ``d``. For an explicit matrix the scale
      is ``S = || |A| |d| ||`` (one uncounted product with the entries'
      magnitudes), the standard bound on the rounding of ``A d``. For a
      matrix-free operator it is ``||A (d1 - d2)||``, where ``d = d1 + d2``
      splits ``d``'s entries by size in turn (the size of the terms whose
      cancellation the product rounds);
    * for an explicit matrix, the Rayleigh quotient ``d' A d``, computed
      exactly (error-free products summed with ``math.fsum``), must be at most
      ``u S`` (``u = eps / 2``): A is then singular along ``d`` within the
      rounding of its own entries. A positive definite ``A`` has ``d' A d >=
      lambda_min ||d||^2`` however its products round, while along a null
      direction known to ``delta`` the quotient is ``delta' A delta``, of
      second order: this tells a condition of 1e15 from a singular matrix
      where the product alone cannot. Past :data:`EXACT_TERMS` stored entries
      the quotient is not formed and the product test is held to the rigorous
      ``gamma_n = n u / (1 - n u)`` instead of :data:`NULL_ULPS` ``eps n``;
    * ``b'd`` must be negative beyond its own rounding, and a nearly feasible
      iterate must be inside the bound (see :func:`infeasibility_evidence`).
    """
    n = ctx.n
    eps = float(np.finfo(np.float64).eps)
    u = 0.5 * eps
    if not np.all(np.isfinite(Ad)):
        return "the confirming product A d is not finite"
    impl = ctx.A._impl
    explicit = isinstance(impl, np.ndarray) or sp.issparse(impl)
    q: Optional[float] = None
    try:
        if explicit:
            absA = abs(impl) if sp.issparse(impl) else np.abs(impl)
            scale = safe_norm(np.asarray(absA @ np.abs(d)).reshape(-1))
            q = _exact_quadratic(impl, d)
            gamma = NULL_ULPS * eps * n if q is not None else n * u / (1.0 - n * u)
            pos = max(safe_norm(np.maximum(Ad, 0.0)),
                      safe_norm(np.maximum(np.asarray(impl.T @ d).reshape(-1), 0.0)))
        else:
            if getattr(impl, "symmetric", None) is not True:
                defect = _symmetry_defect(ctx)
                if defect is not None:
                    return defect
            # alternate signs over d's entries by size: d = d1 + d2 with halves of similar
            # weight, and A (d1 - d2) is the size of the terms that cancel in A d1 + A d2
            signs = np.ones(n)
            signs[np.argsort(-d, kind="stable")[1::2]] = -1.0
            scale = safe_norm(apply_uncounted(ctx.A, signs * d))
            gamma = NULL_ULPS * eps * n
            pos = safe_norm(np.maximum(Ad, 0.0))
    except Exception as exc:
        return f"the scale of A along d could not be measured: {type(exc).__name__}: {exc}"
    # float64 rounding even for an inexact operator: its products only blur A d, and a
    # blur is no evidence (an inexact operator's problem is then never declared infeasible)
    level = gamma * scale
    if not (np.isfinite(scale) and pos <= level):
        return (f"||(A d)_+|| = {pos:.3g} is not zero to the rounding of A along d "
                f"({level:.3g}): A is not singular there")
    if explicit and q is not None and not q <= u * scale:
        return (f"d'A d = {q:.3g} computed exactly exceeds the rounding of A's entries "
                f"along d ({u * scale:.3g} = u || |A| |d| ||): A is definite along d "
                "(its products there are only below their rounding)")
    bd = float(ctx.b @ d)
    if not -bd > NULL_ULPS * eps * n * float(np.abs(ctx.b) @ d):
        return f"b'd = {bd:.3g} is not negative beyond its rounding"
    bound = float("inf") if pos == 0.0 else -bd / pos
    near = safe_norm(np.minimum(w, 0.0)) < 0.5 * -bd
    if near and not bound > BOUND_MARGIN * safe_norm(x):
        ctx.info["infeasibility_bound_within_reach"] = bound
        return (f"the bound ||x|| >= {bound:.3g} is within reach of the nearly feasible "
                "iterate")
    return bound, pos, scale


def _symmetry_defect(ctx: SolverContext) -> Optional[str]:
    """None when the operator passes a symmetry check, else the reason it fails.

    Two uncounted products with seeded random vectors ``p, q``: ``|p'A q - q'A p|``
    must be within ``max(rtol, 64 eps n)`` of ``||p|| ||A q|| + ||q|| ||A p||``
    (``rtol`` the operator's declared accuracy).
    """
    rng = np.random.default_rng(20240601)
    p, q = rng.standard_normal(ctx.n), rng.standard_normal(ctx.n)
    Ap, Aq = apply_uncounted(ctx.A, p), apply_uncounted(ctx.A, q)
    scale = safe_norm(p) * safe_norm(Aq) + safe_norm(q) * safe_norm(Ap)
    tol = max(ctx.A.rtol or 0.0, 64.0 * float(np.finfo(np.float64).eps) * ctx.n)
    gap = abs(float(p @ Aq) - float(q @ Ap))
    if np.isfinite(gap) and gap <= tol * scale:
        return None
    return (f"the operator is not symmetric (|p'Aq - q'Ap| = {gap:.3g} for random p, q, "
            f"{tol:.2g} relative allowed), and the certificate holds only for symmetric A")


#: The exact Rayleigh quotient of :func:`_certificate` is computed for explicit matrices
#: with at most this many stored entries (it sums four error-free terms per entry).
EXACT_TERMS = 1_000_000
_SPLITTER = 134217729.0                       # 2**27 + 1 (Dekker's split)


def _two_product(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``p + e = a * b`` exactly (Dekker), for finite products away from overflow."""
    p = a * b
    ca, cb = _SPLITTER * a, _SPLITTER * b
    ah = ca - (ca - a)
    bh = cb - (cb - b)
    al, bl = a - ah, b - bh
    e = ((ah * bh - p) + ah * bl + al * bh) + al * bl
    return p, e


def _exact_quadratic(impl, d: np.ndarray) -> Optional[float]:
    """``d' A d`` rounded once from its exact value, or None (too large, or out of range)."""
    if sp.issparse(impl):
        coo = impl.tocoo()
        if coo.nnz > EXACT_TERMS:
            return None
        a, i, j = coo.data, coo.row, coo.col
    else:
        if impl.size > EXACT_TERMS:
            return None
        i, j = np.nonzero(impl)
        a = impl[i, j]
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        p, e = _two_product(a, d[j])
        p1, e1 = _two_product(p, d[i])
        p2, e2 = _two_product(e, d[i])
        terms = np.concatenate([p1, e1, p2, e2])
    if not np.all(np.isfinite(terms)) or (terms.size and np.max(np.abs(terms)) > 1e290):
        return None
    return math.fsum(terms.tolist())
