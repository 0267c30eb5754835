"""Bi-PQN: Algorithm 3 of the method paper, and its multi-fidelity chain.

:func:`bi_level` is the outer loop of Algorithm 3; its PQN subproblem is solved by the
next level down, :func:`lcpbench.solvers.pqn.mono.mono_level` for Bi-PQN and another
:func:`bi_level` for the multi-fidelity chain. :func:`low_start` is the paper's
low-fidelity initialisation (the first line of Algorithm 3). The secant pairs carried
across subproblems follow appendix D.2 of the paper ("Across Subproblem Secant
Conditions"), the high-fidelity model's update appendix D.1.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from lcpbench.core.residuals import kkt_abs
from lcpbench.toolkit.quasinewton import DiagonalBFGS, OperatorBFGS, Pairs, Rank2

from .mono import level_model, mono_level, optimal_step, pqn_direction
from .params import DIFFERENCE_TOL, FORCING, GAMMA, WARM_MAX_ITER, BiParamsBase
from .products import DirectionProducts, IterateProducts, LowPoints, ProductRule
from .state import BiCarry, Counters, Decision, LevelResult, Outcome

__all__ = ["bi_level", "low_start", "LowStart", "model_check", "forcing_term"]

Stop = Callable[[np.ndarray, np.ndarray], bool]
Inner = Union[Pairs, BiCarry, None]


def model_check(Qp: np.ndarray, Bp: np.ndarray) -> float:
    """Relative error ``||(Q - B) p|| / ||Q p||`` of the model along the step just taken."""
    den = float(np.linalg.norm(Qp))
    return float(np.linalg.norm(Qp - Bp)) / den if den > 0 else 0.0


def forcing_term(rate: Optional[float], inner_rtol: float) -> float:
    """Relative tolerance of the next subproblem: ``min(inner_rtol, FORCING * rate)``.

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
        return inner_rtol
    return float(min(inner_rtol, FORCING * rate))


@dataclass
class _Bi:
    """The running state of one Bi-PQN level: its models, pairs and forcing history."""

    lows: list[Callable[[np.ndarray], np.ndarray]]
    opts: BiParamsBase
    counters: Counters
    diag: DiagonalBFGS                      # the Mono-PQN model of the fallback steps
    hi_pairs: Pairs                         # (S, Q S, lows[0] S)
    inner: Inner                            # the subproblem level's carried state
    model: Optional[OperatorBFGS] = None    # B = lows[0] + U U' - V V'
    rho: Optional[float] = None             # the last model check
    r_prev: Optional[float] = None          # the last outer residual
    first: bool = True                      # the next subproblem is the warm start
    streak: int = 0                         # consecutive fallbacks
    floor: float = 0.0
    adaptive: bool = True
    #: products=iterate with one low: the low's accuracy and loose products, ``lows[0] x``
    #: at the outer iterate, its error bound, and that of the last subproblem's ``lows[0] z``
    low_points: Optional[LowPoints] = None
    low_x: Optional[np.ndarray] = None
    low_x_error: float = 0.0
    inner_error: Optional[float] = None

    @property
    def base(self) -> Callable[[np.ndarray], np.ndarray]:
        return self.lows[0]

    def carry(self) -> BiCarry:
        return BiCarry(self.hi_pairs, self.inner, self.model)


@dataclass
class _Direction:
    """The subproblem's answer: ``p`` (None: no descent direction), the model's ``B p``
    (None after a Mono-PQN fallback) and the subproblem level's state to carry."""

    p: Optional[np.ndarray]
    Bp: Optional[np.ndarray]
    inner: Inner


