"""Contacts between spheres and the collision-resolution LCP of one time step.

Given sphere centres ``c`` and radii ``a``, a pair ``(i, j)``, ``i < j``, is a
candidate contact when its surface gap ``Phi = |c_j - c_i| - a_i - a_j`` is at
most ``delta`` (eq. collisional-set of the method paper). Contact ``l`` has the
unit normal ``n_l = (c_j - c_i) / |c_j - c_i|`` (from ``i`` to ``j``) and the
column ``D[:, l]`` of the sparse ``(6M, n)`` contact matrix carries ``-n_l`` on
the force rows of sphere ``i`` and ``+n_l`` on those of sphere ``j``; the
torque rows are zero because a frictionless normal force on a sphere passes
through its centre.

Sign convention (checked in the tests): a force magnitude ``x_l >= 0`` pushes
``j`` along ``+n_l`` and ``i`` along ``-n_l``, i.e. apart; the rate of change
of the gap is ``d Phi_l / dt = n_l . (U_j - U_i) = (D' U)_l``, so
``Phi + dt D' U >= 0`` is non-penetration after a forward Euler step to first
order, and with ``U = U_nc + M D x`` it gives the LCP of eq. (defAandb)::

    A = D' M D,      b = (Phi + dt D' U_nc) / dt.

Vectors of forces and velocities are ordered per sphere: ``(F_i, T_i)`` on
rows ``6 i .. 6 i + 5`` map to ``(U_i, Omega_i)`` on the same rows.

The LCP of a step is assembled in :mod:`.problem`, its operator in :mod:`.operators`, and
the mobility models are named in :mod:`.fidelity`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .geometry import check_configuration, pair_gaps

__all__ = ["Contacts", "max_overlap"]


# ----------------------------------------------------------------------------- contacts


@dataclass(frozen=True)
class Contacts:
    """Candidate contacts of a sphere configuration.

    Build with :meth:`from_configuration`.

    Attributes
    ----------
    pairs : ndarray, shape (n, 2), int
        Sphere indices ``(i, j)``, ``i < j``, sorted lexicographically: the pair
        identity of each column (used to carry forces across time steps).
    normals : ndarray, shape (n, 3)
        Unit normals from sphere ``i`` to sphere ``j``.
    gaps : ndarray, shape (n,)
        Surface gaps ``Phi`` (negative when the pair overlaps).
    D : scipy.sparse.csc_matrix, shape (6M, n)
        Contact matrix: ``F_c = D x`` are the forces and torques of the contact
        force magnitudes ``x``.
    M : int
        Number of spheres.
    delta : float
        Gap threshold the pairs were selected with.
    """

    pairs: np.ndarray
    normals: np.ndarray
    gaps: np.ndarray
    D: sp.csc_matrix
    M: int
    delta: float

    @classmethod
    def from_configuration(cls, centers, radii, delta: float) -> Contacts:
        """Candidate pairs with gap ``<= delta``, their normals, gaps and ``D``.

        Parameters
        ----------
        centers : array_like, shape (M, 3)
        radii : float or array_like, shape (M,)
        delta : float
            Gap threshold (finite, non-negative), in the units of the centres.

        Raises
        ------
        ValueError
            Invalid configuration (see :func:`check_configuration`) or ``delta``.
        """
        c, r = check_configuration(centers, radii)
        delta = float(delta)
        if not (np.isfinite(delta) and delta >= 0):
            raise ValueError(f"delta = {delta} must be a finite non-negative gap threshold "
                             "(e.g. a few times the largest displacement per step)")
        pairs, gaps = pair_gaps(c, r, delta)
        M, n = len(c), len(pairs)
        d = c[pairs[:, 1]] - c[pairs[:, 0]] if n else np.empty((0, 3))
        dist = np.linalg.norm(d, axis=1)
        normals = d / dist[:, None] if n else d
        rows = np.concatenate([6 * pairs[:, 0][:, None] + np.arange(3),
                               6 * pairs[:, 1][:, None] + np.arange(3)], axis=1).ravel()
        cols = np.repeat(np.arange(n), 6)
        vals = np.concatenate([-normals, normals], axis=1).ravel()
        D = sp.csc_matrix((vals, (rows, cols)), shape=(6 * M, n))
        return cls(pairs.astype(np.intp), normals, gaps, D, M, delta)

    @property
    def n(self) -> int:
        """Number of candidate contacts."""
        return int(len(self.pairs))

    def pair_ids(self) -> list[tuple[int, int]]:
        """``(i, j)`` per column, for matching forces across time steps."""
        return [(int(i), int(j)) for i, j in self.pairs]

    def index_of(self, old_pairs: np.ndarray) -> np.ndarray:
        """Where each of these contacts was among ``old_pairs`` (pair identity), -1 if new.

        Parameters
        ----------
        old_pairs : ndarray, shape (k, 2)
            Pair identities of a previous step's contacts.

        Returns
        -------
        ndarray of int, shape (n,)
            ``index[l] = k`` when contact ``l`` is the pair ``old_pairs[k]``, else ``-1``;
            ``old_vector[index]`` (where ``index >= 0``) moves a previous step's
            per-contact vector onto these contacts.
        """
        old_pairs = np.asarray(old_pairs, dtype=np.intp).reshape(-1, 2)
        out = np.full(self.n, -1, dtype=np.intp)
        if not self.n or not len(old_pairs):
            return out
        lookup = {(int(i), int(j)): k for k, (i, j) in enumerate(old_pairs)}
        for row, (i, j) in enumerate(self.pairs):
            out[row] = lookup.get((int(i), int(j)), -1)
        return out

    def carry(self, old_pairs: np.ndarray, old_x: np.ndarray) -> np.ndarray:
        """Forces of a previous step mapped onto these contacts by pair identity.

        Parameters
        ----------
        old_pairs : ndarray, shape (k, 2)
            Pair identities of the previous step's contacts.
        old_x : ndarray, shape (k,)
            Their force magnitudes.

        Returns
        -------
        ndarray, shape (n,)
            ``old_x`` of the same pair where it existed before, 0 for new pairs;
            negative or non-finite old values become 0.
        """
        old_pairs = np.asarray(old_pairs, dtype=np.intp).reshape(-1, 2)
        old_x = np.asarray(old_x, dtype=np.float64).reshape(-1)
        if len(old_pairs) != len(old_x):
            raise ValueError(f"carry: {len(old_pairs)} pairs but {len(old_x)} forces; pass "
                             "the pairs and forces of the same step")
        index = self.index_of(old_pairs)
        out = np.zeros(self.n)
        out[index >= 0] = old_x[index[index >= 0]]
        out[~np.isfinite(out)] = 0.0
        return np.maximum(out, 0.0)


def max_overlap(centers: np.ndarray, radii: np.ndarray) -> float:
    """Largest overlap ``max(0, -min gap)`` over all pairs of spheres."""
    _, gaps = pair_gaps(np.asarray(centers, float), np.asarray(radii, float), 0.0)
    return float(max(0.0, -gaps.min())) if len(gaps) else 0.0
