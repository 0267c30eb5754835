"""Proximal quasi-Newton solvers: ``mono-pqn``, ``bi-pqn`` and the ``multi-pqn`` extension.

The method paper's Section 4 ("A Proximal Quasi-Newton Method": Algorithm 1, Mono-PQN,
with Proposition 1 for the weighted prox), Section 4.1 (Algorithm 2, the optimal
over-relaxation), Section 5.2 (Algorithm 3, Bi-PQN) and appendices A (Algorithm 4, the
semi-smooth Newton solve of the prox) and D (Bi-PQN's secant conditions). The package:

* :mod:`~lcpbench.solvers.pqn.mono`: Algorithm 1 as one loop (:func:`~lcpbench.solvers.pqn.mono.mono_level`) and
  Algorithm 2 (:func:`~lcpbench.solvers.pqn.mono.optimal_step`);
* :mod:`~lcpbench.solvers.pqn.bi`: Algorithm 3 as one loop (:func:`~lcpbench.solvers.pqn.bi.bi_level`), its
  low-fidelity start and the multi-fidelity chain;
* :mod:`~lcpbench.solvers.pqn.products`: the product rules (``products=paper`` /
  ``iterate``, ``relax``) the loops call for their one product per iteration;
* :mod:`~lcpbench.solvers.pqn.params`: the parameters and the constants behind them;
* :mod:`~lcpbench.solvers.pqn.state`: the typed outcomes, decisions, counters and carry.

This module wires the loops to the solver context and documents every choice.

MVPs per iteration
------------------
* ``mono-pqn``: ``A x0`` once (free at ``x0 = 0``), then exactly one
  high-fidelity MVP ``A p`` per iteration (plus one every ``recompute_every``
  iterations, if set).
* ``bi-pqn``: the low-fidelity start (one low MVP for its gradient at ``x0``,
  free at ``x0 = 0``, then one per iteration of the low solve), one high MVP at
  its answer, then per outer iteration one high-fidelity MVP ``A p`` and one
  low-fidelity MVP per inner iteration (plus one low MVP per Mono-PQN fallback
  step, to keep the model's update exact); none once the model check has
  handed the solve to Mono-PQN.
* ``multi-pqn``: as ``bi-pqn`` with the subproblem solved by Bi-PQN on the next
  cheaper operator, recursively.

Products of the iterate
-----------------------
``products=iterate`` (default ``paper``) applies the high-fidelity operator to the
new point ``x^ = x + p`` instead of the direction ``p`` and forms ``A p = A x^ - A x``
by difference (:class:`~lcpbench.solvers.pqn.products.IterateProducts`, where the
accuracy argument is): the same number of products, but an operator with Krylov
recycling (the boundary-integral mobility) solves products of converging inputs in
few new directions. Bi-PQN's low products (the low start and the subproblems) are
then of points too, when the low's accuracy is declared or it is a matrix. Once the
difference's error bound passes ``difference_tol`` of ``||A p||`` the solve goes
back to products of ``p``; every convergence claim is confirmed by a counted
product (of the final iterate: cheap with recycling). Measured in
docs/benchmarks.md, "Products of the iterate". With ``relax > 0`` and an operator
that makes products to a requested accuracy (``Operator.product_within``: the
boundary-integral operators stop their Krylov solves earlier) the products of points
are made only as accurately as the residual needs (inexact products;
:class:`~lcpbench.solvers.pqn.products.IterateProducts` has the accuracy argument),
full accuracy again near the solution; claims are confirmed at full accuracy.

Work outside products
---------------------
O(n r) per iteration (r secant pairs kept): the BFGS models are kept in compact
form (pairs and their Gram matrices, :class:`~lcpbench.toolkit.quasinewton.DiagonalBFGS`),
the weighted prox builds its Newton system from Gram matrices
(:func:`~lcpbench.toolkit.prox.compact_prox`), and a Bi-PQN subproblem continues the
previous one's model corrected by the rank-two change of ``B``. Per iteration the pairs
are swept once by the pair update (the new Gram rows; the two-loop's ``W g`` follows
from them by the recurrence ``g + y``), once to form the quasi-Newton point with the
prox's start (:func:`~lcpbench.toolkit.prox.shifted_point`) and once per Newton step
of the prox, whose first step tries the previous prox's active set (one step when it is
still right: :func:`~lcpbench.toolkit.prox.compact_prox`); the secant memory handed back
is one copy of the pairs' rows. The solvers' own dense
algebra runs with BLAS on one thread, entered once per solve; the products (the LCP's
operators) run with the thread counts in force when the solve began.
"""