def bi_level(products: ProductRule, lows: list[Callable[[np.ndarray], np.ndarray]],
             z: np.ndarray, G: np.ndarray, stop: Stop, max_iter: int, opts: BiParamsBase,
             counters: Counters, *, carry: Optional[BiCarry] = None, warm_start: bool = True,
             exact_gradient: Optional[Callable[[np.ndarray], np.ndarray]] = None,
             recompute_every: int = 0, floor: float = 0.0,
             model_error: Optional[float] = None, prev_residual: Optional[float] = None,
             adaptive: bool = True, fallback_seed: Optional[Pairs] = None,
             low_points: Optional[LowPoints] = None) -> tuple[LevelResult, BiCarry]:
    """Algorithm 3 of the paper (Bi-PQN) with ``B^(0) = lows[0]``; deeper ``lows`` solve
    the subproblems.

    Each outer iteration solves the paper's PQN subproblem,
    ``min_{z>=0} 1/2 (z - x)' B (z - x) + g'(z - x)`` with ``B = lows[0] + U U' - V V'``,
    whose gradient ``B (z - x) + g`` is free at ``z = x``; every inner iteration costs
    one product with ``lows[0]`` plus ``O(n r)``. The inner level is Mono-PQN seeded
    with the carried low-fidelity pairs (or, for a longer chain, Bi-PQN with
    ``lows[1]``). ``B p`` comes from the inner gradients (``G_inner_end - g``), so the
    high-fidelity BFGS update needs no extra low-fidelity product. The carried pairs
    are corrected with ``Y <- Y - (u u' - v v') S`` (appendix D.2).

    lcpbench's additions, each a branch of the loop:

    * Inner accuracy: the subproblem is solved until its residual is below
      ``max(eta r, floor)``, ``r`` the outer residual at ``x`` and ``eta`` the forcing
      term of :func:`forcing_term` (``warm_rtol`` for the first with ``warm_start``).
    * Model check (no extra product): after each step the new high gradient
      ``g + eta A p`` is known, and the model predicted ``g + eta B p``;
      ``||(A - B) p|| / ||A p||`` (:func:`model_check`, ``counters.model_errors``)
      feeds the forcing term, and above ``model_tol`` the level finishes as Mono-PQN
      on the high pairs gathered so far, spending no more low products
      (:attr:`Decision.MONO_MODEL`).
    * Fallback: when the subproblem's answer ``p`` does not descend, the model is not
      positive along it, or the inner model is unbounded (an indefinite ``lows[0]``),
      a Mono-PQN step with the diagonal BFGS model of the high pairs is taken instead
      (``counters.mono_fallbacks``, :attr:`Decision.FALLBACK`); its ``lows[0] p``
      costs one extra low product so the model can still be updated. After
      ``max_fallbacks`` in a row the level finishes as Mono-PQN
      (:attr:`Decision.MONO_SUBPROBLEM`).

    ``fallback_seed``: older pairs of ``Q`` (e.g. a previous time step's, only
    approximately ``Q s``) that start the Mono-PQN model of the fallback steps and of
    an abandoned low model; they stay out of ``B``, which they would make less
    accurate than ``lows[0]`` alone for a good low fidelity, and where each would cost
    a product with ``lows[0]``. ``carry``: the state of a previous call or of
    :func:`low_start`. ``low_points``: the low fidelity's products are of points too
    (``products=iterate``, one low fidelity).

    Returns
    -------
    result : LevelResult
        With the high-fidelity pairs (``S``, ``Q S``, ``lows[0] S``), or Mono-PQN's
        after a handoff.
    carry : BiCarry
        To continue later.
    """
    n = z.shape[0]
    hi_pairs = carry.pairs if carry is not None and len(carry.pairs) else Pairs()
    diag = DiagonalBFGS(n, memory=opts.memory or None, scaling=opts.scaling, gamma=GAMMA)
    older = fallback_seed or Pairs()
    diag.set_pairs(list(older.S) + list(hi_pairs.S), list(older.Y) + list(hi_pairs.Y))
    st = _Bi(lows, opts, counters, diag, hi_pairs, carry.inner if carry is not None else None,
             rho=model_error, r_prev=prev_residual, first=warm_start, floor=floor,
             adaptive=adaptive)
    products.model_error(model_error)
    if low_points is not None and carry is not None and carry.low_x is not None:
        st.low_points, st.low_x, st.low_x_error = low_points, carry.low_x, carry.low_x_error

    def as_mono(z: np.ndarray, G: np.ndarray, it: int, checked: bool
                ) -> tuple[LevelResult, BiCarry]:
        """Finish as Mono-PQN on the high pairs gathered so far (the result carries
        Mono-PQN's final pairs, for a later solve's memory; the carry the Bi-PQN pairs)."""
        counters.abandoned_low = True
        model = level_model(n, opts.memory, opts.scaling,
                            Pairs(list(st.diag.S), list(st.diag.Y)))
        out = mono_level(products, z, G, stop, max_iter - it, model, counters,
                         exact_gradient=exact_gradient, recompute_every=recompute_every,
                         checked=checked)
        counters.mono_fallbacks += out.iterations
        return (LevelResult(out.z, out.G, out.outcome, it + out.iterations, out.pairs,
                            out.ray), st.carry())

    if model_error is not None and model_error > opts.model_tol:
        # judged useless before the first step: no low product to rebuild the model
        counters.decisions.append(Decision.MONO_MODEL)
        return as_mono(z, G, 0, checked=False)
    base = lows[0]
    st.hi_pairs = Pairs(list(hi_pairs.S), list(hi_pairs.Y), [
        b if b is not None else base(s) for s, b in zip(hi_pairs.S, hi_pairs.B0S)])
    st.model = _rebuild(base, n, st.hi_pairs)             # line 2: B = A_low (+ the pairs)
    if carry is not None and carry.model is not None:     # the inner pairs: B changed since
        st.inner = _carry(st.inner, _delta(carry.model, st.model), opts)
    it = 0
    while True:
        # line 4: the stopping test (the solver's stop rule), then the iteration cap
        if stop(z, G):
            return LevelResult(z, G, Outcome.STOP, it, st.hi_pairs), st.carry()
        if it >= max_iter:
            return LevelResult(z, G, Outcome.MAX_ITER, it, st.hi_pairs), st.carry()
        poor = st.rho is not None and st.rho > opts.model_tol
        if poor or (opts.max_fallbacks and st.streak >= opts.max_fallbacks):
            counters.decisions.append(Decision.MONO_MODEL if poor else Decision.MONO_SUBPROBLEM)
            return as_mono(z, G, it, checked=True)
        # lines 7-8: x^ from the PQN subproblem on B (low products only), p = x^ - x
        step = _subproblem(st, z, G)
        p = step.p
        if p is None:
            return LevelResult(z, G, Outcome.STATIONARY, it, st.hi_pairs), st.carry()
        # the iteration's one high-fidelity product, A p
        Ap, G_from = products.product(z, G, p)
        # lines 9-10: the optimal over-relaxation (Algorithm 2) and x + eta p
        z_new, G_new, eta = optimal_step(z, G_from, p, Ap)
        if z_new is None or G_new is None:
            return (LevelResult(z, G, Outcome.UNBOUNDED, it, st.hi_pairs, ray=(p, Ap)),
                    st.carry())
        products.stepped(eta)
        z, G = z_new, G_new
        it += 1
        # lines 11-13: the BFGS update of B with (eta p, eta A p), the carried low pairs
        # corrected for it (and the model check, the fallback model's update)
        _update_models(st, products, p, step.Bp, Ap, eta, step.inner)
        if exact_gradient is not None and recompute_every and it % recompute_every == 0:
            G = exact_gradient(z)
            counters.recomputes += 1
            products.restart()


