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

Families
--------
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
              or diverges (found by ``benchmarks/find_bb_cycles.py``)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from lcpbench import LCP, register_problem

__all__ = ["planted", "spd_cond", "singular_psd", "fathi", "tiny", "all_inactive",
           "bad_scale", "bb_cycle", "random_spd_matrix", "planted_b"]


# ---------------------------------------------------------------------- helpers
def _orthogonal(rng: np.random.Generator, n: int) -> np.ndarray:
    """A Haar-random orthogonal matrix (QR of a Gaussian with sign correction)."""
    Q, R = np.linalg.qr(rng.standard_normal((n, n)))
    return Q * np.where(np.diag(R) < 0, -1.0, 1.0)


def random_spd_matrix(rng: np.random.Generator, n: int, cond: float) -> np.ndarray:
    """Symmetric positive definite ``Q diag(lam) Q'`` with condition number ``cond``.

    Eigenvalues: 1 and ``cond`` at the ends, the others log-uniform in between;
    ``Q`` Haar-random orthogonal. The result is symmetrised exactly.
    """
    if n == 0:
        return np.zeros((0, 0))
    if n == 1:
        return np.ones((1, 1))
    inner = 10.0 ** rng.uniform(0.0, np.log10(cond), n - 2)
    lam = np.concatenate([[1.0], inner, [float(cond)]])
    Q = _orthogonal(rng, n)
    A = (Q * lam) @ Q.T
    return (A + A.T) / 2


def _split(rng: np.random.Generator, n: int, n_active: int, n_degenerate: int):
    """Random disjoint index sets (active, degenerate, inactive) of sizes given."""
    perm = rng.permutation(n)
    return perm[:n_active], perm[n_active:n_active + n_degenerate], perm[n_active + n_degenerate:]


