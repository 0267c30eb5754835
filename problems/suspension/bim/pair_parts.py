"""The three parts of the pair plan (:class:`.pairs.PairPlan`), by what they describe.

* :class:`Quadrature`: the pairs summed by quadrature between spheres: each pair's source
  grid at every rung of the tolerance ladder, the source points and weights of every grid
  and the ranges the direct sums cover (the far-field strategy, :mod:`.farfield`, has its
  say in them).
* :class:`NearBlocks`: the stored near-field blocks: which pairs, their values (dense, or in
  rotated form, or rotated at every product) and their memory.
* :class:`ExpansionPairs`: the expansion pairs evaluated on the fly at every product (those
  the block budget leaves unblocked).

The plan's builder fills them; the operators, the transpose and the split low read them.
"""

from __future__ import annotations

import numpy as np

from .kernels_rotated import FlyPairs, PlanBlocks, RotatedPairs
from .pair_frame import PairFrame

__all__ = ["Quadrature", "NearBlocks", "ExpansionPairs"]


class Quadrature:
    """The pairs summed by quadrature between spheres.

    Attributes
    ----------
    tolerance_ladder : tuple of float
        Quadrature accuracies of the rungs (first = the plan's ``quad_tol``).
    level_of : ndarray, shape (M, M)
        Source level of every ordered pair at full accuracy before blocking (-1 self,
        -2 expansion, else the index in ``levels``).
    levels : tuple of int
        Source-grid orders; ``native`` is the index of order p.
    level_radii : dict
        Source-grid order -> scaled distance beyond which it is accurate to ``quad_tol``.
    pairs_per_level : dict
        Source-grid order -> ordered pairs summed directly on it at full accuracy.
    n_far_pairs : int
        Pairs summed by quadrature (not blocked).
    lvl_spheres, lvl_base, n_src, src_xyz, src_scale, synth :
        The spheres on each source grid, their first point, the number of source points,
        their coordinates (three arrays) and weights, and the synthesis matrices of the
        upsampled grids (None for the others).
    dir_ranges : list
        Per rung: ``(ptr, start, stop)`` source ranges summed by each target sphere.
    """

    tolerance_ladder: tuple[float, ...]
    level_of: np.ndarray
    levels: tuple[int, ...]
    native: int
    level_radii: dict[int, float]
    pairs_per_level: dict[int, int]
    n_far_pairs: int
    lvl_spheres: list[np.ndarray]
    lvl_base: list[int]
    n_src: int
    src_xyz: list[np.ndarray]
    src_scale: list[np.ndarray]
    synth: list[np.ndarray | None]
    dir_ranges: list[tuple[np.ndarray, np.ndarray, np.ndarray]]


class NearBlocks:
    """The stored near-field blocks (traction on sphere i per VSH coefficient of sphere j).

    Attributes
    ----------
    blocked : ndarray of bool, shape (M, M)
        Which ordered pairs have a block.
    blocks : ndarray or PlanBlocks
        The blocks sorted by target sphere, ``(n_block_pairs, nv, nv)`` (a
        :class:`.kernels_rotated.PlanBlocks` stack assembled on demand with "table-all").
    block_tgt, block_src, block_ptr : ndarray
        Target and source sphere of every block, and the blocks of each target.
    block_synth, block_synth_T : ndarray
        Synthesis of the summed coefficients at the nodes, and its transpose.
    rotated, fly_pairs, pair_frame :
        With "table-all": the stored table pairs in rotated form, those beyond the budget
        (rotated at every product) and the stored ones in the pair frame (else None);
        ``dense_pos``, ``rot_pos``, ``fly_pos`` are the positions of the assembled, rotated
        and rotated-on-the-fly pairs in the block order.
    n_block_pairs, n_stored_blocks, n_table_blocks : int
        Blocks in all, within the memory budget, and taken from the coaxial table.
    block_bytes : int
        Memory of the stored blocks.
    """

    blocked: np.ndarray
    blocks: np.ndarray | PlanBlocks
    block_tgt: np.ndarray
    block_src: np.ndarray
    block_ptr: np.ndarray
    block_synth: np.ndarray
    block_synth_T: np.ndarray
    rotated: RotatedPairs | None = None
    fly_pairs: FlyPairs | None = None
    pair_frame: PairFrame | None = None
    dense_pos: np.ndarray | None = None
    rot_pos: np.ndarray | None = None
    fly_pos: np.ndarray | None = None
    n_block_pairs: int
    n_stored_blocks: int
    n_table_blocks: int
    block_bytes: int


class ExpansionPairs:
    """The expansion pairs evaluated on the fly (per target sphere, compressed rows).

    Attributes
    ----------
    fly_ptr, fly_idx : ndarray
        Pairs in the projected zone (traction on the finer grid, projected).
    flyn_ptr, flyn_idx : ndarray
        Pairs beyond it (sampled at the native nodes).
    n_near_pairs : int
        Ordered pairs too close for any source grid (expansions, blocked or not).
    """

    fly_ptr: np.ndarray
    fly_idx: np.ndarray
    flyn_ptr: np.ndarray
    flyn_idx: np.ndarray
    n_near_pairs: int
