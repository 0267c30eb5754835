"""Compiled (numba) products of near-field blocks kept in rotated form.

A pair whose block comes from the coaxial table (:mod:`.coaxial`) is kept as its rotation
and its coaxial entries, never as the assembled ``nv x nv`` block ``L D E D^T``
(:meth:`.pairs.PairPlan._build_blocks`):

* ``D``: the real Wigner matrices of degree 0..p of the rotation taking +z to the pair's
  direction, flat (``sum (2n+1)^2`` numbers per pair, shared by the three kinds);
* ``E``: the coaxial block's equal-order entries (``vals``, on the row pattern
  ``ptr`` / ``idx``);
* ``L``: the native analysis of degree <= p fields (the identity but for a few rows
  ``dev``, the same for every pair).

A product per pair is ``c' = D^T c_j`` (block diagonal by kind and degree), ``y = E c'``,
``acc_i += L D y``; the transpose is ``D E^T D^T L^T``.  The kernels take the pairs'
rotated form as one tuple ``form = (D, vals, vrow, perm, groups, layout, dev, L)`` (``D``
(K, nw), ``vals`` (U, nnz) and pair k's coaxial entries its row ``vrow[k]``: a pair and
its reverse share them, the coaxial block depending on the distance alone; ``L`` the rows
``dev`` of the output map).  ``layout[n]`` holds, per degree
n, the first coefficient of degree n, its number of kinds and the offset of its Wigner
matrix in a pair's ``D`` row.  The forward kernels run in parallel over target spheres
(``tptr``: the pairs by target), the transposed one over source spheres (``sptr`` /
``sorder``), the fused one over targets with the transposed parts per pair (summed by
source by the caller).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from .coaxial import CoaxialTable, order_mask
from .jit import parallel_and_serial
from .rotation import degree_slices, rotate_blocks, wigner_directions

__all__ = ["RotatedPairs", "FlyPairs", "PlanBlocks", "rotated_forward", "rotated_forward_serial", "rotated_transpose",
           "rotated_transpose_serial", "rotated_both", "rotated_both_serial"]


@njit(cache=True, fastmath=True)
def _rotate_in(D: np.ndarray, layout: np.ndarray, c: np.ndarray, out: np.ndarray,
               transpose: bool) -> None:
    """``out = D c`` (or ``D^T c``) for one pair's block-diagonal rotation ``D`` (inner
    loops over contiguous rows of ``D``)."""
    for n in range(layout.shape[0]):
        lo, kinds, off = layout[n, 0], layout[n, 1], layout[n, 2]
        w = 2 * n + 1
        if transpose:
            for q in range(lo, lo + kinds * w):
                out[q] = 0.0
            for b in range(w):
                row = off + b * w
                for t in range(kinds):
                    base = lo + t * w
                    cb = c[base + b]
                    for a in range(w):
                        out[base + a] += D[row + a] * cb
        else:
            for t in range(kinds):
                base = lo + t * w
                for a in range(w):
                    row = off + a * w
                    acc = 0.0
                    for b in range(w):
                        acc += D[row + b] * c[base + b]
                    out[base + a] = acc


@njit(cache=True, fastmath=True)
def _coaxial(vals: np.ndarray, groups: np.ndarray, x: np.ndarray, y: np.ndarray,
             transpose: bool) -> None:
    """``y = E x`` (or ``E^T x``) for a coaxial block stored as one dense block per
    azimuthal order (``groups``: first coefficient in order-major order and offset in
    ``vals``), on coefficients in order-major order."""
    for g in range(groups.shape[0] - 1):
        s0, off = groups[g, 0], groups[g, 1]
        s = groups[g + 1, 0] - s0
        if transpose:
            for b in range(s):
                y[s0 + b] = 0.0
            for a in range(s):
                row = off + a * s
                xa = x[s0 + a]
                for b in range(s):
                    y[s0 + b] += vals[row + b] * xa
        else:                                    # BLAS dot: 2.8x the compiled loop here
            xs = x[s0:s0 + s]
            for a in range(s):
                y[s0 + a] = np.dot(vals[off + a * s:off + (a + 1) * s], xs)


@njit(cache=True, fastmath=True)
def _rotated_coaxial(D: np.ndarray, layout: np.ndarray, vals: np.ndarray, perm: np.ndarray,
                     groups: np.ndarray, src: np.ndarray, out: np.ndarray, s1: np.ndarray,
                     s2: np.ndarray, transpose: bool) -> None:
    """``out = D E D^T src`` (``E^T`` with ``transpose``) for one pair, through the
    order-major permutation; ``s1``, ``s2`` are scratch and ``out`` may be ``src``."""
    _rotate_in(D, layout, src, s1, True)
    for q in range(s1.size):                     # to order-major
        s2[q] = s1[perm[q]]
    _coaxial(vals, groups, s2, out, transpose)
    for q in range(s1.size):                     # back to the basis order
        s1[perm[q]] = out[q]
    _rotate_in(D, layout, s1, out, False)


@njit(cache=True, fastmath=True)
def _pair_forward(form: tuple, k: int, c: np.ndarray, acc: np.ndarray,
                  work: np.ndarray) -> None:
    """``acc += L D E D^T c`` for pair k of ``form`` (``work``: (3, nv) scratch)."""
    Ds, vs, vrow, perm, groups, layout, dev, L = form
    D = Ds[k]
    nv = c.size
    y, z = work[1], work[2]
    _rotated_coaxial(D, layout, vs[vrow[k]], perm, groups, c, z, work[0], y, False)
    for i in range(dev.size):                    # rows of L that differ from the identity
        s = 0.0
        for j in range(nv):
            s += L[i, j] * z[j]
        y[i] = s
    for i in range(dev.size):
        z[dev[i]] = y[i]
    for r in range(nv):
        acc[r] += z[r]


@njit(cache=True, fastmath=True)
def _pair_transpose(form: tuple, k: int, x: np.ndarray, out: np.ndarray,
                    work: np.ndarray) -> None:
    """``out += D E^T D^T L^T x`` for pair k of ``form`` (``work``: (3, nv) scratch)."""
    Ds, vs, vrow, perm, groups, layout, dev, L = form
    D = Ds[k]
    nv = x.size
    x1, x2, x3 = work[0], work[1], work[2]
    for r in range(nv):
        x1[r] = x[r]
    for i in range(dev.size):
        x1[dev[i]] -= x[dev[i]]
    for i in range(dev.size):
        xi = x[dev[i]]
        for j in range(nv):
            x1[j] += L[i, j] * xi
    _rotated_coaxial(D, layout, vs[vrow[k]], perm, groups, x1, x1, x2, x3, True)
    for r in range(nv):
        out[r] += x1[r]


def _forward(form, tptr, src, coef, acc):
    """``acc[i] += sum over pairs k with target i of block_k coef[src[k]]``."""
    M, nv = acc.shape
    for i in prange(M):
        work = np.empty((3, nv))
        for k in range(tptr[i], tptr[i + 1]):
            _pair_forward(form, k, coef[src[k]], acc[i], work)


def _transpose(form, sptr, sorder, tgt, x, coef_bar):
    """``coef_bar[j] += sum over pairs k with source j of block_k^T x[tgt[k]]``."""
    M, nv = coef_bar.shape
    for j in prange(M):
        work = np.empty((3, nv))
        for q in range(sptr[j], sptr[j + 1]):
            k = sorder[q]
            _pair_transpose(form, k, x[tgt[k]], coef_bar[j], work)


def _both(form, tptr, src, coef, acc, x, part):
    """:func:`_forward` into ``acc`` and, per pair k with target i, ``part[k] =
    block_k^T x[i]`` (summed by source by the caller), in one pass over the pairs."""
    M, nv = acc.shape
    for i in prange(M):
        work = np.empty((3, nv))
        for k in range(tptr[i], tptr[i + 1]):
            _pair_forward(form, k, coef[src[k]], acc[i], work)
            part[k, :] = 0.0
            _pair_transpose(form, k, x[i], part[k], work)


rotated_forward, rotated_forward_serial = parallel_and_serial(_forward)
rotated_transpose, rotated_transpose_serial = parallel_and_serial(_transpose)
rotated_both, rotated_both_serial = parallel_and_serial(_both)


def _order_major(pattern: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For a pattern that couples coefficients in groups (the equal-order couplings of a
    coaxial block, a block diagonal after a permutation): the permutation grouping them,
    per group its first position and the offset of its dense block, and the positions of
    those dense blocks' entries (row-major) among the pattern's (row-major)."""
    nv = pattern.shape[0]
    label = np.full(nv, -1, dtype=np.int64)
    for r in range(nv):                           # connected groups of the pattern
        if label[r] < 0:
            label[np.nonzero(pattern[r])[0]] = r
    perm = np.argsort(label, kind="stable").astype(np.int64)
    lab = label[perm]
    starts = np.concatenate([[0], np.nonzero(np.diff(lab))[0] + 1, [nv]]).astype(np.int64)
    sizes = np.diff(starts)
    groups = np.stack([starts, np.concatenate([[0], np.cumsum(sizes ** 2)])], axis=1)
    pos = np.full((nv, nv), -1, dtype=np.int64)
    pos[pattern] = np.arange(int(pattern.sum()))
    gather = np.concatenate([pos[np.ix_(perm[a:b], perm[a:b])].ravel()
                             for a, b in zip(starts[:-1], starts[1:])])
    if (gather < 0).any() or gather.size != pattern.sum():
        raise ValueError("the pattern is not block diagonal up to a permutation")
    return perm, groups.astype(np.int64), gather


