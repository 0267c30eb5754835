"""Projected gradient baselines: ``bb-pgd`` (Barzilai-Borwein) and ``a-pgd`` (FISTA).

Both solve the QP form of the LCP, ``min 1/2 x'Ax + b'x`` over ``x >= 0``, whose
gradient is ``w = A x + b``, by the projected (proximal) gradient step
``x+ = max(x - tau w, 0)``. They are the first-order baselines of the method
paper, section "Numerical Results" -> "Comparison Methods" (table
comparisonMethods: BB-PGD with step ``tau_bb``, A-PGD with step ``1/L(A)``, both
with over-relaxation 1).

MVP accounting
--------------
Each iteration costs exactly one counted product ``A x`` (``A 0`` is free: the
operator does not charge zero columns). Everything else the methods need is
obtained from cached products: the BB step uses ``A x_k - A x_{k-1}``, the
safeguarded line search evaluates the quadratic exactly along the step
(``f(x + l d) = f(x) + l w'd + l^2/2 d'Ad`` with ``A d = A x+ - A x``), and FISTA
forms ``A y`` from ``A x_k`` and ``A x_{k-1}``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np

from lcpbench import register_solver
from lcpbench.core.context import SolverContext
from lcpbench.core.result import SolveResult, Status
from lcpbench.core.specs import Bounds, CheckedParams
from lcpbench.toolkit.quasinewton import free_secant_pair
from lcpbench.toolkit.steps import cauchy_step

__all__ = ["BBPGDParams", "APGDParams", "bb_pgd", "a_pgd", "power_iteration"]

_TAU_MIN, _TAU_MAX = 1e-30, 1e30


def _objective(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> float:
    """``1/2 x'Ax + b'x = 1/2 x'(w + b)`` with ``w = A x + b`` (no product)."""
    return 0.5 * float(x @ (w + b))


@dataclass(frozen=True)
class BBPGDParams(CheckedParams):
    """Parameters of bb-pgd.

    Parameters
    ----------
    variant : str
        Barzilai-Borwein step. ``"bb1"`` (default, the paper's
        spectral step): ``tau = s's / s'y``; ``"bb2"``: ``tau = s'y / y'y``;
        ``"alternate"``: BB1 on odd and BB2 on even iterations (the alternating
        step of Dai & Fletcher, Numer. Math. 100 (2005), section 4).
        Here ``s = x_k - x_{k-1}`` and ``y = A x_k - A x_{k-1}``.
    safeguard : bool
        False (default): the paper's baseline, no line search: the projected
        step with ``tau_bb`` is always taken, so the method may cycle (Dai &
        Fletcher 2005 construct examples; see the ``bb-cycle`` problems). True:
        the projected BB direction ``d = max(x - tau w, 0) - x`` is accepted
        only if it passes the nonmonotone Armijo test ``f(x + d) <= f_ref +
        gamma w'd`` against a reference value ``f_ref`` (see ``reference``);
        otherwise the exact minimiser of the quadratic along ``d`` is taken,
        as Dai & Fletcher do for QPs. The step sizes are also clipped to [1e-30, 1e30].
        Both cost no product beyond the one per iteration.
    reference : str
        Reference value of the nonmonotone test. ``"adaptive"`` (default): Dai &
        Fletcher's (2005) ``f_r``, lowered to the largest objective since the
        best one after ``memory`` iterations without a new best. ``"gll"``: the
        maximum of the last ``memory`` objective values (Grippo, Lampariello &
        Lucidi 1986; SPG of Birgin, Martinez & Raydan 2000).
    memory : int
        ``L`` of the adaptive reference or ``M`` of GLL (default 3). With
        ``adaptive`` and 3 the safeguarded method solves every ``bb-cycle``
        instance at about plain BB's cost elsewhere; GLL with the customary
        ``M = 10`` cuts the BB steps so often that ill-conditioned cases run out
        of budget (docs/benchmarks.md, "BB-PGD's safeguards", has the numbers).
        Only with ``safeguard=true``.
    armijo : float
        Sufficient-decrease constant ``gamma`` in ``f(x + d) <= f_max + gamma
        w'd`` (default 1e-4; must be in (0, 1/2] so that the exact line
        minimiser always passes). Only with ``safeguard=true``.
    free_pair : bool
        True (default): with a nonzero warm start, the first step is the BB
        step of the free secant pair ``(x0, A x0)`` instead of the Cauchy step
        (which costs one product).
    """

    variant: Literal["bb1", "bb2", "alternate"] = "bb1"
    safeguard: bool = False
    memory: Annotated[int, Bounds(ge=1)] = 3
    armijo: Annotated[float, Bounds(gt=0, le=0.5)] = 1e-4
    reference: Literal["adaptive", "gll"] = "adaptive"
    free_pair: bool = True


