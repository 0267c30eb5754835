"""Hard and edge-case problem families (small, explicit, seeded).

Every family returns a list of :class:`lcpbench.LCP` with dense symmetric
matrices and ``meta`` holding at least ``family``, ``seed`` (None for
deterministic families) and ``n``; ``cond`` where it is known and ``expect``
hints for the report: ``unsafeguarded_may_fail`` (bb-cycle), ``x_unique``
(False for singular A: compare w, not x), ``solution_is_x0`` (all-inactive),
``absolute_tol_hard`` (bad-scale). Families with
a known exact solution store it in ``LCP.reference`` (``x``, ``w``,
``objective``), with ``w`` the planted value (``A x + b`` agrees with it to
rounding).

Families::

    planted       random SPD, a planted complementary solution with active, inactive
                  and degenerate (x_i = w_i = 0) indices
    spd-cond      SPD with condition numbers 1e1..1e10 (log-spaced across instances)
    singular-psd  A = J J' with redundant contacts (duplicate / combination rows of J)
    fathi         Fathi's ill-conditioned problem (Murty, "Linear complementarity,
                  linear and nonlinear programming", 1988): A = L L', x* = e1
    tiny          n = 0, 1, 2 corner cases
    all-inactive  b >= 0: the solution is x = 0
    bad-scale     b with magnitudes 1e-12..1e6 and mixed signs
    bb-cycle      small SPD instances on which projected BB without line search cycles
                  or diverges (found by ``benchmarks/find_bb_cycles.py``; the matrices
                  are in ``data/bb_cycle.json``)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Annotated

import numpy as np

from lcpbench import LCP, register_problem
from lcpbench.core.guards import dense_family
from lcpbench.core.specs import Bounds, CheckedParams

from .synthetic import (
    Cond,
    Count,
    InstanceSize,
    MatrixCond,
    NonNegative,
    SeededParams,
    Size,
    check_flops,
    meta,
    planted_b,
    planted_pair,
    random_spd_matrix,
    reference,
    seeded,
    spd_estimate,
)

__all__ = ["planted", "spd_cond", "singular_psd", "fathi", "tiny", "all_inactive",
           "bad_scale", "bb_cycle", "random_spd_matrix", "planted_b", "fathi_matrix"]

#: The instances of ``bb-cycle``: literal round-trip floats with the command that found them.
BB_CYCLE_FILE = Path(__file__).with_name("data") / "bb_cycle.json"


# ---------------------------------------------------------------------- planted
@dataclass(frozen=True)
class PlantedParams(SeededParams):
    """Parameters of planted.

    Parameters
    ----------
    n_active : int
        Indices with x_i > 0 = w_i (default 20).
    n_inactive : int
        Indices with x_i = 0 < w_i (default 20).
    n_degenerate : int
        Indices with x_i = w_i = 0 (strict complementarity fails; default 4).
    cond : float
        Condition number of the SPD matrix (default 100).
    """

    n_active: NonNegative = 20
    n_inactive: NonNegative = 20
    n_degenerate: NonNegative = 4
    cond: Cond = 100.0


@register_problem("planted", PlantedParams, default=True, estimate=lambda p: spd_estimate(
    p.count, p.n_active + p.n_inactive + p.n_degenerate))
def planted(p: PlantedParams) -> list[LCP]:
    """Random SPD LCPs with a planted solution (active, inactive and degenerate indices).

    ``A`` is :func:`random_spd_matrix` at ``cond``; ``x*`` is U(0.5, 2) on the
    active set and 0 elsewhere, ``w*`` is U(0.5, 2) on the inactive set and 0
    elsewhere, and ``b = w* - A x*``. Since A is positive definite the solution
    is unique and equals the planted one (stored in ``reference``).
    """
    n = p.n_active + p.n_inactive + p.n_degenerate

    def one(i: int, rng: np.random.Generator) -> LCP:
        A = random_spd_matrix(rng, n, p.cond)
        x, w, b = planted_pair(rng, A, p.n_active, p.n_degenerate)
        return LCP(A, b, name=f"planted-{i}", reference=reference(x, w, b),
                   meta=meta("planted", p.seed, n, instance=i, cond=p.cond,
                             n_active=p.n_active, n_inactive=p.n_inactive,
                             n_degenerate=p.n_degenerate))

    return seeded(p.count, p.seed, one)


# ---------------------------------------------------------------------- spd-cond
@dataclass(frozen=True)
class SpdCondParams(SeededParams):
    """Parameters of spd-cond.

    Parameters
    ----------
    count : int
        Number of instances; their condition numbers are log-spaced from
        ``cond_min`` to ``cond_max`` (default 10).
    cond_min, cond_max : float
        Range of condition numbers (defaults 1e1 and 1e10).
    """

    count: Count = 10
    n: InstanceSize = 50
    cond_min: Cond = 1e1
    cond_max: Cond = 1e10

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.cond_max < self.cond_min:
            raise ValueError(f"cond_max ({self.cond_max:g}) must be >= cond_min "
                             f"({self.cond_min:g})")


@register_problem("spd-cond", SpdCondParams, default=True,
                  estimate=lambda p: spd_estimate(p.count, p.n))
def spd_cond(p: SpdCondParams) -> list[LCP]:
    """SPD LCPs with condition numbers log-spaced over cond_min..cond_max.

    ``A = Q diag(lam) Q'`` (Haar-random ``Q``, eigenvalues 1..cond, see
    :func:`random_spd_matrix`); ``b ~ N(0, 1)`` (mixed signs: active and
    inactive indices).
    """
    conds = np.logspace(np.log10(p.cond_min), np.log10(p.cond_max), p.count)

    def one(i: int, rng: np.random.Generator) -> LCP:
        c = float(conds[i])
        A = random_spd_matrix(rng, p.n, c)
        b = rng.standard_normal(p.n)
        return LCP(A, b, name=f"spd-cond-{i}",
                   meta=meta("spd-cond", p.seed, p.n, instance=i, cond=c))

    return seeded(p.count, p.seed, one)


# ---------------------------------------------------------------------- singular-psd
@dataclass(frozen=True)
class SingularPsdParams(SeededParams):
    """Parameters of singular-psd.

    Parameters
    ----------
    n_independent : int
        Linearly independent rows of J, i.e. the rank of A (default 20).
    n_duplicate : int
        Rows of J that repeat an independent row (a contact listed twice; default 5).
    n_combination : int
        Rows of J that are random combinations of 2-3 independent rows (default 5).
    dof : int
        Columns of J (degrees of freedom; must be >= n_independent; default 40).
    """

    n_independent: Size = 20
    n_duplicate: NonNegative = 5
    n_combination: NonNegative = 5
    dof: Size = 40

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.dof < self.n_independent:
            raise ValueError(f"dof ({self.dof}) must be >= n_independent "
                             f"({self.n_independent}) so that those rows are independent")


def _singular_psd_estimate(p: SingularPsdParams):
    """A = J J' (n x dof rows) per instance: 2 n^2 dof flops and the LCP's check."""
    n = p.n_independent + p.n_duplicate + p.n_combination
    est = dense_family(p.count, max(n, p.dof), matrices=1, temporaries=3,
                       flops_each=2.0 * n * n * p.dof + check_flops(n))
    return est


@register_problem("singular-psd", SingularPsdParams, default=True,
                  estimate=_singular_psd_estimate)
def singular_psd(p: SingularPsdParams) -> list[LCP]:
    """Singular PSD LCPs ``A = J J'`` with redundant contacts (dependent rows of J).

    J has ``n_independent`` Gaussian rows (scaled by 1/sqrt(dof)), then
    duplicates of random independent rows and random combinations of 2-3 of
    them, shuffled; ``A = J J'`` has rank ``n_independent``. ``b = w* - A x*``
    for a planted complementary pair (x* U(0.5, 2) on a random half of the
    indices, w* U(0.5, 2) on a random half of the rest, the remaining indices
    degenerate), so the LCP is solvable by construction. ``x`` is not unique
    (A is singular) but ``w`` and the objective are: the reference stores the
    planted ``x*`` as one solution, and ``w*``.
    """
    n = p.n_independent + p.n_duplicate + p.n_combination
    n_act = n // 2
    n_inact = (n - n_act) // 2

    def one(i: int, rng: np.random.Generator) -> LCP:
        base = rng.standard_normal((p.n_independent, p.dof)) / np.sqrt(p.dof)
        rows = [base]
        if p.n_duplicate:
            rows.append(base[rng.integers(0, p.n_independent, p.n_duplicate)])
        for _ in range(p.n_combination):
            k = min(int(rng.integers(2, 4)), p.n_independent)
            idx = rng.choice(p.n_independent, k, replace=False)
            rows.append((rng.uniform(-1.0, 1.0, k) @ base[idx])[None, :])
        J = np.vstack(rows)[rng.permutation(n)]
        A = J @ J.T
        A = (A + A.T) / 2
        x, w, b = planted_pair(rng, A, n_act, n - n_act - n_inact)
        return LCP(A, b, name=f"singular-psd-{i}", reference=reference(x, w, b),
                   meta=meta("singular-psd", p.seed, n, instance=i, cond=float("inf"),
                             rank=p.n_independent, n_duplicate=p.n_duplicate,
                             n_combination=p.n_combination, dof=p.dof,
                             expect={"x_unique": False}))

    return seeded(p.count, p.seed, one)


# ---------------------------------------------------------------------- fathi
@dataclass(frozen=True)
class FathiParams(CheckedParams):
    """Parameters of fathi.

    Parameters
    ----------
    sizes : tuple of int
        Problem sizes, one instance each (default (5, 10, 20, 40); 1 <= n <= 40:
        the condition number grows like n^4 and beyond 40 the instance stops
        being a solver test and becomes a rounding test).
    """

    sizes: tuple[Annotated[int, Bounds(ge=1, le=40)], ...] = (5, 10, 20, 40)

    def __post_init__(self) -> None:
        if not self.sizes:
            raise ValueError("sizes must list at least one n, e.g. sizes=[5,10]")
        super().__post_init__()


def fathi_matrix(n: int) -> np.ndarray:
    """``L L'`` with ``L = I + 2 * (strictly lower triangle of ones)``."""
    L = np.eye(n) + 2.0 * np.tril(np.ones((n, n)), -1)
    return L @ L.T