def _pattern_parts(pattern: np.ndarray, left_matrix: np.ndarray) -> tuple:
    """What :class:`RotatedPairs` keeps of a coaxial pattern and an output map: the row
    pointers and columns of the pattern, the rows ``dev`` where the map differs from the
    identity and those rows, and the order-major permutation, groups and gather
    (:func:`_order_major`)."""
    nv = pattern.shape[0]
    dev = np.nonzero(np.abs(left_matrix - np.eye(nv)).max(axis=1) > 1e-12)[0]
    return (np.concatenate([[0], np.cumsum(pattern.sum(axis=1))]).astype(np.int64),
            np.nonzero(pattern)[1].astype(np.int64), dev.astype(np.int64),
            np.ascontiguousarray(left_matrix[dev]), *_order_major(pattern))


@dataclass(frozen=True)
class RotatedPairs:
    """Blocks kept in rotated form (see the module): per pair its flat Wigner matrices and
    its coaxial entries.

    Attributes
    ----------
    p : int
        Order of the blocks.
    D : ndarray, shape (K, nw)
        Per pair the real Wigner matrices of degree 0..p, row-major, one after the other.
    vals : ndarray, shape (U, nnz)
        Coaxial blocks' entries, one dense block per azimuthal order m (rows and columns in
        the order-major order ``perm``), row-major; pair k's are row ``vrow[k]``.
    ptr, idx : ndarray
        Row pointers (nv + 1) and columns (nnz) of the equal-order pattern (basis order).
    perm : ndarray
        The coefficients sorted by order m (stable).
    groups : ndarray, shape (G + 1, 2)
        Per order: its first position in ``perm`` and the offset of its block in ``vals``.
    gather : ndarray
        ``vals = (entries on the pattern, row-major)[:, gather]``.
    layout : ndarray, shape (p + 1, 3)
        Per degree: first coefficient, number of kinds, offset of its Wigner matrix.
    dev : ndarray
        Rows of the output map ``L`` that differ from the identity.
    L : ndarray, shape (len(dev), nv)
        Those rows.
    vrow : ndarray, shape (K,)
        Each pair's row of ``vals`` (None: row k, one row per pair).
    """

    p: int
    D: np.ndarray
    vals: np.ndarray
    ptr: np.ndarray
    idx: np.ndarray
    layout: np.ndarray
    dev: np.ndarray
    L: np.ndarray
    perm: np.ndarray
    groups: np.ndarray
    gather: np.ndarray
    vrow: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.vrow is None:
            object.__setattr__(self, "vrow", np.arange(self.D.shape[0], dtype=np.int64))

    @property
    def n_pairs(self) -> int:
        """Pairs kept (rows of ``D``)."""
        return int(self.D.shape[0])

    @classmethod
    def from_table(cls, Dn: list[np.ndarray], table: CoaxialTable, rho: np.ndarray,
                   left_matrix: np.ndarray, pairs: tuple | None = None) -> RotatedPairs:
        """:meth:`build` for the coaxial blocks of ``table`` at the scaled distances
        ``rho``, their entries interpolated straight into the kernels' order.  With
        ``pairs = (targets, sources)`` a pair and its reverse at the same ``rho`` (equal
        radii) share one row of entries: the coaxial block depends on the distance alone
        (only the rotations differ), so half the entries are interpolated and stored."""
        pattern = order_mask(table.p)
        gather = _order_major(pattern)[2]
        rho = np.asarray(rho, dtype=float)
        if pairs is None or not rho.size:
            return cls.build(Dn, table.values(rho, columns=gather), pattern, left_matrix,
                             ordered=True)
        t, s = (np.asarray(a, dtype=np.int64) for a in pairs)
        key = np.column_stack([np.minimum(t, s), np.maximum(t, s), rho.view(np.int64)])
        first, vrow = np.unique(key, axis=0, return_index=True, return_inverse=True)[1:]
        return cls.build(Dn, table.values(rho[first], columns=gather), pattern, left_matrix,
                         ordered=True, vrow=vrow.reshape(-1))

    @classmethod
    def build(cls, Dn: list[np.ndarray], vals: np.ndarray, pattern: np.ndarray,
              left_matrix: np.ndarray, ordered: bool = False,
              vrow: np.ndarray | None = None) -> RotatedPairs:
        """The rotated form of the blocks ``left_matrix D E D^T``: ``Dn[n]`` (K, 2n+1,
        2n+1) the Wigner matrices per degree, ``vals`` (K, nnz) the entries of the coaxial
        blocks on the bool ``pattern`` (nv, nv), row-major (``ordered``: already in the
        order-major order of :attr:`vals`, kept without a copy; ``vrow``: pair k's row of
        ``vals``, which then has a row per distinct block)."""
        p = len(Dn) - 1
        K = Dn[0].shape[0]
        layout = np.empty((p + 1, 3), dtype=np.int64)
        off = 0
        for n, rows in enumerate(degree_slices(p)):
            layout[n] = (int(rows[0, 0]), rows.shape[0], off)
            off += (2 * n + 1) ** 2
        D = np.concatenate([d.reshape(K, -1) for d in Dn], axis=1) if K else np.zeros((0, off))
        ptr, idx, dev, L, perm, groups, gather = _pattern_parts(pattern, left_matrix)
        vals = np.asarray(vals, dtype=float)
        return cls(p, np.ascontiguousarray(D),
                   np.ascontiguousarray(vals if ordered else vals[:, gather]),
                   ptr, idx, layout, dev, L, perm, groups, gather,
                   None if vrow is None else np.ascontiguousarray(vrow, dtype=np.int64))

    @property
    def form(self) -> tuple:
        """The tuple the compiled kernels read."""
        return (self.D, self.vals, self.vrow, self.perm, self.groups, self.layout, self.dev,
                self.L)

    @property
    def nbytes(self) -> int:
        """Memory of the per-pair data (the pattern and output map are shared)."""
        return int(self.D.nbytes + self.vals.nbytes + self.vrow.nbytes)

    @property
    def work(self) -> int:
        """Multiply-adds of one forward product with every pair."""
        nv = self.ptr.size - 1
        rot = int(sum(k * (2 * n + 1) ** 2 for n, k in enumerate(self.layout[:, 1])))
        return int(self.n_pairs * (2 * rot + self.vals.shape[1] + self.dev.size * nv))

    def truncated(self, sel: np.ndarray, q: int) -> RotatedPairs:
        """The rotated form of the pairs ``sel`` restricted to the coefficients of degree
        <= ``q`` on both sides: the leading ``nv(q) x nv(q)`` part of each assembled
        block (``q < 0`` or ``q >= p``: the pairs' blocks whole).

        The rotation is block diagonal by degree and the coefficients are ordered by
        degree, so the leading part of ``L D E D^T`` is ``L_q D_q E_q D_q^T`` with
        ``D_q`` the Wigner matrices of degree <= q (a prefix of each pair's ``D`` row),
        ``E_q`` the coaxial entries between coefficients of degree <= q, and ``L_q`` the
        output map's leading part, exact as long as no output-map row of degree <= q
        reads a coefficient of higher degree (the map differs from the identity only at
        degree p).

        Raises
        ------
        ValueError
            The output map couples a coefficient of degree <= q to a higher one.
        """
        sel = np.asarray(sel, dtype=np.int64)
        nv = self.ptr.size - 1
        shared, vrow = np.unique(self.vrow[sel], return_inverse=True)   # entry rows kept
        vrow = vrow.reshape(-1)
        if q < 0 or q >= self.p:
            return RotatedPairs(self.p, np.ascontiguousarray(self.D[sel]),
                                np.ascontiguousarray(self.vals[shared]), self.ptr, self.idx,
                                self.layout, self.dev, self.L, self.perm, self.groups,
                                self.gather, vrow)
        nq = int(self.layout[q + 1, 0])
        left = np.eye(nv)
        left[self.dev] = self.L
        if np.abs(left[:nq, nq:]).max(initial=0.0) > 0:
            raise ValueError(f"the output map couples coefficients of degree <= {q} to "
                             "higher ones: the truncated blocks would not be the leading "
                             "part of the full ones")
        rows = np.repeat(np.arange(nv), np.diff(self.ptr))
        keep = (rows < nq) & (self.idx < nq)
        pattern = np.zeros((nq, nq), dtype=bool)
        pattern[rows[keep], self.idx[keep]] = True
        entries = np.empty((shared.size, self.vals.shape[1]))   # row-major on the pattern
        entries[:, self.gather] = self.vals[shared]
        ptr, idx, dev, L, perm, groups, gather = _pattern_parts(pattern, left[:nq, :nq])
        nw = int(self.layout[q, 2]) + (2 * q + 1) ** 2
        return RotatedPairs(q, np.ascontiguousarray(self.D[sel, :nw]),
                            np.ascontiguousarray(entries[:, keep][:, gather]), ptr, idx,
                            np.ascontiguousarray(self.layout[:q + 1]), dev, L, perm, groups,
                            gather, vrow)

    def assemble(self, sel: np.ndarray) -> np.ndarray:
        """The assembled blocks ``L D E D^T`` of the pairs ``sel``, ``(len(sel), nv, nv)``."""
        sel = np.asarray(sel, dtype=np.int64)
        nv = self.ptr.size - 1
        Dn = []
        for n in range(self.p + 1):
            w, off = 2 * n + 1, self.layout[n, 2]
            Dn.append(self.D[sel, off:off + w * w].reshape(-1, w, w))
        pattern = np.zeros((nv, nv), dtype=bool)
        pattern[np.repeat(np.arange(nv), np.diff(self.ptr)), self.idx] = True
        left = np.eye(nv)
        left[self.dev] = self.L
        vals = np.empty((sel.size, self.vals.shape[1]))
        vals[:, self.gather] = self.vals[self.vrow[sel]]
        slices = [lo + np.arange(kinds * (2 * n + 1), dtype=np.int64).reshape(kinds, -1)
                  for n, (lo, kinds, _) in enumerate(self.layout)]
        return rotate_blocks(vals, Dn, slices, left_matrix=left, pattern=pattern)