from __future__ import annotations

import sys
from typing import Optional, Union

import numpy as np

from lcpbench import register_solver
from lcpbench.core.context import SolverContext
from lcpbench.core.registry import LowOperators
from lcpbench.core.result import SolveResult, Status
from lcpbench.toolkit.blas import one_blas_thread, with_current_blas_threads
from lcpbench.toolkit.confirm import ConfirmedReport
from lcpbench.toolkit.quasinewton import Pairs, SecantMemory, free_secant_pair

from .bi import LowStart, bi_level, low_start
from .mono import level_model, mono_level
from .params import (
    DIFFERENCE_TOL,
    RECOMPUTE_EVERY,
    BiParamsBase,
    BiPQNParams,
    MonoPQNParams,
    MultiPQNParams,
)
from .products import DirectionProducts, IterateProducts, LowPoints
from .state import Counters, LevelResult, Outcome

__all__ = ["mono_pqn", "bi_pqn", "multi_pqn"]

def _carried(ctx: SolverContext, solver: str) -> Optional[Pairs]:
    """The pairs of ``state=`` (a :class:`SecantMemory` with ``n`` rows), checked."""
    st = ctx.state
    if st is None:
        ctx.info["carried_pairs"] = 0
        return None
    if not isinstance(st, SecantMemory):
        raise TypeError(f"{solver}: state= takes the SecantMemory of a previous PQN solve "
                        f"(result.state), got {type(st).__name__}")
    st.check(ctx.n, solver)
    ctx.info["carried_pairs"] = st.rank
    S, Y = st.pairs()
    return Pairs(S, Y, [None] * len(S)) if len(S) else None


def _finish(ctx: SolverContext, out: LevelResult, counters: Counters) -> SolveResult:
    ctx.info.update(counters.as_dict())
    memory = out.pairs.memory(ctx.n)
    ctx.info["secant_memory"] = memory
    if out.outcome is Outcome.UNBOUNDED:
        if out.ray is not None:         # the top level's p and A p: the framework checks them
            ctx.offer_direction(*out.ray)
        return ctx.finish(out.z, out.G, Status.infeasible,
                          "the quadratic is unbounded below along the search direction: the LCP "
                          "has no solution (A not PSD, or -b outside the cone)", state=memory)
    if out.outcome is Outcome.STATIONARY:
        return ctx.finish(out.z, out.G, Status.stagnated,
                          "no descent direction: the projected gradient vanishes to round-off",
                          state=memory)
    return ctx.finish(out.z, out.G, state=memory)


class _ConfirmEvery:
    """The stop test of ``products=iterate``: every claim confirmed by a counted product
    (``G`` is made of differences)."""

    def __init__(self, stop: ConfirmedReport):
        self.stop = stop
        self.exact = stop.exact

    def __call__(self, z: np.ndarray, G: np.ndarray) -> bool:
        return self.stop(z, G, always=True)


Stop = Union[ConfirmedReport, _ConfirmEvery]


def _product_rule(ctx: SolverContext, p: Union[MonoPQNParams, BiParamsBase],
                  difference_tol: float
                  ) -> tuple[Union[DirectionProducts, IterateProducts], Stop]:
    """``(products, stop)``: the product rule of ``products=`` and the stop test, which
    with products of points confirms every claim by a counted product.

    The difference needs the operator's accuracy: declared (``Operator(rtol=)``),
    a float64 matrix, or measured by the framework (uncounted); an operator of
    unknown accuracy gets products of the direction (``info['products']`` says so).
    """
    stop = ConfirmedReport(ctx)
    apply = with_current_blas_threads(ctx.A.matvec)
    ctx.info["products"] = p.products
    if p.products != "iterate":
        return DirectionProducts(apply), stop
    acc = ctx.operator_accuracy()
    if not acc.known:
        ctx.info["products"] = "paper (the operator's accuracy is unknown)"
        return DirectionProducts(apply), stop
    within = with_current_blas_threads(ctx.A.product_within) if ctx.A.relaxable else None
    ctx.info["relax"] = p.relax if within is not None else 0.0
    return IterateProducts(apply, ctx.b, acc.rtol, difference_tol, relax=p.relax,
                           within=within), _ConfirmEvery(stop)


def _start(ctx: SolverContext):
    x = np.maximum(ctx.x0, 0.0)
    return x, ctx.A @ x + ctx.b