def _subproblem(st: _Bi, z: np.ndarray, G: np.ndarray) -> _Direction:
    """Solve the PQN subproblem at ``z`` to the forcing term's accuracy; fall back if it fails."""
    opts, counters = st.opts, st.counters
    r0 = kkt_abs(z, G)
    if st.first:
        eta_f, cap = opts.warm_rtol, WARM_MAX_ITER
    else:
        rate = min(x for x in (st.rho, r0 / st.r_prev if st.r_prev else None, np.inf)
                   if x is not None)
        eta_f, cap = forcing_term(rate if st.adaptive else None, opts.inner_rtol), \
            opts.inner_max_iter
        counters.forcing.append(eta_f)
    st.first = False
    st.r_prev = r0
    tol_in = max(eta_f * r0, st.floor)
    base, model = st.base, st.model
    assert model is not None

    def B(v: np.ndarray) -> np.ndarray:
        return base(v) + model.correction(v)

    def inner_stop(zz: np.ndarray, GG: np.ndarray) -> bool:
        return kkt_abs(zz, GG) <= tol_in

    points = _low_points(st, B, model, z, G)
    with np.errstate(over="ignore", invalid="ignore"):
        inner, inner_new = _solve_sub(B, points, inner_stop, cap, st.lows, z, G, st.inner,
                                      opts=opts, counters=counters)
    counters.inner_iterations += inner.iterations
    if points is not None:
        counters.low_iterate_products += points.made
        counters.low_loose_products += len(points.loose)
        st.inner_error = points.error
    p = inner.z - z
    Bp = inner.G - G
    ok = inner.outcome is not Outcome.UNBOUNDED and inner.iterations > 0 and \
        bool(np.all(np.isfinite(inner.z))) and float(G @ p) < 0.0 and float(p @ Bp) > 0.0
    st.streak = 0 if ok else st.streak + 1
    if not ok:
        counters.mono_fallbacks += 1
        counters.decisions.append(Decision.FALLBACK)
        return _Direction(pqn_direction(st.diag, z, G, counters), None, inner_new)
    counters.decisions.append(Decision.MODEL)
    return _Direction(p, Bp, inner_new)


