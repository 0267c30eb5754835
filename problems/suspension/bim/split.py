"""A distance-split low fidelity of the boundary-integral mobility.

The boundary-integral low fidelities of lower order (``p3``, ``p4``, ``p6``) lose most of their
accuracy where the LCP looks hardest: between spheres a fraction of a radius apart, whose
squeeze traction is peaked far beyond degree 4 (docs/mobility.md).  This low keeps the high
fidelity's own discretisation near contact and makes the rest cheap:

* every pair closer than ``near_gap`` source radii keeps the high's stored near-field block
  (the full order-p density to the degree-p traction coefficients);
* every other pair acts only through the source density's vector spherical harmonics of
  degree <= q, and its traction on the target is projected onto degree <= q: a
  ``nv(q) x nv(q)`` block instead of ``nv(p) x nv(p)``, the stored block's rows and
  columns of degree <= q (for the pairs the high keeps in rotated form, the coaxial
  table's pairs, its rotation and coaxial entries of degree <= q: never assembled).  q is
  ``far_degree`` for the closest of these pairs and falls gently with distance: a pair
  at centre distance R (in source radii) gets the least q with
  ``q + 1 >= (far_degree + 1) (ln R0 / ln R)^decay``, R0 the distance of a pair at
  ``near_gap``.  ``decay = 1`` would keep the relative truncation
  of every pair equal if the field of a degree-l density simply decayed like
  ``(a / R)^(l + 1)``; the peaked near-contact densities of packed spheres need more than
  that, and ``decay = 0.5`` (the default) was the best measured trade (error against
  block work, ``benchmarks/far_truncation.py``, docs/mobility.md);
* optionally (``rank_tol``), every block it keeps, full or truncated, is compressed by its
  singular value decomposition to the terms above ``rank_tol`` times its largest singular
  value, and applied as ``U (V' c)``: ``2 nv r`` multiply-adds instead of ``nv^2``.  The
  blocks between spheres are far from full rank at a low's accuracy: the field of a
  degree-l density reaches the target's degree-l' harmonics with weight falling like
  ``(a / R)^(l + l' + 1)``, so most of a square degree-truncated block is small at a low's
  accuracy, near-contact blocks included (the ranks kept: docs/mobility.md);
* GMRES stops at the low's own tolerance (``1e-3`` is typical).

It is built from a high :class:`.operator.BimMobility` and shares its set-up (the same
:class:`.setup.BimSetup` object: pairs, stored blocks, self operators, preconditioner);
only its near-field part differs (:class:`SplitBlocks` in place of the stored blocks), and
only the truncated far blocks are new (and, when compressed, their singular value
decompositions; their set-up cost is measured in docs/mobility.md).  Its
transpose is exact (``M.T @ y``: the same pieces transposed, the truncated blocks by the
compiled block-transpose kernel), but the contact operators of lcpbench use this low
unsymmetrised, ``D' M D``, with one forward solve per product: the discrete mobility's own
asymmetry at p = 8 (docs/mobility.md) is far below what a low fidelity is accurate to, and
symmetrising would double the low's cost.

Pairs that the high evaluates by direct quadrature rather than a stored block (beyond the
block budget) stay as they are: the split then
saves less.  Named ``p<k>f<q>e<j>`` in scene specs and ``lcpbench generate --low``
(``p8f4e3``: order 8 near contact, degree 4 far field, GMRES 1e-3), and
``p<k>f<q>r<i>e<j>`` with the blocks compressed at ``rank_tol = 1e-i`` (``p8f6r3e3``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..geometry import check_tolerance
from .blocks import StoredBlocks
from .kernels import (
    PARALLEL_WORK,
    apply_blocks,
    apply_blocks_serial,
    apply_lowrank,
    apply_lowrank_serial,
    dense_rows,
)
from .kernels_adjoint import apply_blocks_adjoint, apply_blocks_adjoint_serial
from .kernels_rotated import (
    PlanBlocks,
    RotatedPairs,
    rotated_forward,
    rotated_forward_serial,
    rotated_transpose,
    rotated_transpose_serial,
)
from .operator import BimMobility
from .pairs import PairPlan

__all__ = ["SplitMobility", "SplitBlocks", "split_mobility", "DEFAULT_NEAR_GAP"]

DEFAULT_NEAR_GAP = 0.5
"""Pairs whose gap is below this many source radii keep the full near-field block."""

_CHUNK = 64
"""Blocks truncated (and factored) at a time: bounds the temporary copies of the blocks."""


class _Group(NamedTuple):
    """Blocks stored dense (of one truncation degree) or factored (of every degree).

    ``blocks`` is ``(K, nv, nv)`` for dense blocks acting on the coefficients ``sel``;
    factored blocks (``blocks`` None) are ``factors = (first, second, off, rank, length)``
    in the ragged layout of :func:`kernels.apply_lowrank`, each on the first ``length[k]``
    coefficients (the coefficients are ordered by degree, so degree <= q is a prefix), and
    ``sel`` is then every coefficient.  ``ptr`` and ``src`` give the blocks by target
    sphere (``fwd`` is their order for :func:`kernels.apply_lowrank`), ``order``,
    ``src_ptr`` and ``tgt`` by source sphere (for the transpose); ``synth`` synthesises
    ``sel`` onto the grid and ``synth_T`` is its transpose.  Blocks the high keeps in
    rotated form are kept so here too, truncated (``rotated``; ``blocks`` and ``factors``
    None).
    """

    blocks: np.ndarray | None
    factors: tuple | None
    ptr: np.ndarray
    src: np.ndarray
    sel: np.ndarray
    synth: np.ndarray
    synth_T: np.ndarray
    fwd: np.ndarray
    order: np.ndarray
    src_ptr: np.ndarray
    tgt: np.ndarray
    rotated: RotatedPairs | None = None

    @property
    def work(self) -> int:
        """Multiply-adds of one product with these blocks."""
        if self.rotated is not None:
            return self.rotated.work
        if self.blocks is not None:
            return int(self.blocks.size)
        assert self.factors is not None          # neither dense nor rotated: factored
        return int(2 * self.factors[0].size)

    def _coef(self, coef: np.ndarray) -> np.ndarray:
        """The coefficients the blocks act on (``sel`` is a prefix of the degree order)."""
        n = self.sel.size
        return coef if n == coef.shape[1] else np.ascontiguousarray(coef[:, :n])

    def apply(self, coef: np.ndarray, M: int) -> np.ndarray:
        """``acc[i] = sum_k E_k coef[src[k], sel]`` over the blocks with target i, (M, |sel|)."""
        acc = np.zeros((M, self.sel.size))
        c = self._coef(np.ascontiguousarray(coef))
        if self.rotated is not None:
            fn = rotated_forward if self.work > PARALLEL_WORK else rotated_forward_serial
            fn(self.rotated.form, self.ptr, self.src, c, acc)
        elif self.blocks is not None:
            fn = apply_blocks if self.work > PARALLEL_WORK else apply_blocks_serial
            fn(self.blocks, self.ptr, self.src, c, acc)
        else:
            assert self.factors is not None
            first, second, off, rank, length = self.factors
            fn = apply_lowrank if self.work > PARALLEL_WORK else apply_lowrank_serial
            fn(first, second, off, rank, length, self.ptr, self.fwd, self.src, c, acc)
        return acc

    def apply_transpose(self, acc_bar: np.ndarray, M: int) -> np.ndarray:
        """The transpose of :meth:`apply`: ``part[j] = sum_k E_k' acc_bar[tgt[k]]`` over the
        blocks with source j, (M, |sel|)."""
        part = np.zeros((M, self.sel.size))
        if self.rotated is not None:
            fn = rotated_transpose if self.work > PARALLEL_WORK else rotated_transpose_serial
            fn(self.rotated.form, self.src_ptr, self.order, self.tgt, acc_bar, part)
        elif self.blocks is not None:
            fn = (apply_blocks_adjoint if self.work > PARALLEL_WORK
                  else apply_blocks_adjoint_serial)
            fn(self.blocks, self.src_ptr, self.order, self.tgt, acc_bar, part)
        else:
            assert self.factors is not None
            first, second, off, rank, length = self.factors
            fn = apply_lowrank if self.work > PARALLEL_WORK else apply_lowrank_serial
            fn(second, first, off, rank, length, self.src_ptr, self.order, self.tgt,
               acc_bar, part)
        return part


class SplitBlocks:
    """The near-field part of the split operator (in place of :class:`.blocks.StoredBlocks`):
    full blocks for the near pairs, degree-truncated (or factored) ones for the far pairs.

    Attributes
    ----------
    groups : list of _Group
        Blocks stored dense (one group per truncation degree) or factored (one group).
    far_degree : int
        Degree of the far-field truncation.
    near_gap : float
        Gap (in source radii) below which a pair keeps its full block.
    rank_tol : float or None
        Relative singular-value cut of the block compression (None: blocks dense).
    n_full_pairs, n_truncated_pairs : int
        Ordered pairs with a full and with a truncated block.
    pairs_per_degree : dict
        Truncation degree -> ordered pairs truncated at it.
    block_work : float
        Multiply-adds of the blocks per product relative to the high's blocks.
    mean_rank : float
        Mean number of terms kept per factored block (0 when none is factored).
    n_factored_blocks : int
        Blocks stored factored (all of them when ``rank_tol`` is given, else 0).
    block_sizes, block_ranks : ndarray or None
        Per block of the high's plan (its order), the coefficients it acts on and the terms
        kept (None without compression).
    """

    fused = False
    """No fused pass: the split blocks differ from the stored ones the fused kernel reads."""

    def __init__(self, plan: PairPlan, *, far_degree: int, near_gap: float, decay: float,
                 rank_tol: float | None) -> None:
        self.M, self.N = plan.M, plan.N
        self.far_degree, self.near_gap, self.rank_tol = int(far_degree), near_gap, rank_tol
        basis = plan.basis
        tgt, src = plan.near.block_tgt, plan.near.block_src
        c, r = plan.centers, plan.radii
        dist = np.linalg.norm(c[tgt] - c[src], axis=1) / r[src]      # in source radii
        reach = (r[tgt] + r[src]) / r[src] + near_gap                # R0 of each pair
        degree = np.full(tgt.size, -1)                               # -1: full block
        far = dist >= reach
        ratio = (np.log(reach[far]) / np.log(dist[far])) ** decay
        degree[far] = np.clip(np.ceil((self.far_degree + 1) * ratio - 1e-9) - 1, 1,
                              self.far_degree)
        if rank_tol is None:
            self._dense_groups(plan, degree)
        else:
            length = np.array([basis.degree.size if q < 0 else int((basis.degree <= q).sum())
                               for q in degree], dtype=np.int64)
            factors = _factor(plan.near.blocks, length, rank_tol)
            self.groups = [_group(None, factors, np.arange(tgt.size), plan, basis.degree.size)]
            self.n_factored_blocks = int(tgt.size)
            self.mean_rank = float(factors[3].mean()) if tgt.size else 0.0
            self.block_sizes: np.ndarray | None = length
            self.block_ranks: np.ndarray | None = factors[3]
        self.n_full_pairs = int((degree < 0).sum())
        self.n_truncated_pairs = int(far.sum())
        self.pairs_per_degree = {int(q): int((degree == q).sum()) for q in np.unique(degree[far])}
        self.block_work = (sum(g.work for g in self.groups)
                           / max(StoredBlocks(plan).work, 1))

    def _dense_groups(self, plan: PairPlan, degree: np.ndarray) -> None:
        """Per truncation degree (-1: the full near blocks) one group of the blocks the
        high keeps dense and one of those it keeps in rotated form (or rotates at each
        product), truncated in that form (:meth:`.kernels_rotated.RotatedPairs.truncated`:
        never assembled)."""
        basis = plan.basis
        self.groups = []
        stack = plan.near.blocks
        for q in np.unique(degree):
            idx = np.nonzero(degree == q)[0]                     # still sorted by target
            n_q = basis.degree.size if q < 0 else int((basis.degree <= q).sum())
            if isinstance(stack, PlanBlocks):
                rot = stack.kinds(idx) != 0
                if rot.any():
                    self.groups.append(_group(None, None, idx[rot], plan, n_q,
                                              rotated=stack.truncated_form(idx[rot], q)))
                idx = idx[~rot]
                if not idx.size:
                    continue
            # the stored blocks are in coefficients on both sides (pairs.py): a near pair
            # keeps its block, a far one keeps the rows and columns of degree <= q (a prefix:
            # the coefficients are ordered by degree)
            if q < 0:
                blocks = np.ascontiguousarray(plan.near.blocks[idx])
            else:
                blocks = np.empty((idx.size, n_q, n_q))
                for k0 in range(0, idx.size, _CHUNK):
                    blocks[k0:k0 + _CHUNK] = plan.near.blocks[idx[k0:k0 + _CHUNK], :n_q, :n_q]
            self.groups.append(_group(blocks, None, idx, plan, n_q))
        self.n_factored_blocks, self.mean_rank = 0, 0.0
        self.block_sizes = self.block_ranks = None

    def apply(self, coef: np.ndarray) -> np.ndarray:
        """The split blocks applied to the VSH coefficients ``coef``, on the grid (M, 3N)."""
        out = np.zeros((self.M, 3 * self.N))
        for g in self.groups:
            out += dense_rows(g.apply(coef, self.M), g.synth)
        return out

    def add_transpose(self, ob: np.ndarray, coef_bar: np.ndarray) -> None:
        """Adds the transposed split blocks' share of adjoint tractions ``ob`` to
        ``coef_bar``."""
        for g in self.groups:
            acc_bar = np.ascontiguousarray(dense_rows(ob, g.synth_T))
            coef_bar[:, g.sel] += g.apply_transpose(acc_bar, self.M)


class SplitMobility(BimMobility):
    """The mobility of a :class:`.operator.BimMobility` with the far field truncated in degree.

    Build it with :func:`split_mobility`: the high's set-up with :class:`SplitBlocks` as the
    near-field part.  Products (``@``, ``matvec``) solve the traction equation with the
    split operator to the low's ``eps_gmres``; transposed products (``M.T @ y``,
    ``rmatvec``, ``matvec_rmatvec``) solve its exact transpose.  The split's own numbers
    (``far_degree``, ``block_work``, ``mean_rank``, ...) are those of ``near``
    (:class:`SplitBlocks`), shown here too.
    """

    near: SplitBlocks

    def __init__(self, high: BimMobility, near: SplitBlocks, eps_gmres: float) -> None:
        self._assemble(high.setup, near, eps_gmres=eps_gmres, on_failure=high.on_failure,
                       maxiter=high.maxiter, recycle=high.recycle, krylov=high.krylov)

    def __getattr__(self, name: str):
        # the split's numbers (far_degree, block_work, ...) are its near part's
        if name in _SPLIT_NUMBERS:
            return getattr(self.near, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")


_SPLIT_NUMBERS = frozenset({"far_degree", "near_gap", "rank_tol", "n_full_pairs",
                            "n_truncated_pairs", "pairs_per_degree", "block_work", "mean_rank",
                            "n_factored_blocks", "block_sizes", "block_ranks"})


def split_mobility(high: BimMobility, far_degree: int, eps_gmres: float,
                   near_gap: float = DEFAULT_NEAR_GAP, decay: float = 0.5,
                   rank_tol: float | None = None) -> SplitMobility:
    """The distance-split low fidelity of ``high`` (see the module docstring).

    Parameters
    ----------
    high : BimMobility
        The high fidelity; its set-up is shared, not copied.
    far_degree : int
        Degree (>= 1, at most ``high.p``) of the far-field truncation.
    eps_gmres : float
        GMRES tolerance of the low.
    near_gap : float
        Pairs with a gap below ``near_gap`` source radii keep their full block.
    decay : float
        How fast the degree falls with distance (see the module docstring): 0 truncates
        every far pair at ``far_degree``, 0.5 is the default.
    rank_tol : float, optional
        Compress every kept block to its singular values above ``rank_tol`` times its
        largest (``1e-3`` for a low accurate to about 1e-3); None keeps the blocks dense.
        Every block is stored factored: a cut that keeps more than half of a block's
        terms makes that block dearer than dense (at 1e-3 a near block keeps about a
        third).

    Raises
    ------
    ValueError
        ``far_degree`` outside ``1..p``, ``near_gap`` or ``decay`` negative, ``eps_gmres``
        or ``rank_tol`` outside (0, 1).
    """
    if isinstance(far_degree, bool) or int(far_degree) != far_degree or not (
            1 <= int(far_degree) <= high.p):
        raise ValueError(f"far_degree = {far_degree!r} must be an integer from 1 to the "
                         f"order p = {high.p} (e.g. 4)")
    gap_limit = float(near_gap)
    if not (np.isfinite(gap_limit) and gap_limit >= 0):
        raise ValueError(f"near_gap = {near_gap!r} must be a number >= 0 (in source radii, "
                         "e.g. 0.5)")
    fall = float(decay)
    if not (np.isfinite(fall) and fall >= 0):
        raise ValueError(f"decay = {decay!r} must be a number >= 0 (0: every far pair at "
                         "far_degree; 0.5: the default fall of the degree with distance)")
    if rank_tol is not None:
        try:
            cut = float(rank_tol)
        except (TypeError, ValueError):
            cut = float("nan")
        if isinstance(rank_tol, bool) or not (np.isfinite(cut) and 0 < cut < 1):
            raise ValueError(f"rank_tol = {rank_tol!r} must be a number in (0, 1), the "
                             "relative singular-value cut of the blocks (e.g. 1e-3), or None")
        rank_tol = cut
    eps = check_tolerance(eps_gmres)
    near = SplitBlocks(high.plan, far_degree=int(far_degree), near_gap=gap_limit, decay=fall,
                       rank_tol=rank_tol)
    return SplitMobility(high, near, eps)


def _group(blocks: np.ndarray | None, factors: tuple | None, idx: np.ndarray,
           plan: PairPlan, n_coef: int, rotated: RotatedPairs | None = None) -> _Group:
    """The :class:`_Group` of the pairs ``idx`` (sorted by target) of the high's plan, acting
    on the first ``n_coef`` coefficients (their synthesis: the leading rows of the plan's
    ``block_synth``, a view when they are all of them)."""
    M = plan.M
    t, s = plan.near.block_tgt[idx], np.ascontiguousarray(plan.near.block_src[idx])
    ptr = np.searchsorted(t, np.arange(M + 1)).astype(np.int64)
    order = np.argsort(s, kind="stable").astype(np.int64)            # for the transpose
    src_ptr = np.searchsorted(s[order], np.arange(M + 1)).astype(np.int64)
    synth = np.ascontiguousarray(plan.near.block_synth[:n_coef])
    synth_T = np.ascontiguousarray(plan.near.block_synth_T[:, :n_coef])
    return _Group(blocks, factors, ptr, s, np.arange(n_coef), synth, synth_T,
                  np.arange(idx.size, dtype=np.int64), order, src_ptr, np.ascontiguousarray(t),
                  rotated)


def _factor(blocks: np.ndarray | PlanBlocks, length: np.ndarray, rank_tol: float) -> tuple:
    """Block k's leading ``length[k] x length[k]`` part by its singular value decomposition,
    cut at ``rank_tol`` times its largest singular value, in the ragged layout of
    :func:`kernels.apply_lowrank`: ``(first, second, off, rank, length)``, ``first`` the
    rows of ``V'`` and ``second`` those of ``(U S)'``."""
    K = blocks.shape[0]
    rank = np.zeros(K, dtype=np.int64)
    firsts: list = [np.zeros(0)] * K              # block k's rows, stored in block order
    seconds: list = [np.zeros(0)] * K
    for L in np.unique(length):
        idx = np.nonzero(length == L)[0]
        for k0 in range(0, idx.size, _CHUNK):
            part = idx[k0:k0 + _CHUNK]
            U, S, Vt = np.linalg.svd(blocks[part, :L, :L])
            for j, k in enumerate(part):
                r = int((S[j] > rank_tol * S[j, 0]).sum())
                rank[k] = r
                firsts[k] = Vt[j, :r].ravel()
                seconds[k] = (U[j, :, :r] * S[j, :r]).T.ravel()
    off = np.concatenate([[0], np.cumsum(rank * length)[:-1]]).astype(np.int64)
    first = np.concatenate(firsts) if K else np.zeros(0)
    second = np.concatenate(seconds) if K else np.zeros(0)
    return first, second, off, rank, length
