"""Krylov subspace recycling for the many solves with one boundary-integral operator.

Every counted product of the contact operator solves the traction equation ``G y = b``
(and, symmetrised, the transposed equation) with the same ``G`` and a new right-hand
side.  The right-hand sides of one configuration live in a space of dimension at most
6M (forces and torques), and the LCP's products in the much smaller space of its
contacts, so the directions one solve has built are most of what the next one needs.
:class:`RecycledGCR` keeps them: it is GCR (generalized conjugate residuals, Eisenstat,
Elman and Schultz 1983) whose search directions ``U`` and their images ``C = G U``
(orthonormal columns) are kept from solve to solve, the "recycled" space of Parks, de
Sturler et al. (GCRO-DR, SIAM J. Sci. Comput. 2006) with no truncation while memory
allows.  A new solve starts from the projection onto the kept space, ``y0 = U C' b``
with residual ``(I - C C') b``, and adds directions only for what is left; once the
kept space contains the right-hand sides of every contact, solves need no new product
at all.

GCR with every direction kept is GMRES in exact arithmetic (the same minimal residual
over the same Krylov space).  Its residual is a recurrence, ``r = b - C a``.  The products
are made at full accuracy (no relaxation), so every kept image is a product of the same
deterministic linear map that ``y`` is applied to, and the recurrence differs from the
true residual ``b - G y`` only by the rounding of the orthogonalisation, bounded by a few
machine epsilons times the number of directions times the sum of the coefficients.  A
solve measures the true residual with one more product when that bound is not far below
the tolerance, or when it stops without converging (budget, stagnation), and then folds
the measured residual back and goes on; the residual it reports is the measured one or,
when the bound allowed skipping the check, the recurrence within that bound.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Optional

import numpy as np

from lcpbench.toolkit.blas import one_blas_thread

from .gram_schmidt import orthogonalise

__all__ = ["RecycledGCR", "KrylovBudget", "DEFAULT_KRYLOV_MB", "BUDGET_FLOOR",
           "default_capacity", "solve_together"]

DEFAULT_KRYLOV_MB = 256.0
"""Default budget (MB) of the kept Krylov directions of one time step: every recycled space
of the step's operators (the high's forward and transposed spaces, its twins at other GMRES
tolerances, the distance-split lows, another order's lows when they are given the same
budget) together, two float64 vectors per direction (:class:`KrylovBudget`)."""

BUDGET_FLOOR = 60
"""Directions every recycled space may keep whatever the shared budget says (the restart
length of the un-recycled GMRES): a solve always has a Krylov space to work in, so a full
budget makes later solves truncated GCR, never a failure.  The budget is therefore
exceeded by at most this many directions per space."""

_BREAKDOWN = 1e-14
"""A new image ``G u`` whose part outside the kept space is below this fraction of its
norm adds nothing: the solve stops adding directions (lucky breakdown or stagnation)."""


_ROUNDING = 64 * np.finfo(np.float64).eps
"""Rounding drift of the residual recurrence per direction and unit coefficient: the images
``C`` are products of the same deterministic linear map as the one applied to ``y``, so
``b - G y`` and the recurrence ``r`` differ only by the rounding of the orthogonalisation
and the updates, at most about this times (directions) x (sum of |coefficients|)."""

_MAX_CHECKS = 5
"""True-residual checks per solve at most: a recurrence refuted this often is not going
to agree with the operator (the caller reports the measured residual)."""


def default_capacity(n: int, megabytes: float = DEFAULT_KRYLOV_MB) -> int:
    """Directions a kept space of vectors of length ``n`` may hold within ``megabytes``
    (two float64 vectors per direction)."""
    return max(0, int(megabytes * 1e6 // (16 * max(int(n), 1))))


class KrylovBudget:
    """One memory budget for the kept directions of several :class:`RecycledGCR` spaces.

    The operators of one time step (the high fidelity's forward and transposed spaces,
    its twins at other tolerances, the distance-split lows) each keep a recycled space;
    with a budget each space joins it, and a space grows only while the directions held
    by all members together fit in ``megabytes`` (below :data:`BUDGET_FLOOR` directions a
    space always grows).  A space that may not grow replaces its oldest direction instead
    (truncated GCR: the residual recurrence stays exact).  Members are held weakly: a
    space that is collected gives its share back.

    Parameters
    ----------
    megabytes : float
        The budget in MB (1e6 bytes), >= 0 (default :data:`DEFAULT_KRYLOV_MB`).

    Raises
    ------
    ValueError
        ``megabytes`` is not a finite number >= 0.
    """

    def __init__(self, megabytes: float = DEFAULT_KRYLOV_MB) -> None:
        try:
            mb = float(megabytes)
        except (TypeError, ValueError):
            mb = float("nan")
        if isinstance(megabytes, bool) or not (np.isfinite(mb) and mb >= 0):
            raise ValueError(f"Krylov budget {megabytes!r} MB must be a finite number >= 0 "
                             f"(memory of the kept directions of one step, e.g. "
                             f"{DEFAULT_KRYLOV_MB:g}; 0 turns recycling off)")
        self.megabytes = mb
        self.nbytes = int(mb * 1e6)
        self._members: weakref.WeakSet = weakref.WeakSet()

    def join(self, space: RecycledGCR) -> None:
        """Count ``space``'s directions against this budget."""
        self._members.add(space)

    @property
    def used(self) -> int:
        """Bytes held by the members' kept directions now."""
        return sum(16 * s.n * s.size for s in list(self._members))

    @property
    def members(self) -> int:
        """Spaces counted against the budget now."""
        return len(self._members)

    def may_grow(self, space: RecycledGCR) -> bool:
        """Whether ``space`` may keep one more direction."""
        return space.size < BUDGET_FLOOR or self.used + 16 * space.n <= self.nbytes

    def __repr__(self) -> str:
        return (f"<KrylovBudget {self.megabytes:g} MB, {self.used / 1e6:.1f} MB used by "
                f"{self.members} spaces>")


