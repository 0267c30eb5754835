"""The bi-fidelity PQN level (the paper's Bi-PQN algorithm) and its multi-fidelity chain.

:func:`bi_level` solves its PQN subproblem by the next level down, which is
:func:`lcpbench.toolkit.pqn_levels.mono_level` for Bi-PQN and another
:func:`bi_level` for the multi-fidelity chain; :func:`low_start` is the
paper's low-fidelity initialisation. Both run the shared level loop
:func:`lcpbench.toolkit.pqn_levels.iterate_level`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from lcpbench.core.residuals import kkt_abs
from lcpbench.toolkit.pqn_levels import (
    HANDOFF,
    BiOptions,
    Counters,
    IterateProducts,
    LevelOutcome,
    LevelTask,
    forcing_term,
    iterate_level,
    model_check,
    mono_level,
    pqn_direction,
)
from lcpbench.toolkit.quasinewton import DiagonalBFGS, OperatorBFGS, Pairs, Rank2

__all__ = ["bi_level", "low_start"]


def _rebuild(base: Callable, n: int, pairs: Pairs) -> OperatorBFGS:
    """``B = base + U U' - V V'`` from pairs with cached base products (no product)."""
    model = OperatorBFGS(base, n)
    for s, y, b0s in zip(pairs.S, pairs.Y, pairs.B0S):
        model.update(s, y, b0s + model.correction(s))
    return model


def bi_level(apply: Callable[[np.ndarray], np.ndarray], lows: list, z: np.ndarray,
             G: np.ndarray, stop: Callable[[np.ndarray, np.ndarray], bool], max_iter: int,
             opts: BiOptions, counters: Counters, *, state: Optional[dict] = None,
             warm_start: bool = True,
             exact_gradient: Optional[Callable[[np.ndarray], np.ndarray]] = None,
             floor: float = 0.0, model_error: Optional[float] = None,
             prev_residual: Optional[float] = None, adaptive: bool = True,
             fallback_seed: Optional[Pairs] = None,
             products: Optional[IterateProducts] = None) -> tuple[LevelOutcome, dict]:
    """Algorithm bpqn (Bi-PQN) with ``B^(0) = lows[0]``; deeper ``lows`` solve the subproblems.

    Each outer iteration solves the paper's PQN subproblem,
    ``min_{z>=0} 1/2 (z - x)' B (z - x) + g'(z - x)`` with ``B = lows[0] + U U' - V V'``,
    whose gradient ``B (z - x) + g`` is free at ``z = x``; every inner
    iteration costs one product with ``lows[0]`` plus ``O(n r)``. The inner
    level is Mono-PQN seeded with the carried low-fidelity pairs (or, for a
    longer chain, Bi-PQN with ``lows[1]``). ``B p`` comes from the inner
    gradients (``G_inner_end - g``), so the high-fidelity BFGS update needs no
    extra low-fidelity product. The carried pairs are corrected with
    ``Y <- Y - (u u' - v v') S`` (appendix "Across Subproblem Secant Conditions").

    Inner accuracy: the subproblem is solved until its residual is below
    ``max(eta r, floor)``, ``r`` the outer residual at ``x`` and ``eta`` the
    forcing term of :func:`forcing_term` (``inner_rtol`` while nothing is
    measured yet, or ``warm_rtol`` with ``warm_start``).

    Model check (no extra high-fidelity product): after each step the new
    high-fidelity gradient ``g + eta A p`` is known, and the model predicted
    ``g + eta B p``; ``||(A - B) p|| / ||A p||`` (:func:`model_check`, listed
    in ``counters.model_errors``) feeds the forcing term, and once it exceeds
    ``model_tol`` the model is judged useless: the level finishes as Mono-PQN
    on the high-fidelity pairs gathered so far, spending no more low
    products (``counters.decisions`` ends with ``mono:model``).

    Fallback: when the subproblem's answer ``p`` does not descend
    (``g'p >= 0``), the model is not positive along it (``p'Bp <= 0``), or the
    inner model is unbounded (an indefinite ``lows[0]``), a Mono-PQN step with
    the diagonal BFGS model of the high-fidelity pairs is taken instead
    (counted in ``mono_fallbacks``, decision ``fallback``); its ``lows[0] p``
    costs one extra low-fidelity product so the model can still be updated.
    After ``max_fallbacks`` in a row the level finishes as Mono-PQN
    (``mono:subproblem``).

    ``fallback_seed``: older pairs of ``Q`` (e.g. a previous time step's,
    only approximately ``Q s``) that start the Mono-PQN model of the
    fallback steps and of an abandoned low model; they stay out of ``B``,
    which they would make less accurate than ``lows[0]`` alone for a good
    low fidelity, and where each would cost a product with ``lows[0]``.

    ``products``: the outer level's high products are of the new point
    (:class:`~lcpbench.toolkit.pqn_products.IterateProducts`, ``products=iterate``),
    also in its Mono-PQN fallback steps and after a handoff.

    Warm start (``warm_start=True``, the old start kept as ``start=high``):
    the first subproblem is solved to ``warm_rtol``. The paper's start is
    :func:`low_start`, whose answer comes in through ``state``.

    Returns
    -------
    outcome : LevelOutcome
        With the high-fidelity pairs (``S``, ``Q S``, ``lows[0] S``).
    state : dict
        ``{"pairs": Pairs, "inner": Pairs|dict}`` to continue later.
    """
    task = LevelTask(apply, stop, max_iter, opts, counters, exact_gradient, products)
    state = state or {}
    hi_pairs: Pairs = state.get("pairs") or Pairs()
    diag = DiagonalBFGS(z.shape[0], memory=opts.memory or None, scaling=opts.scaling,
                        gamma=opts.gamma)
    older = fallback_seed or Pairs()
    diag.set_pairs(list(older.S) + list(hi_pairs.S), list(older.Y) + list(hi_pairs.Y))
    st = _BiState(lows, diag, hi_pairs, state.get("inner"), rho=model_error,
                  r_prev=prev_residual, first=warm_start, floor=floor, adaptive=adaptive)
    if products is not None:
        products.model_error(model_error)
    if products is not None and products.low_rtol is not None and len(lows) == 1 \
            and state.get("Lx") is not None:
        st.Lx, st.Lx_err, st.low_rtol = state["Lx"], state["Lx_err"], products.low_rtol
        st.relax, st.low_within = products.relax, products.low_within
    if model_error is not None and model_error > opts.model_tol:
        # judged useless before the first step: no low product to rebuild the model
        counters.decisions.append("mono:model")
        return _as_mono(task, z, G, 0, st)
    base = lows[0]
    st.hi_pairs = Pairs(list(hi_pairs.S), list(hi_pairs.Y), [
        b if b is not None else base(s) for s, b in zip(hi_pairs.S, hi_pairs.B0S)])
    st.model = _rebuild(base, z.shape[0], st.hi_pairs)
    if state.get("model") is not None:  # our pairs were corrected by the caller: so is B
        st.inner_state = _carry(st.inner_state, _delta(state["model"], st.model), opts)
    pending: dict = {}

    def direction(zz: np.ndarray, GG: np.ndarray):
        poor = st.rho is not None and st.rho > opts.model_tol
        if poor or (opts.max_fallbacks and st.streak >= opts.max_fallbacks):
            counters.decisions.append("mono:model" if poor else "mono:subproblem")
            return HANDOFF
        p, pending["Bp"], pending["inner"] = _outer_direction(task, st, zz, GG)
        return p

    def update(p: np.ndarray, Qp: np.ndarray, eta: float, G: np.ndarray) -> None:
        _update_models(task, st, _Step(p, pending["Bp"], Qp, eta), pending["inner"])

    z, G, reason, it, ray = iterate_level(task, z, G, direction, update)
    if reason == HANDOFF:
        return _as_mono(task, z, G, it, st, checked=True)
    return LevelOutcome(z, G, reason, it, st.hi_pairs, ray), st.carried()


@dataclass
class _BiState:
    """The running state of a Bi-PQN level: its models, pairs and forcing history."""

    lows: list
    diag: DiagonalBFGS                      # the Mono-PQN model of the fallback steps
    hi_pairs: Pairs                         # (S, Q S, lows[0] S)
    inner_state: Any                        # the subproblem level's carried pairs / state
    model: Optional[OperatorBFGS] = None    # B = lows[0] + U U' - V V'
    rho: Optional[float] = None             # the last model check
    r_prev: Optional[float] = None          # the last outer residual
    first: bool = True                      # the next subproblem is the warm start
    streak: int = 0                         # consecutive fallbacks
    floor: float = 0.0
    adaptive: bool = True
    #: products=iterate with one low: ``lows[0] x`` at the outer iterate, its error bound,
    #: the low's accuracy and the error bound of the last subproblem's final ``lows[0] z``
    Lx: Optional[np.ndarray] = None
    Lx_err: float = 0.0
    low_rtol: Optional[float] = None
    inner_err: Optional[float] = None
    #: loose low products (``relax``; ``low_within(v, rtol)``, None: the low has one accuracy)
    relax: float = 0.0
    low_within: Optional[Callable] = None

    @property
    def base(self) -> Callable:
        return self.lows[0]

    def carried(self) -> dict:
        return {"pairs": self.hi_pairs, "inner": self.inner_state, "model": self.model}


@dataclass
class _Step:
    """An outer step along ``p``: the model's ``B p`` (None after a fallback), ``Q p``, ``eta``."""

    p: np.ndarray
    Bp: Optional[np.ndarray]
    Qp: np.ndarray
    eta: float


