"""Mono-PQN: Algorithm 1 of the method paper, with its step size (Algorithm 2).

:func:`mono_level` minimises a quadratic over ``z >= 0`` given only

* a product rule for its Hessian ``Q`` (:mod:`lcpbench.solvers.pqn.products`: a counted
  MVP of some operator, or a low-fidelity product plus ``O(n r)`` low-rank corrections),
* a start ``z0`` and the gradient ``G0`` there.

The gradient is tracked by the recurrence ``G <- G + eta Q p``, so each iteration costs
exactly one product with ``Q`` (Remark 2 of the paper). The same loop solves the
high-fidelity problem (``mono-pqn``), Bi-PQN's subproblems and the low-fidelity start
(:mod:`lcpbench.solvers.pqn.bi`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Optional

import numpy as np

from lcpbench.toolkit.prox import compact_prox
from lcpbench.toolkit.quasinewton import DiagonalBFGS, ModelPairs, Pairs
from lcpbench.toolkit.steps import exact_step, feasible_step_bound

from .params import GAMMA, PROX_MAX_ITER, PROX_TOL
from .products import ProductRule
from .state import Counters, LevelResult, Outcome

__all__ = ["mono_level", "level_model", "pqn_direction", "optimal_step"]


def level_model(n: int, memory: int, scaling: str, seed: Optional[Pairs] = None
                ) -> DiagonalBFGS:
    """The BFGS model ``B = D + U U' - V V'`` a Mono-PQN loop starts from.

    ``memory`` pairs kept (0: all, at most ``n``); ``seed`` the pairs to start from.
    A seed that holds its model with that memory (a previous subproblem's, corrected
    for the change of ``B``) is continued, not rebuilt.
    """
    if seed is not None and seed.model is not None and seed.model.memory == (memory or max(n, 1)):
        model, seed.model = seed.model, None          # continue the handed-on model
        return model
    model = DiagonalBFGS(n, memory=memory or None, scaling=scaling, gamma=GAMMA)
    if seed is not None and len(seed):
        model.set_pairs(seed.S, seed.Y)
    return model


def pqn_direction(model: DiagonalBFGS, z: np.ndarray, G: np.ndarray, counters: Counters
                  ) -> Optional[np.ndarray]:
    """The Mono-PQN direction ``p = prox^B(z - H G) - z`` (Algorithm 1, lines 5-8).

    ``H G`` by the compact two-loop recursion, the weighted prox by Proposition 1 of the
    paper (semi-smooth Newton, Algorithm 4, on the root problem in ``2r`` unknowns;
    ``max(., 0)`` while ``r = 0``). Falls back to the projected-gradient direction with
    step ``1/d`` when the prox step does not descend (an inexact prox); returns None when
    no descent direction exists (``z`` is stationary).
    """
    d, W, P, N, gram = model.compact()
    shift = None
    if model.rank:
        # z - H G = (z - G/d) - W' c: the W' c part is formed inside the prox's first
        # sweep over the pairs, and W G was computed in the sweep that stored the last pair
        shift = -d * model.two_loop(model.products_with(G), d)
    zhat, info = compact_prox(z - G / d, d, W, P, N, gram, active=model.active, shift=shift,
                              tol=PROX_TOL, max_iter=PROX_MAX_ITER)
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
    """Algorithm 2 of the paper: ``eta* = min(eta', eta_hat)`` and the moved point.

    Returns ``(z + eta* p, G + eta* Q p, eta*)``, or ``(None, None, inf)`` when the
    quadratic is unbounded along ``p``. The blocking component(s) are set to exactly 0
    so round-off never leaves ``z`` slightly negative.
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


def mono_level(products: ProductRule, z: np.ndarray, G: np.ndarray,
               stop: Callable[[np.ndarray, np.ndarray], bool], max_iter: int,
               model: DiagonalBFGS, counters: Counters, *,
               exact_gradient: Optional[Callable[[np.ndarray], np.ndarray]] = None,
               recompute_every: int = 0, checked: bool = False) -> LevelResult:
    """Algorithm 1 of the paper (Mono-PQN) on ``min_{z>=0} q(z)``, ``Q`` the Hessian of ``q``.

    Parameters
    ----------
    products : ProductRule
        Makes the iteration's one product ``Q p``.
    z, G : ndarray
        Start and the gradient of ``q`` there (not recomputed: free).
    stop : callable
        ``stop(z, G) -> bool``, tested before every iteration (for the top level the
        solver context's report, which applies the stop rule).
    max_iter : int
        Iteration cap of this loop.
    model : DiagonalBFGS
        The quasi-Newton model, updated in place (:func:`level_model`).
    exact_gradient : callable, optional
        ``z -> Q z + c`` (one product); used every ``recompute_every`` iterations to
        reset the recurrence's drift (Remark 2: "or with periodic recomputation").
    checked : bool
        The caller has already tested ``stop`` at the start point (skip it once: a
        second report of the same iterate would look like stagnation).
    """
    it = 0
    while True:
        # line 4: the stopping test (the solver's stop rule), then the iteration cap
        if not checked and stop(z, G):
            return LevelResult(z, G, Outcome.STOP, it, ModelPairs(model))
        checked = False
        if it >= max_iter:
            return LevelResult(z, G, Outcome.MAX_ITER, it, ModelPairs(model))
        # lines 5-8: x~ = z - H G, x^ = prox^B(x~), p = x^ - z
        p = pqn_direction(model, z, G, counters)
        if p is None:
            return LevelResult(z, G, Outcome.STATIONARY, it, ModelPairs(model))
        # the iteration's one product, Q p (cached for the step and the update)
        Qp, G_from = products.product(z, G, p)
        # lines 9-10: the optimal over-relaxation (Algorithm 2) and z + eta p
        z_new, G_new, eta = optimal_step(z, G_from, p, Qp)
        if z_new is None or G_new is None:
            return LevelResult(z, G, Outcome.UNBOUNDED, it, ModelPairs(model), ray=(p, Qp))
        products.stepped(eta)
        z, G = z_new, G_new
        it += 1
        # line 11: the BFGS update with (eta p, eta Q p); pairs with s'y <= 0 skipped
        if not model.add_pair(eta * p, eta * Qp, G):
            counters.skipped_pairs += 1
        if exact_gradient is not None and recompute_every and it % recompute_every == 0:
            G = exact_gradient(z)
            counters.recomputes += 1
            products.restart()