def _low_points(st: _Bi, B: Callable[[np.ndarray], np.ndarray], model: OperatorBFGS,
                x: np.ndarray, g: np.ndarray) -> Optional[IterateProducts]:
    """The subproblem's products of points (``products=iterate``, one low fidelity whose
    ``lows[0] x`` is tracked), else None.

    The subproblem's gradient is ``G = B (z - x) + g`` with ``B = L + C`` (``L = lows[0]``,
    ``C`` the exact low-rank correction), so ``L z = G - g + L x - C (z - x)`` is known at
    every inner iterate and ``B p = L (z + p) - L z + C p``."""
    if st.low_x is None or st.low_points is None:
        return None
    shift = st.low_x - g

    def known(zz: np.ndarray, GG: np.ndarray) -> np.ndarray:
        return GG + shift - model.correction(zz - x)

    lp = st.low_points
    sub = IterateProducts(B, None, lp.rtol, DIFFERENCE_TOL, base=st.base, known=known,
                          correction=model.correction, error=st.low_x_error, n=x.shape[0],
                          relax=lp.relax, within=lp.within)
    sub.model_error(st.rho)     # B p from the inner gradients feeds the outer model check
    return sub


def _update_models(st: _Bi, products: ProductRule, p: np.ndarray, Bp: Optional[np.ndarray],
                   Qp: np.ndarray, eta: float, inner_new: Inner) -> None:
    """After a step: the model check, the BFGS updates of ``B`` and of the fallback model,
    and the subproblem's pairs carried with ``Y <- Y + (B_new - B_old) S``."""
    opts, counters = st.opts, st.counters
    s, y = eta * p, eta * Qp
    old_model = st.model
    assert old_model is not None
    corr = old_model.correction(p)
    b0p = st.base(p) if Bp is None else Bp - corr
    Bs = eta * (b0p + corr)
    if st.low_x is not None:        # lows[0] x+ = lows[0] x + eta lows[0] p, and its error
        rtol = st.low_points.rtol if st.low_points is not None else 0.0
        if Bp is None or st.inner_error is None:
            st.low_x_error += eta * (rtol or 0.0) * float(np.linalg.norm(b0p))
        else:                       # (1 - eta) lows[0] x + eta lows[0] z_inner
            st.low_x_error = abs(1.0 - eta) * st.low_x_error + eta * st.inner_error
        st.low_x = st.low_x + eta * b0p
        st.inner_error = None
    # the model check: the new high gradient is known; how well did B predict it?
    st.rho = model_check(Qp, b0p + corr)
    counters.model_errors.append(st.rho)
    products.model_error(st.rho)
    model = _copy_model(old_model)
    uv = model.update(s, y, Bs)
    if uv is None:
        counters.skipped_pairs += 1
    else:
        st.hi_pairs.add(s, y, eta * b0p)
    st.diag.add_pair(s, y)
    delta: Optional[Callable[[np.ndarray], np.ndarray]] = None if uv is None else Rank2(*uv)
    if opts.memory and len(st.hi_pairs) > opts.memory:
        st.hi_pairs.trim(opts.memory)
        model = _rebuild(st.base, p.shape[0], st.hi_pairs)
        delta = _delta(old_model, model)
    st.model = model
    st.inner = _carry(inner_new, delta, opts)


@dataclass
class LowStart:
    """The answer of :func:`low_start`.

    Parameters
    ----------
    x, g : ndarray
        The start of the outer iteration and ``A x + b``.
    carry : BiCarry or None
        :func:`bi_level`'s carry: the free pair and the low solve's pairs (None when
        the low solve broke down; then ``x`` is the given start).
    model_error : float or None
        ``||(A - L) x|| / ||A x||``.
    residual : float or None
        The low problem's residual at the given start, the stand-in for the outer
        residual before the first high product (for the forcing term).
    """

    x: np.ndarray
    g: np.ndarray
    carry: Optional[BiCarry] = None
    model_error: Optional[float] = None
    residual: Optional[float] = None