def _outer_direction(task: LevelTask, st: _BiState, z: np.ndarray, G: np.ndarray):
    """Solve the PQN subproblem at ``z`` to the forcing term's accuracy; fall back if it fails.

    Returns ``(p, Bp, inner_state)``: the direction (None: no descent direction
    exists), ``B p`` from the inner gradients (None after a Mono-PQN fallback)
    and the subproblem level's state to carry once the step is taken.
    """
    opts, counters = task.opts, task.counters
    r0 = kkt_abs(z, G)
    if st.first:
        eta_f, cap = opts.warm_rtol, opts.warm_max_iter
    else:
        rate = min(x for x in (st.rho, r0 / st.r_prev if st.r_prev else None, np.inf)
                   if x is not None)
        eta_f, cap = forcing_term(rate if st.adaptive else None, opts), opts.inner_max_iter
        counters.forcing.append(eta_f)
    st.first = False
    st.r_prev = r0
    tol_in = max(eta_f * r0, st.floor)
    base, model = st.base, st.model
    assert model is not None

    def B(v):
        return base(v) + model.correction(v)

    def inner_stop(zz, GG):
        return kkt_abs(zz, GG) <= tol_in

    sub = _low_points(st, model, z, G, opts)
    with np.errstate(over="ignore", invalid="ignore"):
        inner, inner_new = _solve_sub(LevelTask(B, inner_stop, cap, opts, counters, products=sub),
                                      st.lows, z, G, st.inner_state)
    counters.inner_iterations += inner.iterations
    if sub is not None:
        counters.low_iterate_products += sub.made
        counters.low_loose_products += len(sub.loose)
        st.inner_err = sub.error
    p = inner.z - z
    Bp = inner.G - G
    ok = inner.reason != "unbounded" and inner.iterations > 0 and \
        bool(np.all(np.isfinite(inner.z))) and float(G @ p) < 0.0 and float(p @ Bp) > 0.0
    st.streak = 0 if ok else st.streak + 1
    if not ok:
        counters.mono_fallbacks += 1
        counters.decisions.append("fallback")
        return pqn_direction(st.diag, z, G, opts, counters), None, inner_new
    counters.decisions.append("model")
    return p, Bp, inner_new