class RecycledGCR:
    """GCR for ``G y = b`` that keeps its directions across solves.

    Parameters
    ----------
    apply : callable
        ``apply(v) -> G v`` at full accuracy (a 1-D float array of the same length).
    n : int
        Length of the unknowns.
    capacity : int
        Most directions kept; when full, a new direction replaces the oldest (truncated
        GCR, which keeps the residual recurrence exact).  0 keeps nothing between solves:
        every solve is then full GCR (GMRES) from zero.
    budget : KrylovBudget, optional
        A memory budget shared with other spaces: the space stops growing (and replaces
        its oldest direction) when the members' directions together would exceed it.

    Attributes
    ----------
    size : int
        Directions kept now.
    products : int
        Products of ``G`` made so far (iterations and residual checks).
    """

    def __init__(self, apply: Callable[[np.ndarray], np.ndarray], n: int,
                 capacity: int, budget: Optional[KrylovBudget] = None) -> None:
        self.apply = apply
        self.n = int(n)
        self.capacity = max(0, int(capacity))
        self.budget = budget if self.capacity else None
        if self.budget is not None:
            self.budget.join(self)
        # ring buffer of the directions and their images side by side, row k = [u_k, c_k]
        # (rows [0, _filled) valid), so that one pass over it applies both
        self._W = np.empty((0, 2 * self.n))
        self._filled = 0
        self._next = 0
        self.products = 0

    @property
    def size(self) -> int:
        return self._filled

    @property
    def _U(self) -> np.ndarray:
        """The kept directions (rows; a view of the ring buffer)."""
        return self._W[:, :self.n]

    @property
    def _C(self) -> np.ndarray:
        """Their images, orthonormal rows (a view of the ring buffer)."""
        return self._W[:, self.n:]

    def clear(self) -> None:
        """Forget the kept directions (the operator changed)."""
        self._filled = self._next = 0

    def _reserve(self, rows: int) -> None:
        """Room for ``rows`` directions in all (pages are touched only when written)."""
        if self._W.shape[0] < rows:
            W = np.empty((rows, 2 * self.n))
            W[:self._filled] = self._W[:self._filled]
            self._W = W

    def _add(self, u: np.ndarray, c: np.ndarray) -> None:
        """Keep a direction: in a new row while there is room (and the budget allows),
        else in place of the oldest."""
        if self._filled < self._W.shape[0] and (self.budget is None
                                                or self.budget.may_grow(self)):
            i = self._filled
            self._filled += 1
        else:
            i = self._next % self._filled
            self._next = i + 1
        self._W[i, :self.n] = u
        self._W[i, self.n:] = c

    def _project(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(U' h, C' h, h)`` with ``h = C v`` over the directions held: the part of ``v``
        in the span of the images, the directions that produce it and the coefficients (two
        BLAS passes: ``h``, then both sums in one pass over the ring buffer)."""
        k = self._filled
        if k == 0:
            return np.zeros(self.n), np.zeros(self.n), np.zeros(0)
        h = self._C[:k] @ v
        both = h @ self._W[:k]
        return both[:self.n], both[self.n:], h

    def _orthogonalise(self, u: np.ndarray, c: np.ndarray) -> tuple[float, float]:
        """Make the image ``c`` orthogonal to the kept images (and ``u`` follow it, so that
        ``c`` stays the image of ``u``), in place: classical Gram-Schmidt over the kept
        images, repeated once when the first pass removed more than ``1 - 1/sqrt(2)`` of the
        norm (twice is enough, Kahan), the directions updated once with the summed
        coefficients.  Returns the norms of ``c`` before and after."""
        k = self._filled
        if k == 0:
            nc0 = float(np.linalg.norm(c))
            return nc0, nc0
        h, nc0, nc = orthogonalise(self._C[:k], c)
        u -= h @ self._U[:k]
        return nc0, nc

    def solve(self, b: np.ndarray, rtol: float, maxiter: int,
              x0: Optional[np.ndarray] = None) -> tuple[np.ndarray, int, float]:
        """Solve ``G y = b`` to relative residual ``rtol``.

        Parameters
        ----------
        b : ndarray
        rtol : float
            Relative tolerance on the true residual ``||b - G y|| / ||b||``.
        maxiter : int
            Most new directions (products) of this solve, residual checks not included.
        x0 : ndarray, optional
            An initial guess (e.g. the solution of a nearby system): the solve starts from
            ``x0`` plus the projection of its residual onto the kept space, at the price
            of one product for that residual (counted in :attr:`products`); a guess whose
            residual is not below ``||b||`` is dropped (the solve starts from zero).

        Returns
        -------
        y : ndarray
        iterations : int
            New directions built (products of ``G``, not counting the residual checks).
        residual : float
            Relative residual of ``y``: measured with one more product, or the recurrence
            when its rounding bound is below a tenth of ``rtol`` (see the module docs).
        """
        return solve_together([(self, b)], lambda vs: [self.apply(vs[0])], rtol, maxiter,
                              x0=[x0])[0]

    def iterate(self, b: np.ndarray, rtol: float, maxiter: int,
                x0: Optional[np.ndarray] = None):
        """The solve of :meth:`solve` as a generator: it yields every vector whose product
        it needs and is sent the product back; its return value is ``(y, iterations,
        residual)``.  :func:`solve_together` drives several at once."""
        b = np.asarray(b, dtype=np.float64).reshape(-1)
        nb = float(np.linalg.norm(b))
        if nb == 0.0:
            return np.zeros(self.n), 0, 0.0
        keep = self.capacity > 0
        self._reserve(self.capacity if keep else max(int(maxiter), 1))
        y, r = np.zeros(self.n), b.copy()
        if x0 is not None and np.any(x0):
            guess = np.array(x0, dtype=np.float64).reshape(-1)
            r0 = b - self._image((yield guess))
            if float(np.linalg.norm(r0)) < nb:          # the guess helps: start from it
                y, r = guess, r0
        du, dc, h = self._project(r)
        y += du
        r -= dc
        # sum of |coefficients| of y in the directions: bounds the rounding drift
        weight = float(np.abs(h).sum())
        its = checks = 0
        stalled = force = False       # force: after a refuted check, one new direction
        res = 1.0
        try:
            while True:
                while ((force or float(np.linalg.norm(r)) > rtol * nb) and its < maxiter
                       and not stalled):
                    force = False
                    u = r / float(np.linalg.norm(r))
                    c = self._image((yield u))
                    its += 1
                    nc0, nc = self._orthogonalise(u, c)
                    if not nc > _BREAKDOWN * nc0:
                        stalled = True
                        break
                    c /= nc
                    u /= nc
                    alpha = float(c @ r)
                    y += alpha * u
                    r -= alpha * c
                    weight += abs(alpha)
                    self._add(u, c)
                res = float(np.linalg.norm(r)) / nb
                drift = _ROUNDING * self._filled * weight / nb
                if res <= rtol and drift <= 0.1 * rtol:
                    break             # the recurrence is the true residual to << rtol
                # measure the truth (the recurrence may have drifted, or the solve stopped)
                r = b - self._image((yield y))
                res = float(np.linalg.norm(r)) / nb
                checks += 1
                if res <= rtol or its >= maxiter or stalled or checks >= _MAX_CHECKS:
                    break
                force = True
                # fold the true residual back onto every direction (no product), go on
                du, dc, _ = self._project(r)
                y += du
                r -= dc
        finally:
            if not keep:
                self.clear()
        return y, its, res

    def _image(self, c) -> np.ndarray:
        self.products += 1
        return np.array(c, dtype=np.float64).reshape(-1)


def solve_together(jobs: list, apply_many: Callable[[list], list], rtol: float,
                   maxiter: int, x0: Optional[list] = None
                   ) -> list[tuple[np.ndarray, int, float]]:
    """Run several :meth:`RecycledGCR.solve` in lock step, so that their products can be
    made in one pass (for example a forward and a transposed solve reading the same stored
    blocks once).

    Parameters
    ----------
    jobs : list of (RecycledGCR, ndarray)
        Each solver with its right-hand side.
    apply_many : callable
        ``apply_many(vectors)`` gets one entry per job, a vector or ``None`` for a job that
        needs no product this round, and returns the images in the same places.
    rtol, maxiter
        As in :meth:`RecycledGCR.solve`, for every job.
    x0 : list, optional
        An initial guess per job (None entries: none).

    Returns
    -------
    list of (y, iterations, residual), one per job.
    """
    guesses = x0 if x0 is not None else [None] * len(jobs)
    gens = [solver.iterate(b, rtol, maxiter, g) for (solver, b), g in zip(jobs, guesses)]
    out: list = [None] * len(gens)
    need: list = [None] * len(gens)
    with one_blas_thread():           # the orthogonalisation: vector work beside the kernels
        for k, g in enumerate(gens):
            try:
                need[k] = next(g)
            except StopIteration as stop:
                out[k] = stop.value
        while any(v is not None for v in need):
            images = apply_many(need)
            for k, g in enumerate(gens):
                if need[k] is None:
                    continue
                try:
                    need[k] = g.send(images[k])
                except StopIteration as stop:
                    out[k], need[k] = stop.value, None
    return out