@dataclass(frozen=True)
class FlyPairs:
    """Table pairs beyond the memory budget: only their directions and scaled distances
    are kept, and their rotated form is computed at every product, a chunk of pairs at a
    time (the same blocks as if stored: the table's, rotated).

    Attributes
    ----------
    u : ndarray, shape (K, 3)
        Unit vectors from source to target centre.
    rho : ndarray, shape (K,)
        Scaled distances.
    table : CoaxialTable
        The coaxial table.
    left_matrix : ndarray, shape (nv, nv)
        The output map ``L``.
    """

    u: np.ndarray
    rho: np.ndarray
    table: CoaxialTable
    left_matrix: np.ndarray

    chunk = 256
    """Pairs whose rotated form is held at a time (about 18 MB at p = 8)."""

    def rotated(self, sel) -> RotatedPairs:
        """The rotated form of the pairs ``sel`` (an index array or a slice)."""
        p = self.table.p
        return RotatedPairs.from_table(wigner_directions(self.u[sel], p), self.table,
                                       self.rho[sel], self.left_matrix)

    def chunks(self):
        """Slices of at most :attr:`chunk` consecutive pairs covering them all."""
        K = self.rho.size
        return [slice(k, min(k + self.chunk, K)) for k in range(0, K, self.chunk)]


