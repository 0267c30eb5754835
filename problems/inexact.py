"""Inexact operators: LCPs whose every product is an iterative solve at a stated tolerance.

Every product of the live mobility is a GMRES solve that meets its tolerance
only approximately, so ``A v`` carries a relative error of about that
tolerance and two products of nearby vectors do not differ by exactly ``A``
times their difference. This family reproduces the situation with a small
sparse SPD matrix ``K`` (a shifted 1-D Laplacian with random positive
weights) and ``A = K^{-1}``: each product ``v -> K^{-1} v`` is a conjugate
gradient solve at relative tolerance ``rtol``. The operator declares that
accuracy (``Operator(..., rtol=rtol)``), so solvers loosen their stop test to
what it allows and say so in the result's message.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, cg, spsolve

from lcpbench import LCP, Operator, register_problem
from lcpbench.core.guards import Estimate
from lcpbench.core.specs import Bounds

from .synthetic import Count, InstanceSize, SeededParams, seeded

__all__ = ["InexactInverse", "exact_product", "inexact_inverse", "inexact_lcp", "stiffness"]


def stiffness(rng: np.random.Generator, n: int, shift: float) -> sp.csr_matrix:
    """A weighted 1-D Laplacian plus ``shift`` times the identity (SPD, sparse)."""
    c = rng.uniform(0.5, 2.0, n + 1)                     # conductances of the n + 1 links
    main = c[:-1] + c[1:] + shift
    return sp.diags([-c[1:-1], main, -c[1:-1]], [-1, 0, 1], format="csr")


class InexactInverse(LinearOperator):
    """``v -> K^{-1} v`` by conjugate gradients to relative tolerance ``rtol``.

    The solve starts from zero every time, so the same ``v`` always gives the
    same (inexact) answer; nearby vectors do not. A solve that does not reach
    its tolerance in ``10 n`` iterations raises, naming the residual.
    :meth:`exact` is the same product by a sparse direct solve, for checking
    answers against the operator it approximates.

    Parameters
    ----------
    K : sparse matrix
        The SPD matrix whose inverse is applied.
    rtol : float
        Relative residual tolerance of every CG solve.
    """

    def __init__(self, K: sp.spmatrix, rtol: float):
        super().__init__(dtype=np.dtype(np.float64), shape=K.shape)
        self.K = sp.csr_matrix(K)
        self.rtol = float(rtol)

    def _matvec(self, v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=np.float64).reshape(-1)
        n = self.shape[0]
        y, code = cg(self.K, v, rtol=self.rtol, atol=0.0, maxiter=10 * n)
        if code != 0:
            res = np.linalg.norm(self.K @ y - v) / max(np.linalg.norm(v), 1e-300)
            raise RuntimeError(f"inner CG did not reach rtol {self.rtol:g} (relative residual "
                               f"{res:.3g} after {10 * n} iterations)")
        return y

    def _adjoint(self) -> InexactInverse:
        return self

    def exact(self, v: np.ndarray) -> np.ndarray:
        """``K^{-1} v`` by a sparse direct solve (to rounding, not at ``rtol``)."""
        return spsolve(self.K.tocsc(), np.asarray(v, dtype=np.float64).reshape(-1))


def inexact_inverse(K: sp.spmatrix, rtol: float) -> InexactInverse:
    """``v -> K^{-1} v`` by conjugate gradients at relative tolerance ``rtol``.

    An :class:`InexactInverse`, which also gives the exact product.
    """
    return InexactInverse(K, rtol)


def exact_product(lcp: LCP, x: np.ndarray) -> np.ndarray:
    """``A x`` to rounding for an instance of this family (a direct solve, not counted).

    For tests and benchmarks that check answers against the operator the
    inexact products approximate. Raises ``TypeError`` for other instances.
    """
    impl = getattr(lcp.A, "_impl", None)
    if not isinstance(impl, InexactInverse):
        raise TypeError(f"{lcp.name!r} is not an inexact-operator instance (its high operator "
                        "is not an InexactInverse); exact_product needs one from this module")
    return impl.exact(x)


def inexact_lcp(rng: np.random.Generator, n: int, rtol: float, *, shift: float = 1e-2,
                name: str = "inexact") -> LCP:
    """One LCP with ``A = K^{-1}`` applied by CG at ``rtol`` and ``b ~ N(0, 1)``.

    The operator declares ``rtol`` as its accuracy; ``meta`` records ``rtol``
    and ``shift`` (the smallest eigenvalue of ``K`` is above ``shift``, so
    ``||A||_2 < 1 / shift``).
    """
    K = stiffness(rng, n, shift)
    A = Operator(inexact_inverse(K, rtol), rtol=rtol)
    b = rng.standard_normal(n)
    return LCP(A, b, name=name, meta={"family": "inexact", "n": int(n), "rtol": float(rtol),
                                       "shift": float(shift)})


@dataclass(frozen=True)
class InexactParams(SeededParams):
    """Parameters of inexact.

    Parameters
    ----------
    rtol : float
        Relative tolerance of every inner CG solve, the operator's declared
        accuracy (default 1e-6, the GMRES tolerance of the live backend's
        cheaper settings).
    """

    count: Count = 4
    n: InstanceSize = 60
    rtol: Annotated[float, Bounds(gt=0, lt=1)] = 1e-6


def _inexact_estimate(p: InexactParams) -> Estimate:
    """A sparse tridiagonal K (about 64 bytes per row with b) per instance; no dense work."""
    return Estimate(p.count, p.n, p.count * (64.0 * p.n + 2048.0), 0.0)


@register_problem("inexact", InexactParams, estimate=_inexact_estimate)
def inexact(p: InexactParams) -> list[LCP]:
    """LCPs whose products are conjugate-gradient solves at a stated tolerance."""
    return seeded(p.count, p.seed,
                  lambda i, rng: inexact_lcp(rng, p.n, p.rtol, name=f"inexact-{i}"))