@register_problem("fathi", FathiParams, default=True)
def fathi(p: FathiParams) -> list[LCP]:
    """Fathi's problem: ``A = L L'``, ``L = I + 2 tril(1, -1)``, ``b = -e``, solution ``x* = e1``.

    Y. Fathi, "Computational complexity of LCPs associated with positive
    definite symmetric matrices", Math. Programming 17 (1979); see also Murty
    (1988), ch. 6. At ``x* = e1``: ``L' e1 = e1`` and ``L e1 = (1, 2, ..., 2)``,
    so ``w* = A e1 - e = (0, 1, ..., 1)``: one active index, strictly
    complementary. Principal pivoting methods need exponentially many pivots;
    A is SPD but its condition number grows quickly with n.
    """
    out = []
    for n in p.sizes:
        A = fathi_matrix(n)
        b = -np.ones(n)
        x = np.zeros(n)
        x[0] = 1.0
        w = np.ones(n)
        w[0] = 0.0
        out.append(LCP(A, b, name=f"fathi-{n}", reference=reference(x, w, b),
                       meta=meta("fathi", None, n, cond=float(np.linalg.cond(A)))))
    return out


# ---------------------------------------------------------------------- tiny
@dataclass(frozen=True)
class TinyParams:
    """Parameters of tiny (none: the cases are fixed).

    Parameters
    ----------
    """


