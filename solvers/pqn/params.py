"""The parameters of ``mono-pqn``, ``bi-pqn`` and ``multi-pqn``, and the constants behind them.

A user tunes the model's memory and scaling, what the products are applied to, and for
Bi-PQN its start, its subproblems' accuracy and when it gives up on the low fidelity. The
other choices are constants below, each with the reason it is not a parameter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from lcpbench.core.specs import Bounds, CheckedParams

__all__ = ["ModelParams", "BiParamsBase", "MonoPQNParams", "BiPQNParams", "MultiPQNParams", "GAMMA", "PROX_TOL",
           "PROX_MAX_ITER", "RECOMPUTE_EVERY", "DIFFERENCE_TOL", "FORCING", "WARM_MAX_ITER"]

#: Damping of the BB2 scaling ``D = I / (GAMMA tau_BB2)``: the authors' code's value; no
#: shipped sweep, benchmark or test ever set another.
GAMMA = 0.8
#: Tolerance of the semi-smooth Newton root solve of the weighted prox (Algorithm 4 of the
#: method paper, on the root problem of Proposition 1): the root of a piecewise linear
#: function, found to rounding in a few Newton steps, so no looser value saves work.
PROX_TOL = 1e-12
#: Newton steps of the weighted prox before it falls back to an accelerated projected
#: gradient solve in the metric (``info['prox_fallbacks']``); the shipped sets need at most
#: a dozen, so the cap only guards against a breakdown.
PROX_MAX_ITER = 100
#: Iterations between exact gradients ``A x + b`` (one extra MVP) against the drift of the
#: recurrence ``A x+ = A x + eta A p`` (Remark 2 of the paper): far beyond the paper's
#: ten-odd iterations, so the extra MVP appears only on hard problems. Bi-PQN's outer
#: iteration converges in a few steps and uses it as is; ``mono-pqn`` exposes it.
RECOMPUTE_EVERY = 50
#: ``products=iterate``: the largest bound on the relative error of ``A p`` formed by
#: difference (:class:`~lcpbench.solvers.pqn.products.IterateProducts`). The difference's
#: error moves only the step length and the secant pair, never the gradient, and the bound
#: is a worst case: on a 27-sphere lattice at p = 6 a limit of 0.1 switched to products of
#: directions two products before convergence (143 inner applications against 127 with 0.5
#: or 0.9, the same MVPs). ``mono-pqn`` exposes it; Bi-PQN's low products use it too.
DIFFERENCE_TOL = 0.5
#: Safety factor of Bi-PQN's forcing term ``eta = min(inner_rtol, FORCING rate)``
#: (Eisenstat and Walker's choice; :func:`~lcpbench.solvers.pqn.bi.forcing_term`):
#: ``inner_rtol`` caps it, so a user who wants tighter subproblems sets that.
FORCING = 0.5
#: Iteration cap of Bi-PQN's low-fidelity start: it stops at ``warm_rtol`` long before
#: (the shipped sets take at most about 15 iterations); the cap only bounds a breakdown.
WARM_MAX_ITER = 50


@dataclass(frozen=True)
class ModelParams(CheckedParams):
    """The quasi-Newton model and the products (shared by every PQN solver).

    Parameters
    ----------
    memory : int
        Secant pairs kept in the BFGS model ``B = D + U U' - V V'`` (0: all, up
        to the iteration cap and at most n, the oldest dropped beyond n; the
        paper uses full memory since it converges in about ten iterations).
        For Bi-PQN: the high-fidelity pairs of ``B = A_low + U U' - V V'`` and of
        the Mono-PQN fallback model.
    scaling : str
        ``bb`` (default): ``D = I / (gamma tau_BB2)`` from the newest pair with
        ``gamma = 0.8``, as the authors' code does; ``identity``: ``D = I`` as written in
        Algorithm 1 of the method paper. ``bb`` needs fewer MVPs on every family we
        measured (docs/benchmarks.md).
    products : str
        What the high-fidelity product of an iteration is applied to. ``paper``
        (default): the direction, ``A p``, as in the paper. ``iterate``: the new
        point ``x^ = x + p``, with ``A p = A x^ - A x`` by difference
        (:class:`~lcpbench.solvers.pqn.products.IterateProducts`): an operator that
        recycles Krylov directions solves products of converging inputs in few new
        directions, and a new direction ``p`` in nearly the cold number
        (docs/benchmarks.md, "Products of the iterate"). Falls back to ``paper``
        products once the difference is too inaccurate, and every convergence claim
        is then confirmed by a counted product.
    relax : float
        ``products=iterate`` with an operator that makes products to a requested
        accuracy (:meth:`lcpbench.core.operator.Operator.product_within`; the
        boundary-integral contact operator stops its Krylov solve earlier): the
        product of a point may carry an error up to ``relax`` times the current
        natural residual (:class:`~lcpbench.solvers.pqn.products.IterateProducts`,
        where the accuracy argument is). 0 (default): every product at the
        operator's full accuracy, the paper's. Claims are confirmed at full accuracy
        either way.
    """

    memory: Annotated[int, Bounds(ge=0)] = 0              # 0 keeps every pair
    scaling: Literal["bb", "identity"] = "bb"
    products: Literal["paper", "iterate"] = "paper"
    relax: Annotated[float, Bounds(ge=0, lt=1)] = 0.0


@dataclass(frozen=True)
class MonoPQNParams(ModelParams):
    """Parameters of mono-pqn.

    Parameters
    ----------
    recompute_every : int
        Recompute ``A x`` exactly (one extra MVP) every this many iterations to
        bound the drift of the recurrence ``A x+ = A x + eta A p``; 0 never.
        Default 50: far beyond the paper's ten-odd iterations, so the extra MVP
        appears only on hard problems.
    free_pair : bool
        With a nonzero warm start ``x0``, seed the BFGS memory with the free
        secant pair ``(x0 - 0, A x0 - A 0)``: ``A x0`` is known from the first
        gradient and ``A 0 = 0`` (as the authors' code does).
    difference_tol : float
        ``products=iterate``: largest bound on the relative error of ``A p`` formed
        by difference, ``(rtol ||A x^|| + e_x) / ||A p||`` with ``rtol`` the
        operator's accuracy; products of ``p`` from the iteration after the bound
        passes a tenth of it. Default 0.5 (:data:`DIFFERENCE_TOL`, where the
        measurement behind it is).
    """

    recompute_every: Annotated[int, Bounds(ge=0)] = RECOMPUTE_EVERY   # 0 never recomputes
    free_pair: bool = True
    difference_tol: Annotated[float, Bounds(gt=0, lt=1)] = DIFFERENCE_TOL


@dataclass(frozen=True)
class BiParamsBase(ModelParams):
    """The choices of a Bi-PQN solve (``bi-pqn`` and ``multi-pqn``).

    Parameters
    ----------
    start : str
        ``low`` (default, the first line of Algorithm 3 of the method paper): solve
        the low-fidelity LCP from ``x0`` first, with no high-fidelity product, then
        take the first high MVP at its answer, which also gives a free secant pair
        and the first model check. ``high``: ``A x0`` first and a first subproblem
        solved to ``warm_rtol``. Pairs carried in with ``state=`` seed only the
        Mono-PQN model of fallback steps.
    warm_rtol : float
        Relative tolerance of the low-fidelity start (``start=low``: of the
        low-fidelity LCP's residual at ``x0``; ``start=high``: of the first
        subproblem). Before the first high product nothing measures the
        model, so the start cannot follow it; the forcing term takes over at
        the first outer step, whose tolerance the start's model check sets
        (a tighter ``warm_rtol`` pays off only for a very accurate low:
        docs/benchmarks.md, "PQN defaults: the measurements behind them").
    inner_rtol : float
        Largest relative tolerance of a subproblem: it is solved until its
        residual ``||min(z, B(z - x) + g)||`` falls below ``eta`` times its value
        at ``z = x`` (the outer residual), ``eta = min(inner_rtol, 0.5 rate)``,
        ``rate`` the smaller of the model's measured error and the last ratio of
        outer residuals (an Eisenstat-Walker forcing term,
        :func:`~lcpbench.solvers.pqn.bi.forcing_term`). An accurate model is so
        solved to its accuracy, a poor one is not over-solved.
    inner_max_iter : int
        Inner iteration cap per subproblem.
    inner_memory : int
        Low-fidelity pairs carried across subproblems (0: all).
    model_tol : float
        When to give up on the low fidelity, by the model check: after every high
        MVP the high gradient is known, and ``||(A - B) p|| / ||A p||``
        (``info['model_errors']``) says how well the model predicted it. Above
        ``model_tol`` the low fidelity is judged useless and the solve finishes as
        Mono-PQN on the high-fidelity pairs gathered so far
        (``info['abandoned_low']``; ``info['decisions']`` lists every step's
        choice), so a useless ``A_low`` costs about its start. Default 0.5:
        between what the shipped useful lows measure and what useless ones do
        (docs/benchmarks.md, "PQN defaults: the measurements behind them").
    max_fallbacks : int
        When to give up on the low fidelity, by its steps: after this many
        consecutive Mono-PQN fallbacks (a subproblem answer that does not descend)
        the low-fidelity model is abandoned likewise; 0 never abandons it on that
        ground.
    """

    start: Literal["low", "high"] = "low"
    warm_rtol: Annotated[float, Bounds(gt=0, lt=1)] = 0.1
    inner_rtol: Annotated[float, Bounds(gt=0, lt=1)] = 0.1
    inner_max_iter: Annotated[int, Bounds(ge=1)] = 20
    inner_memory: Annotated[int, Bounds(ge=0)] = 0        # 0 keeps every pair
    model_tol: Annotated[float, Bounds(gt=0, finite=False)] = 0.5   # inf: never judge
    max_fallbacks: Annotated[int, Bounds(ge=0)] = 3       # 0: never abandon the low model


@dataclass(frozen=True)
class BiPQNParams(BiParamsBase):
    """Parameters of bi-pqn.

    Parameters
    ----------
    low : str
        Name of the low-fidelity operator in the LCP's ``low`` (empty: the only one).
    """

    low: str = ""


@dataclass(frozen=True)
class MultiPQNParams(BiParamsBase):
    """Parameters of multi-pqn: ``lows`` names the chain (the others as for bi-pqn).

    Parameters
    ----------
    lows : list of str
        Low-fidelity operators from the most to the least accurate, e.g.
        ``lows=[p6,p4,p3]`` (empty: every low operator of the LCP, ordered by
        decreasing cost).

    Notes
    -----
    multi-pqn's ``start`` defaults to ``high``: solving the first low problem
    through the whole chain cost more than it saved on the shipped sets
    (docs/benchmarks.md, "PQN defaults: the measurements behind them"). Levels
    below the top solve their subproblems to the fixed ``inner_rtol``: the
    forcing term follows the high-fidelity residual, which only the top level sees.
    """

    lows: tuple[str, ...] = ()
    start: Literal["low", "high"] = "high"
