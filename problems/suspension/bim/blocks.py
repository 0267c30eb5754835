"""The stored near-field blocks of the pair plan, applied forward, transposed and both at once.

A block (built by :meth:`.pairs.PairPlan._build_blocks`) maps the VSH coefficients of the
density on sphere j to the degree-p traction coefficients on sphere i.  The operator asks
its near-field part three things, which :class:`StoredBlocks` answers for the plan's own
blocks and :class:`.split.SplitBlocks` for the distance-split low fidelity's:

* ``apply(coef)``: the blocks' traction on every grid, ``(M, 3N)``;
* ``add_transpose(ob, coef_bar)``: the transpose, added to the adjoint coefficients;
* ``apply_both(coef, ob, coef_bar, out)``: both in one pass over the blocks (memory traffic
  bounds a product when the blocks are many); ``fused`` says whether it is offered.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse as sp

from .kernels import PARALLEL_WORK, apply_blocks, apply_blocks_serial, dense_rows
from .kernels_adjoint import (
    apply_blocks_adjoint,
    apply_blocks_adjoint_serial,
    apply_blocks_both,
    apply_blocks_both_serial,
)
from .pairs import PairPlan

__all__ = ["StoredBlocks"]


class StoredBlocks:
    """The plan's dense near-field blocks as the operator's near-field part.

    Parameters
    ----------
    plan : PairPlan
        The pair plan whose ``blocks`` (sorted by target sphere) are applied.
    """

    fused = True
    """The forward and the transposed products can share one pass over the blocks."""

    def __init__(self, plan: PairPlan) -> None:
        self.plan = plan

    @property
    def work(self) -> int:
        """Multiply-adds of one product with the blocks."""
        return int(self.plan.blocks.size)

    def apply(self, coef: np.ndarray) -> np.ndarray:
        """The stored blocks applied to the VSH coefficients ``coef``, on the grid
        ``(M, 3N)`` (zeros when no pair has a block)."""
        plan = self.plan
        if not plan.n_block_pairs:
            return np.zeros((plan.M, 3 * plan.N))
        fn = apply_blocks if plan.blocks.size > PARALLEL_WORK else apply_blocks_serial
        acc = np.zeros((plan.M, plan.blocks.shape[1]))
        fn(plan.blocks, plan.block_ptr, plan.block_src, coef, acc)
        return dense_rows(acc, plan.block_synth)

    @cached_property
    def _by_source(self) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
        """The blocks by source sphere (order, pointers) and the sum of per-block parts by
        source sphere, for the transposed products (built on first use)."""
        plan = self.plan
        order = np.argsort(plan.block_src, kind="stable").astype(np.int64)
        ptr = np.searchsorted(plan.block_src[order], np.arange(plan.M + 1)).astype(np.int64)
        nb = plan.block_src.size
        by_source = sp.csr_matrix((np.ones(nb), (plan.block_src, np.arange(nb))),
                                  shape=(plan.M, nb))
        return order, ptr, by_source

    def add_transpose(self, ob: np.ndarray, coef_bar: np.ndarray) -> None:
        """Adds the transposed blocks' share of adjoint tractions ``ob`` (M, 3N) to the
        adjoint coefficients ``coef_bar`` (M, nv)."""
        plan = self.plan
        if not plan.n_block_pairs:
            return
        order, ptr, _ = self._by_source
        fn = (apply_blocks_adjoint if plan.blocks.size > PARALLEL_WORK
              else apply_blocks_adjoint_serial)
        fn(plan.blocks, ptr, order, plan.block_tgt, dense_rows(ob, plan.block_synth_T),
           coef_bar)

    def apply_both(self, coef: np.ndarray, ob: np.ndarray, coef_bar: np.ndarray,
                   out: np.ndarray) -> None:
        """:meth:`apply` added to ``out`` and :meth:`add_transpose` added to ``coef_bar``,
        reading every block once."""
        plan = self.plan
        if not plan.n_block_pairs:
            return
        part = np.empty((plan.block_src.size, coef.shape[1]))
        fn = apply_blocks_both if plan.blocks.size > PARALLEL_WORK else apply_blocks_both_serial
        acc = np.zeros((plan.M, plan.blocks.shape[1]))
        fn(plan.blocks, plan.block_ptr, plan.block_src, coef, acc,
           dense_rows(ob, plan.block_synth_T), part)
        out += dense_rows(acc, plan.block_synth)
        coef_bar += self._by_source[2] @ part