#: The cases of ``tiny``: (key, A, b, solution x, note).
_TINY_CASES = (
    ("n0", np.zeros((0, 0)), np.zeros(0), np.zeros(0), "empty"),
    ("n1-active", [[2.0]], [-3.0], [1.5], "x > 0"),
    ("n1-inactive", [[2.0]], [3.0], [0.0], "x = 0 < w"),
    ("n1-degenerate", [[2.0]], [0.0], [0.0], "x = w = 0"),
    ("n2-spd", [[2.0, 1.0], [1.0, 2.0]], [-3.0, -3.0], [1.0, 1.0], "both active"),
    ("n2-degenerate", [[2.0, 1.0], [1.0, 2.0]], [-2.0, -1.0], [1.0, 0.0], "x2 = w2 = 0"),
    ("n2-singular", [[1.0, 1.0], [1.0, 1.0]], [-1.0, -1.0], [0.5, 0.5],
     "singular A, x not unique"),
)


@register_problem("tiny", TinyParams, default=True)
def tiny(p: TinyParams) -> list[LCP]:
    """Corner cases with n = 0, 1, 2, each with its exact solution as reference.

    ``tiny-n0``: empty. ``tiny-n1-active``: 2x - 3 (x = 1.5).
    ``tiny-n1-inactive``: 2x + 3 (x = 0). ``tiny-n1-degenerate``: 2x + 0
    (x = w = 0). ``tiny-n2-spd``: both active. ``tiny-n2-degenerate``:
    A = [[2, 1], [1, 2]], b = (-2, -1) gives x = (1, 0), w = (0, 0): index 2
    is degenerate. ``tiny-n2-singular``: A = [[1, 1], [1, 1]], b = (-1, -1):
    every x >= 0 with x1 + x2 = 1 solves it (w = 0; reference x = (0.5, 0.5)).
    """
    out = []
    for key, A, b, x, note in _TINY_CASES:
        A = np.asarray(A, dtype=float)
        b = np.asarray(b, dtype=float)
        x = np.asarray(x, dtype=float)
        w = A @ x + b
        out.append(LCP(A, b, name=f"tiny-{key}", reference=reference(x, w, b),
                       meta=meta("tiny", None, len(b), case=key, note=note,
                                 expect={"x_unique": key != "n2-singular"})))
    return out


