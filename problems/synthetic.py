"""Building blocks of the synthetic problem families (``hard`` and ``random``).

Random SPD matrices of a given condition number, planted complementary
solutions, the seeded loop every family runs (instance ``i`` draws from
``default_rng([seed, i])``, so an instance does not depend on how many others
are generated), and the parameter types whose bounds the registry checks when
a family's parameters are built.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Optional

import numpy as np

from lcpbench import LCP
from lcpbench.core.guards import Estimate, dense_family
from lcpbench.core.lcp import PSD_CHECK_MAX_N
from lcpbench.core.specs import Bounds, CheckedParams, Doc

__all__ = ["Count", "Seed", "Size", "NonNegative", "Cond", "InstanceSize", "MatrixCond",
           "SeededParams", "seeded",
           "random_spd_matrix",
           "planted_b", "planted_pair", "reference", "meta", "spd_flops", "check_flops",
           "spd_estimate"]

#: Number of instances of a family.
Count = Annotated[int, Bounds(ge=1)]
#: The seed of a family (``default_rng`` takes non-negative seeds).
Seed = Annotated[int, Bounds(ge=0)]
#: A problem size or another count that must be positive.
Size = Annotated[int, Bounds(ge=1)]
#: A count that may be zero.
NonNegative = Annotated[int, Bounds(ge=0)]
#: A condition number.
Cond = Annotated[float, Bounds(ge=1)]
#: The size ``n`` of every instance of a family (documented here, once).
InstanceSize = Annotated[int, Bounds(ge=1), Doc("Size of every instance.")]
#: The condition number of a family's A (documented here, once).
MatrixCond = Annotated[float, Bounds(ge=1), Doc("Condition number of A.")]



@dataclass(frozen=True)
class SeededParams(CheckedParams):
    """Parameters every seeded family shares (a family redeclares ``count`` for its own default).

    Parameters
    ----------
    count : int
        Number of instances.
    seed : int
        Random seed; instance i draws from ``default_rng([seed, i])``, so it does not depend
        on how many instances are generated.
    """

    count: Count = 5
    seed: Seed = 0

def seeded(count: int, seed: int, make: Callable[[int, np.random.Generator], LCP]) -> list[LCP]:
    """``[make(i, default_rng([seed, i])) for i in range(count)]``: one random stream per instance.

    Parameters
    ----------
    count : int
        Number of instances.
    seed : int
        The family's seed.
    make : callable
        ``make(i, rng) -> LCP`` builds instance ``i`` from its own generator.

    Returns
    -------
    list of LCP
    """
    return [make(i, np.random.default_rng([seed, i])) for i in range(count)]


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


def spd_flops(n: int) -> float:
    """Work of :func:`random_spd_matrix` in matrix-product operations (a QR, Q, Q diag Q').

    Householder QR and forming Q are about 8/3 n^3 flops at a fraction of the speed of a
    matrix product; the product ``(Q lam) Q'`` is 2 n^3.
    """
    return 10.0 * float(n) ** 3


def check_flops(n: int) -> float:
    """Work of the LCP's positive-semidefiniteness check (an eigenvalue solve up to
    :data:`lcpbench.core.lcp.PSD_CHECK_MAX_N`, none beyond)."""
    return 10.0 * float(n) ** 3 if n <= PSD_CHECK_MAX_N else 0.0


def spd_estimate(count: int, n: int, *, matrices: int = 1, extra_flops: float = 0.0
                 ) -> Estimate:
    """The :class:`~lcpbench.core.guards.Estimate` of ``count`` random SPD instances of size n.

    Each keeps ``matrices`` dense n x n matrices; building one holds four more
    (the Gaussian, Q, R and the scaled Q) and costs :func:`spd_flops` plus the LCP's
    check plus ``extra_flops``.
    """
    return dense_family(count, n, matrices=matrices, temporaries=4,
                        flops_each=spd_flops(n) + check_flops(n) + extra_flops)


def planted_b(A: np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``b = w - A x``, so that ``(x, w)`` solves the LCP when complementary."""
    return w - A @ x


def planted_pair(rng: np.random.Generator, A: np.ndarray, n_active: int,
                 n_degenerate: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A complementary pair ``(x, w)`` planted in ``A`` and the ``b`` that makes it a solution.

    A random permutation splits the indices into ``n_active`` with ``x_i > 0 = w_i``,
    ``n_degenerate`` with ``x_i = w_i = 0`` and the rest with ``x_i = 0 < w_i``; the
    nonzero values are U(0.5, 2).

    Returns
    -------
    x, w, b : ndarray
        ``b = w - A x``.
    """
    n = A.shape[0]
    perm = rng.permutation(n)
    act, inact = perm[:n_active], perm[n_active + n_degenerate:]
    x = np.zeros(n)
    w = np.zeros(n)
    x[act] = rng.uniform(0.5, 2.0, act.size)
    w[inact] = rng.uniform(0.5, 2.0, inact.size)
    return x, w, planted_b(A, x, w)


def reference(x: np.ndarray, w: np.ndarray, b: np.ndarray) -> dict:
    """The ``LCP.reference`` of a known solution: ``x``, ``w`` and the QP objective."""
    return {"x": x, "w": w, "objective": 0.5 * float(x @ (w + b)) if x.size else 0.0}


def meta(family: str, seed: Optional[int], n: int, **extra) -> dict:
    """``LCP.meta`` of a synthetic instance: family, seed (None if deterministic), n, extras."""
    return {"family": family, "seed": seed, "n": int(n), **extra}