def _low_points(st: _BiState, model: OperatorBFGS, x: np.ndarray, g: np.ndarray,
                opts: BiOptions) -> Optional[IterateProducts]:
    """The subproblem's products of points (``products=iterate``, one low fidelity whose
    ``lows[0] x`` is tracked), else None.

    The subproblem's gradient is ``G = B (z - x) + g`` with ``B = L + C`` (``L = lows[0]``,
    ``C`` the exact low-rank correction), so ``L z = G - g + L x - C (z - x)`` is known at
    every inner iterate and ``B p = L (z + p) - L z + C p``."""
    if st.Lx is None or st.low_rtol is None:
        return None
    shift = st.Lx - g

    def known(zz, GG):
        return GG + shift - model.correction(zz - x)

    sub = IterateProducts(None, st.low_rtol, opts.difference_tol, base=st.base, known=known,
                          correction=model.correction, error=st.Lx_err, n=x.shape[0],
                          relax=st.relax, within=st.low_within)
    sub.model_error(st.rho)     # B p from the inner gradients feeds the outer model check
    return sub


def _update_models(task: LevelTask, st: _BiState, step: _Step, inner_new) -> None:
    """After a step: the model check, the BFGS updates of ``B`` and of the fallback model,
    and the subproblem's pairs carried with ``Y <- Y + (B_new - B_old) S``."""
    opts, counters = task.opts, task.counters
    p, eta = step.p, step.eta
    s, y = eta * p, eta * step.Qp
    old_model = st.model
    assert old_model is not None
    corr = old_model.correction(p)
    b0p = st.base(p) if step.Bp is None else step.Bp - corr
    Bs = eta * (b0p + corr)
    if st.Lx is not None:           # lows[0] x+ = lows[0] x + eta lows[0] p, and its error
        if step.Bp is None or st.inner_err is None:
            st.Lx_err += eta * (st.low_rtol or 0.0) * float(np.linalg.norm(b0p))
        else:                       # (1 - eta) lows[0] x + eta lows[0] z_inner
            st.Lx_err = abs(1.0 - eta) * st.Lx_err + eta * st.inner_err
        st.Lx = st.Lx + eta * b0p
        st.inner_err = None
    # the model check: the new high gradient is known; how well did B predict it?
    st.rho = model_check(step.Qp, b0p + corr)
    counters.model_errors.append(st.rho)
    if task.products is not None:
        task.products.model_error(st.rho)
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
    st.inner_state = _carry(inner_new, delta, opts)


