"""Secant pairs a PQN solve hands back and takes as a warm start, and the free first pair.

:class:`SecantMemory` is the pairs ``y_i = A s_i`` of one LCP (``result.state``,
``state=``), with their mapping onto another LCP's unknowns (time stepping with a
changing contact set); :func:`free_secant_pair` is the pair a warm start gives at no
cost. Re-exported by :mod:`lcpbench.toolkit.quasinewton`.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["SecantMemory", "bb2_scale", "free_secant_pair"]


def bb2_scale(s: np.ndarray, y: np.ndarray) -> float:
    """Barzilai-Borwein (BB2) step ``s'y / y'y`` (inverse curvature estimate)."""
    yy = float(y @ y)
    return float(s @ y) / yy if yy > 0 else 1.0


def free_secant_pair(x: np.ndarray, w: np.ndarray, b: np.ndarray
                     ) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """The secant pair ``(x - 0, A x - A 0)`` a warm start gives for free.

    With ``w = A x + b`` already computed, ``A x = w - b`` and ``A 0 = 0`` needs
    no product, so ``(s, y) = (x, w - b)`` is a secant pair of ``A`` at no cost
    (the authors' code seeds its quasi-Newton memory and BB-PGD's first step
    with it). None when ``x = 0`` or the pair has no positive curvature.
    """
    if not np.any(x):
        return None
    y = w - b
    return (x, y) if _accept(x, y, 1e-12) else None


class SecantMemory:
    """Secant pairs ``y_i = A s_i`` of one LCP, oldest first: a PQN solver's warm-start memory.

    The PQN solvers hand their final pairs back as ``result.state`` (also
    ``result.info['secant_memory']``) and start their model from the pairs of
    ``state=`` (``lcpbench.solve(..., state=memory)``). Row ``l`` of ``S`` and
    ``Y`` belongs to unknown ``l`` of the LCP (a contact, in a suspension).

    Parameters
    ----------
    S, Y : array_like, shape (n, r)
        Steps and their products with ``A``, one pair per column (a 1-D array
        is one pair). Copied; must be finite and of the same shape.

    Raises
    ------
    ValueError
        Shapes differ, an array is not 1-D or 2-D, or an entry is not finite.
    """

    def __init__(self, S, Y):
        S = np.array(S, dtype=np.float64)
        Y = np.array(Y, dtype=np.float64)
        S = S[:, None] if S.ndim == 1 else S
        Y = Y[:, None] if Y.ndim == 1 else Y
        if S.ndim != 2 or S.shape != Y.shape:
            raise ValueError(f"secant memory: S has shape {S.shape} and Y {Y.shape}; give two "
                             "arrays of the same shape (n, r), one pair y = A s per column")
        if not (np.all(np.isfinite(S)) and np.all(np.isfinite(Y))):
            raise ValueError("secant memory: S or Y has non-finite entries; pass finite pairs")
        # stored one pair per row: a solver's pairs are rows, and copying them in this layout
        # is a plain sweep (columns of an (n, r) array would be a strided transpose)
        self._S, self._Y = np.ascontiguousarray(S.T), np.ascontiguousarray(Y.T)

    @classmethod
    def from_rows(cls, S: np.ndarray, Y: np.ndarray) -> SecantMemory:
        """The memory of ``(r, n)`` arrays, one pair per row, oldest first (taken, not copied:
        the caller hands them over)."""
        mem = cls.__new__(cls)
        mem._S = np.asarray(S, dtype=np.float64).reshape(-1, S.shape[-1])
        mem._Y = np.asarray(Y, dtype=np.float64).reshape(mem._S.shape)
        return mem

    @classmethod
    def from_pairs(cls, S: list, Y: list, n: int) -> SecantMemory:
        """The memory of lists of pair vectors (oldest first) of length ``n``."""
        if not len(S):
            return cls.from_rows(np.zeros((0, n)), np.zeros((0, n)))
        return cls.from_rows(np.array(S, dtype=np.float64), np.array(Y, dtype=np.float64))

    @property
    def S(self) -> np.ndarray:
        """The steps, shape ``(n, r)``, one pair per column (a read-only view)."""
        view = self._S.T
        view.flags.writeable = False
        return view

    @property
    def Y(self) -> np.ndarray:
        """The products ``A s``, shape ``(n, r)`` (a read-only view)."""
        view = self._Y.T
        view.flags.writeable = False
        return view

    @property
    def n(self) -> int:
        """Unknowns of the LCP the pairs belong to."""
        return int(self._S.shape[1])

    @property
    def rank(self) -> int:
        """Number of pairs."""
        return int(self._S.shape[0])

    def __len__(self) -> int:
        return self.rank

    def pairs(self) -> tuple[list, list]:
        """``(S, Y)`` as lists of vectors (copies), oldest first."""
        return list(self._S.copy()), list(self._Y.copy())

    def check(self, n: int, solver: str) -> None:
        """Raise a ``ValueError`` naming the mismatch unless the pairs have ``n`` rows."""
        if self.n != n:
            raise ValueError(f"{solver}: the secant memory (state=) has {self.n} rows but the "
                             f"LCP has n = {n} unknowns; map it to this LCP's unknowns first "
                             "(SecantMemory.remap) or pass state=None")

    def remap(self, index, min_kept: float = 0.5,
              curvature_tol: float = 1e-12) -> SecantMemory:
        """The pairs moved to another LCP's unknowns, row ``l`` taken from old row ``index[l]``.

        Made for a changed contact set: ``index[l]`` is the previous position of
        new contact ``l``, or ``-1`` for a new contact (row 0 in ``S`` and ``Y``).
        The moved ``y`` is only an approximation of ``A_new s``: it lacks the
        coupling of new contacts and of vanished ones, and ``A`` itself moved
        with the particles. A pair is therefore kept only while it still says
        something about the new operator:

        * at least ``min_kept`` of ``||s||^2`` and of ``||y||^2`` is on contacts
          that survive (a step made mostly along vanished contacts is
          dropped: its ``y`` would be mostly coupling that no longer exists);
        * the moved pair has positive curvature, ``s'y > curvature_tol ||s|| ||y||``,
          the test every BFGS update applies, so the model stays positive definite.

        The solver's model only preconditions: every step is still measured with
        the new ``A`` (one counted product), so an inexact pair costs
        iterations, never correctness. The pairs are kept rather than rescaled
        or dropped because that measured best: on the lattice simulations
        (docs/benchmarks.md, "Quasi-Newton memory across time steps") every
        mapped pair halved Mono-PQN's MVPs per step, keeping only the newest
        pairs gained less, and the share threshold made no difference there
        (it guards contact sets that change more than a packing cluster's).

        Parameters
        ----------
        index : array_like of int, shape (n_new,)
            Old row of each new unknown, ``-1`` where there is none.
        min_kept : float
            Share of a pair's norms that must survive the mapping (0 keeps
            every pair that passes the curvature test, 1 only pairs entirely on
            surviving contacts).
        curvature_tol : float
            Threshold of the curvature test.

        Returns
        -------
        SecantMemory
            With ``n_new`` rows and the surviving pairs, oldest first.
        """
        index = np.asarray(index, dtype=np.intp).reshape(-1)
        if index.size and (index.max() >= self.n or index.min() < -1):
            raise ValueError(f"remap: index entries must be -1 or rows 0..{self.n - 1} of the "
                             f"memory, got {index.min()}..{index.max()}")
        known = index >= 0
        S = np.zeros((index.size, self.rank))
        Y = np.zeros((index.size, self.rank))
        S[known] = self.S[index[known]]
        Y[known] = self.Y[index[known]]
        keep = []
        for i in range(self.rank):
            s, y = S[:, i], Y[:, i]
            s0, y0 = float(self.S[:, i] @ self.S[:, i]), float(self.Y[:, i] @ self.Y[:, i])
            if s0 <= 0 or y0 <= 0:
                continue
            if float(s @ s) < min_kept * s0 or float(y @ y) < min_kept * y0:
                continue
            if _accept(s, y, curvature_tol):
                keep.append(i)
        return SecantMemory(S[:, keep], Y[:, keep])

    def __repr__(self) -> str:
        return f"SecantMemory(n={self.n}, pairs={self.rank})"


def _accept(s: np.ndarray, y: np.ndarray, tol: float) -> bool:
    sy = float(s @ y)
    return np.isfinite(sy) and sy > tol * float(np.linalg.norm(s) * np.linalg.norm(y)) and sy > 0
