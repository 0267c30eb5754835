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
from functools import cached_property

import numpy as np
from numba import get_num_threads, njit, prange

from .coaxial import CoaxialTable, order_mask
from .jit import parallel_and_serial
from .panel_kernels import LANES as _PANEL_LANES
from .panel_kernels import WIDTH, gather_turned, rows_lanes, rows_scalar, rows_turned, vectorising
from .rotation import degree_slices, wigner_quarter

__all__ = ["LANES", "ZERO_TOL", "PairFrame", "coaxial_support"]

LANES = _PANEL_LANES
"""Items (a pair and its reverse, or a pair alone) per chunk: a chunk is one panel of the
kernel (:mod:`.panel_kernels`), its two directions side by side."""

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

@njit(cache=True, fastmath=True, boundscheck=False, error_model="numpy")
def _scatter(Y, k, out):
    """``out[k[j], r] += Y[r, j]``: the panel's columns added to rows of ``out`` (column
    by column: each output row is read and written once per column, in order)."""
    for j in range(WIDTH):
        o = out[k[j]]
        for r in range(Y.shape[0]):
            o[r] += Y[r, j]


@njit(cache=True, fastmath=True, boundscheck=False, error_model="numpy")
def _panel(vals, cs, rows, kin, out, kout, adjoint, q, z, e, X, Y):
    """One panel: ``D E D^T`` (``adjoint`` false) or ``D E^T D^T`` (true) of the columns
    gathered from ``rows[kin]``, added to ``out[kout]``.  ``q`` holds the quarter turn
    ``P`` and ``P^T`` as row lists over every coefficient, ``z`` the (cos, sin) row pairs of
    the turns about z and the rows of order 0, ``e`` the coaxial entries by row (``E``)
    and by column (``E^T``).  Each turn about z is applied as the rows it turns are
    written (:mod:`.panel_kernels`)."""
    qrp, qci, qcv, trp, tci, tcv = q
    zi, zj, zm, ones = z
    frp, fci, fwi, arp, aci, awi = e
    m1 = cs.shape[1]
    cphi, sphi = cs[0].reshape((m1, WIDTH)), cs[1].reshape((m1, WIDTH))
    cth, sth = cs[2].reshape((m1, WIDTH)), cs[3].reshape((m1, WIDTH))
    # into the pair frame: D^T = P Rz(-theta) P^T Rz(-phi)
    gather_turned(rows, kin, zi, zj, zm, ones, cphi, sphi, -1.0, X)
    rows_turned(trp, tci, tcv, zi, zj, zm, ones, cth, sth, -1.0, X, Y)
    rows_scalar(qrp, qci, qcv, Y, X)
    if adjoint:                                          # the coaxial block
        rows_lanes(arp, aci, awi, vals, X, Y)
    else:
        rows_lanes(frp, fci, fwi, vals, X, Y)
    # back to the lab frame: D = Rz(phi) P Rz(theta) P^T
    rows_turned(trp, tci, tcv, zi, zj, zm, ones, cth, sth, 1.0, Y, X)
    rows_turned(qrp, qci, qcv, zi, zj, zm, ones, cphi, sphi, 1.0, X, Y)
    _scatter(Y, kout, out)


