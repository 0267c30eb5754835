"""A distance-split low fidelity of the boundary-integral mobility.

The boundary-integral low fidelities of lower order (``p3``, ``p4``, ``p6``) lose most of their
accuracy where the LCP looks hardest: between spheres a fraction of a radius apart, whose
squeeze traction is peaked far beyond degree 4 (docs/mobility.md).  This low keeps the high
fidelity's own discretisation near contact and makes the rest cheap:

* every pair closer than ``near_gap`` source radii keeps the high's stored near-field block
  (the full order-p density to the degree-p traction coefficients);
* every other pair acts only through the source density's vector spherical harmonics of
  degree <= q, and its traction on the target is projected onto degree <= q: a
  ``nv(q) x nv(q)`` block instead of ``nv(p) x nv(p)`` (about 11 times fewer multiply-adds
  at q = 4, p = 8), the stored block's rows and columns of degree <= q.  q is
  ``far_degree`` for the closest of these pairs and falls gently with distance: a pair
  at centre distance R (in source radii) gets the least q with
  ``q + 1 >= (far_degree + 1) (ln R0 / ln R)^decay``, R0 the distance of a pair at
  ``near_gap``.  ``decay = 1`` would keep the relative truncation
  of every pair equal if the field of a degree-l density simply decayed like
  ``(a / R)^(l + 1)``; the peaked near-contact densities of packed spheres need more than
  that, and ``decay = 0.5`` (the default) was the best measured trade (error against
  block work, ``benchmarks/far_truncation.py``, docs/mobility.md);
* GMRES stops at the low's own tolerance (``1e-3`` is typical).

It is built from a high :class:`bim.BimMobility` and shares its set-up (pairs, stored
blocks, self operators, preconditioner); only the truncated far blocks are new.  Its
transpose is exact (``M.T @ y``: the same pieces transposed, the truncated blocks by the
compiled block-transpose kernel), but the contact operators of lcpbench use this low
unsymmetrised, ``D' M D``, with one forward solve per product: the discrete mobility's own
asymmetry at p = 8, about 4e-5, is far below what a low fidelity is accurate to, and
symmetrising would double the low's cost.

Pairs that the high evaluates by direct quadrature rather than a stored block (beyond the
block budget, from about a hundred spheres at p = 8) stay as they are: the split then
saves less.  Named ``p<k>f<q>e<j>`` in scene specs and ``lcpbench generate --low``
(``p8f4e3``: order 8 near contact, degree 4 far field, GMRES 1e-3).
"""

from __future__ import annotations

import numpy as np

from .bim import BimMobility
from .bim_adjoint import AdjointPieces
from .kernels import PARALLEL_WORK, apply_blocks, apply_blocks_serial, dense_rows
from .kernels_adjoint import apply_blocks_adjoint, apply_blocks_adjoint_serial

__all__ = ["SplitMobility", "split_mobility", "DEFAULT_NEAR_GAP"]

DEFAULT_NEAR_GAP = 0.5
"""Pairs whose gap is below this many source radii keep the full near-field block."""

_CHUNK = 64
"""Blocks truncated at a time (bounds the temporary copy of the stored blocks)."""