def planted_b(A: np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``b = w - A x``, so that ``(x, w)`` solves the LCP when complementary."""
    return w - A @ x


def _ref(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> dict:
    return {"x": x, "w": w, "objective": 0.5 * float(x @ (w + b)) if x.size else 0.0}


def _meta(family: str, seed: Optional[int], n: int, **extra) -> dict:
    return {"family": family, "seed": seed, "n": int(n), **extra}


def _check_count(count: int) -> None:
    if not (isinstance(count, int) and count >= 1):
        raise ValueError(f"count must be an integer >= 1, got {count!r}")


def _check_cond(name: str, cond: float) -> None:
    if not (np.isfinite(cond) and cond >= 1):
        raise ValueError(f"{name} must be a finite condition number >= 1, got {cond!r}")


# ---------------------------------------------------------------------- planted
@dataclass(frozen=True)
class PlantedParams:
    """Parameters of planted.

    Parameters
    ----------
    count : int
        Number of instances (default 5).
    seed : int
        Random seed; instance i uses ``default_rng([seed, i])`` (default 0).
    n_active : int
        Indices with x_i > 0 = w_i (default 20).
    n_inactive : int
        Indices with x_i = 0 < w_i (default 20).
    n_degenerate : int
        Indices with x_i = w_i = 0 (strict complementarity fails; default 4).
    cond : float
        Condition number of the SPD matrix (default 100).
    """

    count: int = 5
    seed: int = 0
    n_active: int = 20
    n_inactive: int = 20
    n_degenerate: int = 4
    cond: float = 100.0

    def __post_init__(self) -> None:
        _check_count(self.count)
        for k in ("n_active", "n_inactive", "n_degenerate"):
            if not (isinstance(getattr(self, k), int) and getattr(self, k) >= 0):
                raise ValueError(f"{k} must be an integer >= 0, got {getattr(self, k)!r}")
        _check_cond("cond", self.cond)


@register_problem("planted", PlantedParams, default=True)
def planted(p: PlantedParams) -> list[LCP]:
    """Random SPD LCPs with a planted solution (active, inactive and degenerate indices).

    ``A`` is :func:`random_spd_matrix` at ``cond``; ``x*`` is U(0.5, 2) on the
    active set and 0 elsewhere, ``w*`` is U(0.5, 2) on the inactive set and 0
    elsewhere, and ``b = w* - A x*``. Since A is positive definite the solution
    is unique and equals the planted one (stored in ``reference``).
    """
    n = p.n_active + p.n_inactive + p.n_degenerate
    out = []
    for i in range(p.count):
        rng = np.random.default_rng([p.seed, i])
        A = random_spd_matrix(rng, n, p.cond)
        act, deg, inact = _split(rng, n, p.n_active, p.n_degenerate)
        x = np.zeros(n)
        w = np.zeros(n)
        x[act] = rng.uniform(0.5, 2.0, act.size)
        w[inact] = rng.uniform(0.5, 2.0, inact.size)
        b = planted_b(A, x, w)
        out.append(LCP(A, b, name=f"planted-{i}", reference=_ref(x, w, b),
                       meta=_meta("planted", p.seed, n, instance=i, cond=p.cond,
                                  n_active=p.n_active, n_inactive=p.n_inactive,
                                  n_degenerate=p.n_degenerate)))
    return out


# ---------------------------------------------------------------------- spd-cond
@dataclass(frozen=True)
class SpdCondParams:
    """Parameters of spd-cond.

    Parameters
    ----------
    count : int
        Number of instances; their condition numbers are log-spaced from
        ``cond_min`` to ``cond_max`` (default 10).
    seed : int
        Random seed (default 0).
    n : int
        Size of every instance (default 50).
    cond_min, cond_max : float
        Range of condition numbers (defaults 1e1 and 1e10).
    """

    count: int = 10
    seed: int = 0
    n: int = 50
    cond_min: float = 1e1
    cond_max: float = 1e10

    def __post_init__(self) -> None:
        _check_count(self.count)
        if self.n < 1:
            raise ValueError(f"n must be >= 1, got {self.n}")
        _check_cond("cond_min", self.cond_min)
        _check_cond("cond_max", self.cond_max)
        if self.cond_max < self.cond_min:
            raise ValueError("cond_max must be >= cond_min")


@register_problem("spd-cond", SpdCondParams, default=True)
def spd_cond(p: SpdCondParams) -> list[LCP]:
    """SPD LCPs with condition numbers log-spaced over cond_min..cond_max.

    ``A = Q diag(lam) Q'`` (Haar-random ``Q``, eigenvalues 1..cond, see
    :func:`random_spd_matrix`); ``b ~ N(0, 1)`` (mixed signs: active and
    inactive indices).
    """
    conds = np.logspace(np.log10(p.cond_min), np.log10(p.cond_max), p.count)
    out = []
    for i, c in enumerate(conds):
        rng = np.random.default_rng([p.seed, i])
        A = random_spd_matrix(rng, p.n, float(c))
        b = rng.standard_normal(p.n)
        out.append(LCP(A, b, name=f"spd-cond-{i}",
                       meta=_meta("spd-cond", p.seed, p.n, instance=i, cond=float(c))))
    return out


# ---------------------------------------------------------------------- singular-psd
@dataclass(frozen=True)
class SingularPsdParams:
    """Parameters of singular-psd.

    Parameters
    ----------
    count : int
        Number of instances (default 5).
    seed : int
        Random seed (default 0).
    n_independent : int
        Linearly independent rows of J, i.e. the rank of A (default 20).
    n_duplicate : int
        Rows of J that repeat an independent row (a contact listed twice; default 5).
    n_combination : int
        Rows of J that are random combinations of 2-3 independent rows (default 5).
    dof : int
        Columns of J (degrees of freedom; must be >= n_independent; default 40).
    """

    count: int = 5
    seed: int = 0
    n_independent: int = 20
    n_duplicate: int = 5
    n_combination: int = 5
    dof: int = 40

    def __post_init__(self) -> None:
        _check_count(self.count)
        if self.n_independent < 1:
            raise ValueError("n_independent must be >= 1")
        if self.n_duplicate < 0 or self.n_combination < 0:
            raise ValueError("n_duplicate and n_combination must be >= 0")
        if self.dof < self.n_independent:
            raise ValueError(f"dof ({self.dof}) must be >= n_independent "
                             f"({self.n_independent}) so that those rows are independent")


@register_problem("singular-psd", SingularPsdParams, default=True)
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
    out = []
    for i in range(p.count):
        rng = np.random.default_rng([p.seed, i])
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
        n_act = n // 2
        n_inact = (n - n_act) // 2
        act, deg, inact = _split(rng, n, n_act, n - n_act - n_inact)
        x = np.zeros(n)
        w = np.zeros(n)
        x[act] = rng.uniform(0.5, 2.0, act.size)
        w[inact] = rng.uniform(0.5, 2.0, inact.size)
        b = planted_b(A, x, w)
        out.append(LCP(A, b, name=f"singular-psd-{i}", reference=_ref(x, w, b),
                       meta=_meta("singular-psd", p.seed, n, instance=i, cond=float("inf"),
                                  rank=p.n_independent, n_duplicate=p.n_duplicate,
                                  n_combination=p.n_combination, dof=p.dof,
                                  expect={"x_unique": False})))
    return out


# ---------------------------------------------------------------------- fathi
@dataclass(frozen=True)
class FathiParams:
    """Parameters of fathi.

    Parameters
    ----------
    sizes : tuple of int
        Problem sizes, one instance each (default (5, 10, 20, 40); 1 <= n <= 40:
        the condition number grows like n^4 and beyond 40 the instance stops
        being a solver test and becomes a rounding test).
    """

    sizes: tuple[int, ...] = (5, 10, 20, 40)

    def __post_init__(self) -> None:
        if not self.sizes:
            raise ValueError("sizes must list at least one n")
        for n in self.sizes:
            if not (isinstance(n, int) and 1 <= n <= 40):
                raise ValueError(f"fathi sizes must be integers in 1..40, got {n!r}")


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
        out.append(LCP(A, b, name=f"fathi-{n}", reference=_ref(x, w, b),
                       meta=_meta("fathi", None, n, cond=float(np.linalg.cond(A)))))
    return out


# ---------------------------------------------------------------------- tiny
@dataclass(frozen=True)
class TinyParams:
    """Parameters of tiny (none: the cases are fixed).

    Parameters
    ----------
    """


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
    cases = [
        ("n0", np.zeros((0, 0)), np.zeros(0), np.zeros(0), "empty"),
        ("n1-active", [[2.0]], [-3.0], [1.5], "x > 0"),
        ("n1-inactive", [[2.0]], [3.0], [0.0], "x = 0 < w"),
        ("n1-degenerate", [[2.0]], [0.0], [0.0], "x = w = 0"),
        ("n2-spd", [[2.0, 1.0], [1.0, 2.0]], [-3.0, -3.0], [1.0, 1.0], "both active"),
        ("n2-degenerate", [[2.0, 1.0], [1.0, 2.0]], [-2.0, -1.0], [1.0, 0.0],
         "x2 = w2 = 0"),
        ("n2-singular", [[1.0, 1.0], [1.0, 1.0]], [-1.0, -1.0], [0.5, 0.5],
         "singular A, x not unique"),
    ]
    out = []
    for key, A, b, x, note in cases:
        A = np.asarray(A, dtype=float)
        b = np.asarray(b, dtype=float)
        x = np.asarray(x, dtype=float)
        w = A @ x + b
        out.append(LCP(A, b, name=f"tiny-{key}", reference=_ref(x, w, b),
                       meta=_meta("tiny", None, len(b), case=key, note=note,
                                  expect={"x_unique": key != "n2-singular"})))
    return out


# ---------------------------------------------------------------------- all-inactive
@dataclass(frozen=True)
class AllInactiveParams:
    """Parameters of all-inactive.

    Parameters
    ----------
    count : int
        Number of instances (default 3).
    seed : int
        Random seed (default 0).
    n : int
        Size (default 30).
    cond : float
        Condition number of A (default 100).
    zero_fraction : float
        Fraction of entries of b set exactly to 0 (degenerate: x_i = w_i = 0;
        default 0.1).
    """

    count: int = 3
    seed: int = 0
    n: int = 30
    cond: float = 100.0
    zero_fraction: float = 0.1

    def __post_init__(self) -> None:
        _check_count(self.count)
        if self.n < 1:
            raise ValueError(f"n must be >= 1, got {self.n}")
        _check_cond("cond", self.cond)
        if not 0 <= self.zero_fraction <= 1:
            raise ValueError("zero_fraction must be in [0, 1]")


@register_problem("all-inactive", AllInactiveParams, default=True)
def all_inactive(p: AllInactiveParams) -> list[LCP]:
    """SPD LCPs with ``b >= 0``: the solution is ``x = 0``, ``w = b`` (no contact active).

    A solver started at 0 should stop at once with zero MVPs (a zero product
    is free).
    """
    out = []
    for i in range(p.count):
        rng = np.random.default_rng([p.seed, i])
        A = random_spd_matrix(rng, p.n, p.cond)
        b = rng.uniform(0.1, 1.0, p.n)
        b[rng.permutation(p.n)[:int(round(p.zero_fraction * p.n))]] = 0.0
        x = np.zeros(p.n)
        out.append(LCP(A, b, name=f"all-inactive-{i}", reference=_ref(x, b.copy(), b),
                       meta=_meta("all-inactive", p.seed, p.n, instance=i, cond=p.cond,
                                  expect={"solution_is_x0": True})))
    return out


# ---------------------------------------------------------------------- bad-scale
@dataclass(frozen=True)
class BadScaleParams:
    """Parameters of bad-scale.

    Parameters
    ----------
    count : int
        Number of instances (default 3).
    seed : int
        Random seed (default 0).
    n : int
        Size (default 40).
    cond : float
        Condition number of A (default 100).
    log_min, log_max : float
        log10 range of the magnitudes of b (defaults -12 and 6).
    """

    count: int = 3
    seed: int = 0
    n: int = 40
    cond: float = 100.0
    log_min: float = -12.0
    log_max: float = 6.0

    def __post_init__(self) -> None:
        _check_count(self.count)
        if self.n < 1:
            raise ValueError(f"n must be >= 1, got {self.n}")
        _check_cond("cond", self.cond)
        if self.log_max < self.log_min:
            raise ValueError("log_max must be >= log_min")


@register_problem("bad-scale", BadScaleParams, default=True)
def bad_scale(p: BadScaleParams) -> list[LCP]:
    """SPD LCPs whose b spans magnitudes 10^log_min..10^log_max with mixed signs.

    Entry i of b is ``+-10^u``, u uniform in [log_min, log_max], random sign;
    the extremes are always present. Absolute stop rules are meaningless on
    the small entries; relative ones are dominated by the large ones.
    """
    out = []
    for i in range(p.count):
        rng = np.random.default_rng([p.seed, i])
        A = random_spd_matrix(rng, p.n, p.cond)
        u = rng.uniform(p.log_min, p.log_max, p.n)
        u[:2] = (p.log_min, p.log_max)
        b = rng.choice([-1.0, 1.0], p.n) * 10.0 ** u[rng.permutation(p.n)]
        out.append(LCP(A, b, name=f"bad-scale-{i}",
                       meta=_meta("bad-scale", p.seed, p.n, instance=i, cond=p.cond,
                                  b_log_range=(p.log_min, p.log_max),
                                  expect={"absolute_tol_hard": True})))
    return out


# ---------------------------------------------------------------------- bb-cycle
@dataclass(frozen=True)
class BbCycleParams:
    """Parameters of bb-cycle (none: the instances are fixed).

    Parameters
    ----------
    """


@register_problem("bb-cycle", BbCycleParams, default=True)
def bb_cycle(p: BbCycleParams) -> list[LCP]:
    """Small SPD LCPs on which projected BB without line search fails (cycles or diverges).

    Found by ``benchmarks/find_bb_cycles.py --seed 0`` (seeded random search
    over SPD matrices with n = 3..8 and condition numbers up to ~2e3, running
    projected BB1 from x = 0 with an exact Cauchy first step, 1 MVP per
    iteration: method paper, eq. spectralStepSize; Dai & Fletcher, Numer.
    Math. 100 (2005) show such counterexamples exist). Kept were instances
    whose KKT residual stays above 1e-6 over the last quarter of 5000
    iterations, also with the gradient by recurrence, with b perturbed by
    1e-9 relative and with first steps of 0.5..2 times the Cauchy step
    (``--robust-start``), so that rounding and start-up differences between
    implementations do not remove the failure; confirmed with
    ``lcpbench.solve(..., solver="bb-pgd")`` (status not converged within
    2000 iterations). ``kind``
    in meta says whether the residual cycles (bounded) or diverges. The
    matrices are literal round-trip floats, exactly symmetric, regenerable by
    ``candidate(0, trial)`` in that script. The reference QP solvers solve them
    easily (they are strictly convex).
    """
    out = []
    for d in _BB_CYCLE_DATA:
        A = np.array(d["A"], dtype=float)
        b = np.array(d["b"], dtype=float)
        out.append(LCP(A, b, name=f"bb-cycle-{d['trial']}",
                       meta=_meta("bb-cycle", 0, len(b), trial=d["trial"], cond=d["cond"],
                                  kind=d["kind"], found_by="benchmarks/find_bb_cycles.py",
                                  expect={"unsafeguarded_may_fail": True})))
    return out


# Instances printed by ``python benchmarks/find_bb_cycles.py --seed 0 --max-cond 2e3
# --robust-start --keep 8`` (trials 593, 602, 1062, 1164, 1540: bounded cycles; 1260, 1877:
# divergence; trial 747 was left out: its cycle has a small residual, ~2e-3).
_BB_CYCLE_DATA = [
    dict(trial=593, cond=1216, kind='cycle',
         A=[
             [88.16540346083988, -113.43092054780185, 58.41266435869903, -189.95517402960883,
              167.07157011344003],
             [-113.43092054780185, 169.64125116218722, -83.11333845094477, 299.482382570513,
              -254.0081990624866],
             [58.41266435869903, -83.11333845094477, 65.26495700694412, -144.87563239645937,
              122.66365674967965],
             [-189.95517402960883, 299.482382570513, -144.87563239645937, 545.0879470406265,
              -452.96987853669856],
             [167.07157011344003, -254.0081990624866, 122.66365674967965, -452.96987853669856,
              421.28311783045416],
         ],
         b=[0.1642199806044702, 0.0033593069074787946, -0.2555050375578252, -0.2164952536030857,
            0.035016716987910555]),
    dict(trial=602, cond=1708, kind='cycle',
         A=[
             [1409.0385182043408, -435.20811812544616, -181.54610315014875, -374.431070213295,
              80.41176900291345, -223.61967328269787],
             [-435.20811812544616, 142.42254987525976, 54.652607712940835, 118.18475335562852,
              -29.249088945169277, 61.79276349277975],
             [-181.54610315014875, 54.652607712940835, 34.310607683389414, 55.734335931826095,
              -3.7405411857946955, 25.01486242007533],
             [-374.431070213295, 118.18475335562852, 55.734335931826095, 113.72521806401737,
              -20.04940552325755, 46.98262485548291],
             [80.41176900291345, -29.249088945169277, -3.7405411857946955, -20.04940552325755,
              12.375226760946232, -9.477101137799757],
             [-223.61967328269787, 61.79276349277975, 25.01486242007533, 46.98262485548291,
              -9.477101137799757, 53.71509877452669],
         ],
         b=[5.727698997178665, 7.502272903336048, 7.262155517819868, -4.926971978422028,
            -7.904825840139522, 5.992585559182537]),
    dict(trial=1062, cond=1930, kind='cycle',
         A=[
             [1.659709185376959, 25.32344317860954, -4.5334035120847656],
             [25.32344317860954, 1883.071018926355, -295.52645132181914],
             [-4.5334035120847656, -295.52645132181914, 48.37700162810998],
         ],
         b=[-1.5894317317453615, -0.037214013181774405, 3.092732218875055]),
    dict(trial=1164, cond=633.9, kind='cycle',
         A=[
             [24.3023530170041, 14.063788435800017, -45.12289084195403, -23.1496947888718,
              -57.65936731071524, 57.99427922232496, -49.07725225380672, -9.749841011398294],
             [14.063788435800017, 18.532510960356408, -32.609187368657345, -8.321200801321147,
              -37.25474317973877, 30.412291179226173, -24.979754658915517, -10.327540250578368],
             [-45.12289084195403, -32.609187368657345, 102.93514789192496, 50.311280880495545,
              126.31993644823525, -130.91630009435184, 108.06824511382717, 22.87567193598151],
             [-23.1496947888718, -8.321200801321147, 50.311280880495545, 44.76720747957658,
              72.9937141067669, -78.96523351571739, 68.0648136061018, 8.28153947416987],
             [-57.65936731071524, -37.25474317973877, 126.31993644823525, 72.9937141067669,
              165.4836114749438, -168.61928990707514, 139.52845174351836, 25.9934305207573],
             [57.99427922232496, 30.412291179226173, -130.91630009435184, -78.96523351571739,
              -168.61928990707514, 188.76107071553548, -155.52179410502413, -23.7255229030793],
             [-49.07725225380672, -24.979754658915517, 108.06824511382717, 68.0648136061018,
              139.52845174351836, -155.52179410502413, 135.52715621570565, 19.484560090864427],
             [-9.749841011398294, -10.327540250578368, 22.87567193598151, 8.28153947416987,
              25.9934305207573, -23.7255229030793, 19.484560090864427, 16.047340930038942],
         ],
         b=[0.11792218008053042, -0.4551048872389898, 0.7963776938395436, -0.38278002329095706,
            -0.39468556724908005, 0.5788167041037479, 0.11257630920179276, -0.14611509874895412]),
    dict(trial=1540, cond=1477, kind='cycle',
         A=[
             [210.86041115270322, 276.9116253982594, 118.58455748592381, 306.6533929394013,
              -250.80900662511775, -57.146735090897906, -13.06097972586325],
             [276.9116253982594, 393.51465124244385, 148.96090919463853, 444.1576726015472,
              -344.2774928245286, -79.93579025821629, -6.553607521186711],
             [118.58455748592381, 148.96090919463853, 95.67811898202073, 160.79848589178684,
              -109.6439868234965, -30.90206675977571, -23.583869848519402],
             [306.6533929394013, 444.1576726015472, 160.79848589178684, 511.67728601890275,
              -383.7002338121959, -93.52281913330168, -1.2925656668633954],
             [-250.80900662511775, -344.2774928245286, -109.6439868234965, -383.7002338121959,
              353.9521282150129, 73.2614721961392, -18.24515218284644],
             [-57.146735090897906, -79.93579025821629, -30.90206675977571, -93.52281913330168,
              73.2614721961392, 31.353182197014142, -17.520354477774042],
             [-13.06097972586325, -6.553607521186711, -23.583869848519402, -1.2925656668633954,
              -18.24515218284644, -17.520354477774042, 46.52465547342823],
         ],
         b=[0.0518870795366651, -0.1645995234768234, -0.2171497480430451, -0.10735996226338357,
            -0.854855968962599, -0.1669466870302374, 0.3455425507395015]),
    dict(trial=1260, cond=582.7, kind='divergence',
         A=[
             [355.83205821120976, 16.695730956040663, -5.596639338701898, 157.13427854712927,
              -235.0631532210549],
             [16.695730956040663, 7.148744482683763, 2.2392869469453602, 10.297150688941592,
              -11.614304246081415],
             [-5.596639338701898, 2.2392869469453602, 3.848996928736721, -0.8293845353965283,
              2.459901294886323],
             [157.13427854712927, 10.297150688941592, -0.8293845353965283, 74.00077071089297,
              -102.78834113506231],
             [-235.0631532210549, -11.614304246081415, 2.459901294886323, -102.78834113506231,
              159.18300592205318],
         ],
         b=[-2.5258115992386636, 2.694913823429838, -4.862916085170021, 1.4297175616072781,
            -2.2662776063024093]),
    dict(trial=1877, cond=1925, kind='divergence',
         A=[
             [801.5080394223224, 787.2754438462678, -528.8197255716337],
             [787.2754438462678, 775.8062800130222, -519.6473364648174],
             [-528.8197255716337, -519.6473364648174, 350.6818583348484],
         ],
         b=[-0.5616494813909465, 2.7960347815724207, -3.1211061775731377]),
]