def _run(vals, cs, src, tgt, coef, xadj, forward, adjoint, q, z, e, acc, bar):
    """Every chunk, the threads each taking a contiguous share and summing into their own
    copy ``acc[t]`` / ``bar[t]``; ``src``, ``tgt`` (C, WIDTH) the panels' sphere rows
    (an empty slot: the zero row past the last sphere)."""
    T = acc.shape[0] if forward else bar.shape[0]
    C = vals.shape[0]
    nv = acc.shape[2] if forward else bar.shape[2]
    for t in prange(T):
        X = np.empty((nv, WIDTH))
        Y = np.empty((nv, WIDTH))
        for c in range(t * C // T, (t + 1) * C // T):
            if forward:
                _panel(vals[c], cs[c], coef, src[c], acc[t], tgt[c], False, q, z, e, X, Y)
            if adjoint:
                _panel(vals[c], cs[c], xadj, tgt[c], bar[t], src[c], True, q, z, e, X, Y)


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


def _panel_order(layout: np.ndarray) -> np.ndarray:
    """The order of the coefficients in a panel (panel row i holds coefficient
    ``order[i]``): by order m, then cosine before sine, then kind and degree, so that the
    rows the coaxial block couples (equal order and type) lie together and one order's
    rows stay in the first-level cache while its entries are summed."""
    key = []
    for n in range(layout.shape[0]):
        lo, kinds = (int(v) for v in layout[n])
        w = 2 * n + 1
        for t in range(kinds):
            for i in range(w):
                m, sine = (i + 1) // 2, int(i > 0 and i % 2 == 0)
                key.append((m, sine, t, n, lo + t * w + i))
    key.sort()
    return np.array([k[-1] for k in key], dtype=np.int64)


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
        inv = np.argsort(_panel_order(_layout(p)))      # coefficient -> panel row
        by_row = np.lexsort((inv[cols[keep]], inv[rows[keep]]))
        vals = np.zeros((C * LANES, keep.size))
        if items.shape[0]:
            vals[:items.shape[0]] = table.values(rho[items[:, 0]], columns=keep)[:, by_row]
        keep = keep[by_row]
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

    @cached_property
    def _structure(self) -> tuple:
        """The kernel's fixed arrays (every index unsigned, rows in the panel's order
        :func:`_panel_order`, which comes first): the quarter turn ``P`` and
        ``P^T`` as row lists over the ``nv`` coefficients, the row pairs of the turns
        about z, the coaxial entries by row and by column, the output map's rows."""
        nv = self.nv
        order = _panel_order(self.layout)
        inv = np.argsort(order)
        qptr, qa, qb, qv = self.quarter
        P = np.zeros((nv, nv))
        zi, zj, zm = [], [], []
        for n in range(self.layout.shape[0]):
            lo, kinds = (int(v) for v in self.layout[n])
            w = 2 * n + 1
            sl = slice(qptr[n], qptr[n + 1])
            for t in range(kinds):
                base = lo + t * w
                P[base + qa[sl], base + qb[sl]] = qv[sl]
                for m in range(1, n + 1):
                    zi.append(base + 2 * m - 1)
                    zj.append(base + 2 * m)
                    zm.append(m)
        u8 = np.uint64

        def by_rows(rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, ...]:
            order = np.lexsort((cols, rows))
            ptr = np.searchsorted(rows[order], np.arange(nv + 1))
            return ptr.astype(u8), cols[order].astype(u8), order.astype(u8)

        pa, pb = np.nonzero(P)
        pv = P[pa, pb]
        qrp, qci, qo = by_rows(inv[pa], inv[pb])
        trp, tci, to = by_rows(inv[pb], inv[pa])
        return (order,
                (qrp, qci, pv[qo.astype(np.int64)], trp, tci, pv[to.astype(np.int64)]),
                (inv[zi].astype(u8), inv[zj].astype(u8), np.array(zm, u8),
                 np.setdiff1d(np.arange(nv), inv[zi + zj]).astype(u8)),
                by_rows(inv[self.er], inv[self.ec]) + by_rows(inv[self.ec], inv[self.er]))

    def _apply(self, coef: np.ndarray | None, xadj: np.ndarray | None, M: int,
               parallel: bool) -> tuple[np.ndarray, np.ndarray]:
        T = get_num_threads() if parallel else 1
        T = max(1, min(T, self.vals.shape[0]))
        nv = self.nv
        C = self.vals.shape[0]
        fwd, adj = coef is not None, xadj is not None
        acc = np.zeros((T, M + 1, nv) if fwd else (1, 1, nv))
        bar = np.zeros((T, M + 1, nv) if adj else (1, 1, nv))

        order, q, z, e = self._structure
        dev, left = self.dev, self.L

        def rows(a: np.ndarray | None, transpose: bool) -> np.ndarray:
            out = np.zeros((M + 1 if a is not None else 1, nv))
            if a is not None:
                if transpose and dev.size:               # L^T on every sphere's row
                    a = a.copy()
                    held = a[:, dev].copy()
                    a[:, dev] = 0.0
                    a += held @ left
                out[:M] = a[:, order]
            return out

        def slots(k: np.ndarray) -> np.ndarray:
            return np.where(k < 0, M, k).reshape(C, WIDTH).astype(np.uint64)

        if C:
            fn = _run_parallel if T > 1 else _run_serial
            with vectorising():
                fn(self.vals, self.cs, slots(self.src), slots(self.tgt), rows(coef, False),
                   rows(xadj, True), fwd, adj, q, z, e, acc, bar)
        back = np.empty(nv, dtype=np.int64)
        back[order] = np.arange(nv)
        out = acc[:, :M].sum(axis=0)[:, back]
        if fwd and dev.size:                             # L on every sphere's row
            out[:, dev] = out @ left.T
        return out, bar[:, :M].sum(axis=0)[:, back]

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