@register_solver("mono-pqn", MonoPQNParams)
def mono_pqn(ctx: SolverContext, p: MonoPQNParams) -> SolveResult:
    """Mono-fidelity proximal quasi-Newton method (Algorithm 1 of the method paper).

    Each iteration: ``x~ = x - H g`` with ``H = B^-1`` applied by the BFGS
    two-loop recursion in O(n r); ``x^ = prox^B(x~)`` by Proposition 1
    of the paper (semi-smooth Newton on the 2r-dimensional root problem,
    Algorithm 4; closed form ``max(x~, 0)`` while ``r = 0``);
    ``p = x^ - x``; one MVP ``A p``; the optimal over-relaxation ``eta*`` of
    Algorithm 2 from the cached ``A p``; ``x+ = x + eta p``,
    ``A x+ = A x + eta A p``; BFGS update with ``(eta p, eta A p)`` (Nocedal &
    Wright, ch. 6), pairs with ``s'y <= 0`` skipped. The paper's choices:
    full memory, optimal step (not unit), and the stopping rule of its Section 6
    (``||min(x, A x + b)||``). Choices the paper leaves open, taken from the authors' code:
    the BB-scaled initial diagonal with ``gamma = 0.8``. If an inexact prox
    gives no descent, the projected-gradient direction is used (counted as
    ``gradient_fallbacks``).

    Secant memory: ``result.state`` (also ``result.info['secant_memory']``) is
    a :class:`~lcpbench.toolkit.quasinewton.SecantMemory`, the pairs of the
    final model (the carried ones that passed the curvature test, then this
    solve's, at most ``memory`` or n). ``lcpbench.solve(..., state=memory)``
    starts the model from them (``info['carried_pairs']``), older than the
    free pair of the warm start; they cost no product. The memory must have n
    rows (a ``ValueError``, else a ``TypeError`` for another object: the
    solve returns ``failed`` naming it); for a changed contact set map it
    first (``SecantMemory.remap``, or the lattice scene's ``carry_memory``).
    Pairs of an earlier, different ``A`` are only approximate curvature: they
    precondition, every step is still measured with this ``A``.
    """
    x, g = _start(ctx)
    counters = Counters()
    products, stop = _product_rule(ctx, p, p.difference_tol)
    seed = _carried(ctx, "mono-pqn")
    pair = free_secant_pair(x, g, ctx.b) if p.free_pair else None
    if pair is not None:
        seed = seed or Pairs()
        seed.add(*pair)
        ctx.info["free_pair"] = True
    exact = with_current_blas_threads(stop.exact)
    with one_blas_thread():       # the solver's own small dense algebra; products keep theirs
        model = level_model(ctx.n, p.memory, p.scaling, seed)
        out = mono_level(products, x, g, stop, sys.maxsize, model, counters,
                         exact_gradient=exact, recompute_every=p.recompute_every)
    ctx.info.update(products.as_dict())
    ctx.info["rank"] = len(out.pairs)
    return _finish(ctx, out, counters)


def _low_names(ctx: SolverContext, wanted: tuple, solver: str) -> list[str]:
    if not ctx.low:
        raise ValueError(f"{solver} needs a low-fidelity operator but the LCP has none: build it "
                         "with LCP(A, b, low={'name': operator}) or use mono-pqn")
    if not wanted:
        if solver == "bi-pqn" and len(ctx.low) > 1:
            raise ValueError(f"bi-pqn: the LCP has several low-fidelity operators "
                             f"({', '.join(ctx.low)}); choose one with low=NAME")
        return sorted(ctx.low, key=lambda k: -(ctx.low[k].cost or 0.0))
    missing = [w for w in wanted if w not in ctx.low]
    if missing:
        raise ValueError(f"{solver}: no low-fidelity operator named {', '.join(missing)}; this "
                         f"LCP has {', '.join(ctx.low)}")
    return list(wanted)


def _run_chain(ctx: SolverContext, p: BiParamsBase, names: list[str], solver: str
               ) -> SolveResult:
    x = np.maximum(ctx.x0, 0.0)
    counters = Counters()
    lows = [with_current_blas_threads(ctx.low[k].matvec) for k in names]
    carried = _carried(ctx, solver)          # for the Mono-PQN model only (bi_level)
    products, stop = _product_rule(ctx, p, DIFFERENCE_TOL)
    low_points = None
    if isinstance(products, IterateProducts) and len(names) == 1:
        # the low's products of points too, where its accuracy is declared or it is a matrix
        low = ctx.low[names[0]]
        rtol = low.rtol if low.rtol is not None else (0.0 if low.explicit else None)
        if rtol is not None:
            within = with_current_blas_threads(low.product_within) if low.relaxable else None
            low_points = LowPoints(rtol, p.relax, within)
    floor = 0.1 * ctx.threshold
    from_low = p.start == "low"
    exact = with_current_blas_threads(stop.exact)
    with one_blas_thread():       # the solver's own small dense algebra; products keep theirs
        # Algorithm 3, line 1: the low-fidelity start (start=high: A x0 first)
        start = low_start(lows, x, ctx.b, p, counters, exact, floor, low_points=low_points) \
            if from_low else LowStart(x, exact(x))
        out, _ = bi_level(products, lows, start.x, start.g, stop, sys.maxsize, p, counters,
                          carry=start.carry, warm_start=not from_low, exact_gradient=exact,
                          recompute_every=RECOMPUTE_EVERY, floor=floor,
                          model_error=start.model_error, prev_residual=start.residual,
                          fallback_seed=carried, low_points=low_points)
    ctx.info.update(products.as_dict())
    ctx.info["rank"] = len(out.pairs)
    ctx.info["low"] = ",".join(names)
    return _finish(ctx, out, counters)


