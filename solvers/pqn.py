"""Proximal quasi-Newton solvers: ``mono-pqn``, ``bi-pqn`` and the ``multi-pqn`` extension.

The method paper's sections "A Proximal Quasi-Newton Method" (algorithm pqn),
"Mono-PQN Step Size Selection" (algorithm stepSize), "A Bifidelity Proximal
Quasi-Newton Method" (algorithm bpqn) and appendices "Fast Solutions to Weighted
Proximal Operator" and "Bifidelity Proximal Quasi-Newton". The iteration itself
lives in :mod:`lcpbench.solvers.pqn_levels`; this module wires it to the solver
context and documents every choice.

MVPs per iteration
------------------
* ``mono-pqn``: ``A x0`` once (free at ``x0 = 0``), then exactly one
  high-fidelity MVP ``A p`` per iteration (plus one every ``recompute_every``
  iterations, if set).
* ``bi-pqn``: per outer iteration one high-fidelity MVP ``A p`` and one
  low-fidelity MVP per inner iteration (plus one low MVP per Mono-PQN fallback
  step, to keep the model's update exact).
* ``multi-pqn``: as ``bi-pqn`` with the subproblem solved by Bi-PQN on the next
  cheaper operator, recursively.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Optional

import numpy as np

from lcpbench import register_solver
from lcpbench.toolkit.confirm import ConfirmedReport
from lcpbench.core.context import SolverContext
from lcpbench.core.result import SolveResult, Status

from .pqn_levels import Counters, LevelOptions, Pairs, bi_level, mono_level

__all__ = ["MonoPQNParams", "BiPQNParams", "MultiPQNParams", "mono_pqn", "bi_pqn", "multi_pqn"]

_MONO_DOC = """
    memory : int
        Secant pairs kept in the BFGS model ``B = D + U U' - V V'`` (0: all, up
        to the iteration cap and at most n, the oldest dropped beyond n; the
        paper uses full memory since it converges in about ten iterations).
    scaling : str
        ``bb`` (default): ``D = I / (gamma tau_BB2)`` from the newest pair, as the
        authors' code does; ``identity``: ``D = I`` as in the paper's Mono-PQN algorithm.
        ``bb`` needs fewer MVPs on every family we measured (docs/benchmarks.md).
    gamma : float
        Damping of the BB2 scaling (authors' value 0.8).
    prox_tol : float
        Tolerance of the semi-smooth Newton root solve of the weighted prox.
    prox_max_iter : int
        Newton iterations before the weighted prox falls back to an accelerated
        projected gradient solve in the metric (reported as ``prox_fallbacks``).
    recompute_every : int
        Recompute ``A x`` exactly (one extra MVP) every this many iterations to
        bound the drift of the recurrence ``A x+ = A x + eta A p``; 0 never.
        Default 50: far beyond the paper's ten-odd iterations, so the extra MVP
        appears only on hard problems."""

_INNER_DOC = """
    inner_rtol : float
        The Bi-PQN subproblem is solved until its residual
        ``||min(z, B(z - x) + g)||`` falls below ``inner_rtol`` times its value at
        ``z = x`` (which is the outer residual).
    inner_max_iter : int
        Inner iteration cap per subproblem.
    inner_memory : int
        Low-fidelity pairs carried across subproblems (0: all).
    warm_rtol : float
        Relative tolerance of the low-fidelity initialisation (the first
        subproblem, line 1 of the paper's Bi-PQN).
    warm_max_iter : int
        Iteration cap of the low-fidelity initialisation.
    max_fallbacks : int
        After this many consecutive Mono-PQN fallbacks the low-fidelity model is
        abandoned and the solve finishes as Mono-PQN on the high-fidelity pairs
        (``info['abandoned_low']``), so a useless ``A_low`` costs at most this
        many wasted subproblems; 0 never abandons it."""


@dataclass(frozen=True)
class MonoPQNParams:
    memory: int = 0
    scaling: str = "bb"
    gamma: float = 0.8
    prox_tol: float = 1e-12
    prox_max_iter: int = 100
    recompute_every: int = 50

    def __post_init__(self) -> None:
        if self.memory < 0:
            raise ValueError("memory must be >= 0 (0 keeps every pair)")
        if self.scaling not in ("bb", "identity"):
            raise ValueError(f"scaling must be 'bb' or 'identity', got {self.scaling!r}")
        if not 0 < self.gamma <= 1:
            raise ValueError(f"gamma must be in (0, 1], got {self.gamma}")
        if not self.prox_tol > 0 or self.prox_max_iter < 1:
            raise ValueError("prox_tol must be > 0 and prox_max_iter >= 1")
        if self.recompute_every < 0:
            raise ValueError("recompute_every must be >= 0 (0 never recomputes)")

    def options(self) -> LevelOptions:
        extra = {k: getattr(self, k) for k in ("inner_rtol", "inner_max_iter", "inner_memory",
                                                "warm_rtol", "warm_max_iter",
                                                "max_fallbacks") if hasattr(self, k)}
        return LevelOptions(memory=self.memory, scaling=self.scaling, gamma=self.gamma,
                            prox_tol=self.prox_tol, prox_max_iter=self.prox_max_iter,
                            recompute_every=self.recompute_every, **extra)


MonoPQNParams.__doc__ = "Parameters of mono-pqn.\n\n    Parameters\n    ----------" + _MONO_DOC


@dataclass(frozen=True)
class BiPQNParams(MonoPQNParams):
    low: str = ""
    inner_rtol: float = 0.01
    inner_max_iter: int = 20
    inner_memory: int = 0
    warm_rtol: float = 0.1
    warm_max_iter: int = 50
    max_fallbacks: int = 3

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.max_fallbacks < 0:
            raise ValueError("max_fallbacks must be >= 0 (0: never abandon the low model)")
        if not 0 < self.inner_rtol < 1 or not 0 < self.warm_rtol < 1:
            raise ValueError("inner_rtol and warm_rtol must be in (0, 1)")
        if self.inner_max_iter < 1 or self.warm_max_iter < 1:
            raise ValueError("inner_max_iter and warm_max_iter must be >= 1")
        if self.inner_memory < 0:
            raise ValueError("inner_memory must be >= 0 (0 keeps every pair)")


BiPQNParams.__doc__ = ("Parameters of bi-pqn.\n\n    Parameters\n    ----------\n"
                       "    low : str\n        Name of the low-fidelity operator in the LCP's "
                       "``low`` (empty: the only one).\n" + _MONO_DOC.strip("\n") + "\n"
                       "        (memory, scaling and gamma also set the fallback model.)"
                       + _INNER_DOC)


@dataclass(frozen=True)
class MultiPQNParams(BiPQNParams):
    lows: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.low:
            raise ValueError("multi-pqn takes `lows` (an ordered list), not `low`")


MultiPQNParams.__doc__ = BiPQNParams.__doc__.replace("Parameters of bi-pqn.", "Parameters of multi-pqn.") \
    .replace("    low : str\n        Name of the low-fidelity operator in the LCP's ``low`` (empty: "
             "the only one).\n",
             "    low : str\n        Unused (use ``lows``).\n") + """
    lows : list of str
        Low-fidelity operators from the most to the least accurate, e.g.
        ``lows=[p6,p4,p3]`` (empty: every low operator of the LCP, ordered by
        decreasing cost)."""


def _seed(ctx: SolverContext) -> Optional[Pairs]:
    """High-fidelity pairs from a previous solve's ``state`` (time stepping)."""
    st = ctx.state
    if isinstance(st, dict) and isinstance(st.get("pairs"), Pairs) and st.get("n") == ctx.n:
        return st["pairs"]
    return None


def _finish(ctx: SolverContext, out, counters: Counters, state: dict) -> SolveResult:
    ctx.info.update(counters.as_dict())
    state["n"] = ctx.n
    if out.reason == "unbounded":
        return ctx.finish(out.z, out.G, Status.failed,
                          "the quadratic is unbounded below along the search direction: the LCP "
                          "has no solution (A not PSD, or -b outside the cone)", state=state)
    if out.reason == "stationary":
        return ctx.finish(out.z, out.G, Status.stagnated,
                          "no descent direction: the projected gradient vanishes to round-off",
                          state=state)
    return ctx.finish(out.z, out.G, state=state)


def _start(ctx: SolverContext):
    x = np.maximum(ctx.x0, 0.0)
    return x, ctx.A @ x + ctx.b


@register_solver("mono-pqn", MonoPQNParams)
def mono_pqn(ctx: SolverContext, p: MonoPQNParams) -> SolveResult:
    """Mono-fidelity proximal quasi-Newton method (Mono-PQN of the method paper).

    Each iteration: ``x~ = x - H g`` with ``H = B^-1`` applied by the BFGS
    two-loop recursion in O(n r); ``x^ = prox^B(x~)`` by Proposition
    prop-nnProx (semi-smooth Newton on the 2r-dimensional root problem,
    algorithm semiSmoothNewton; closed form ``max(x~, 0)`` while ``r = 0``);
    ``p = x^ - x``; one MVP ``A p``; the optimal over-relaxation ``eta*`` of
    algorithm stepSize from the cached ``A p``; ``x+ = x + eta p``,
    ``A x+ = A x + eta A p``; BFGS update with ``(eta p, eta A p)`` (Nocedal &
    Wright, ch. 6), pairs with ``s'y <= 0`` skipped. The paper's choices:
    full memory, optimal step (not unit), and the stopping rule of eq.
    kkt-error. Choices the paper leaves open, taken from the authors' code:
    the BB-scaled initial diagonal with ``gamma = 0.8``. If an inexact prox
    gives no descent, the projected-gradient direction is used (counted as
    ``gradient_fallbacks``). ``result.state`` carries the secant pairs; pass
    it back as ``state=`` to start the next time step's model from them.
    """
    x, g = _start(ctx)
    counters = Counters()
    stop = ConfirmedReport(ctx)
    out = mono_level(ctx.A.matvec, x, g, stop, sys.maxsize, p.options(), counters,
                     seed=_seed(ctx), exact_gradient=stop.exact)
    ctx.info["rank"] = len(out.pairs)
    return _finish(ctx, out, counters, {"pairs": out.pairs})


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


def _run_chain(ctx: SolverContext, p: BiPQNParams, names: list[str]) -> SolveResult:
    x, g = _start(ctx)
    counters = Counters()
    lows = [ctx.low[k].matvec for k in names]
    st = ctx.state if isinstance(ctx.state, dict) and ctx.state.get("n") == ctx.n and \
        ctx.state.get("lows") == names else None
    # previous step's pairs: their low products are redone on this step's A_low
    level_state = {"pairs": Pairs(list(st["pairs"].S), list(st["pairs"].Y),
                                  [None] * len(st["pairs"]))} if st else None
    stop = ConfirmedReport(ctx)
    out, state = bi_level(ctx.A.matvec, lows, x, g, stop, sys.maxsize, p.options(),
                          counters, state=level_state, warm_start=True,
                          exact_gradient=stop.exact)
    ctx.info["rank"] = len(out.pairs)
    ctx.info["low"] = ",".join(names)
    return _finish(ctx, out, counters, {"pairs": state["pairs"], "lows": names})


@register_solver("bi-pqn", BiPQNParams, multifidelity=True)
def bi_pqn(ctx: SolverContext, p: BiPQNParams) -> SolveResult:
    """Bi-fidelity proximal quasi-Newton method (Bi-PQN of the method paper).

    ``B^(0) = A_low`` (the operator named by ``low``); each outer iteration
    solves the subproblem of eq. pqnSubproblem,
    ``min_{z>=0} 1/2 z'Bz + (A x + b - B x)'z``, by Mono-PQN with B-products (one
    low-fidelity MVP plus O(n r) each), warm-started at ``x`` where its gradient
    is the known ``A x + b``; the subproblem's secant pairs are carried to the
    next one with ``Y <- Y - (u u' - v v') S`` (appendix "Across Subproblem
    Secant Conditions"); the BFGS correction of ``B`` takes ``B s`` from the
    inner gradients (no extra low MVP); one high-fidelity MVP ``A p`` per outer
    iteration and the optimal over-relaxation of algorithm stepSize. Start:
    the paper's low-fidelity initialisation (Mono-PQN on the low-fidelity
    problem from ``x^(-1)``), here as the first subproblem solved to
    ``warm_rtol``. Robustness beyond the paper: if the model is not positive
    along ``p``, ``p`` does not descend, or the subproblem is unbounded (an
    indefinite ``A_low``), a Mono-PQN step on the high-fidelity pairs is taken
    instead (``info['mono_fallbacks']``). The paper's choices: full memory,
    BFGS updates stored unrolled. ``result.state`` carries the high-fidelity
    pairs for the next time step (the model is rebuilt on the new ``A_low``
    with one low MVP per pair).
    """
    return _run_chain(ctx, p, _low_names(ctx, (p.low,) if p.low else (), "bi-pqn"))


@register_solver("multi-pqn", MultiPQNParams, multifidelity=True)
def multi_pqn(ctx: SolverContext, p: MultiPQNParams) -> SolveResult:
    """Multi-fidelity PQN: Bi-PQN whose subproblems are solved by Bi-PQN on a cheaper operator.

    An extension beyond the paper (its "Conclusions and Future Work"): with
    ``lows = [L1, L2, ..., Lm]`` the outer level is Bi-PQN with ``B^(0) = L1``;
    its subproblem ``min 1/2 (z-x)'B(z-x) + g'(z-x)`` is solved by Bi-PQN with
    ``B'^(0) = L2``, and so on, the last level by Mono-PQN. Each level carries
    its subproblem pairs across calls with the correction of the level above.
    With one operator it is ``bi-pqn``.
    """
    return _run_chain(ctx, p, _low_names(ctx, p.lows, "multi-pqn"))