def low_start(lows: list[Callable[[np.ndarray], np.ndarray]], z: np.ndarray, b: np.ndarray,
              opts: BiParamsBase, counters: Counters,
              exact_gradient: Callable[[np.ndarray], np.ndarray], floor: float, *,
              low_points: Optional[LowPoints] = None) -> LowStart:
    """The paper's initialisation (Algorithm 3, line 1): the low-fidelity LCP first.

    ``min_{z>=0} 1/2 z' L z + b'z`` with ``L = lows[0]`` is solved from ``z``
    (Mono-PQN, or Bi-PQN on ``lows[1:]`` for a chain) to ``warm_rtol`` times
    its residual at ``z``, with no high-fidelity product; its gradient at
    ``z`` costs one low product (none at ``z = 0``). Then the first
    high-fidelity MVP gives ``A z1`` at its answer ``z1``, which makes
    ``(z1 - 0, A z1 - A 0)`` a free secant pair (``L z1`` is known from the
    low solve's gradient) and measures the model's error along ``z1``
    (:func:`model_check`) before any outer step.
    """
    L = lows[0]
    Gl = L(z) + b
    r_low = kkt_abs(z, Gl)
    tol = max(opts.warm_rtol * r_low, floor)

    def stop(zz: np.ndarray, GG: np.ndarray) -> bool:
        return kkt_abs(zz, GG) <= tol

    sub = None
    if low_points is not None:
        sub = IterateProducts(L, b, low_points.rtol, DIFFERENCE_TOL, relax=low_points.relax,
                              within=low_points.within)
    with np.errstate(over="ignore", invalid="ignore"):
        out, inner = _solve_sub(L, sub, stop, WARM_MAX_ITER, lows, z, Gl, None, opts=opts,
                                counters=counters)
    counters.inner_iterations += out.iterations
    if out.outcome is Outcome.UNBOUNDED or not (np.all(np.isfinite(out.z))
                                                and np.all(np.isfinite(out.G))):
        counters.decisions.append(Decision.START_X0)
        return LowStart(z, exact_gradient(z))
    z1 = out.z
    G1 = exact_gradient(z1)
    Az, Lz = G1 - b, out.G - b
    rho = model_check(Az, Lz)
    counters.model_errors.append(rho)
    counters.decisions.append(Decision.START_LOW)
    carry = BiCarry(Pairs([z1], [Az], [Lz]) if np.any(z1) else Pairs(), inner,
                    OperatorBFGS(L, z.shape[0]))
    if sub is not None:             # L z1 for the subproblems' products of points
        counters.low_iterate_products += sub.made
        counters.low_loose_products += len(sub.loose)
        carry.low_x = Lz
        carry.low_x_error = sub.error if sub.error is not None else \
            sub.rtol * float(np.linalg.norm(Lz))
    return LowStart(z1, G1, carry, rho, r_low)


def _solve_sub(apply: Callable[[np.ndarray], np.ndarray], points: Optional[IterateProducts],
               stop: Stop, cap: int, lows: list[Callable[[np.ndarray], np.ndarray]],
               z: np.ndarray, G: np.ndarray, inner: Inner, *, opts: BiParamsBase,
               counters: Counters) -> tuple[LevelResult, Inner]:
    """The paper's PQN subproblem, solved by the next level down (Mono-PQN or Bi-PQN)."""
    rule: ProductRule = points if points is not None else DirectionProducts(apply)
    if len(lows) == 1:
        seed = inner if isinstance(inner, Pairs) else None
        model = level_model(z.shape[0], opts.inner_memory, opts.scaling, seed)
        out = mono_level(rule, z, G, stop, cap, model, counters)
        return out, out.pairs
    return bi_level(rule, lows[1:], z, G, stop, cap, opts, counters,
                    carry=inner if isinstance(inner, BiCarry) else None,
                    warm_start=False, adaptive=False)


def _rebuild(base: Callable[[np.ndarray], np.ndarray], n: int, pairs: Pairs) -> OperatorBFGS:
    """``B = base + U U' - V V'`` from pairs with cached base products (no product)."""
    model = OperatorBFGS(base, n)
    for s, y, b0s in zip(pairs.S, pairs.Y, pairs.B0S):
        model.update(s, y, b0s + model.correction(s))
    return model


def _copy_model(model: OperatorBFGS) -> OperatorBFGS:
    new = OperatorBFGS(model.apply_B0, model.n, model.curvature_tol)
    new.U, new.V, new.skipped = model.U, model.V, model.skipped
    return new


def _delta(old: OperatorBFGS, new: OperatorBFGS) -> Callable[[np.ndarray], np.ndarray]:
    """``v -> (B_new - B_old) v`` for two corrections of the same base (``O(n r)``)."""
    return lambda v: new.correction(v) - old.correction(v)


def _carry(inner: Inner, delta: Optional[Callable[[np.ndarray], np.ndarray]],
           opts: BiParamsBase) -> Inner:
    """Correct an inner level's pairs (and, down a chain, its own pairs) for a model change.

    ``delta`` None: the model did not change (a skipped update).
    """
    if isinstance(inner, Pairs):
        out = inner if delta is None else inner.corrected(delta)
        out.trim(opts.inner_memory)
        return out
    if isinstance(inner, BiCarry) and delta is not None:
        # the inner level's Hessian is this level's B: its high pairs see the change;
        # its base (a lower fidelity) and its own inner pairs are unaffected.
        return BiCarry(inner.pairs.corrected(delta), inner.inner, inner.model)
    return inner