class _AdaptiveReference:
    """Dai & Fletcher's (2005) adaptive reference value ``f_r`` of the nonmonotone search.

    ``f_best`` is the least objective so far and ``f_c`` the largest since then;
    when ``L`` consecutive iterations fail to improve ``f_best``, the reference
    drops to ``f_c``. Unlike the GLL maximum, the reference stays put while the
    method makes progress, so the long BB steps that ill-conditioned problems
    need are not cut.
    """

    def __init__(self, f0: float, L: int):
        self.value = float("inf")
        self.best = self.current = f0
        self.L = L
        self.fails = 0

    def update(self, f: float) -> None:
        if f < self.best:
            self.best = self.current = f
            self.fails = 0
            return
        self.current = max(self.current, f)
        self.fails += 1
        if self.fails == self.L:
            self.value, self.current, self.fails = self.current, f, 0


def _bb_step(variant: str, k: int, ss: float, sy: float, yy: float) -> float:
    """BB1 / BB2 / alternating step; ``nan`` when the curvature ``s'y`` is not positive."""
    if not sy > 0.0:
        return float("nan")
    use_bb2 = variant == "bb2" or (variant == "alternate" and k % 2 == 0)
    return sy / yy if use_bb2 else ss / sy


@register_solver("bb-pgd", BBPGDParams)
def bb_pgd(ctx: SolverContext, p: BBPGDParams) -> SolveResult:
    """Projected gradient descent with the Barzilai-Borwein step (BB-PGD).

    The method paper's baseline (section "Comparison Methods", eq.
    spectralStepSize; Yan, Corona et al., J. Comput. Phys. 2020, found it the
    best method for boundary-integral collision resolution): one MVP per
    iteration, no line search. As in the authors' ``BBPGD_matfree.m``, the first
    step is the BB step of the free secant pair ``(x0, A x0)`` when the warm
    start ``x0`` is not zero (``A x0`` is known from the first gradient, ``A 0 =
    0``), else the Cauchy step ``tau_0 = w'w / w'Aw`` of the unconstrained
    quadratic (one counted product ``A w``); ``free_pair=false`` always takes
    the Cauchy step.

    Choices the source leaves open (lcpbench's, documented): when
    ``s'y <= 0`` (``s`` in the null space of a singular PSD ``A``, or no move)
    the previous step is kept instead of dividing by zero; with
    ``safeguard=true`` see :class:`BBPGDParams`. ``info``: ``variant``,
    ``safeguard``, ``kept_steps`` (iterations whose BB step was undefined),
    ``line_search_cuts`` (safeguarded steps shortened by the line search),
    ``last_tau``.
    """
    b = ctx.b
    x = np.maximum(ctx.x0, 0.0)
    w = ctx.A @ x + b
    ctx.info.update(variant=p.variant, safeguard=p.safeguard, kept_steps=0,
                    line_search_cuts=0)
    if ctx.report(x, w):
        return ctx.finish(x, w)
    pair = free_secant_pair(x, w, b) if p.free_pair else None
    if pair is not None:
        s0, y0 = pair
        tau = _bb_step(p.variant, 1, float(s0 @ s0), float(s0 @ y0), float(y0 @ y0))
    else:
        tau = cauchy_step(w, ctx.A @ w)
    if not np.isfinite(tau) or tau <= 0.0:
        tau = 1.0
    f = _objective(x, w, b)
    recent: deque = deque([f], maxlen=p.memory)
    ref = _AdaptiveReference(f, p.memory)
    k = 1
    while True:
        if p.safeguard:
            tau = min(max(tau, _TAU_MIN), _TAU_MAX)
        xn = np.maximum(x - tau * w, 0.0)
        wn = ctx.A @ xn + b
        s, y = xn - x, wn - w
        if p.safeguard:
            wd, dAd = float(w @ s), float(s @ y)
            fn = f + wd + 0.5 * dAd
            f_ref = max(recent) if p.reference == "gll" else ref.value
            if fn > f_ref + p.armijo * wd and dAd > 0.0:
                lam = min(1.0, -wd / dAd) if wd < 0.0 else 0.0
                xn, wn = x + lam * s, w + lam * y
                s, y = lam * s, lam * y
                fn = f + lam * wd + 0.5 * lam * lam * dAd
                ctx.info["line_search_cuts"] += 1
            f = fn
            recent.append(f)
            ref.update(f)
        x, w = xn, wn
        ctx.info["last_tau"] = tau
        if ctx.report(x, w):
            return ctx.finish(x, w)
        new = _bb_step(p.variant, k, float(s @ s), float(s @ y), float(y @ y))
        if np.isfinite(new) and new > 0.0:
            tau = new
        else:
            ctx.info["kept_steps"] += 1
            if p.safeguard:
                tau = _TAU_MAX if float(s @ s) > 0.0 else tau
        k += 1