# ---------------------------------------------------------------------- all-inactive
@dataclass(frozen=True)
class AllInactiveParams(SeededParams):
    """Parameters of all-inactive.

    Parameters
    ----------
    zero_fraction : float
        Fraction of entries of b set exactly to 0 (degenerate: x_i = w_i = 0;
        default 0.1).
    """

    count: Count = 3
    n: InstanceSize = 30
    cond: MatrixCond = 100.0
    zero_fraction: Annotated[float, Bounds(ge=0, le=1)] = 0.1


@register_problem("all-inactive", AllInactiveParams, default=True,
                  estimate=lambda p: spd_estimate(p.count, p.n))
def all_inactive(p: AllInactiveParams) -> list[LCP]:
    """SPD LCPs with ``b >= 0``: the solution is ``x = 0``, ``w = b`` (no contact active).

    A solver started at 0 should stop at once with zero MVPs (a zero product
    is free).
    """
    def one(i: int, rng: np.random.Generator) -> LCP:
        A = random_spd_matrix(rng, p.n, p.cond)
        b = rng.uniform(0.1, 1.0, p.n)
        b[rng.permutation(p.n)[:int(round(p.zero_fraction * p.n))]] = 0.0
        x = np.zeros(p.n)
        return LCP(A, b, name=f"all-inactive-{i}", reference=reference(x, b.copy(), b),
                   meta=meta("all-inactive", p.seed, p.n, instance=i, cond=p.cond,
                             expect={"solution_is_x0": True}))

    return seeded(p.count, p.seed, one)


