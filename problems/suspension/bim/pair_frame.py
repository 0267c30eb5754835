"""Products of the coaxial-table pairs in the pair frame, batched over pairs.

A table pair's block is ``L D E D^T`` (:mod:`.kernels_rotated` keeps it so): ``D`` the
rotation taking +z to the pair's direction, ``E`` the coaxial block of its distance,
``L`` the output map.  This module applies the same blocks with three facts of their
physics that the per-pair form does not use:

* **The rotation is two turns about z and two fixed quarter turns.**  ``D = Rz(phi) P
  Rz(theta) P^T`` (:mod:`.rotation`): the turns about z act on each (cosine, sine) pair of
  order m as a 2 x 2 rotation by ``m phi`` (closed form, a few numbers per pair), and the
  quarter turn ``P`` is one small matrix per degree shared by every pair.  No Wigner matrix
  is stored per pair: a pair keeps its two angles' cosines and sines of each order.
* **The coaxial block is sparser than its equal-order pattern.**  Two spheres on the z axis
  are symmetric under every reflection through a plane containing the axis, so the
  cosine-type and sine-type fields of order m decouple (except through the toroidal kind,
  whose parity is the opposite), and the normal kind is driven only by the tangential
  poloidal one; two thirds of the equal-order entries vanish.  The entries kept
  (:func:`coaxial_support`) are those the table does not resolve from zero: its
  Chebyshev coefficients bound every entry over the table's range, and the dropped ones are
  quadrature noise below ``ZERO_TOL`` times the largest entry.
* **A pair and its reverse share their coaxial block** (equal radii: the block depends on
  the distance alone), so each distinct block is read once per product for both
  directions.

The pairs are grouped in chunks of :data:`LANES` items (a pair and its reverse, or a pair
alone); a chunk's data is laid out with the item innermost, so that every step (the turns,
the quarter turns, the coaxial entries, the output map) is a loop over contiguous
vectors of the chunk's items: each coaxial entry is read once and multiplies the four
vectors of its item (forward and transposed, both directions) when both products are
asked together.  Chunks run in parallel, each thread summing into its own copy of the
output.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import get_num_threads, njit, prange

from .coaxial import CoaxialTable, order_mask
from .jit import parallel_and_serial
from .rotation import degree_slices, wigner_quarter

__all__ = ["LANES", "ZERO_TOL", "PairFrame", "coaxial_support"]

LANES = 16
"""Items (a pair and its reverse, or a pair alone) per chunk: the length of the contiguous
vectors the kernel works on (measured: 8 to 32 are within a few percent at p = 8)."""

ZERO_TOL = 1e-11
"""An equal-order entry whose bound over the whole table is below this times the table's
largest entry is a structural zero (measured at p = 8: the dropped entries are at most
2e-14 times the largest, the kept ones at least 1e-6)."""


def coaxial_support(table: CoaxialTable) -> np.ndarray:
    """Positions, among the equal-order entries of ``order_mask(p)`` (row-major), of the
    entries of the coaxial block that are not structural zeros (see the module): those
    whose Chebyshev coefficients' absolute sum, the largest over the table's panels,
    exceeds :data:`ZERO_TOL` times that of the largest entry."""
    bound = np.abs(table.coefs).sum(axis=1).max(axis=0)
    return np.nonzero(bound > ZERO_TOL * bound.max())[0].astype(np.int64)


# ---- the compiled kernel ---------------------------------------------------------------------

@njit(cache=True, fastmath=True)
def _turn_z(x, layout, cs, which, sign, V, B):
    """Turns about z of the columns of ``x`` (nv, V*B): rows (cos m, sin m) of every (kind,
    degree) by ``sign * m * angle``, the angle's cosines and sines ``cs[which]`` (p+1, 2, B)
    per order, direction (column block v uses direction v % 2) and item."""
    for n in range(1, layout.shape[0]):
        lo, kinds = layout[n, 0], layout[n, 1]
        w = 2 * n + 1
        for t in range(kinds):
            base = lo + t * w
            for m in range(1, n + 1):
                i = base + 2 * m - 1
                j = i + 1
                for v in range(V):
                    d = v % 2
                    for lane in range(B):
                        c = cs[which, m, d, lane]
                        s = sign * cs[which + 1, m, d, lane]
                        col = v * B + lane
                        xi = x[i, col]
                        xj = x[j, col]
                        x[i, col] = c * xi - s * xj
                        x[j, col] = s * xi + c * xj


@njit(cache=True, fastmath=True)
def _quarter(x, y, layout, qptr, qa, qb, qv, transpose):
    """``y = P x`` (or ``P^T x``) on every (kind, degree) block of rows, ``P`` the quarter
    turn of each degree given by its nonzeros ``qa, qb, qv`` (rows, columns, values;
    degree n's are ``qptr[n]:qptr[n+1]``)."""
    VB = x.shape[1]
    for n in range(layout.shape[0]):
        lo, kinds = layout[n, 0], layout[n, 1]
        w = 2 * n + 1
        for t in range(kinds):
            base = lo + t * w
            for a in range(w):
                for col in range(VB):
                    y[base + a, col] = 0.0
            for e in range(qptr[n], qptr[n + 1]):
                a, b = (qb[e], qa[e]) if transpose else (qa[e], qb[e])
                val = qv[e]
                for col in range(VB):
                    y[base + a, col] += val * x[base + b, col]


@njit(cache=True, fastmath=True)
def _chunk(vals, cs, tgt, src, coef, xadj, nf, na, layout, qptr, qa, qb, qv, er, ec, dev,
           L, X, Y, acc, bar):
    """One chunk: ``nf`` forward vectors (``L D E D^T coef[src]`` added to ``acc[tgt]``)
    and ``na`` transposed ones (``D E^T D^T L^T xadj[tgt]`` added to ``bar[src]``), each
    one per direction (``nf``, ``na`` are 0 or 2)."""
    nv = X.shape[0]
    B = vals.shape[1]
    V = nf + na
    for v in range(V):                                   # gather (and L^T on the adjoint)
        d = v % 2
        for lane in range(B):
            col = v * B + lane
            k = src[d, lane] if v < nf else tgt[d, lane]
            if k < 0:
                for r in range(nv):
                    X[r, col] = 0.0
                continue
            row = coef[k] if v < nf else xadj[k]
            for r in range(nv):
                X[r, col] = row[r]
            if v >= nf:
                for i in range(dev.size):
                    X[dev[i], col] = 0.0
                for i in range(dev.size):
                    xi = row[dev[i]]
                    for r in range(nv):
                        X[r, col] += L[i, r] * xi
    # into the pair frame: D^T = P Rz(-theta) P^T Rz(-phi)
    _turn_z(X, layout, cs, 0, -1.0, V, B)
    _quarter(X, Y, layout, qptr, qa, qb, qv, True)
    _turn_z(Y, layout, cs, 2, -1.0, V, B)
    _quarter(Y, X, layout, qptr, qa, qb, qv, False)
    for r in range(nv):                                  # the coaxial block
        for col in range(V * B):
            Y[r, col] = 0.0
    for e in range(er.size):
        r, c = er[e], ec[e]
        for v in range(V):
            a, b = (r, c) if v < nf else (c, r)
            off = v * B
            for lane in range(B):
                Y[a, off + lane] += vals[e, lane] * X[b, off + lane]
    # back to the lab frame: D = Rz(phi) P Rz(theta) P^T
    _quarter(Y, X, layout, qptr, qa, qb, qv, True)
    _turn_z(X, layout, cs, 2, 1.0, V, B)
    _quarter(X, Y, layout, qptr, qa, qb, qv, False)
    _turn_z(Y, layout, cs, 0, 1.0, V, B)
    for v in range(V):                                   # L on the forward, scatter
        d = v % 2
        for lane in range(B):
            col = v * B + lane
            if v < nf:
                k = tgt[d, lane]
                if k < 0:
                    continue
                for i in range(dev.size):
                    s = 0.0
                    for r in range(nv):
                        s += L[i, r] * Y[r, col]
                    X[i, col] = s
                for i in range(dev.size):
                    Y[dev[i], col] = X[i, col]
                out = acc[k]
            else:
                k = src[d, lane]
                if k < 0:
                    continue
                out = bar[k]
            for r in range(nv):
                out[r] += Y[r, col]


def _run(vals, cs, tgt, src, coef, xadj, nf, na, layout, qptr, qa, qb, qv, er, ec, dev, L,
         acc, bar):
    """Every chunk, the threads each taking a contiguous share and summing into their own
    copy ``acc[t]`` / ``bar[t]``."""
    T = acc.shape[0]
    C = vals.shape[0]
    nv = acc.shape[2]
    B = vals.shape[2]
    for t in prange(T):
        X = np.empty((nv, (nf + na) * B))
        Y = np.empty((nv, (nf + na) * B))
        for c in range(t * C // T, (t + 1) * C // T):
            _chunk(vals[c], cs[c], tgt[c], src[c], coef, xadj, nf, na, layout, qptr, qa,
                   qb, qv, er, ec, dev, L, X, Y, acc[t], bar[t])


_run_parallel, _run_serial = parallel_and_serial(_run)


# ---- the pairs' data ---------------------------------------------------------------------------

def _quarter_nonzeros(p: int) -> tuple[np.ndarray, ...]:
    """The quarter turns of degree 0..p as nonzero lists (pointer per degree, rows,
    columns, values); entries below 1e-15 are rounding of exact zeros."""
    ptr, rows, cols, vals = [0], [], [], []
    for Pn in wigner_quarter(p):
        a, b = np.nonzero(np.abs(Pn) > 1e-15)
        rows.append(a)
        cols.append(b)
        vals.append(Pn[a, b])
        ptr.append(ptr[-1] + a.size)
    return (np.array(ptr, dtype=np.int64), np.concatenate(rows).astype(np.int64),
            np.concatenate(cols).astype(np.int64), np.concatenate(vals))


def _layout(p: int) -> np.ndarray:
    """Per degree: first coefficient and number of kinds."""
    return np.array([(int(rows[0, 0]), rows.shape[0]) for rows in degree_slices(p)],
                    dtype=np.int64)


def _items(tgt: np.ndarray, src: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Pairs grouped into items ``(first, second)`` (indices into the pairs; ``second`` -1
    for a pair whose reverse is not among them): a pair and its reverse at the same
    distance share one item."""
    key = np.column_stack([np.minimum(tgt, src), np.maximum(tgt, src), rho.view(np.int64)])
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    order = np.argsort(inv, kind="stable")
    starts = np.concatenate([[0], np.nonzero(np.diff(inv[order]))[0] + 1, [order.size]])
    items = np.full((starts.size - 1, 2), -1, dtype=np.int64)
    for g, (a, b) in enumerate(zip(starts[:-1], starts[1:])):
        members = order[a:b]
        if members.size > 2:
            raise ValueError("a pair of spheres appears more than twice among the pairs")
        items[g, :members.size] = members
    return items


@dataclass(frozen=True)
class PairFrame:
    """The table pairs' blocks in the pair frame (see the module), in chunks of items.

    Attributes
    ----------
    p : int
        Order of the blocks.
    n_pairs : int
        Pairs held.
    vals : ndarray, shape (C, nnz, LANES)
        Per chunk the coaxial entries kept (:func:`coaxial_support`) of each item.
    cs : ndarray, shape (C, 4, p + 1, 2, LANES)
        Per chunk ``cos(m phi), sin(m phi), cos(m theta), sin(m theta)`` per order m,
        direction and item.
    tgt, src : ndarray, shape (C, 2, LANES)
        Target and source sphere per direction and item (-1: none).
    er, ec : ndarray
        Rows and columns of the kept coaxial entries (basis order).
    quarter : tuple of ndarray
        The quarter turns' nonzeros (:func:`_quarter_nonzeros`).
    layout : ndarray, shape (p + 1, 2)
        Per degree its first coefficient and number of kinds.
    dev : ndarray
        Rows of the output map that differ from the identity.
    L : ndarray, shape (len(dev), nv)
        Those rows.
    """

    p: int
    n_pairs: int
    vals: np.ndarray
    cs: np.ndarray
    tgt: np.ndarray
    src: np.ndarray
    er: np.ndarray
    ec: np.ndarray
    quarter: tuple
    layout: np.ndarray
    dev: np.ndarray
    L: np.ndarray

    @classmethod
    def from_table(cls, u: np.ndarray, rho: np.ndarray, tgt: np.ndarray, src: np.ndarray,
                   table: CoaxialTable, left_matrix: np.ndarray,
                   support: np.ndarray | None = None) -> PairFrame:
        """The pairs ``(tgt[k], src[k])`` along the unit vectors ``u[k]`` (source to target)
        at scaled distances ``rho[k]``, their blocks the table's ``L D E D^T`` with ``L`` =
        ``left_matrix``; ``support`` the coaxial entries kept (default
        :func:`coaxial_support`)."""
        p = table.p
        u = np.asarray(u, dtype=float).reshape(-1, 3)
        rho = np.ascontiguousarray(rho, dtype=float)
        tgt = np.asarray(tgt, dtype=np.int64)
        src = np.asarray(src, dtype=np.int64)
        pattern = order_mask(p)
        nv = pattern.shape[0]
        rows, cols = np.nonzero(pattern)
        keep = coaxial_support(table) if support is None else np.asarray(support, np.int64)
        items = _items(tgt, src, rho) if rho.size else np.zeros((0, 2), dtype=np.int64)
        C = -(-items.shape[0] // LANES)
        pad = np.full((C * LANES, 2), -1, dtype=np.int64)
        pad[:items.shape[0]] = items
        vals = np.zeros((C * LANES, keep.size))
        if items.shape[0]:
            vals[:items.shape[0]] = table.values(rho[items[:, 0]], columns=keep)
        theta = np.arctan2(np.hypot(u[:, 0], u[:, 1]), u[:, 2])
        phi = np.arctan2(u[:, 1], u[:, 0])
        m = np.arange(p + 1, dtype=float)
        cs = np.zeros((C * LANES, 2, 4, p + 1))
        cs[:, :, 0] = cs[:, :, 2] = 1.0                  # an empty slot: no turn
        ids = np.zeros((2, C * LANES, 2), dtype=np.int64) - 1
        for d in range(2):
            k = pad[:, d]
            has = k >= 0
            kk = k[has]
            cs[has, d, 0] = np.cos(m * phi[kk, None])
            cs[has, d, 1] = np.sin(m * phi[kk, None])
            cs[has, d, 2] = np.cos(m * theta[kk, None])
            cs[has, d, 3] = np.sin(m * theta[kk, None])
            ids[0, has, d] = tgt[kk]
            ids[1, has, d] = src[kk]
        left = np.asarray(left_matrix, dtype=float)
        dev = np.nonzero(np.abs(left - np.eye(nv)).max(axis=1) > 1e-12)[0].astype(np.int64)
        return cls(
            p, int(rho.size),
            np.ascontiguousarray(vals.reshape(C, LANES, keep.size).transpose(0, 2, 1)),
            np.ascontiguousarray(cs.reshape(C, LANES, 2, 4, p + 1).transpose(0, 3, 4, 2, 1)),
            np.ascontiguousarray(ids[0].reshape(C, LANES, 2).transpose(0, 2, 1)),
            np.ascontiguousarray(ids[1].reshape(C, LANES, 2).transpose(0, 2, 1)),
            np.ascontiguousarray(rows[keep], dtype=np.int64),
            np.ascontiguousarray(cols[keep], dtype=np.int64),
            _quarter_nonzeros(p), _layout(p), dev, np.ascontiguousarray(left[dev]))

    @property
    def nv(self) -> int:
        """Coefficients per sphere."""
        return int(self.L.shape[1])

    @property
    def nbytes(self) -> int:
        """Memory of the per-pair data."""
        return int(self.vals.nbytes + self.cs.nbytes + self.tgt.nbytes + self.src.nbytes)

    @property
    def work(self) -> int:
        """Multiply-adds of one forward product with every pair (both directions of an
        item counted, the quarter turns by their nonzeros)."""
        kinds = self.layout[:, 1]
        qn = np.diff(self.quarter[0])
        quarter = int((kinds * qn).sum())
        turns = int(sum(k * 4 * n for n, k in enumerate(kinds)))
        per = 4 * quarter + 4 * turns + self.er.size + self.dev.size * self.nv
        return int(2 * self.vals.shape[0] * self.vals.shape[2] * per)

    def _apply(self, coef: np.ndarray | None, xadj: np.ndarray | None, M: int,
               parallel: bool) -> tuple[np.ndarray, np.ndarray]:
        T = get_num_threads() if parallel else 1
        T = max(1, min(T, self.vals.shape[0]))
        nv = self.nv
        nf, na = (0 if coef is None else 2), (0 if xadj is None else 2)
        acc = np.zeros((T, M, nv) if nf else (1, 1, nv))
        bar = np.zeros((T, M, nv) if na else (1, 1, nv))
        empty = np.zeros((1, nv))
        c = empty if coef is None else np.ascontiguousarray(coef, dtype=float)
        x = empty if xadj is None else np.ascontiguousarray(xadj, dtype=float)
        if self.vals.shape[0]:
            fn = _run_parallel if T > 1 else _run_serial
            fn(self.vals, self.cs, self.tgt, self.src, c, x, nf, na, self.layout,
               *self.quarter, self.er, self.ec, self.dev, self.L, acc, bar)
        return acc.sum(axis=0), bar.sum(axis=0)

    def forward(self, coef: np.ndarray, acc: np.ndarray, parallel: bool = True) -> None:
        """``acc[i] += sum over pairs k with target i of block_k coef[src_k]``; ``coef``,
        ``acc`` are (M, nv)."""
        acc += self._apply(coef, None, acc.shape[0], parallel)[0]

    def transpose(self, x: np.ndarray, bar: np.ndarray, parallel: bool = True) -> None:
        """``bar[j] += sum over pairs k with source j of block_k^T x[tgt_k]``."""
        bar += self._apply(None, x, bar.shape[0], parallel)[1]

    def both(self, coef: np.ndarray, acc: np.ndarray, x: np.ndarray, bar: np.ndarray,
             parallel: bool = True) -> None:
        """:meth:`forward` and :meth:`transpose` in one pass over the pairs' data."""
        a, b = self._apply(coef, x, acc.shape[0], parallel)
        acc += a
        bar += b