# --------------------------------------------------------------------------- A-PGD


@dataclass(frozen=True)
class APGDParams(CheckedParams):
    """Parameters of a-pgd.

    Parameters
    ----------
    L : float
        Lipschitz constant of the gradient, ``lambda_max(A)``. 0 (default):
        obtained as ``constants`` says.
    mu : float
        Strong-convexity constant ``lambda_min(A)``. With ``0 < mu < L`` the
        constant momentum ``(sqrt(L) - sqrt(mu)) / (sqrt(L) + sqrt(mu))`` of
        Nesterov's method for strongly convex functions is used; with ``mu = 0``
        the FISTA sequence ``t_{k+1} = (1 + sqrt(1 + 4 t_k^2)) / 2``.
    constants : str
        How ``L`` (and ``mu``) are obtained when ``L = 0``. ``"power"``
        (default): ``power_iters`` power iterations on ``A`` whose products are
        counted, ``L = power_safety * Rayleigh quotient``, ``mu = 0``.
        ``"oracle"``: ``lambda_max`` and ``lambda_min`` computed by the
        framework without counting (the paper's "unrealistically generous"
        setting, section "Comparison Methods"; reported as
        ``info['oracle_constants']``, so the E-MVPs understate the real cost).
    power_iters : int
        Power iterations for ``constants="power"`` (default 20).
    power_safety : float
        Factor >= 1 on the power-iteration estimate, which approaches
        ``lambda_max`` from below (default 1.1).
    restart : str
        Adaptive restart of the momentum (O'Donoghue & Candes, Found. Comput.
        Math. 15 (2015)): ``"none"`` (default: plain FISTA as in the paper),
        ``"gradient"`` (restart when ``(y_k - x_{k+1})'(x_{k+1} - x_k) > 0``),
        ``"function"`` (restart when the objective increases). Both tests use
        cached products only.
    seed : int
        Seed of the power iteration's start vector.
    """

    L: Annotated[float, Bounds(ge=0)] = 0.0
    mu: Annotated[float, Bounds(ge=0)] = 0.0
    constants: Literal["power", "oracle"] = "power"
    power_iters: Annotated[int, Bounds(ge=1)] = 20
    power_safety: Annotated[float, Bounds(ge=1)] = 1.1
    restart: Literal["none", "gradient", "function"] = "none"
    seed: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()              # the declared bounds
        if self.L > 0.0 and self.mu > self.L:
            raise ValueError(f"mu ({self.mu}) must not exceed L ({self.L})")


