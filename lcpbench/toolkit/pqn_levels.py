"""The iteration machinery of the PQN solvers at one fidelity level.

A *level* minimises a convex (or, for a poor low-fidelity model, possibly
non-convex) quadratic over ``z >= 0`` given only

* ``apply(v)``: the product with its Hessian ``Q`` (a counted MVP of some
  operator, or a low-fidelity product plus ``O(n r)`` low-rank corrections),
* a start ``z0`` and the gradient ``G0`` there.

The gradient is tracked by the recurrence ``G <- G + eta Q p`` so each
iteration costs exactly one product with ``Q`` (section "Mono-PQN Step Size
Selection", remark "Computing eta* requires no extra MVPs").

* :func:`mono_level` is the paper's Mono-PQN algorithm on that quadratic.
* :func:`iterate_level` is the loop every level runs (Mono-PQN here, Bi-PQN in
  :mod:`lcpbench.toolkit.pqn_bilevel`), given its direction and model update.

Levels exchange secant pairs as :class:`Pairs` (``S``, ``Y = Q S`` and, when
the receiving level has an operator base ``B0``, the cached ``B0 S``), so
no product is ever repeated to rebuild a model.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Literal, Optional

import numpy as np

from lcpbench.core.specs import Bounds, CheckedParams
from lcpbench.toolkit.pqn_products import IterateProducts
from lcpbench.toolkit.prox import compact_prox
from lcpbench.toolkit.quasinewton import DiagonalBFGS, ModelPairs, Pairs, Rank2
from lcpbench.toolkit.steps import exact_step, feasible_step_bound

__all__ = ["Pairs", "Rank2", "MonoOptions", "BiOptions", "LevelOutcome", "Counters", "LevelTask",
           "IterateProducts", "HANDOFF", "mono_level", "iterate_level", "pqn_direction", "optimal_step",
           "model_check", "forcing_term"]


@dataclass(frozen=True)
class MonoOptions(CheckedParams):
    """Choices of a Mono-PQN level (the parameters of ``mono-pqn``).

    Parameters
    ----------
    memory : int
        Secant pairs kept in the BFGS model ``B = D + U U' - V V'`` (0: all, up
        to the iteration cap and at most n, the oldest dropped beyond n; the
        paper uses full memory since it converges in about ten iterations).
    scaling : str
        ``bb`` (default): ``D = I / (gamma tau_BB2)`` from the newest pair, as the
        authors' code does; ``identity``: ``D = I`` as written in the paper's Mono-PQN algorithm.
        ``bb`` needs fewer MVPs on every family we measured (docs/benchmarks.md).
    gamma : float
        Damping of the BB2 scaling (authors' value 0.8).
    prox_tol : float
        Tolerance of the semi-smooth Newton root solve of the weighted prox (the
        paper's proposition on the weighted non-negative prox).
    prox_max_iter : int
        Newton iterations before the weighted prox falls back to an accelerated
        projected gradient solve in the metric (reported as ``prox_fallbacks``).
    recompute_every : int
        Recompute ``A x`` exactly (one extra MVP) every this many iterations to
        bound the drift of the recurrence ``A x+ = A x + eta A p``; 0 never.
        Default 50: far beyond the paper's ten-odd iterations, so the extra MVP
        appears only on hard problems.
    free_pair : bool
        With a nonzero warm start ``x0``, seed the BFGS memory with the free
        secant pair ``(x0 - 0, A x0 - A 0)``: ``A x0`` is known from the first
        gradient and ``A 0 = 0`` (as the authors' code does).
    products : str
        What the high-fidelity product of an iteration is applied to. ``paper``
        (default): the direction, ``A p``, as in the paper. ``iterate``: the new
        point ``x^ = x + p``, with ``A p = A x^ - A x`` by difference
        (:class:`IterateProducts`): an operator that recycles Krylov directions
        solves products of converging inputs in few new directions, and a new
        direction ``p`` in nearly the cold number (docs/benchmarks.md, "Products of
        the iterate"). Falls back to ``paper`` products once the difference is
        too inaccurate (``difference_tol``), and every convergence claim is then
        confirmed by a counted product.
    difference_tol : float
        ``products=iterate``: largest bound on the relative error of ``A p`` formed
        by difference, ``(rtol ||A x^|| + e_x) / ||A p||`` with ``rtol`` the
        operator's accuracy (:class:`IterateProducts`); products of ``p`` from the
        iteration after the bound passes a tenth of it. Default 0.5: the
        difference's error moves only the step length and the secant pair, never
        the gradient (which stays as accurate as a product of the iterate), and the
        bound is a worst case; on a 27-sphere lattice at p = 6 a limit of 0.1 switched
        to directions two products before convergence (143 inner applications
        against 127 with 0.5 or 0.9, the same MVPs).
    relax : float
        ``products=iterate`` with an operator that makes products to a requested
        accuracy (:meth:`lcpbench.core.operator.Operator.product_within`; the
        boundary-integral contact operator stops its Krylov solve earlier): the
        product of a point may carry an error up to ``relax`` times the current
        natural residual (:class:`IterateProducts`, where the accuracy argument is).
        0 (default): every product at the operator's full accuracy, the paper's. Claims
        are confirmed at full accuracy either way.
    """

    memory: Annotated[int, Bounds(ge=0)] = 0              # 0 keeps every pair
    scaling: Literal["bb", "identity"] = "bb"
    gamma: Annotated[float, Bounds(gt=0, le=1)] = 0.8
    prox_tol: Annotated[float, Bounds(gt=0)] = 1e-12
    prox_max_iter: Annotated[int, Bounds(ge=1)] = 100
    recompute_every: Annotated[int, Bounds(ge=0)] = 50   # 0 never recomputes
    free_pair: bool = True
    products: Literal["paper", "iterate"] = "paper"
    difference_tol: Annotated[float, Bounds(gt=0, lt=1)] = 0.5
    relax: Annotated[float, Bounds(ge=0, lt=1)] = 0.0


@dataclass(frozen=True)
class BiOptions(MonoOptions):
    """Choices of a Bi-PQN level (the parameters of ``bi-pqn`` and ``multi-pqn``); memory,
    scaling and gamma of :class:`MonoOptions` also set the fallback model.

    Parameters
    ----------
    start : str
        ``low`` (default, the paper's Bi-PQN algorithm): solve the low-fidelity LCP
        from ``x0`` first, with no high-fidelity product, then take the first
        high MVP at its answer, which also gives a free secant pair and the
        first model check. ``high``: the previous start, ``A x0`` first and a
        first subproblem solved to ``warm_rtol``. Pairs carried in with
        ``state=`` seed only the Mono-PQN model of fallback steps.
    inner_rtol : float
        Largest relative tolerance of a subproblem: it is solved until its
        residual ``||min(z, B(z - x) + g)||`` falls below ``eta`` times its value
        at ``z = x`` (the outer residual), ``eta = min(inner_rtol, forcing *
        rate)``, ``rate`` the smaller of the model's measured error and the last
        ratio of outer residuals (an Eisenstat-Walker forcing term; see
        ``lcpbench.toolkit.pqn_levels.forcing_term``). An accurate model is so
        solved to its accuracy, a poor one is not over-solved.
    forcing : float
        Safety factor of the forcing term (default 0.5).
    inner_max_iter : int
        Inner iteration cap per subproblem.
    inner_memory : int
        Low-fidelity pairs carried across subproblems (0: all).
    warm_rtol : float
        Relative tolerance of the low-fidelity start (``start=low``: of the
        low-fidelity LCP's residual at ``x0``; ``start=high``: of the first
        subproblem). Before the first high product nothing measures the
        model, so the start cannot follow it; the forcing term takes over at
        the first outer step, whose tolerance the start's model check sets
        (a tighter ``warm_rtol`` pays off only for a very accurate low:
        docs/benchmarks.md, "PQN defaults: the measurements behind them").
    warm_max_iter : int
        Iteration cap of the low-fidelity start.
    model_tol : float
        The model check: after every high MVP the high gradient is known, and
        ``||(A - B) p|| / ||A p||`` (``info['model_errors']``) says how well the
        model predicted it. Above ``model_tol`` the low fidelity is judged
        useless and the solve finishes as Mono-PQN on the high-fidelity pairs
        gathered so far (``info['abandoned_low']``; ``info['decisions']`` lists
        every step's choice), so a useless ``A_low`` costs about its start.
        Default 0.5: between what the shipped useful lows measure and what
        useless ones do (docs/benchmarks.md, "PQN defaults: the measurements
        behind them").
    max_fallbacks : int
        After this many consecutive Mono-PQN fallbacks (a subproblem answer
        that does not descend) the low-fidelity model is abandoned likewise;
        0 never abandons it on that ground.
    """

    start: Literal["low", "high"] = "low"
    inner_rtol: Annotated[float, Bounds(gt=0, lt=1)] = 0.1
    forcing: Annotated[float, Bounds(gt=0, le=1)] = 0.5
    inner_max_iter: Annotated[int, Bounds(ge=1)] = 20
    inner_memory: Annotated[int, Bounds(ge=0)] = 0        # 0 keeps every pair
    warm_rtol: Annotated[float, Bounds(gt=0, lt=1)] = 0.1
    warm_max_iter: Annotated[int, Bounds(ge=1)] = 50
    model_tol: Annotated[float, Bounds(gt=0, finite=False)] = 0.5   # inf: never judge
    max_fallbacks: Annotated[int, Bounds(ge=0)] = 3       # 0: never abandon the low model


@dataclass
class Counters:
    """Per-solve counters, copied into ``SolveResult.info``."""

    prox_newton_iters: int = 0
    prox_damped: int = 0
    prox_fallbacks: int = 0
    gradient_fallbacks: int = 0
    mono_fallbacks: int = 0
    recomputes: int = 0
    inner_iterations: int = 0
    low_iterate_products: int = 0     # products=iterate: low products of points
    low_loose_products: int = 0       # relax > 0: low products made to a looser accuracy
    skipped_pairs: int = 0
    abandoned_low: bool = False
    model_errors: list = field(default_factory=list)
    forcing: list = field(default_factory=list)
    decisions: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, list) else v) for k, v in self.__dict__.items()}


@dataclass
class LevelOutcome:
    """How a level ended: ``stop`` (its stop test held), ``max_iter``,
    ``unbounded`` (negative curvature with no blocking constraint: the model
    is not bounded below, so the answer is the last point), or ``stationary``
    (no descent direction exists: the projected gradient vanishes)."""

    z: np.ndarray
    G: np.ndarray
    reason: str
    iterations: int
    pairs: Pairs
    #: For ``unbounded``: the direction ``p`` and its product ``Q p`` (the evidence a
    #: solver offers the framework, which checks every ``infeasible`` claim).
    ray: Optional[tuple] = None


def pqn_direction(model: DiagonalBFGS, z: np.ndarray, G: np.ndarray, opts: MonoOptions,
                  counters: Counters) -> Optional[np.ndarray]:
    """The Mono-PQN direction ``p = prox^B(z - H G) - z`` (the paper's PQN step).

    Falls back to the projected-gradient direction with step ``1/d`` when the
    prox step does not descend (an inexact prox); returns None when no descent
    direction exists (``z`` is stationary).
    """
    d, W, P, N, gram = model.compact()
    shift = None
    if model.rank:
        # z - H G = (z - G/d) - W' c: the W' c part is formed inside the prox's first
        # sweep over the pairs, and W G was computed in the sweep that stored the last pair
        shift = -d * model.two_loop(model.products_with(G), d)
    zhat, info = compact_prox(z - G / d, d, W, P, N, gram, active=model.active, shift=shift,
                              tol=opts.prox_tol, max_iter=opts.prox_max_iter)
    counters.prox_newton_iters += info.newton_iters
    counters.prox_damped += info.damped
    counters.prox_fallbacks += int(info.fallback)
    p = zhat - z
    if float(G @ p) < 0.0:
        return p
    counters.gradient_fallbacks += 1
    p = np.maximum(z - G / d, 0.0) - z
    return p if float(G @ p) < 0.0 else None


def optimal_step(z: np.ndarray, G: np.ndarray, p: np.ndarray, Qp: np.ndarray
          ) -> tuple[Optional[np.ndarray], Optional[np.ndarray], float]:
    """Algorithm stepSize: ``eta* = min(eta', eta_hat)`` and the moved point.

    Returns ``(None, None, inf)`` when the quadratic is unbounded along ``p``.
    The blocking component(s) are set to exactly 0 so round-off never leaves
    ``z`` slightly negative.
    """
    eta_u = exact_step(G, p, Qp)
    eta_b = feasible_step_bound(z, p)
    eta = min(eta_u, eta_b)
    if not np.isfinite(eta):
        return None, None, eta
    z_new = z + eta * p
    if eta_b <= eta_u:
        neg = p < 0
        block = np.zeros_like(neg)
        block[neg] = -z[neg] / p[neg] <= eta_b * (1 + 1e-14)
        z_new[block] = 0.0
    np.maximum(z_new, 0.0, out=z_new)
    return z_new, G + eta * Qp, eta


def _step_along(task: LevelTask, z: np.ndarray, G: np.ndarray, p: Optional[np.ndarray]):
    """One product ``Q p`` and the step of :func:`optimal_step` along ``p``.

    Returns ``((Qp, z_new, G_new, eta), "", None)``, or None with the reason the
    level ends there: ``stationary`` (no direction ``p``) or ``unbounded`` with
    the ray ``(p, Qp)``.
    """
    if p is None:
        return None, "stationary", None
    Qp = task.apply(p) if task.products is None else task.products(task.apply, z, G, p)
    if task.products is not None and task.products.fresh is not None:
        G, task.products.fresh = task.products.fresh, None     # A x refreshed (loose products)
    z_new, G_new, eta = optimal_step(z, G, p, Qp)
    if z_new is None:
        return None, "unbounded", (p, Qp)
    if task.products is not None:
        task.products.stepped(eta)
    return (Qp, z_new, G_new, eta), "", None


def mono_level(apply: Callable[[np.ndarray], np.ndarray], z: np.ndarray, G: np.ndarray,
               stop: Callable[[np.ndarray, np.ndarray], bool], max_iter: int,
               opts: BiOptions, counters: Counters, *, seed: Optional[Pairs] = None,
               memory: Optional[int] = None,
               exact_gradient: Optional[Callable[[np.ndarray], np.ndarray]] = None,
               checked: bool = False, products: Optional[IterateProducts] = None
               ) -> LevelOutcome:
    """Algorithm pqn (Mono-PQN) on ``min_{z>=0} q(z)`` with Hessian product ``apply``.

    Parameters
    ----------
    apply : callable
        ``Q v``; called exactly once per iteration (``Q p``).
    z, G : ndarray
        Start and the gradient of ``q`` there (not recomputed: free).
    stop : callable
        ``stop(z, G) -> bool``, tested before every iteration (for the top
        level this is the solver context's monitor).
    max_iter : int
        Iteration cap of this level.
    seed : Pairs, optional
        Secant pairs of ``Q`` to start the BFGS model from.
    memory : int, optional
        Pairs kept (0 = all); defaults to ``opts.memory``.
    exact_gradient : callable, optional
        ``z -> Q z + c`` (one product); used every ``opts.recompute_every``
        iterations to reset the recurrence's drift.
    checked : bool
        The caller has already tested ``stop`` at the start point (skip it once:
        a second report of the same iterate would look like stagnation).
    products : IterateProducts, optional
        Apply ``apply`` to the new point instead of the direction (top level only).
    """
    mem = opts.memory if memory is None else memory
    if seed is not None and seed.model is not None and \
            seed.model.memory == (mem or max(z.shape[0], 1)):
        model, seed.model = seed.model, None          # continue the handed-on model
    else:
        model = DiagonalBFGS(z.shape[0], memory=mem or None, scaling=opts.scaling,
                             gamma=opts.gamma)
        if seed is not None and len(seed):
            model.set_pairs(seed.S, seed.Y)
    task = LevelTask(apply, stop, max_iter, opts, counters, exact_gradient, products)

    def update(p: np.ndarray, Qp: np.ndarray, eta: float, G: np.ndarray) -> None:
        if not model.add_pair(eta * p, eta * Qp, G):
            counters.skipped_pairs += 1

    z, G, reason, it, ray = iterate_level(task, z, G, lambda zz, GG: pqn_direction(
        model, zz, GG, opts, counters), update, checked=checked)
    return LevelOutcome(z, G, reason, it, ModelPairs(model), ray)


HANDOFF = "handoff"     # a direction rule's answer: finish the level as Mono-PQN


def iterate_level(task: LevelTask, z: np.ndarray, G: np.ndarray, direction: Callable,
             update: Callable, checked: bool = False):
    """The loop every level runs: stop test, cap, ``direction(z, G)``, one product, step,
    ``update(p, Qp, eta, G)`` (``G`` the new gradient), and the periodic exact gradient
    against the recurrence's drift.

    ``direction`` returns the search direction, None (no descent direction:
    ``stationary``) or ``HANDOFF`` (the caller finishes otherwise). Returns
    ``(z, G, reason, iterations, ray)``.
    """
    opts, it = task.opts, 0
    reason, ray = "max_iter", None
    while True:
        if not checked and task.stop(z, G):
            reason = "stop"
            break
        checked = False
        if it >= task.max_iter:
            break
        p = direction(z, G)
        if isinstance(p, str):
            reason = p
            break
        step, end, ray = _step_along(task, z, G, p)
        if step is None:
            reason = end
            break
        Qp, z, G, eta = step
        it += 1
        update(p, Qp, eta, G)
        if task.exact_gradient is not None and opts.recompute_every and \
                it % opts.recompute_every == 0:
            G = task.exact_gradient(z)
            task.counters.recomputes += 1
            if task.products is not None:
                task.products.restart()
    return z, G, reason, it, ray


@dataclass
class LevelTask:
    """What a level is asked: minimise the quadratic with Hessian product ``apply``
    until ``stop(z, G)`` holds or ``max_iter`` iterations are spent."""

    apply: Callable
    stop: Callable
    max_iter: int
    opts: BiOptions
    counters: Counters
    exact_gradient: Optional[Callable] = None
    #: products of the new point (``products=iterate``, the top level only: it knows ``b``)
    products: Optional[IterateProducts] = None


def model_check(Qp: np.ndarray, Bp: np.ndarray) -> float:
    """Relative error ``||(Q - B) p|| / ||Q p||`` of the model along the step just taken."""
    den = float(np.linalg.norm(Qp))
    return float(np.linalg.norm(Qp - Bp)) / den if den > 0 else 0.0


def forcing_term(rate: Optional[float], opts: BiOptions) -> float:
    """Relative tolerance of the next subproblem: ``min(inner_rtol, forcing * rate)``.

    ``rate`` is the expected contraction of the outer residual: the smaller of
    the model's measured relative error (:func:`model_check`) and the last
    observed ratio of outer residuals. An inexact Newton method needs its
    inner residual only below a fraction of the outer residual it expects next
    (Eisenstat & Walker, SIAM J. Sci. Comput. 17 (1996): the forcing term
    follows how well the local model predicted the last step, their choice 1,
    or the observed rate, their choice 2); solving further buys no outer
    progress, since the model's own error then dominates the next residual,
    and solving less throws away the accuracy an accurate model offers.
    """
    if rate is None or not np.isfinite(rate):
        return opts.inner_rtol
    return float(min(opts.inner_rtol, opts.forcing * rate))