def _as_mono(task: LevelTask, z: np.ndarray, G: np.ndarray, it: int, st: _BiState,
             checked: bool = False) -> tuple[LevelOutcome, dict]:
    """Finish a Bi-PQN level as Mono-PQN on the high-fidelity pairs gathered so far.

    The outcome carries Mono-PQN's final pairs (what the model knows at the
    end, for a later solve's memory); the state keeps the Bi-PQN pairs.
    """
    task.counters.abandoned_low = True
    out = mono_level(task.apply, z, G, task.stop, task.max_iter - it, task.opts, task.counters,
                     seed=Pairs(list(st.diag.S), list(st.diag.Y)),
                     exact_gradient=task.exact_gradient, checked=checked,
                     products=task.products)
    task.counters.mono_fallbacks += out.iterations
    return (LevelOutcome(out.z, out.G, out.reason, it + out.iterations, out.pairs, out.ray),
            st.carried())


def low_start(lows: list, z: np.ndarray, b: np.ndarray, opts: BiOptions, counters: Counters,
              exact_gradient: Callable[[np.ndarray], np.ndarray], floor: float, *,
              products: Optional[IterateProducts] = None):
    """The paper's initialisation (Bi-PQN algorithm, line 1): the low-fidelity LCP first.

    ``min_{z>=0} 1/2 z' L z + b'z`` with ``L = lows[0]`` is solved from ``z``
    (Mono-PQN, or Bi-PQN on ``lows[1:]`` for a chain) to ``warm_rtol`` times
    its residual at ``z``, with no high-fidelity product; its gradient at
    ``z`` costs one low product (none at ``z = 0``). Then the first
    high-fidelity MVP gives ``A z1`` at its answer ``z1``, which makes
    ``(z1 - 0, A z1 - A 0)`` a free secant pair (``L z1`` is known from the
    low solve's gradient) and measures the model's error along ``z1``
    (:func:`model_check`) before any outer step.

    Returns
    -------
    z1, G1 : ndarray
        The start of the outer iteration and ``A z1 + b``.
    state : dict or None
        ``bi_level``'s state: the free pair and the low solve's pairs (None
        when the low solve broke down; then ``z1`` is the given ``z``).
    model_error : float or None
        ``||(A - L) z1|| / ||A z1||``.
    residual : float or None
        The low problem's residual at ``z``, the stand-in for the outer
        residual before the first high product (for the forcing term).
    """
    L = lows[0]
    Gl = L(z) + b
    r_low = kkt_abs(z, Gl)
    tol = max(opts.warm_rtol * r_low, floor)

    def stop(zz, GG):
        return kkt_abs(zz, GG) <= tol

    sub = None
    if products is not None and products.low_rtol is not None and len(lows) == 1:
        sub = IterateProducts(b, products.low_rtol, opts.difference_tol, relax=products.relax,
                              within=products.low_within)
    with np.errstate(over="ignore", invalid="ignore"):
        out, inner_state = _solve_sub(LevelTask(L, stop, opts.warm_max_iter, opts, counters,
                                                products=sub), lows, z, Gl, None)
    counters.inner_iterations += out.iterations
    if out.reason == "unbounded" or not (np.all(np.isfinite(out.z))
                                         and np.all(np.isfinite(out.G))):
        counters.decisions.append("start:x0")
        return z, exact_gradient(z), None, None, None
    z1 = out.z
    G1 = exact_gradient(z1)
    Az, Lz = G1 - b, out.G - b
    rho = model_check(Az, Lz)
    counters.model_errors.append(rho)
    counters.decisions.append("start:low")
    state = {"pairs": Pairs([z1], [Az], [Lz]) if np.any(z1) else Pairs(),
             "inner": inner_state, "model": OperatorBFGS(L, z.shape[0])}
    if sub is not None:             # L z1 for the subproblems' products of points
        counters.low_iterate_products += sub.made
        counters.low_loose_products += len(sub.loose)
        state["Lx"] = Lz
        state["Lx_err"] = sub.error if sub.error is not None else \
            sub.rtol * float(np.linalg.norm(Lz))
    return z1, G1, state, rho, r_low


