"""Pair set-up of the boundary-integral mobility: how each pair of spheres interacts.

Built once per configuration by :class:`.setup.BimSetup` and reused by every forward,
transposed and split product: which ordered pairs are summed by direct quadrature on which
source grid at each accuracy rung of relaxed GMRES, which get exact-expansion blocks (stored
within a memory budget, closest first) and which are evaluated on the fly, and the
source points of the direct sums.

The stored near-field blocks are built here (:meth:`PairPlan._build_blocks`).  By default
(``pair_blocks="table-all"``) the block of a pair of two spheres of equal radius is the
coaxial table's block at the pair's scaled distance (:mod:`.coaxial`) rotated into the
pair's direction (:mod:`.rotation`), kept in rotated form (:mod:`.kernels_rotated`: the
rotation and the coaxial entries, applied at product time); pairs of unequal radii (the
radius ratio would be a second table axis), pairs beyond the table's range and p = 1 are
built directly and stored assembled.  ``pair_blocks="direct"`` builds every block
directly (one exact-expansion response per pair: the reference); ``"table"`` takes only
projected-zone pairs from the table, assembled.  Nothing that reads the blocks
(:mod:`.blocks`, :mod:`.split`,
:mod:`.adjoint`) depends on how they were built.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np

from lcpbench.toolkit.blas import one_blas_thread

from .coaxial import RHO_MIN, coaxial_table, order_mask, table_range
from .farfield import FarField
from .kernels import real_block_columns, traction_response
from .kernels_rotated import FlyPairs, PlanBlocks, RotatedPairs
from .pair_frame import PairFrame
from .pair_parts import ExpansionPairs, NearBlocks, Quadrature
from .rotation import degree_slices, rotate_blocks, wigner_directions
from .sphere_vsh import (
    SphereGrid,
    VSHBasis,
    expansion_factors,
    grid_levels,
    quadrature_radius,
    sampled_basis,
    sphere_grid,
)

__all__ = ["PairPlan", "Grids", "PROJECT_RHO", "RELAX_STEP", "PAIR_BLOCKS", "csr"]

PROJECT_RHO = 3.0
"""Pairs with ``rho = (d_ij - a_i)/a_j < 3`` (gap below 2 a_j) are always expansion pairs
with the projected near field, whatever the quadrature tolerance, so that the
discretisation does not change with ``eps_gmres``; beyond, values at the nodes
(quadrature, or expansions at tight tolerances).  The measured choice of the radius:
docs/mobility.md, "Measured choices behind the defaults"."""

PAIR_BLOCKS = ("direct", "table", "table-all")
"""How the stored blocks are built: all directly (the reference), from the coaxial table
and rotations for the projected zone (assembled), or from the table for every
equal-radius pair, kept in rotated form (the default; node sampling replaced by the exact
projection)."""

RELAX_STEP = 10.0
"""Ratio of successive quadrature tolerances on the ladder of relaxed GMRES."""


class Grids(NamedTuple):
    """The grids and bases of one order ``p`` that the pair plan is built on.

    Attributes
    ----------
    p : int
        Spherical-harmonic order.
    grid, near_grid : SphereGrid
        Native order-p grid and the finer grid of the projected near field.
    near_proj : ndarray or None
        Projection from the finer grid onto degree p (None: node sampling).
    basis : VSHBasis
        Vector spherical harmonics of order p (analysis, synthesis, complex form).
    """

    p: int
    grid: SphereGrid
    near_grid: SphereGrid
    near_proj: np.ndarray | None
    basis: VSHBasis


def csr(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """Compressed rows ``(ptr, idx)`` of a list of index lists."""
    ptr = np.zeros(len(lists) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(x) for x in lists])
    idx = np.array([j for x in lists for j in x], dtype=np.int64)
    return ptr, idx


class PairPlan:
    """How every ordered pair (i, j) of spheres is evaluated, by ``rho = (d_ij - a_i)/a_j``.

    Direct quadrature on the coarsest source grid (:func:`sphere_vsh.grid_levels`)
    accurate to the tolerance there (:func:`sphere_vsh.quadrature_radius`), once per rung
    of the tolerance ladder, else exact expansions (dense blocks within
    ``near_block_mb``, the rest on the fly).  Pairs in the zone ``rho < PROJECT_RHO``
    are expansion pairs at any tolerance when ``near_proj`` is given.

    Parameters
    ----------
    centers, radii : ndarray
        Checked configuration, shapes (M, 3) and (M,).
    grids : Grids
        The order, the native and near-field grids, the near-field projection and the basis.
    quad_tol : float
        Quadrature accuracy of the full-accuracy rung.
    far : FarField
        The far-field strategy (:mod:`.farfield`): which source grids the quadrature
        pairs may use, whether they are relaxed, and the ranges of the direct sums.
    near_block_mb : float
        Memory budget of the stored blocks.
    pair_blocks : {"table-all", "table", "direct"}
        How the stored blocks are built (see :meth:`_build_blocks`; default "table-all").

    Attributes
    ----------
    quadrature : Quadrature
        The pairs summed by quadrature: source grids per rung, source points, direct-sum
        ranges (:class:`.pair_parts.Quadrature`).
    near : NearBlocks
        The stored near-field blocks (:class:`.pair_parts.NearBlocks`).
    expansions : ExpansionPairs
        The expansion pairs evaluated on the fly (:class:`.pair_parts.ExpansionPairs`).
    """

    def __init__(self, centers: np.ndarray, radii: np.ndarray, grids: Grids, *,
                 quad_tol: float, far: FarField, near_block_mb: float,
                 pair_blocks: str = "table-all") -> None:
        if pair_blocks not in PAIR_BLOCKS:
            raise ValueError(f"pair_blocks = {pair_blocks!r}; use 'direct' (every block built "
                             "directly), 'table' (coaxial table and rotations for the "
                             "projected zone) or 'table-all' (the table for node-sampled "
                             "pairs too)")
        self.pair_blocks = pair_blocks
        self.centers, self.radii, self.M, self.p = centers, radii, centers.shape[0], grids.p
        self.quad_tol, self.far_field = quad_tol, far
        self.grid, self.near_grid, self.near_proj = grids.grid, grids.near_grid, grids.near_proj
        self.N = grids.grid.size
        self.basis = grids.basis
        self.near_block_mb = float(near_block_mb)
        self.quadrature, self.near, self.expansions = Quadrature(), NearBlocks(), ExpansionPairs()
        self._classify()

    def _classify(self) -> None:
        """Pair classes, tolerance ladder, blocks and source points (see the class)."""
        level_of, ladder_levels = self._levels()
        self._build_blocks()
        level_of = np.where(self.near.blocked, -2, level_of)
        ladder_levels = [np.where(self.near.blocked, -2, lv) for lv in ladder_levels]
        slot = self._sources(ladder_levels)
        self._ranges(level_of, ladder_levels, slot)
        self.quadrature.pairs_per_level = {q: int((level_of == L).sum())
                                           for L, q in enumerate(self.quadrature.levels)}
        self.quadrature.n_far_pairs = int((level_of >= 0).sum())
        self.expansions.n_near_pairs = int((self.quadrature.level_of == -2).sum())

    def _levels(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """The source level of every ordered pair at full accuracy (``level_of``: -1 self,
        -2 expansion, else the index in ``levels``) and at every rung of the tolerance
        ladder."""
        M, p = self.M, self.p
        c, r = self.centers, self.radii
        levels = grid_levels(p)
        # accuracy ladder for relaxed (inexact) GMRES: quad_tol * RELAX_STEP^k <= 1e-4
        tols = [self.quad_tol]
        if self.far_field.relaxes:
            while tols[-1] * RELAX_STEP <= 1e-4 * (1 + 1e-9) and len(tols) < 12:
                tols.append(tols[-1] * RELAX_STEP)
        self.quadrature.tolerance_ladder = tuple(tols)
        rho = np.full((M, M), np.inf)
        if M > 1:
            d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
            rho = (d - r[:, None]) / r[None, :]
            np.fill_diagonal(rho, np.inf)

        def classify(tol: float) -> tuple[np.ndarray, np.ndarray]:
            if M == 1:                                     # no pairs: nothing to measure
                radius = np.full(len(levels), np.inf)
            else:
                radius = np.minimum.accumulate([quadrature_radius(p, q, tol) for q in levels])
            lv = np.full((M, M), -2, dtype=np.int64)       # -1: self, -2: expansion
            for L in range(len(levels) - 1, -1, -1):
                lv[rho >= radius[L]] = L
            np.fill_diagonal(lv, -1)
            return lv, radius

        level_of, radius = classify(self.quad_tol)
        native = levels.index(p)
        self.quadrature.native = native
        level_of = self.far_field.levels(level_of, native)
        if self.near_proj is not None:     # the projected zone: expansions at any tolerance
            level_of[(rho < PROJECT_RHO) & (level_of >= 0)] = -2
        self.quadrature.level_radii = dict(zip(levels, radius.tolist()))
        ladder_levels = [level_of]
        for tol in tols[1:]:
            lv, _ = classify(tol)
            ladder_levels.append(np.where(level_of == -2, -2, lv))   # expansion pairs stay
        self.quadrature.levels = levels
        self.quadrature.level_of = level_of
        return level_of, ladder_levels

    def _sources(self, ladder_levels: list[np.ndarray]) -> np.ndarray:
        """Source points and weights of every level (the spheres any rung sums on it) and
        the synthesis of the upsampled levels; returns each sphere's first point per level
        (-1 when it is not a source there)."""
        M, p, levels, native = self.M, self.p, self.quadrature.levels, self.quadrature.native
        c, r = self.centers, self.radii
        self.quadrature.lvl_spheres, self.quadrature.lvl_base = [], []
        base = 0
        for L, q in enumerate(levels):
            used = np.nonzero(np.any([(lv == L).any(axis=0) for lv in ladder_levels], axis=0))[0]
            if L == native:
                used = self.far_field.native_sources(used, M)
            self.quadrature.lvl_spheres.append(used)
            self.quadrature.lvl_base.append(base)
            base += used.size * sphere_grid(q).size
        self.quadrature.n_src = base
        xyz = np.empty((3, base))
        self.quadrature.src_scale = []
        slot = np.full((len(levels), M), -1, dtype=np.int64)
        for L, q in enumerate(levels):
            g = sphere_grid(q)
            J = self.quadrature.lvl_spheres[L]
            b0 = self.quadrature.lvl_base[L]
            pts = c[J, None, :] + r[J, None, None] * g.nodes[None]
            xyz[:, b0:b0 + J.size * g.size] = pts.reshape(-1, 3).T
            self.quadrature.src_scale.append(
                np.ascontiguousarray((r[J] ** 2)[:, None] * g.weights[None, :]))
            slot[L, J] = b0 + np.arange(J.size) * g.size
        self.quadrature.src_xyz = [np.ascontiguousarray(xyz[k]) for k in range(3)]
        self.quadrature.synth = [None if q == p or self.quadrature.lvl_spheres[L].size == 0
                      else np.ascontiguousarray(sampled_basis(p, q).T)
                      for L, q in enumerate(levels)]
        return slot

    def _ranges(self, level_of: np.ndarray, ladder_levels: list[np.ndarray],
                slot: np.ndarray) -> None:
        """Per rung, the source ranges each target sphere sums (``dir_ranges``, as the
        far-field strategy has them: :meth:`.farfield.FarField.ranges`)."""
        M, native = self.M, self.quadrature.native
        nq = np.array([sphere_grid(q).size for q in self.quadrature.levels], dtype=np.int64)

        def ranges(lv: np.ndarray, keep) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            ii, jj = np.nonzero(keep(lv))                   # row-major: grouped by target i
            L = lv[ii, jj]
            start = slot[L, jj]
            ptr = np.searchsorted(ii, np.arange(M + 1)).astype(np.int64)
            return ptr, start.astype(np.int64), (start + nq[L]).astype(np.int64)

        self.quadrature.dir_ranges = self.far_field.ranges(level_of, ladder_levels, native, ranges)

    def _build_blocks(self) -> None:
        """Dense near-field blocks (traction on sphere i per VSH coefficient of sphere j),
        closest pairs first, within the memory budget; the other expansion pairs
        are kept for on-the-fly evaluation (with one warning saying how many pairs the
        budget left unblocked and what they would need).

        A block is stored in coefficients on both sides, ``A E`` (``nv x nv``: the
        traction's VSH coefficients of degree <= p per density coefficient), not as nodal
        values (``3N x nv``); products synthesise the summed coefficients at the nodes once
        per sphere (``block_synth``).  The mobility does not change: the traction equation's
        self part keeps degree <= p fields and their nodal complement apart, and everything
        that reaches another sphere or the velocities is the density's degree <= p part, so
        the complement of a block's output never reaches a velocity (``tests/test_bim.py``
        checks it; docs/mobility.md has what it saves).

        With ``pair_blocks="table"`` the blocks of projected-zone pairs of equal radii come
        from the coaxial table (:mod:`.coaxial`) rotated into the pair's direction
        (:mod:`.rotation`): the exact projection of the traction onto degree p, the same
        for every orientation, which the direct build approximates on the order-2p grid
        fixed in the lab frame (they differ by that build's orientation-dependent error,
        docs/mobility.md, "Coaxial pair table"; so do table blocks and the on-the-fly
        projection of pairs the budget leaves unblocked).  Node-sampled pairs (sampling at
        the native nodes is orientation-dependent by construction), pairs of unequal radii
        (the radius ratio would be a second table axis), pairs beyond the table's range
        and p = 1 are built directly (:meth:`_direct_blocks`, the reference, used for every
        pair with ``pair_blocks="direct"``).  ``pair_blocks="table-all"`` (the default)
        takes the equal-radius node-sampled pairs from the table too (their node sampling
        is replaced by the exact projection, docs/mobility.md) and keeps the table pairs in
        rotated form; the budget counts each pair at what it stores, and table pairs
        beyond it keep their table blocks, rotated at every product (``fly_pairs``), so
        the discretisation does not depend on the budget."""
        M = self.M
        # candidates: expansion pairs, then pairs whose quadrature needs a source grid finer
        # than p (a stored block is then much cheaper per product than the sum; measured in
        # docs/mobility.md, "Blocks for fine-grid pairs")
        lv = self.quadrature.level_of
        fine = [L for L, q in enumerate(self.quadrature.levels) if q > self.p]
        ii, jj = np.nonzero((lv == -2) | np.isin(lv, fine))
        pairs = list(zip(ii.tolist(), jj.tolist()))
        if pairs:
            pairs = [pairs[k] for k in np.argsort(self._rho(ii, jj), kind="stable")]
        mb = self._block_bytes(np.array([i for i, _ in pairs], dtype=np.int64),
                               np.array([j for _, j in pairs], dtype=np.int64)) / 2 ** 20
        nb = int(np.searchsorted(np.cumsum(mb), self.near_block_mb * (1 + 1e-12), side="right"))
        blocked, rest = pairs[:nb], pairs[nb:]
        if rest:
            warnings.warn(f"near_block_mb = {self.near_block_mb:g} leaves {len(rest)} of "
                          f"{len(pairs)} near pairs without a stored block (they would need "
                          f"{mb[nb:].sum():.3g} MB more); they are evaluated on the fly "
                          "at every product: raise near_block_mb to store them",
                          RuntimeWarning, stacklevel=4)
        fly: list[tuple[int, int]] = []
        if self.pair_blocks == "table-all" and rest:      # table pairs: rotated on the fly
            ri = np.array([i for i, _ in rest], dtype=np.int64)
            rj = np.array([j for _, j in rest], dtype=np.int64)
            ok = self._table_pairs(ri, rj) & (self.quadrature.level_of[ri, rj] == -2)
            fly = [rest[k] for k in np.nonzero(ok)[0]]
            rest = [rest[k] for k in np.nonzero(~ok)[0]]
        stored = len(blocked)
        blocked = sorted(blocked + fly)                    # grouped by target sphere
        self.near.block_bytes = int(round(mb[:nb].sum() * 2 ** 20))
        with one_blas_thread():
            self.near.blocks = self._block_values(blocked, set(fly))
        b = self.basis
        self.near.block_synth = np.ascontiguousarray(b.B.T)      # (nv, 3N): coefficients -> nodes
        self.near.block_synth_T = np.ascontiguousarray(b.B)      # its transpose, for the adjoint
        self.near.block_tgt = np.array([i for i, _ in blocked], dtype=np.int64)
        self.near.block_src = np.array([j for _, j in blocked], dtype=np.int64)
        self.near.block_ptr = np.searchsorted(self.near.block_tgt,
                                              np.arange(M + 1)).astype(np.int64)
        lists: list[list[int]] = [[] for _ in range(M)]          # projected (zone)
        node_lists: list[list[int]] = [[] for _ in range(M)]     # sampled at the nodes
        for i, j in rest:
            if self.quadrature.level_of[i, j] == -2:
                zone = self.near_proj is None or self._projected(i, j)
                (lists if zone else node_lists)[i].append(j)
        self.near.blocked = np.zeros((M, M), dtype=bool)
        for i, j in blocked:
            self.near.blocked[i, j] = True
        self.expansions.fly_ptr, self.expansions.fly_idx = csr(lists)
        self.expansions.flyn_ptr, self.expansions.flyn_idx = csr(node_lists)
        self.near.n_block_pairs = len(blocked)
        self.near.n_stored_blocks = stored

    def _rho(self, ii: np.ndarray, jj: np.ndarray) -> np.ndarray:
        """Scaled distances ``(d_ij - a_i)/a_j`` of the pairs ``(ii, jj)``."""
        d = np.linalg.norm(self.centers[ii] - self.centers[jj], axis=-1)
        return (d - self.radii[ii]) / self.radii[jj]

    def _table_pairs(self, ii: np.ndarray, jj: np.ndarray) -> np.ndarray:
        """Which pairs ``(ii, jj)`` take their block from the coaxial table (``pair_blocks``
        "table": projected-zone pairs, "table-all": any; equal radii, in the table's range,
        p >= 2)."""
        if self.pair_blocks == "direct" or self.p < 2 or not ii.size:
            return np.zeros(ii.size, dtype=bool)
        rho = self._rho(ii, jj)
        same = np.abs(self.radii[ii] - self.radii[jj]) <= 1e-12 * self.radii[jj]
        zone = (np.ones(ii.size, dtype=bool) if self.pair_blocks == "table-all"
                else np.array([self._projected(i, j) for i, j in zip(ii, jj)], dtype=bool))
        return zone & same & (rho >= RHO_MIN) & (rho <= table_range(self.p))

    def _block_bytes(self, ii: np.ndarray, jj: np.ndarray) -> np.ndarray:
        """Memory of each pair's stored block: assembled (``nv x nv``), or in rotated form
        (Wigner matrices, its row index and coaxial entries) for table pairs with
        ``"table-all"``; a pair and its reverse share their coaxial entries
        (:meth:`.kernels_rotated.RotatedPairs.from_table`), each charged half."""
        nv = self.basis.B.shape[1]
        full = np.full(ii.size, 8.0 * nv * nv)
        if self.pair_blocks != "table-all" or self.p < 2:
            return full
        nw = sum((2 * n + 1) ** 2 for n in range(self.p + 1))
        rot = 8.0 * (nw + 1 + 0.5 * int(order_mask(self.p).sum()))
        return np.where(self._table_pairs(ii, jj), rot, full)

    def _block_values(self, blocked: list[tuple[int, int]],
                      fly: set | frozenset = frozenset()) -> np.ndarray | PlanBlocks:
        """The blocks of the ``blocked`` pairs, ``(len(blocked), nv, nv)``: from the
        coaxial table where it applies (``pair_blocks`` "table" or "table-all"), else
        built directly; with "table-all" the table pairs are kept in rotated form
        (``rotated``, a :class:`.kernels_rotated.RotatedPairs`), those in ``fly`` (beyond
        the memory budget) as direction and distance only (``fly_pairs``, rotated at
        every product), and the stack is a :class:`.kernels_rotated.PlanBlocks` that
        assembles them when indexed."""
        nv = self.basis.B.shape[1]
        ii = np.array([i for i, _ in blocked], dtype=np.int64)
        jj = np.array([j for _, j in blocked], dtype=np.int64)
        use = self._table_pairs(ii, jj)
        self.near.n_table_blocks = int(use.sum())
        self.near.rotated = self.near.fly_pairs = self.near.pair_frame = None
        if not use.any():                                  # every block built directly
            return self._direct_blocks(blocked)
        table = coaxial_table(self.p, table_range(self.p))
        u = self.centers[ii] - self.centers[jj]
        u /= np.linalg.norm(u, axis=1)[:, None]
        rho = self._rho(ii, jj)
        rest = np.nonzero(~use)[0]
        direct = (self._direct_blocks([blocked[k] for k in rest]) if rest.size
                  else np.zeros((0, nv, nv)))
        if self.pair_blocks == "table-all":
            late = np.array([pair in fly for pair in blocked], dtype=bool)
            keep, late = np.nonzero(use & ~late)[0], np.nonzero(use & late)[0]
            self.near.rotated = RotatedPairs.from_table(wigner_directions(u[keep], self.p), table,
                                                   rho[keep], self._output_map,
                                                   pairs=(ii[keep], jj[keep]))
            self.near.pair_frame = PairFrame.from_table(u[keep], rho[keep], ii[keep], jj[keep],
                                                   table, self._output_map)
            if late.size:
                self.near.fly_pairs = FlyPairs(u[late], rho[late], table, self._output_map)
            self.near.dense_pos, self.near.rot_pos, self.near.fly_pos = rest, keep, late
            return PlanBlocks(direct, self.near.rotated, self.near.fly_pairs, (rest, keep, late))
        Dn = wigner_directions(u[use], self.p)
        vals = table.values(rho[use])
        E = np.empty((len(blocked), nv, nv))
        E[use] = rotate_blocks(vals, Dn, degree_slices(self.p), left_matrix=self._output_map,
                               pattern=order_mask(self.p))
        E[rest] = direct
        return E

    @property
    def _output_map(self) -> np.ndarray:
        """``A B``: what the native analysis keeps of degree <= p coefficients (the
        identity but for the pair of degree-p, order-p sine columns the native grid does
        not tell apart), applied to the rotated table blocks so that they are stated in
        the same coefficients as the direct build's."""
        return self.basis.A @ self.basis.B

    def _direct_blocks(self, blocked: list[tuple[int, int]]) -> np.ndarray:
        """The blocks of the ``blocked`` pairs built directly: one exact-expansion
        response per pair, on the finer grid projected onto degree p in the projected
        zone, at the native nodes otherwise (fine-grid quadrature pairs and node
        sampling)."""
        p = self.p
        b = self.basis
        nv = b.B.shape[1]
        flat = np.argmax(np.abs(b.to_complex), axis=0)
        cfac = b.to_complex[flat, np.arange(nv)]
        fac = np.ascontiguousarray(expansion_factors(p))
        E = np.empty((len(blocked), nv, nv))
        to_coef = {True: b.A @ self.near_proj if self.near_proj is not None else b.A,
                   False: b.A}
        # expansion pairs: responses on the finer grid, projected onto degree p;
        # quadrature pairs (smooth traction) and node sampling: at the native nodes
        projected = np.array([self._projected(i, j) for i, j in blocked], dtype=bool)
        for proj in (True, False):
            idx = np.nonzero(projected == proj)[0]
            nodes = self.near_grid.nodes if proj else self.grid.nodes
            Nq = nodes.shape[0]
            chunk = max(1, int(64e6 // (Nq * 9 * (p + 1) ** 2 * 16)))     # ~64 MB of responses
            for k0 in range(0, idx.size, chunk):
                part = idx[k0:k0 + chunk]
                ii = np.array([blocked[k][0] for k in part])
                jj = np.array([blocked[k][1] for k in part])
                tgt = (self.centers[ii, None, :]
                       + self.radii[ii, None, None] * nodes[None]).reshape(-1, 3)
                resp = np.empty((tgt.shape[0], 3, p + 1, p + 1, 3), dtype=np.complex128)
                traction_response(np.ascontiguousarray(tgt),
                                  np.ascontiguousarray(np.tile(nodes, (len(part), 1))),
                                  np.ascontiguousarray(np.repeat(self.centers[jj], Nq, axis=0)),
                                  np.repeat(self.radii[jj], Nq), p, fac, resp)
                Ep = np.empty((len(part), 3 * Nq, nv))
                real_block_columns(resp.reshape(len(part) * Nq, -1, 3), flat, cfac, Ep)
                E[part] = np.matmul(to_coef[proj], Ep)
        return E

    def _projected(self, i: int, j: int) -> bool:
        """Whether pair (i, j) gets the projected near field (the zone ``rho < 2``)."""
        if self.near_proj is None or self.quadrature.level_of[i, j] != -2:
            return False
        d = float(np.linalg.norm(self.centers[i] - self.centers[j]))
        return (d - self.radii[i]) / self.radii[j] < PROJECT_RHO