@register_solver("bi-pqn", BiPQNParams, multifidelity=LowOperators(one="low"))
def bi_pqn(ctx: SolverContext, p: BiPQNParams) -> SolveResult:
    """Bi-fidelity proximal quasi-Newton method (Algorithm 3 of the method paper).

    ``B^(0) = A_low`` (the operator named by ``low``); each outer iteration
    solves the paper's PQN subproblem (Section 5.2),
    ``min_{z>=0} 1/2 z'Bz + (A x + b - B x)'z``, by Mono-PQN with B-products (one
    low-fidelity MVP plus O(n r) each), warm-started at ``x`` where its gradient
    is the known ``A x + b``; the subproblem's secant pairs are carried to the
    next one with ``Y <- Y - (u u' - v v') S`` (appendix D.2, "Across
    Subproblem Secant Conditions"); the BFGS correction of ``B`` takes ``B s`` from the
    inner gradients (no extra low MVP); one high-fidelity MVP ``A p`` per outer
    iteration and the optimal over-relaxation of Algorithm 2. Start:
    the paper's low-fidelity initialisation (Mono-PQN on the low-fidelity
    problem from ``x^(-1) = x0``, no high-fidelity product before it), then
    the first high MVP at its answer ``x^(0)``, which also gives the free
    secant pair ``(x^(0), A x^(0))`` (the authors' code seeds its memory with
    it). lcpbench's additions, documented on the parameters: subproblem
    tolerances that follow the outer residual (``forcing``), and a model check
    from the high gradient each step already yields, which hands a useless low
    fidelity's solve to Mono-PQN (``model_tol``; ``info['decisions']``,
    ``info['model_errors']``, ``info['forcing']``). Robustness beyond the
    paper: if the model is not positive along ``p``, ``p`` does not descend,
    or the subproblem is unbounded (an indefinite ``A_low``), a Mono-PQN step on the high-fidelity pairs is taken
    instead (``info['mono_fallbacks']``). The paper's choices: full memory,
    BFGS updates stored unrolled.

    Secant memory, as for ``mono-pqn``: ``result.state`` holds the final
    high-fidelity pairs (Mono-PQN's, when the low model was abandoned), and
    ``state=`` starts the Mono-PQN model of the fallback steps and of an
    abandoned low model from the given pairs, at no cost. They stay out of
    the bi-fidelity model ``B``: pairs of a previous step's ``A`` would make
    it less accurate than a good ``A_low`` alone, and each would cost a
    low-fidelity product ``A_low s`` (docs/benchmarks.md, "Quasi-Newton memory
    across time steps").
    """
    return _run_chain(ctx, p, _low_names(ctx, (p.low,) if p.low else (), "bi-pqn"), "bi-pqn")


@register_solver("multi-pqn", MultiPQNParams, multifidelity=LowOperators(chain="lows"))
def multi_pqn(ctx: SolverContext, p: MultiPQNParams) -> SolveResult:
    """Multi-fidelity PQN: Bi-PQN whose subproblems are solved by Bi-PQN on a cheaper operator.

    An extension beyond the paper (its Section 7, "Conclusions and Future Work"): with
    ``lows = [L1, L2, ..., Lm]`` the outer level is Bi-PQN with ``B^(0) = L1``;
    its subproblem ``min 1/2 (z-x)'B(z-x) + g'(z-x)`` is solved by Bi-PQN with
    ``B'^(0) = L2``, and so on, the last level by Mono-PQN. Each level carries
    its subproblem pairs across calls with the correction of the level above.
    With one operator it is ``bi-pqn``.
    """
    return _run_chain(ctx, p, _low_names(ctx, p.lows, "multi-pqn"), "multi-pqn")