class PlanBlocks:
    """The pair plan's blocks as a read-only stack ``(K, nv, nv)`` assembled on demand:
    blocks kept dense are returned as stored, blocks kept in rotated form
    (:class:`RotatedPairs`) or computed at each product (:class:`FlyPairs`) are assembled
    when indexed.  Indexing takes what the readers of ``plan.blocks`` use: an integer, a
    slice or an index array, optionally followed by slices of rows and columns
    (``blocks[idx, :n, :n]``).

    Parameters
    ----------
    dense : ndarray, shape (Kd, nv, nv)
        The blocks kept dense.
    rotated : RotatedPairs
        The blocks kept in rotated form.
    fly : FlyPairs or None
        The blocks computed at each product.
    positions : tuple of ndarray
        The positions in the stack of the dense, rotated and computed blocks.
    """

    ndim = 3

    def __init__(self, dense: np.ndarray, rotated: RotatedPairs, fly: FlyPairs | None,
                 positions: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        nv = rotated.ptr.size - 1
        self.shape = (int(sum(x.size for x in positions)), nv, nv)
        self.dense, self.rotated, self.fly = dense, rotated, fly
        self._kind = np.empty(self.shape[0], dtype=np.int64)
        self._at = np.empty(self.shape[0], dtype=np.int64)
        for kind, pos in enumerate(positions):
            self._kind[pos] = kind
            self._at[pos] = np.arange(pos.size)

    @property
    def size(self) -> int:
        """Entries of the assembled stack (the work of an assembled product)."""
        return int(np.prod(self.shape))

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key):
        rest: tuple = ()
        if isinstance(key, tuple):
            key, rest = key[0], key[1:]
        sel = np.arange(self.shape[0])[key]
        scalar = sel.ndim == 0
        sel = np.atleast_1d(sel)
        kind, at = self._kind[sel], self._at[sel]
        out = np.empty((sel.size,) + self.shape[1:])
        for k, assemble in enumerate((lambda i: self.dense[i],
                                      lambda i: self.rotated.assemble(i),
                                      lambda i: self.fly.rotated(i).assemble(np.arange(i.size)))):
            mine = kind == k
            if mine.any():
                out[mine] = assemble(at[mine])
        out = out[0] if scalar else out
        return out[(slice(None),) * (0 if scalar else 1) + rest] if rest else out

    def kinds(self, sel: np.ndarray) -> np.ndarray:
        """How each block of ``sel`` is kept: 0 dense, 1 in rotated form, 2 computed at
        each product."""
        return self._kind[np.asarray(sel, dtype=np.int64)]

    def truncated_form(self, sel: np.ndarray, q: int) -> RotatedPairs:
        """The rotated form, restricted to degree <= ``q`` (:meth:`RotatedPairs.truncated`),
        of the blocks ``sel``, every one kept in rotated form or computed at each product
        (those are rotated here once, a chunk at a time).

        Raises
        ------
        ValueError
            A block of ``sel`` is kept dense.
        """
        sel = np.asarray(sel, dtype=np.int64)
        kind, at = self._kind[sel], self._at[sel]
        if (kind == 0).any():
            raise ValueError("blocks kept dense have no rotated form; take them from the "
                             "stack (blocks[sel])")
        parts: list[tuple[np.ndarray, RotatedPairs]] = []
        mine = np.nonzero(kind == 1)[0]
        if mine.size or not sel.size:
            parts.append((mine, self.rotated.truncated(at[mine], q)))
        fly = np.nonzero(kind == 2)[0]
        step = FlyPairs.chunk
        for k0 in range(0, fly.size, step):
            rows = fly[k0:k0 + step]
            parts.append((rows, self.fly.rotated(at[rows]).truncated(np.arange(rows.size), q)))
        if len(parts) == 1:
            return parts[0][1]
        first = parts[0][1]
        D = np.empty((sel.size, first.D.shape[1]))
        vrow = np.empty(sel.size, dtype=np.int64)
        offset = 0
        for rows, part in parts:
            D[rows], vrow[rows] = part.D, part.vrow + offset
            offset += part.vals.shape[0]
        vals = np.concatenate([part.vals for _, part in parts])
        return RotatedPairs(first.p, D, vals, first.ptr, first.idx, first.layout, first.dev,
                            first.L, first.perm, first.groups, first.gather, vrow)