class SplitMobility(BimMobility):
    """The mobility of a :class:`bim.BimMobility` with the far field truncated in degree.

    Build it with :func:`split_mobility`.  Products (``@``, ``matvec``) solve the traction
    equation with the split operator to the low's ``eps_gmres``; transposed products
    (``M.T @ y``, ``rmatvec``, ``matvec_rmatvec``) solve its exact transpose.

    Attributes
    ----------
    far_degree : int
        Degree of the far-field truncation.
    near_gap : float
        Gap (in source radii) below which a pair keeps its full block.
    n_full_pairs, n_truncated_pairs : int
        Ordered pairs with a full and with a truncated block.
    pairs_per_degree : dict
        Truncation degree -> ordered pairs truncated at it.
    block_work : float
        Multiply-adds of the blocks per product relative to the high's blocks.
    """

    far_degree: int
    near_gap: float

    def _apply_bie(self, sigma: np.ndarray, rung: int = 0) -> np.ndarray:
        """The split operator: self, unblocked pairs as in the high, full blocks for the
        near pairs and degree-truncated blocks for the far ones."""
        out, coef = self._apply_bie_unblocked(sigma, rung)
        if coef is not None:
            for blocks, ptr, src, sel, synth, _adj in self._groups:
                fn = apply_blocks if blocks.size > PARALLEL_WORK else apply_blocks_serial
                acc = np.zeros((self.M, sel.size))
                fn(blocks, ptr, src, np.ascontiguousarray(coef[:, sel]), acc)
                out += dense_rows(acc, synth)
        return out.reshape(-1)

    @property
    def adjoint_pieces(self) -> AdjointPieces:
        """The transposed pieces, with the split blocks in place of the high's blocks."""
        if self._pieces is None:
            self._pieces = _SplitAdjoint(self)
        return self._pieces

    def _apply_pair(self, u_f: np.ndarray, u_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``G u_f`` and ``G' u_a`` of the split operator (no fused pass: its blocks differ
        from the stored ones the fused kernel reads)."""
        return (self._apply_bie(self._precondition(u_f)),
                self.adjoint_pieces.operator(u_a))


class _SplitAdjoint(AdjointPieces):
    """:class:`bim_adjoint.AdjointPieces` of a :class:`SplitMobility`: the unblocked pieces
    are the high's, the blocks are the split's, transposed."""

    def __init__(self, op: SplitMobility) -> None:
        super().__init__(op)
        self.groups = op._groups

    def apply_bie(self, w: np.ndarray) -> np.ndarray:
        """Transpose of :meth:`SplitMobility._apply_bie`."""
        out, coef_bar, ob = self.apply_bie_unblocked(w)
        if coef_bar is not None:
            for blocks, _ptr, _src, sel, synth, (order, src_ptr, tgt) in self.groups:
                fn = (apply_blocks_adjoint if blocks.size > PARALLEL_WORK
                      else apply_blocks_adjoint_serial)
                acc_bar = np.ascontiguousarray(dense_rows(ob, np.ascontiguousarray(synth.T)))
                part = np.zeros((self.op.M, sel.size))
                fn(blocks, src_ptr, order, tgt, acc_bar, part)
                coef_bar[:, sel] += part
            out += dense_rows(coef_bar, self.analysis)
        return out.reshape(-1)


def split_mobility(high: BimMobility, far_degree: int, eps_gmres: float,
                   near_gap: float = DEFAULT_NEAR_GAP, decay: float = 0.5) -> SplitMobility:
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

    Raises
    ------
    ValueError
        ``far_degree`` outside ``1..p``, ``near_gap`` or ``decay`` negative, ``eps_gmres``
        outside (0, 1).
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
    base = high.at_tolerance(eps_gmres)
    low = SplitMobility.__new__(SplitMobility)
    low.__dict__.update(base.__dict__)
    low.far_degree, low.near_gap = int(far_degree), gap_limit
    low._fresh_solvers()                      # its recycled space applies the split operator
    plan, basis = high.plan, high.basis
    tgt, src = plan.block_tgt, plan.block_src
    c, r = high.centers, high.radii
    dist = np.linalg.norm(c[tgt] - c[src], axis=1) / r[src]      # in source radii
    reach = (r[tgt] + r[src]) / r[src] + gap_limit               # R0 of each pair
    degree = np.full(tgt.size, -1)                               # -1: full block
    far = dist >= reach
    ratio = (np.log(reach[far]) / np.log(dist[far])) ** fall
    degree[far] = np.clip(np.ceil((low.far_degree + 1) * ratio - 1e-9) - 1, 1, low.far_degree)
    low._groups = []
    work = 0
    for q in np.unique(degree):
        idx = np.nonzero(degree == q)[0]                         # still sorted by target
        ptr = np.searchsorted(tgt[idx], np.arange(high.M + 1)).astype(np.int64)
        # the stored blocks are in coefficients on both sides (bim_pairs): a near pair keeps
        # its block, a far one keeps the rows and columns of degree <= q
        sel = np.arange(basis.degree.size) if q < 0 else np.nonzero(basis.degree <= q)[0]
        if q < 0:
            blocks = np.ascontiguousarray(plan.blocks[idx])
        else:
            blocks = np.empty((idx.size, sel.size, sel.size))
            for k0 in range(0, idx.size, _CHUNK):
                part = idx[k0:k0 + _CHUNK]
                blocks[k0:k0 + part.size] = plan.blocks[part][:, sel][:, :, sel]
        synth = np.ascontiguousarray(basis.B[:, sel].T)
        order = np.argsort(src[idx], kind="stable").astype(np.int64)    # for the transpose
        src_ptr = np.searchsorted(src[idx][order], np.arange(high.M + 1)).astype(np.int64)
        low._groups.append((blocks, ptr, np.ascontiguousarray(src[idx]), sel, synth,
                            (order, src_ptr, np.ascontiguousarray(tgt[idx]))))
        work += blocks.size
    low.n_full_pairs = int((degree < 0).sum())
    low.n_truncated_pairs = int(far.sum())
    low.pairs_per_degree = {int(q): int((degree == q).sum()) for q in np.unique(degree[far])}
    low.block_work = work / max(plan.blocks.size, 1)
    low._pieces = None                        # its own transposed pieces, built on first use
    return low
