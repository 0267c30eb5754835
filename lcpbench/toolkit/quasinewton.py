"""BFGS Hessian models in the form ``B = B0 + U U' - V V'`` (unrolled factors).

:class:`DiagonalBFGS` keeps its pairs in compact form (the pairs and their Gram matrix)
and the unrolled factors as small coefficient matrices over the pairs, so its work per
iteration is O(n r); :class:`OperatorBFGS` stores the factors themselves.

The BFGS update ``B+ = B + y y'/(y's) - (B s)(B s)'/(s'B s)`` adds the column
``y / sqrt(y's)`` to ``U`` and ``B s / sqrt(s'B s)`` to ``V`` (Nocedal & Wright,
2006, sec. 6.1 and 7.2 "unrolling"), which is the diagonal-plus-low-rank form the
weighted prox (:mod:`lcpbench.toolkit.prox`) needs. Two initial models are used by the
PQN solvers:

* :class:`DiagonalBFGS` — ``B0 = D`` diagonal (``d * I``): the Mono-PQN model, with
  ``H = B^-1`` applied by the two-loop recursion in O(n r).
* :class:`OperatorBFGS` — ``B0`` a (low-fidelity) operator: the Bi-PQN model
  ``B = A_low + U U' - V V'`` (the paper's bi-fidelity quasi-Newton model).

:class:`SecantMemory` (defined in :mod:`lcpbench.toolkit.pqn_memory`, re-exported here) is
the pairs a PQN solve hands back and takes as a warm
start (``result.state``, ``state=``), with their mapping onto another LCP's
unknowns (time stepping with a changing contact set).

Pairs with too little curvature (``y's <= curvature_tol * ||s|| ||y||``) are
skipped, as in the authors' code, so ``B`` stays positive definite whenever
``B0`` is.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from lcpbench.toolkit.pqn_memory import SecantMemory, _accept, bb2_scale, free_secant_pair
from lcpbench.toolkit.prox import ActiveGram, row_products

__all__ = ["DiagonalBFGS", "OperatorBFGS", "SecantMemory", "Pairs", "ModelPairs", "Rank2",
           "bb2_scale", "free_secant_pair"]


class DiagonalBFGS:
    """BFGS model ``B = d I + U U' - V V'`` from stored secant pairs, kept in compact form.

    The pairs live in one ``(2 r, n)`` array ``W`` (rows ``s_0, y_0, s_1, y_1, ...``
    by storage slot) beside their Gram matrix ``W W'`` (Byrd, Nocedal & Schnabel,
    Math. Program. 63 (1994), the compact representation): adding a pair costs
    one pass over ``W`` (its new Gram row), dropping one costs nothing. The
    unrolled factors are never formed: ``U = W' P`` and ``V = W' N`` with small
    coefficient matrices ``P, N`` (``2r x r``) computed from the Gram matrix in
    ``O(r^3)`` by the same recursion as the unrolled update
    (``u_k = y_k / sqrt(y_k's_k)``, ``v_k = B_k s_k / sqrt(s_k'B_k s_k)``), so the
    model is the same as the unrolled one's to rounding and a change of ``d``
    (the BB scaling moves it every iteration) costs no pass over ``W``.
    ``apply_H`` is the two-loop recursion in the same coefficients: two passes.

    Parameters
    ----------
    n : int
    memory : int or None
        Number of pairs kept (oldest dropped first); None keeps up to ``n``
        (``max(n, 1)``): more pairs than unknowns add no curvature information
        and make the ``2r``-dimensional prox system larger than the problem
        (on ``spd-cond`` cond 1e10, n = 50, full memory reached r = 184 and took
        228 s; capped at n it took 2 s and fewer E-MVPs).
    scaling : {"identity", "bb"}
        ``identity``: ``d = 1`` (``H0 = I`` as in the paper's Mono-PQN algorithm). ``bb``:
        ``d = 1 / (gamma * tau_bb2)`` from the newest pair, as the authors' code
        (``h0 = gamma * s'y / y'y``, clipped to ``[tau_min, tau_max]``); ``d = 1``
        before the first pair.
    gamma : float
        Damping of the BB scaling (authors' default 0.8).
    curvature_tol : float
        Pairs with ``y's <= curvature_tol ||s|| ||y||`` are skipped.
    """

    def __init__(self, n: int, memory: Optional[int] = None, scaling: str = "bb",
                 gamma: float = 0.8, curvature_tol: float = 1e-12,
                 tau_min: float = 1e-14, tau_max: float = 1e14):
        if scaling not in ("identity", "bb"):
            raise ValueError(f"scaling must be 'identity' or 'bb', got {scaling!r}")
        self.n = n
        self.memory = memory if memory is not None else max(n, 1)
        self.scaling = scaling
        self.gamma = gamma
        self.curvature_tol = curvature_tol
        self.tau_min, self.tau_max = tau_min, tau_max
        self.skipped = 0
        self._W = np.zeros((0, n))          # rows 2k, 2k+1: s and y of storage slot k
        self._gram = np.zeros((0, 0))       # W W' by rows of _W
        self._order: list[int] = []         # storage slots, oldest pair first
        self._coef: Optional[tuple] = None  # (d, P, N) for the current pairs
        #: the last prox's active set and W diag(mask) W' (kept up to date with W)
        self._active = ActiveGram(np.zeros(n, dtype=bool), np.zeros((0, 0)))
        self._Wg: Optional[tuple] = None    # (g, W g) of the last add_pair's g

    # ------------------------------------------------------------------ pairs
    def add_pair(self, s: np.ndarray, y: np.ndarray, g: Optional[np.ndarray] = None) -> bool:
        """Store the secant pair ``(s, y)`` (``B s = y``); False if skipped.

        ``g`` (optional, the new gradient): its products with the pairs are kept for
        :meth:`products_with` (the next direction's two-loop recursion needs them). When
        ``g`` is the previous pair's ``g`` plus ``y`` (the PQN gradient recurrence
        ``g + eta A p`` with ``y = eta A p``), they are ``W g_old + W y``, ``W y`` being
        the new Gram column, so no product with ``g`` is made; otherwise ``W g`` is
        computed in the same sweep over the pairs as the new Gram rows.
        """
        prev, self._Wg = self._Wg, None
        if not _accept(s, y, self.curvature_tol):
            self.skipped += 1
            return False
        m = len(self._order)
        if m >= self.memory:                # replace the oldest pair's slot
            slot = self._order.pop(0)
        else:                               # the first free slot (dropped pairs leave holes)
            taken = set(self._order)
            slot = next(k for k in range(m + 1) if k not in taken)
            if 2 * slot + 2 > self._W.shape[0]:
                self._grow(min(max(self._W.shape[0], 4, slot + 1), self.memory))
        used = 2 * (max(self._order + [slot]) + 1)
        self._grow_gram(used)
        self._W[2 * slot] = s
        self._W[2 * slot + 1] = y
        rows = self._W[:used]
        mask = self._active.mask
        new = self._W[2 * slot:2 * slot + 2]            # s and y, as stored
        vectors = [new, new * mask]
        recurrence = g is not None and prev is not None and prev[1].shape[0] <= used \
            and np.array_equal(g, prev[0] + y)
        if g is not None and not recurrence:
            vectors.append(g)
        g_in, g = g, row_products(rows, vectors)
        self._gram[:used, 2 * slot:2 * slot + 2] = g[:, :2]
        self._gram[2 * slot:2 * slot + 2, :used] = g[:, :2].T
        A = self._active.gram
        if A.shape[0] < used:
            A = np.pad(A, (0, used - A.shape[0]))
        A[:used, 2 * slot:2 * slot + 2] = g[:, 2:4]
        A[2 * slot:2 * slot + 2, :used] = g[:, 2:4].T
        self._active.gram = A
        self._order.append(slot)
        self._coef = None
        if len(vectors) == 3:
            self._Wg = (np.array(g_in, dtype=np.float64), g[:, 4].copy())
        elif recurrence and prev is not None:
            Wg = g[:, 1].copy()
            Wg[:prev[1].shape[0]] += prev[1]
            Wg[2 * slot:2 * slot + 2] = (float(s @ g_in), float(y @ g_in))   # new rows
            self._Wg = (np.array(g_in, dtype=np.float64), Wg)
        return True

    def products_with(self, g: np.ndarray) -> np.ndarray:
        """``W g`` over the rows of :meth:`compact`'s ``W``: kept from :meth:`add_pair` when
        ``g`` is the vector it was given (compared entry by entry), else one sweep."""
        m = 2 * (max(self._order) + 1) if self._order else 0
        if self._Wg is not None and self._Wg[1].shape[0] == m and \
                np.array_equal(self._Wg[0], g):
            return self._Wg[1]
        return row_products(self._W[:m], (g,))[:, 0]

    def _grow(self, slots: int) -> None:
        """Room for ``slots`` pairs (the callers double it: amortised one copy of the pairs)."""
        W = np.empty((2 * slots, self.n))      # rows are read only once written
        W[:self._W.shape[0]] = self._W
        self._W = W

    def _grow_gram(self, rows: int) -> None:
        """The Gram matrix's room for ``rows`` rows at least (doubling)."""
        k = self._gram.shape[0]
        if rows > k:
            G = np.zeros((max(rows, 2 * k), max(rows, 2 * k)))
            G[:k, :k] = self._gram
            self._gram = G

    def trim(self, memory: int) -> None:
        """Keep the newest ``memory`` pairs (0 keeps all)."""
        if memory and len(self._order) > memory:
            del self._order[:-memory]
            self._coef = self._Wg = None

    def correct(self, u: np.ndarray, v: np.ndarray) -> None:
        """Pairs of the changed Hessian ``Q + u u' - v v'``: ``y_i <- y_i + u u's_i - v v's_i``.

        ``O(n r)``: four passes over the pairs (their products with ``u``, ``v``
        and the active set's), one update of the ``y`` rows, and the Gram
        matrices corrected in ``O(r^2)``. Pairs that lose the curvature test are
        dropped (counted in ``skipped``), as :meth:`set_pairs` would.
        """
        self._Wg = None
        if not self._order:
            return
        m = 2 * (max(self._order) + 1)
        W = self._W[:m]
        mask = self._active.mask
        Wu, Wv = row_products(W, (u, v)).T
        alpha, beta = np.zeros(m), np.zeros(m)
        for k in self._order:
            alpha[2 * k + 1], beta[2 * k + 1] = Wu[2 * k], Wv[2 * k]
            W[2 * k + 1] += alpha[2 * k + 1] * u - beta[2 * k + 1] * v
        uu, uv, vv = float(u @ u), float(u @ v), float(v @ v)
        self._gram[:m, :m] += _rank2_gram(Wu, Wv, alpha, beta, uu, uv, vv)
        A = self._active.gram
        if A.shape[0] == m:
            um, vm = np.where(mask, u, 0.0), np.where(mask, v, 0.0)
            Wum, Wvm = row_products(W, (um, vm)).T
            A += _rank2_gram(Wum - alpha * float(u @ um) + beta * float(v @ um),
                             Wvm - alpha * float(u @ vm) + beta * float(v @ vm),
                             alpha, beta, float(u @ um), float(u @ vm), float(v @ vm))
        elif A.shape[0]:
            self._active = ActiveGram(np.zeros(self.n, dtype=bool), np.zeros((0, 0)))
        keep = []
        for k in self._order:
            sy, ss, yy = self._gram[2 * k, 2 * k + 1], self._gram[2 * k, 2 * k], \
                self._gram[2 * k + 1, 2 * k + 1]
            if np.isfinite(sy) and sy > 0 and \
                    sy > self.curvature_tol * np.sqrt(max(ss, 0.0) * max(yy, 0.0)):
                keep.append(k)
            else:
                self.skipped += 1
        self._order = keep
        self._coef = None

    def set_pairs(self, S: list, Y: list) -> None:
        """Replace the memory by the given pairs (curvature-checked, oldest first)."""
        self._order, self._coef, self._Wg = [], None, None
        for s, y in zip(S, Y):
            self.add_pair(s, y)

    def rows(self) -> tuple[np.ndarray, np.ndarray]:
        """``(S, Y)`` as ``(r, n)`` arrays, one pair per row, oldest first (copies)."""
        return self._W[[2 * k for k in self._order]], self._W[[2 * k + 1 for k in self._order]]

    @property
    def S(self) -> list:
        """The steps, oldest first (copies)."""
        return [self._W[2 * k].copy() for k in self._order]

    @property
    def Y(self) -> list:
        """The products ``A s``, oldest first (copies)."""
        return [self._W[2 * k + 1].copy() for k in self._order]

    @property
    def rank(self) -> int:
        return len(self._order)

    @property
    def d(self) -> float:
        """The diagonal scalar of ``B0``."""
        if self.scaling == "identity" or not self._order:
            return 1.0
        k = 2 * self._order[-1]
        sy, yy = self._gram[k, k + 1], self._gram[k + 1, k + 1]
        tau = float(sy) / float(yy) if yy > 0 else 1.0
        return 1.0 / (self.gamma * float(np.clip(tau, self.tau_min, self.tau_max)))

    # ------------------------------------------------------------------ B = d + UU' - VV'
    def compact(self) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(d, W, P, N, G)``: ``B = d I + (W'P)(W'P)' - (W'N)(W'N)'`` and ``G = W W'``.

        ``W`` (``m x n``, a view: do not modify) holds the pairs' rows; ``P`` and
        ``N`` (``m x r``) are the unrolled factors' coefficients, built in
        ``O(r^3)`` from the Gram matrix ``G`` (``m x m``).
        """
        d = self.d
        if self._coef is None or self._coef[0] != d:
            self._coef = (d, *self._coefficients(d))
        m = 2 * (max(self._order) + 1) if self._order else 0
        return d, self._W[:m], self._coef[1], self._coef[2], self._gram[:m, :m]

    @property
    def active(self) -> ActiveGram:
        """The active set of the last prox with its Gram matrix over the rows of ``W``
        (:func:`lcpbench.toolkit.prox.compact_prox` starts from it and updates it)."""
        return self._active

    def _coefficients(self, d: float) -> tuple[np.ndarray, np.ndarray]:
        """``P, N`` of the unrolled factors in the rows of ``W`` (the unrolled recursion)."""
        m = 2 * (max(self._order) + 1) if self._order else 0
        G = self._gram[:m, :m]
        r = len(self._order)
        P, N = np.zeros((m, r)), np.zeros((m, r))
        for k, slot in enumerate(self._order):
            i = 2 * slot
            # B_k s_k = d s_k + U_k U_k' s_k - V_k V_k' s_k in the rows of W
            Gs = G[:, i]
            bs = P[:, :k] @ (P[:, :k].T @ Gs) - N[:, :k] @ (N[:, :k].T @ Gs)
            bs[i] += d
            sBs, sy = float(Gs @ bs), float(G[i, i + 1])
            if not (sBs > 0 and sy > 0):   # numerical breakdown: restart from d I
                return np.zeros((m, 0)), np.zeros((m, 0))
            P[i + 1, k] = 1.0 / np.sqrt(sy)
            N[:, k] = bs / np.sqrt(sBs)
        return P, N

    def factors(self) -> tuple[float, np.ndarray, np.ndarray]:
        """``(d, U, V)`` with ``B = d I + U U' - V V'`` formed explicitly (``O(n r^2)``)."""
        d, W, P, N, _ = self.compact()
        return d, W.T @ P, W.T @ N

    def apply_H(self, g: np.ndarray) -> np.ndarray:
        """``H g = B^-1 g`` by the two-loop recursion with ``H0 = I / d`` (two passes, O(n r))."""
        g = np.asarray(g, dtype=np.float64)
        if not self._order:
            return g / self.d
        d, W, _, _, G = self.compact()
        c = self.two_loop(W @ g, d)
        return g / d + W.T @ c

    def two_loop(self, Wg: np.ndarray, d: float) -> np.ndarray:
        """Coefficients ``c`` with ``H g = g / d + W' c``, from ``W g`` and the Gram matrix."""
        m = Wg.shape[0]
        G = self._gram[:m, :m]
        si = [2 * k for k in self._order]
        yi = [2 * k + 1 for k in self._order]
        r = len(si)
        rho = [1.0 / G[si[i], yi[i]] for i in range(r)]
        alpha = np.zeros(r)
        c = np.zeros(m)
        for i in range(r - 1, -1, -1):     # q = g - sum_{j>i} alpha_j y_j
            alpha[i] = rho[i] * (Wg[si[i]] - G[si[i], yi[i + 1:]] @ alpha[i + 1:])
        c[yi] = -alpha / d                 # r0 = q / d
        yr0 = (Wg[yi] - G[np.ix_(yi, yi)] @ alpha) / d
        step = np.zeros(r)                 # alpha_j - beta_j
        for i in range(r):
            beta = rho[i] * (yr0[i] + G[yi[i], si[:i]] @ step[:i])
            step[i] = alpha[i] - beta
        c[si] += step
        return c


def _rank2_gram(Wu, Wv, alpha, beta, uu, uv, vv):
    """Change of ``W W'`` when row ``i`` of ``W`` gains ``alpha_i u - beta_i v``.

    ``Wu``, ``Wv`` are the products of the rows before the change with ``u`` and ``v``.
    """
    X = np.outer(Wu, alpha) - np.outer(Wv, beta)
    ab = np.outer(alpha, beta)
    return X + X.T + uu * np.outer(alpha, alpha) - uv * (ab + ab.T) + vv * np.outer(beta, beta)


class OperatorBFGS:
    """BFGS corrections of an operator: ``B = B0 + U U' - V V'``.

    The paper's bi-fidelity quasi-Newton model.

    Parameters
    ----------
    apply_B0 : callable
        Product with ``B0`` (a low-fidelity MVP, counted by its operator).
    curvature_tol : float
        Updates with too little curvature are skipped.
    """

    def __init__(self, apply_B0: Callable[[np.ndarray], np.ndarray], n: int,
                 curvature_tol: float = 1e-12):
        self.apply_B0 = apply_B0
        self.n = n
        self.U = np.zeros((n, 0))
        self.V = np.zeros((n, 0))
        self.curvature_tol = curvature_tol
        self.skipped = 0

    def correction(self, v: np.ndarray) -> np.ndarray:
        """``(U U' - V V') v`` in O(n r), no product."""
        return self.U @ (self.U.T @ v) - self.V @ (self.V.T @ v)

    def apply(self, v: np.ndarray) -> np.ndarray:
        """``B v``: one product with ``B0`` plus O(n r)."""
        return self.apply_B0(v) + self.correction(v)

    def update(self, s: np.ndarray, y: np.ndarray, Bs: np.ndarray):
        """BFGS update with the secant pair ``(s, y = A s)`` and the known ``B s``.

        Returns the new columns ``(u, v)`` (None if skipped): the caller uses them
        to correct carried low-fidelity pairs, ``Y <- Y - (u u' - v v') S``.
        """
        sy = float(s @ y)
        sBs = float(s @ Bs)
        if not (_accept(s, y, self.curvature_tol) and sBs > 0):
            self.skipped += 1
            return None
        u = y / np.sqrt(sy)
        v = Bs / np.sqrt(sBs)
        self.U = np.column_stack([self.U, u])
        self.V = np.column_stack([self.V, v])
        return u, v


@dataclass
class Pairs:
    """Secant pairs ``Q s_i = y_i`` (oldest first) with optional cached ``B0 s_i``.

    ``model``: the Mono-PQN model that holds exactly these pairs (a level hands
    it on so the next subproblem continues it instead of rebuilding it).
    """

    S: list = field(default_factory=list)
    Y: list = field(default_factory=list)
    B0S: list = field(default_factory=list)
    model: Optional[DiagonalBFGS] = field(default=None, repr=False, compare=False)

    def add(self, s: np.ndarray, y: np.ndarray, b0s: Optional[np.ndarray] = None) -> None:
        self.S.append(s)
        self.Y.append(y)
        self.B0S.append(b0s)

    def trim(self, memory: int) -> None:
        """Keep the newest ``memory`` pairs (0 keeps all)."""
        if memory and len(self.S) > memory:
            del self.S[:-memory], self.Y[:-memory], self.B0S[:-memory]
            if self.model is not None:
                self.model.trim(memory)

    def corrected(self, delta: Callable[[np.ndarray], np.ndarray]) -> Pairs:
        """Pairs for a changed Hessian ``Q + Delta``: ``Y <- Y + Delta S`` (``B0 S`` kept).

        With a rank-two ``delta`` (:class:`Rank2`) and a model, the model is
        corrected in place in ``O(n r)`` and handed on (its pairs that lose the
        curvature test dropped, as rebuilding it would).
        """
        if isinstance(delta, Rank2) and self.model is not None:
            model, self.model = self.model, None
            model.correct(delta.u, delta.v)
            return ModelPairs(model)
        return Pairs(list(self.S), [y + delta(s) for s, y in zip(self.S, self.Y)],
                     list(self.B0S))

    def __len__(self) -> int:
        return len(self.S)

    def memory(self, n: int) -> SecantMemory:
        """The pairs as a :class:`SecantMemory` (one copy, row by row)."""
        return SecantMemory.from_pairs(self.S, self.Y, n)


class ModelPairs(Pairs):
    """The pairs a Mono-PQN model holds, read from it (copies made only when asked)."""

    def __init__(self, model: DiagonalBFGS):
        self.model = model

    S = property(lambda self: self.model.S if self.model is not None else [])
    Y = property(lambda self: self.model.Y if self.model is not None else [])
    B0S = property(lambda self: [None] * len(self))

    def __len__(self) -> int:
        return self.model.rank if self.model is not None else 0

    def memory(self, n: int) -> SecantMemory:
        """The pairs as a :class:`SecantMemory` (one copy of the model's rows)."""
        if self.model is None:
            return SecantMemory.from_pairs([], [], n)
        return SecantMemory.from_rows(*self.model.rows())

    def add(self, s, y, b0s=None) -> None:
        raise TypeError("ModelPairs are read-only; add pairs to the model")

    def trim(self, memory: int) -> None:
        if self.model is not None:
            self.model.trim(memory)



@dataclass(frozen=True)
class Rank2:
    """``v -> u u'v - w w'v``: the change of a BFGS model by one update."""

    u: np.ndarray
    v: np.ndarray

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.u * float(self.u @ x) - self.v * float(self.v @ x)
