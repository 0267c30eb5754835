"""The contact operator ``A = D' M D`` of one configuration, symmetrised or not.

For ``rpy`` and ``self`` (exactly symmetric mobilities) a product is one mobility solve,
``v -> D' (M (D v))``.  The discrete boundary-integral mobility is symmetric only to its
discretisation error (docs/mobility.md), so its contact operator is symmetrised
explicitly, ``v -> D' (M + M') D v / 2``, with the exact adjoint of the discrete mobility
(``BimMobility.rmatvec``, GMRES on the transposed equation): one forward and one adjoint
solve per product (in one call when the mobility makes both together,
``BimMobility.matvec_rmatvec``).  :class:`ContactOperator` keeps the last products
``M D v`` so that the position update after a solve needs no new solve.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Optional

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

__all__ = ["ContactOperator", "contact_product"]


def _apply(M: LinearOperator, v: np.ndarray) -> np.ndarray:
    return np.asarray(M.matvec(v), dtype=np.float64).reshape(-1)


def _apply_adjoint(M: LinearOperator, v: np.ndarray) -> np.ndarray:
    return np.asarray(M.rmatvec(v), dtype=np.float64).reshape(-1)


def _forward_and_adjoint(M: LinearOperator, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(M f, M' f)``, in one call when the operator makes both together
    (``BimMobility.matvec_rmatvec``: the two solves in lock step)."""
    both = getattr(M, "matvec_rmatvec", None)
    if both is None:
        return _apply(M, f), _apply_adjoint(M, f)
    u, ua = both(f, f)
    return (np.asarray(u, dtype=np.float64).reshape(-1),
            np.asarray(ua, dtype=np.float64).reshape(-1))


def _accuracy_hook(M: LinearOperator):
    """The mobility's ``at_accuracy(rtol)`` context (looser solves on request), or None."""
    return getattr(M, "at_accuracy", None)


def _symmetrized(M: LinearOperator, D: sp.csc_matrix, Dt: sp.csr_matrix, v: np.ndarray,
                 forward: Optional[np.ndarray] = None) -> np.ndarray:
    """``D' (M + M') D v / 2``: the explicitly symmetrised contact operator (one forward
    and one adjoint mobility solve; ``forward`` = ``M D v`` when already known)."""
    Dv = D @ v
    if forward is None:
        u, ua = _forward_and_adjoint(M, Dv)
    else:
        u, ua = forward, _apply_adjoint(M, Dv)
    return Dt @ (0.5 * (u + ua))


def contact_product(M: LinearOperator, D: sp.csc_matrix, symmetrize: bool) -> LinearOperator:
    """``v -> D' M D v`` (or ``D' (M + M') D v / 2``) without a cache: the operator of a low
    fidelity, whose products never move the spheres.  Its ``cold_products`` is the
    mobility's (None when the mobility keeps nothing between products)."""
    Dt = D.T.tocsr()
    n = D.shape[1]

    def mv(v: np.ndarray) -> np.ndarray:
        return _symmetrized(M, D, Dt, v) if symmetrize else Dt @ _apply(M, D @ v)

    op = LinearOperator((n, n), dtype=np.float64, matvec=mv)
    # a mobility that keeps Krylov directions offers products at a first product's cost
    # (BimMobility.cold_products): what a timing of this low's cost must use
    op.cold_products = getattr(M, "cold_products", None)
    # an iterative mobility offers products to a looser accuracy (the hook
    # lcpbench.Operator.product_within uses)
    op.at_accuracy = _accuracy_hook(M)
    return op


class ContactOperator:
    """``v -> D' M D v`` (or ``D' (M + M') D v / 2`` with ``symmetrize``) with a small
    cache of ``M D v`` for the position update.

    Parameters
    ----------
    D : scipy.sparse.csc_matrix, shape (6M, n)
        Contact matrix.
    M : LinearOperator, shape (6M, 6M)
        Mobility.
    cache : int
        Products ``M D v`` kept.
    symmetrize : bool
        Symmetrise with the adjoint solve.

    Attributes
    ----------
    solves : int
        Mobility solves made so far (forward and adjoint).
    """

    def __init__(self, D: sp.csc_matrix, M: LinearOperator, cache: int = 8,
                 symmetrize: bool = False):
        self.D, self.Dt, self.M = D, D.T.tocsr(), M
        self._cache: list[tuple[np.ndarray, np.ndarray]] = []
        self._size = cache
        self.symmetrize = bool(symmetrize)
        self.solves = 0
        self._loose = 0                  # > 0 inside at_accuracy: products are not cached

    @contextlib.contextmanager
    def at_accuracy(self, rtol: float) -> Iterator[None]:
        """Products made inside are solved to relative accuracy ``rtol`` (the mobility's
        ``at_accuracy``) and kept out of the cache, so that the position update never
        uses a loose product.  ``TypeError`` for a mobility without that hook."""
        hook = _accuracy_hook(self.M)
        if hook is None:
            raise TypeError(f"{type(self.M).__name__} has no at_accuracy(rtol): its products "
                            "have one accuracy")
        self._loose += 1
        try:
            with hook(rtol):
                yield
        finally:
            self._loose -= 1

    def _cached(self, v: np.ndarray) -> Optional[np.ndarray]:
        for key, u in reversed(self._cache):
            if key.shape == v.shape and np.array_equal(key, v):
                return u
        return None

    def _remember(self, v: np.ndarray, u: np.ndarray) -> None:
        if self._loose:
            return
        self._cache.append((v.copy(), u))
        del self._cache[:-self._size]

    def velocity(self, v: np.ndarray) -> np.ndarray:
        """``M D v``: from the cache when ``v`` was applied before, else one solve."""
        v = np.asarray(v, dtype=np.float64).reshape(-1)
        if not np.any(v):
            return np.zeros(self.D.shape[0])
        u = self._cached(v)
        if u is None:
            u = _apply(self.M, self.D @ v)
            self.solves += 1
            self._remember(v, u)
        return u.copy()

    def matvec(self, v: np.ndarray) -> np.ndarray:
        """One product of the contact operator."""
        if not self.symmetrize:
            return self.Dt @ self.velocity(v)
        v = np.asarray(v, dtype=np.float64).reshape(-1)
        if not np.any(v):
            return np.zeros(self.D.shape[1])
        u = self._cached(v)
        if u is not None:
            self.solves += 1                              # the adjoint solve
            return _symmetrized(self.M, self.D, self.Dt, v, forward=u)
        u, ua = _forward_and_adjoint(self.M, self.D @ v)  # both solves, together
        self.solves += 2
        self._remember(v, u)
        return self.Dt @ (0.5 * (u + ua))

    def operator(self) -> LinearOperator:
        """The contact operator as a symmetric ``LinearOperator`` (n, n); its
        ``cold_products`` is the mobility's (as :func:`contact_product`'s), and so is
        ``at_accuracy`` (None when the mobility has one accuracy)."""
        n = self.D.shape[1]
        op = LinearOperator((n, n), matvec=self.matvec, rmatvec=self.matvec, dtype=np.float64)
        op.cold_products = getattr(self.M, "cold_products", None)
        op.at_accuracy = self.at_accuracy if _accuracy_hook(self.M) is not None else None
        return op
