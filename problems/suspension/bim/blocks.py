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

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from .kernels import PARALLEL_WORK, apply_blocks, apply_blocks_serial, dense_rows
from .kernels_adjoint import (
    apply_blocks_adjoint,
    apply_blocks_adjoint_serial,
    apply_blocks_both,
    apply_blocks_both_serial,
)
from .kernels_rotated import (
    FlyPairs,
    PlanBlocks,
    RotatedPairs,
    rotated_both,
    rotated_both_serial,
    rotated_forward,
    rotated_forward_serial,
    rotated_transpose,
    rotated_transpose_serial,
)
from .pair_frame import PairFrame
from .pairs import PairPlan

__all__ = ["StoredBlocks"]


class _Dense(NamedTuple):
    """Blocks kept assembled, sorted by target sphere: values, targets, sources, pointers
    by target, and (for transposes) their order and pointers by source and the sum of
    per-block parts by source."""

    blocks: np.ndarray
    tgt: np.ndarray
    src: np.ndarray
    ptr: np.ndarray
    sorder: np.ndarray
    sptr: np.ndarray
    by_source: sp.csr_matrix


def _part(blocks, tgt: np.ndarray, src: np.ndarray, M: int) -> _Dense:
    """The :class:`_Dense` record of blocks (or a rotated form) with targets ``tgt``
    (sorted) and sources ``src``."""
    order = np.argsort(src, kind="stable").astype(np.int64)
    nb = src.size
    return _Dense(blocks, tgt, src,
                  np.searchsorted(tgt, np.arange(M + 1)).astype(np.int64),
                  order, np.searchsorted(src[order], np.arange(M + 1)).astype(np.int64),
                  sp.csr_matrix((np.ones(nb), (src, np.arange(nb))), shape=(M, nb)))