def _solve_sub(sub: LevelTask, lows: list, z: np.ndarray, G: np.ndarray, inner_state):
    """The paper's PQN subproblem, solved by the next level down (Mono-PQN or Bi-PQN)."""
    if len(lows) == 1:
        inner = mono_level(sub.apply, z, G, sub.stop, sub.max_iter, sub.opts, sub.counters,
                           seed=inner_state if isinstance(inner_state, Pairs) else None,
                           memory=sub.opts.inner_memory, products=sub.products)
        return inner, inner.pairs
    return bi_level(sub.apply, lows[1:], z, G, sub.stop, sub.max_iter, sub.opts, sub.counters,
                    state=inner_state if isinstance(inner_state, dict) else None,
                    warm_start=False, adaptive=False)


def _copy_model(model: OperatorBFGS) -> OperatorBFGS:
    new = OperatorBFGS(model.apply_B0, model.n, model.curvature_tol)
    new.U, new.V, new.skipped = model.U, model.V, model.skipped
    return new


def _delta(old: OperatorBFGS, new: OperatorBFGS) -> Callable[[np.ndarray], np.ndarray]:
    """``v -> (B_new - B_old) v`` for two corrections of the same base (``O(n r)``)."""
    return lambda v: new.correction(v) - old.correction(v)


def _carry(inner_state, delta: Optional[Callable], opts: BiOptions):
    """Correct an inner level's pairs (and, down a chain, its own pairs) for a model change.

    ``delta`` None: the model did not change (a skipped update).
    """
    if isinstance(inner_state, Pairs):
        out = inner_state if delta is None else inner_state.corrected(delta)
        out.trim(opts.inner_memory)
        return out
    if isinstance(inner_state, dict) and delta is not None:
        # the inner level's Hessian is this level's B: its high pairs see the change;
        # its base (a lower fidelity) and its own inner pairs are unaffected.
        return {"pairs": inner_state["pairs"].corrected(delta), "inner": inner_state["inner"],
                "model": inner_state["model"]}
    return inner_state
