"""LCPs without a solution: a direction ``d >= 0`` with ``A d = 0`` and ``b'd < 0``.

For a positive semidefinite ``A`` the LCP has a solution exactly when it is
feasible, and by Farkas' lemma it is infeasible exactly when some ``d >= 0``
has ``A d = 0`` and ``b'd < 0``: along ``d`` the objective
``1/2 x'Ax + b'x`` decreases without bound. A solver can only report that it
found such a direction (status ``infeasible``) or ran out of budget; a
``converged`` claim on these instances is always false. Two constructions:

* ``infeasible``: ``A = J J'`` of rank ``k < n`` whose null space contains a
  planted ``d >= 0``, and ``b`` with ``b'd < 0``;
* ``unbounded``: ``A`` with some zero rows and columns (variables that do not
  enter the quadratic at all) and a negative ``b_i`` on one of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from lcpbench import LCP, register_problem
from lcpbench.core.guards import dense_family
from lcpbench.core.specs import Bounds, Doc

from .synthetic import Count, SeededParams, check_flops, seeded

__all__ = ["infeasible_lcp", "unbounded_lcp"]


def infeasible_lcp(rng: np.random.Generator, n: int, *, rank: int | None = None,
                   name: str = "infeasible") -> LCP:
    """``A = J J'`` (rank ``k < n``) with a null direction ``d >= 0`` and ``b'd < 0``.

    ``d`` is non-negative with a random support of at least two entries, ``J``
    is a Gaussian matrix projected onto the orthogonal complement of ``d``, and
    ``b`` a Gaussian vector shifted along ``d`` so that ``b'd = -||d||``.
    ``meta['direction']`` holds the certificate ``d``.
    """
    if n < 2:
        raise ValueError(f"an infeasible symmetric LCP needs n >= 2, got {n}")
    k = int(rank) if rank is not None else int(rng.integers(1, n))
    if not 1 <= k < n:
        raise ValueError(f"rank must be in 1..n-1, got {k}")
    d = np.zeros(n)
    support = rng.choice(n, size=int(rng.integers(2, n + 1)), replace=False)
    d[support] = rng.uniform(0.2, 1.0, support.size)
    d /= np.linalg.norm(d)
    G = rng.standard_normal((n, k)) * 10.0 ** rng.uniform(-2, 2)
    J = G - np.outer(d, d @ G)
    A = J @ J.T
    A = (A + A.T) / 2
    g = rng.standard_normal(n)
    b = g - (g @ d + 1.0) * d
    return LCP(A, b, name=name, meta={"family": "infeasible", "n": n, "rank": k,
                                       "direction": d.tolist()})


def unbounded_lcp(rng: np.random.Generator, n: int, *, name: str = "unbounded") -> LCP:
    """``A = diag(S, 0)`` with ``S`` SPD and a negative ``b_i`` on a zero row.

    ``x_i`` can grow without bound while ``w_i = b_i < 0``: no point is feasible.
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    m = int(rng.integers(1, n + 1))                      # zero rows and columns
    order = rng.permutation(n)
    A = np.zeros((n, n))
    live = order[m:]
    if live.size:
        J = rng.standard_normal((live.size, live.size))
        A[np.ix_(live, live)] = J @ J.T + 1e-3 * np.eye(live.size)
    b = rng.standard_normal(n)
    b[order[0]] = -abs(b[order[0]]) - 0.1
    return LCP((A + A.T) / 2, b, name=name, meta={"family": "unbounded", "n": n,
                                                   "zero_rows": int(m)})


@dataclass(frozen=True)
class InfeasibleParams(SeededParams):
    """Parameters of infeasible and unbounded."""

    count: Count = 4
    n: Annotated[int, Bounds(ge=2), Doc("Size of every instance.")] = 5


def _estimate(p: InfeasibleParams):
    """A dense n x n A per instance, from a product of n x k factors (k < n)."""
    return dense_family(p.count, p.n, matrices=1, temporaries=3,
                        flops_each=2.0 * float(p.n) ** 3 + check_flops(p.n))


@register_problem("infeasible", InfeasibleParams, estimate=_estimate)
def infeasible(p: InfeasibleParams) -> list[LCP]:
    """LCPs without a solution: a null direction d >= 0 of A with b'd < 0."""
    return seeded(p.count, p.seed, lambda i, rng: infeasible_lcp(rng, p.n, name=f"infeasible-{i}"))


@register_problem("unbounded", InfeasibleParams, estimate=_estimate)
def unbounded(p: InfeasibleParams) -> list[LCP]:
    """LCPs whose QP is unbounded below: a zero row of A with a negative b_i."""
    return seeded(p.count, p.seed, lambda i, rng: unbounded_lcp(rng, p.n, name=f"unbounded-{i}"))