# ---------------------------------------------------------------------- bad-scale
@dataclass(frozen=True)
class BadScaleParams(SeededParams):
    """Parameters of bad-scale.

    Parameters
    ----------
    n : int
        Size (at least 2, for the two extreme magnitudes).
    log_min, log_max : float
        log10 range of the magnitudes of b (defaults -12 and 6).
    """

    count: Count = 3
    n: Annotated[int, Bounds(ge=2)] = 40
    cond: MatrixCond = 100.0
    log_min: Annotated[float, Bounds()] = -12.0
    log_max: Annotated[float, Bounds()] = 6.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.log_max < self.log_min:
            raise ValueError(f"log_max ({self.log_max:g}) must be >= log_min ({self.log_min:g})")


@register_problem("bad-scale", BadScaleParams, default=True,
                  estimate=lambda p: spd_estimate(p.count, p.n))
def bad_scale(p: BadScaleParams) -> list[LCP]:
    """SPD LCPs whose b spans magnitudes 10^log_min..10^log_max with mixed signs.

    Entry i of b is ``+-10^u``, u uniform in [log_min, log_max], random sign;
    the extremes are always present. Absolute stop rules are meaningless on
    the small entries; relative ones are dominated by the large ones.
    """
    def one(i: int, rng: np.random.Generator) -> LCP:
        A = random_spd_matrix(rng, p.n, p.cond)
        u = rng.uniform(p.log_min, p.log_max, p.n)
        u[:2] = (p.log_min, p.log_max)
        b = rng.choice([-1.0, 1.0], p.n) * 10.0 ** u[rng.permutation(p.n)]
        return LCP(A, b, name=f"bad-scale-{i}",
                   meta=meta("bad-scale", p.seed, p.n, instance=i, cond=p.cond,
                             b_log_range=(p.log_min, p.log_max),
                             expect={"absolute_tol_hard": True}))

    return seeded(p.count, p.seed, one)


# ---------------------------------------------------------------------- bb-cycle
@dataclass(frozen=True)
class BbCycleParams:
    """Parameters of bb-cycle (none: the instances are fixed).

    Parameters
    ----------
    """


@lru_cache(maxsize=1)
def _bb_cycle_data() -> tuple[dict, ...]:
    with open(BB_CYCLE_FILE, encoding="utf-8") as f:
        return tuple(json.load(f)["instances"])


@register_problem("bb-cycle", BbCycleParams, default=True)
def bb_cycle(p: BbCycleParams) -> list[LCP]:
    """Small SPD LCPs on which projected BB without line search fails (cycles or diverges).

    Found by ``benchmarks/find_bb_cycles.py --seed 0`` (seeded random search
    over SPD matrices with n = 3..8 and condition numbers up to ~2e3, running
    projected BB1 from x = 0 with an exact Cauchy first step, 1 MVP per
    iteration, the spectral step of the method paper; Dai & Fletcher, Numer.
    Math. 100 (2005) show such counterexamples exist). Kept were instances
    whose KKT residual stays above 1e-6 over the last quarter of 5000
    iterations, also with the gradient by recurrence, with b perturbed by
    1e-9 relative and with first steps of 0.5..2 times the Cauchy step
    (``--robust-start``), so that rounding and start-up differences between
    implementations do not remove the failure; confirmed with
    ``lcpbench.solve(..., solver="bb-pgd")`` (status not converged within
    2000 iterations). ``kind`` in meta says whether the residual cycles
    (bounded) or diverges. The matrices are stored in ``data/bb_cycle.json``
    as round-trip floats, exactly symmetric, regenerable by
    ``candidate(0, trial)`` in that script. The reference QP solvers solve them
    easily (they are strictly convex).
    """
    out = []
    for d in _bb_cycle_data():
        A = np.array(d["A"], dtype=float)
        b = np.array(d["b"], dtype=float)
        out.append(LCP(A, b, name=f"bb-cycle-{d['trial']}",
                       meta=meta("bb-cycle", 0, len(b), trial=d["trial"], cond=d["cond"],
                                 kind=d["kind"], found_by="benchmarks/find_bb_cycles.py",
                                 expect={"unsafeguarded_may_fail": True})))
    return out