class StoredBlocks:
    """The plan's near-field blocks as the operator's near-field part: blocks stored
    assembled (``plan.near.blocks``, or its dense part), and with ``pair_blocks="table-all"``
    the table pairs in rotated form (``plan.near.rotated``, :mod:`.kernels_rotated`).

    Parameters
    ----------
    plan : PairPlan
        The pair plan whose blocks (sorted by target sphere) are applied.
    """

    fused = True
    """The forward and the transposed products can share one pass over the blocks."""

    def __init__(self, plan: PairPlan) -> None:
        self.plan = plan
        self.rotated: RotatedPairs | None = plan.near.rotated
        tgt, src = plan.near.block_tgt, plan.near.block_src
        self.fly: FlyPairs | None = plan.near.fly_pairs
        self.frame: PairFrame | None = plan.near.pair_frame
        self._fly = None
        if self.rotated is None:
            self._dense = _part(plan.near.blocks, tgt, src, plan.M)
            self._rot = None
        else:
            d, r = plan.near.dense_pos, plan.near.rot_pos
            assert isinstance(plan.near.blocks, PlanBlocks)     # rotated pairs: a mixed stack
            self._dense = _part(plan.near.blocks.dense, tgt[d], src[d], plan.M)
            self._rot = _part(self.rotated.form, tgt[r], src[r], plan.M)
            if self.fly is not None:
                late = plan.near.fly_pos
                assert late is not None                     # set with the rotated pairs
                self._fly = [_part(None, tgt[late[s]], src[late[s]], plan.M)
                             for s in self.fly.chunks()]

    @property
    def work(self) -> int:
        """Multiply-adds of one product with the blocks (those rotated at each product
        counted as if stored)."""
        rot = 0 if self.rotated is None else self.rotated.work
        if self.rotated is not None and self.rotated.n_pairs:
            per_pair = self.rotated.work / self.rotated.n_pairs
            rot += int(per_pair * (0 if self.fly is None else self.fly.rho.size))
        return int(self._dense.blocks.size) + rot

    def _fly_parts(self):
        """Per chunk of the pairs rotated at each product: their record with their rotated
        form in place of blocks."""
        if self._fly is None:
            return []
        return [part._replace(blocks=self.fly.rotated(s).form)
                for s, part in zip(self.fly.chunks(), self._fly)]

    def _rotated_parts(self) -> list[_Dense]:
        """The parts applied by the per-pair rotated kernels (:mod:`.kernels_rotated`):
        the pairs rotated at each product, and the stored rotated form when no pair-frame
        form (:mod:`.pair_frame`) applies those pairs instead."""
        parts = [] if self.frame is not None else [self._rot]
        return [r for r in parts + self._fly_parts() if r is not None and r.src.size]

    @property
    def nbytes(self) -> int:
        """Memory of the stored near field (per-pair data)."""
        rot = 0 if self.rotated is None else self.rotated.nbytes
        return int(self._dense.blocks.nbytes) + rot

    def _coef_acc(self, coef: np.ndarray) -> np.ndarray:
        """The blocks' output in coefficients ``(M, nv)``."""
        plan, d = self.plan, self._dense
        acc = np.zeros((plan.M, plan.near.block_synth.shape[0]))
        if d.src.size:
            fn = apply_blocks if d.blocks.size > PARALLEL_WORK else apply_blocks_serial
            fn(d.blocks, d.ptr, d.src, coef, acc)
        fn = rotated_forward if self.work > PARALLEL_WORK else rotated_forward_serial
        for r in self._rotated_parts():
            fn(r.blocks, r.ptr, r.src, np.ascontiguousarray(coef), acc)
        if self.frame is not None:
            self.frame.forward(coef, acc, parallel=self.work > PARALLEL_WORK)
        return acc

    def apply(self, coef: np.ndarray) -> np.ndarray:
        """The stored blocks applied to the VSH coefficients ``coef``, on the grid
        ``(M, 3N)`` (zeros when no pair has a block)."""
        plan = self.plan
        if not plan.near.n_block_pairs:
            return np.zeros((plan.M, 3 * plan.N))
        return dense_rows(self._coef_acc(coef), plan.near.block_synth)

    def _add_transpose_coef(self, x: np.ndarray, coef_bar: np.ndarray) -> None:
        """Adds the transposed blocks applied to adjoint coefficients ``x`` (M, nv)."""
        d = self._dense
        if d.src.size:
            fn = (apply_blocks_adjoint if d.blocks.size > PARALLEL_WORK
                  else apply_blocks_adjoint_serial)
            fn(d.blocks, d.sptr, d.sorder, d.tgt, x, coef_bar)
        fn = rotated_transpose if self.work > PARALLEL_WORK else rotated_transpose_serial
        for r in self._rotated_parts():
            fn(r.blocks, r.sptr, r.sorder, r.tgt, x, coef_bar)
        if self.frame is not None:
            self.frame.transpose(x, coef_bar, parallel=self.work > PARALLEL_WORK)

    def add_transpose(self, ob: np.ndarray, coef_bar: np.ndarray) -> None:
        """Adds the transposed blocks' share of adjoint tractions ``ob`` (M, 3N) to the
        adjoint coefficients ``coef_bar`` (M, nv)."""
        plan = self.plan
        if not plan.near.n_block_pairs:
            return
        self._add_transpose_coef(np.ascontiguousarray(dense_rows(ob, plan.near.block_synth_T)),
                                 coef_bar)

    def apply_both(self, coef: np.ndarray, ob: np.ndarray, coef_bar: np.ndarray,
                   out: np.ndarray) -> None:
        """:meth:`apply` added to ``out`` and :meth:`add_transpose` added to ``coef_bar``,
        reading every block once."""
        plan = self.plan
        if not plan.near.n_block_pairs:
            return
        x = np.ascontiguousarray(dense_rows(ob, plan.near.block_synth_T))
        coef = np.ascontiguousarray(coef)
        acc = np.zeros((plan.M, plan.near.block_synth.shape[0]))
        rot = (rotated_both, rotated_both_serial)
        for part, fns in ([(self._dense, (apply_blocks_both, apply_blocks_both_serial))]
                          + [(r, rot) for r in self._rotated_parts()]):
            if part is None or not part.src.size:
                continue
            fn = fns[0] if self.work > PARALLEL_WORK else fns[1]
            bar = np.empty((part.src.size, coef.shape[1]))
            fn(part.blocks, part.ptr, part.src, coef, acc, x, bar)
            coef_bar += part.by_source @ bar
        if self.frame is not None:
            self.frame.both(coef, acc, x, coef_bar, parallel=self.work > PARALLEL_WORK)
        out += dense_rows(acc, plan.near.block_synth)