def power_iteration(apply, n: int, iters: int, seed: int = 0) -> float:
    """Rayleigh-quotient estimate of ``lambda_max`` of a symmetric PSD operator.

    Parameters
    ----------
    apply : callable
        ``v -> A v`` (a counted operator's ``@`` when the products must count).
    n : int
        Dimension.
    iters : int
        Products spent.
    seed : int
        Seed of the random start vector.

    Returns
    -------
    float
        ``v'Av / v'v`` at the last iterate, a lower bound on ``lambda_max``.
    """
    v = np.random.default_rng(seed).standard_normal(n)
    v /= np.linalg.norm(v)
    est = 0.0
    for _ in range(iters):
        Av = apply(v)
        est = float(v @ Av)
        nrm = float(np.linalg.norm(Av))
        if nrm == 0.0 or not np.isfinite(nrm):
            break
        v = Av / nrm
    return est


@register_solver("a-pgd", APGDParams)
def a_pgd(ctx: SolverContext, p: APGDParams) -> SolveResult:
    """Accelerated projected gradient (FISTA, Beck & Teboulle 2009) with step ``1/L``.

    The A-PGD baseline of the method paper (section "Comparison Methods":
    step ``1/L(A)``, over-relaxation 1; the paper grants ``L`` and ``mu`` as
    known, here ``constants="oracle"`` or explicit ``L``/``mu``). One MVP per
    iteration: ``A x_{k+1}`` is computed, and the gradient at the extrapolated
    point ``y_{k+1} = x_{k+1} + beta (x_{k+1} - x_k)`` is formed as
    ``(1 + beta) A x_{k+1} - beta A x_k + b`` without a product. Reported
    iterates are the ``x_k`` (with their exact ``w``).

    The authors' ``APGD.m`` (after Erleben's Num4LCP) instead backtracks on
    ``L`` with extra products each iteration; the paper's comparison uses the
    known constant, which is what this solver implements. ``info``: ``L``,
    ``mu``, ``power_mvps``, ``oracle_constants``, ``restarts``.
    """
    b, n = ctx.b, ctx.n
    x = np.maximum(ctx.x0, 0.0)
    w = ctx.A @ x + b
    ctx.info.update(restarts=0, power_mvps=0, oracle_constants=False)
    if ctx.report(x, w):
        return ctx.finish(x, w)
    L, mu = p.L, p.mu
    if L == 0.0:
        if p.constants == "oracle":
            L, mu = ctx.oracle_spectrum()
        else:
            before = ctx.A.count
            L = p.power_safety * power_iteration(lambda v: ctx.A @ v, n, p.power_iters, p.seed)
            ctx.info["power_mvps"] = ctx.A.count - before
            mu = 0.0
    if L == 0.0:
        # A vanished on the estimate's vectors (A = 0, up to probability zero): the
        # objective is linear and every step length is safe; take L = 1.
        L = 1.0
        ctx.info["zero_curvature"] = True
    if not (np.isfinite(L) and L > 0.0):
        return ctx.finish(x, w, Status.failed,
                          f"Lipschitz constant estimate {L!r} is not positive: A is zero or "
                          "not PSD; pass a-pgd:L=<lambda_max(A)>")
    mu = min(mu, L)
    ctx.info.update(L=L, mu=mu)
    strong = mu > 0.0
    beta_const = (np.sqrt(L) - np.sqrt(mu)) / (np.sqrt(L) + np.sqrt(mu)) if strong else 0.0
    t = 1.0
    y, wy = x, w                     # extrapolated point and its gradient
    f = _objective(x, w, b)
    while True:
        xn = np.maximum(y - wy / L, 0.0)
        wn = ctx.A @ xn + b
        fn = _objective(xn, wn, b)
        if ctx.report(xn, wn):
            return ctx.finish(xn, wn)
        restart = (p.restart == "gradient" and float((y - xn) @ (xn - x)) > 0.0) or \
                  (p.restart == "function" and fn > f)
        if restart:
            ctx.info["restarts"] += 1
            t, beta = 1.0, 0.0
        elif strong:
            beta = beta_const
        else:
            t_next = 0.5 * (1.0 + np.sqrt(1.0 + 4.0 * t * t))
            beta = (t - 1.0) / t_next
            t = t_next
        y = xn + beta * (xn - x)
        wy = (1.0 + beta) * wn - beta * w
        x, w, f = xn, wn, fn
