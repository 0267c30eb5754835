"""Importers of LCPs stored in other libraries' formats: Siconos numerics and FCLIB.

Siconos numerics ``.dat`` (text)
    The layout of ``linearComplementarity_printInFile`` / ``_newFromFile``
    (siconos ``numerics/src/LCP/LinearComplementarityProblem.c``): the size ``n``, then
    the matrix as written by ``NM_write_in_file`` (``numerics/src/linalg/NumericsMatrix.c``),
    then the ``n`` entries of ``q`` (siconos solves ``w = M z + q``, the sign convention of
    ``lcpbench.LCP(A, b)``). The matrix starts with its storage type and sizes::

        storage            0 dense | 1 sparse block (SBM) | 2 sparse (CSparse)
        size0 size1
        dense:  size0<TAB>size1, then size0*size1 values in column-major order
                (siconos' dense storage is Fortran order; a newline every size1 values)
        SBM:    nbblocks, blocknumber0, blocknumber1, cumulative row and column block
                sizes, filled1, filled2, row pointers index1, block columns index2, then
                for each block its number and its values in column-major order
        sparse: origin (1 triplet, 2 CSC, 3 CSR), then CSparse's text dump:
                a version line, "m-by-n, nzmax: .. nnz: ..", and either
                "col j : locations a to b" blocks of "i : value" lines (CSC; "row" for
                CSR) or "i j : value" lines (triplet)

    Text after ``q`` (siconos' test files carry remarks there) is ignored. The reader
    accepts all three storages; the "half triplet" origin (4) is refused, because
    siconos' own reader cannot read it back either. The writer
    :func:`write_siconos_lcp` writes dense storage exactly as siconos does (``%32.24e``,
    which round-trips float64), or CSC / triplet sparse storage with values in ``%.17g``
    (siconos writes sparse values with ``%g``, six digits, but its reader parses any
    precision: lcpbench keeps every bit).

FCLIB local problems (HDF5)
    ``/fclib_local`` of the Frictional Contact Library (``src/fclib.h``): ``spacedim``
    (2 or 3), ``W`` in fclib's matrix storage (datasets ``nzmax, m, n, nz, p, i, x``;
    ``nz >= 0`` triplet with ``i`` rows and ``p`` columns as in CSparse, ``nz == -1`` CSC,
    ``nz == -2`` CSR; fclib has no dense storage), ``vectors/q``, ``vectors/mu`` and an
    optional ``info`` group (``title``, ``description``, ``math_info`` strings). The
    frictionless LCP is the normal-contact block: contact k has local coordinates
    ``d*k .. d*k + d - 1`` with the normal first, so ``A = W[N, N]`` and ``b = q[N]`` with
    ``N = {d*k}``. Problems with equality constraints (``V``, ``R``) are refused:
    dropping the multipliers would change the problem.

Symmetry policy
    ``lcpbench.LCP`` is symmetric. A matrix whose asymmetry ``max|A - A'| / max|A|``
    exceeds :data:`lcpbench.core.lcp.SYMMETRY_RTOL` but not ``symmetrize_rtol`` is replaced by
    ``(A + A') / 2`` with a warning that states the asymmetry; above ``symmetrize_rtol``
    the reader raises ``ValueError``. Defaults: 0 for Siconos (its collection holds
    genuinely non-symmetric LCPs: symmetrising them would change the problem), 1e-6 for
    FCLIB (W = H' M^-1 H is symmetric in exact arithmetic; exported W carry round-off).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import h5py
import numpy as np
import scipy.sparse as sp

from lcpbench import LCP, register_problem
from lcpbench.core.lcp import SYMMETRY_RTOL

__all__ = ["read_siconos_lcp", "write_siconos_lcp", "read_fclib_local", "write_fclib_local",
           "SiconosFormatError", "SICONOS_STORAGES", "FCLIB_DEFAULT_SYMMETRIZE_RTOL"]

PathLike = Union[str, Path]

#: Storage names accepted by :func:`write_siconos_lcp`.
SICONOS_STORAGES = ("dense", "csc", "triplet")
#: Default ``symmetrize_rtol`` of :func:`read_fclib_local`.
FCLIB_DEFAULT_SYMMETRIZE_RTOL = 1e-6

_NM_DENSE, _NM_SPARSE_BLOCK, _NM_SPARSE = 0, 1, 2
_NSM_TRIPLET, _NSM_CSC, _NSM_CSR, _NSM_HALF_TRIPLET = 1, 2, 3, 4


class SiconosFormatError(ValueError):
    """A Siconos ``.dat`` file does not follow the numerics format."""


# ---------------------------------------------------------------------- symmetry
def _symmetric(A, what: str, symmetrize_rtol: float):
    """Return ``A`` or its symmetric part, following the module's symmetry policy."""
    dense = A.toarray() if sp.issparse(A) else A
    if dense.size == 0:
        return A
    scale = float(np.max(np.abs(dense)))
    asym = float(np.max(np.abs(dense - dense.T)))
    rel = asym / scale if scale > 0 else 0.0
    if rel <= SYMMETRY_RTOL:
        return A
    if rel > symmetrize_rtol:
        raise ValueError(
            f"{what}: the matrix is not symmetric (max|A-A'| = {asym:.3g}, {rel:.3g} relative "
            f"to max|A|), but lcpbench solves symmetric LCPs. Pass symmetrize_rtol >= "
            f"{rel:.2g} to replace it by (A + A')/2 if the asymmetry is round-off")
    warnings.warn(f"{what}: symmetrised the matrix (max|A-A'| = {asym:.3g}, {rel:.3g} relative "
                  f"to max|A|, within symmetrize_rtol = {symmetrize_rtol:g})", RuntimeWarning,
                  stacklevel=4)
    return (A + A.T) / 2


def _build(A, b, path: Path, what: str, symmetrize_rtol: float, **kw) -> LCP:
    A = _symmetric(A, f"{path}: {what}", symmetrize_rtol)
    try:
        return LCP(A, b, **kw)
    except (ValueError, TypeError) as exc:
        raise type(exc)(f"{path}: {what} is not a valid lcpbench LCP: {exc}") from None


# ---------------------------------------------------------------------- siconos
class _Cursor:
    """Whitespace tokens and whole lines of a text file, as fscanf and fgets see them."""

    def __init__(self, text: str, path: Path):
        self.lines = text.splitlines()
        self.path = path
        self.line = 0
        self.toks: list[str] = self.lines[0].split() if self.lines else []
        self.tok = 0

    def fail(self, msg: str) -> SiconosFormatError:
        return SiconosFormatError(f"{self.path}, line {self.line + 1}: {msg}. The file does not "
                                  "follow the Siconos numerics LCP format (size, matrix as "
                                  "NM_write_in_file writes it, then q)")

    def _advance_line(self) -> bool:
        self.line += 1
        if self.line >= len(self.lines):
            self.toks, self.tok = [], 0
            return False
        self.toks, self.tok = self.lines[self.line].split(), 0
        return True

    def token(self, what: str) -> str:
        while self.tok >= len(self.toks):
            if not self._advance_line():
                raise self.fail(f"the file ends where {what} was expected (truncated?)")
        t = self.toks[self.tok]
        self.tok += 1
        return t

    def int(self, what: str) -> int:
        t = self.token(what)
        try:
            return int(t)
        except ValueError:
            raise self.fail(f"expected an integer for {what}, found {t!r}") from None

    def float(self, what: str) -> float:
        t = self.token(what)
        try:
            return float(t)
        except ValueError:
            raise self.fail(f"expected a number for {what}, found {t!r}") from None

    def next_line(self, what: str) -> str:
        """The rest of the current line is skipped; return the next whole line."""
        if not self._advance_line():
            raise self.fail(f"the file ends where {what} was expected (truncated?)")
        self.tok = len(self.toks)          # consumed as a whole
        return self.lines[self.line]


def _read_dense(c: _Cursor, size0: int, size1: int) -> np.ndarray:
    r0, r1 = c.int("the dense row count"), c.int("the dense column count")
    if (r0, r1) != (size0, size1):
        raise c.fail(f"dense sizes {r0}x{r1} disagree with the header {size0}x{size1}")
    vals = np.array([c.float(f"dense entry {k}") for k in range(size0 * size1)])
    return vals.reshape((size1, size0)).T.copy()          # column-major storage


def _read_sbm(c: _Cursor, size0: int, size1: int) -> np.ndarray:
    nbblocks = c.int("the number of blocks")
    M = np.zeros((size0, size1))
    if nbblocks == 0:
        return M
    bn0, bn1 = c.int("blocknumber0"), c.int("blocknumber1")
    rows = [c.int(f"blocksize0[{k}]") for k in range(bn0)]
    cols = [c.int(f"blocksize1[{k}]") for k in range(bn1)]
    if (rows and rows[-1] != size0) or (cols and cols[-1] != size1):
        raise c.fail(f"cumulative block sizes end at {rows[-1:]}x{cols[-1:]}, not at the "
                     f"matrix size {size0}x{size1}")
    filled1, filled2 = c.int("filled1"), c.int("filled2")
    index1 = [c.int(f"index1_data[{k}]") for k in range(filled1)]
    index2 = [c.int(f"index2_data[{k}]") for k in range(filled2)]
    if filled1 != bn0 + 1 or index1[-1] != filled2 or filled2 != nbblocks:
        raise c.fail(f"inconsistent block structure (filled1 {filled1}, blocknumber0 {bn0}, "
                     f"filled2 {filled2}, nbblocks {nbblocks})")
    for r in range(filled1 - 1):
        r_lo = rows[r - 1] if r else 0
        for blk in range(index1[r], index1[r + 1]):
            col = index2[blk]
            if not 0 <= col < bn1:
                raise c.fail(f"block {blk} has column block {col}, outside 0..{bn1 - 1}")
            c_lo = cols[col - 1] if col else 0
            nr, nc = rows[r] - r_lo, cols[col] - c_lo
            num = c.int(f"the number of block {blk}")
            if num != blk:
                raise c.fail(f"block numbering: found block {num} where block {blk} belongs")
            vals = np.array([c.float(f"entry {k} of block {blk}") for k in range(nr * nc)])
            M[r_lo:r_lo + nr, c_lo:c_lo + nc] = vals.reshape((nc, nr)).T
    return M


def _parse_dims(c: _Cursor, line: str) -> tuple[int, int, int, bool, bool]:
    toks = line.split()
    triplet = bool(toks) and toks[0] == "triplet:"
    csr = bool(toks) and toks[0] == "csr:"
    shift = int(triplet or csr)
    try:
        m_s, _, n_s = toks[shift].rstrip(",").partition("-by-")
        m, n = int(m_s), int(n_s)
        nnz = int(toks[shift + 4].rstrip(",")) if len(toks) > shift + 4 else -1
    except (IndexError, ValueError):
        raise c.fail(f"cannot read the CSparse size line {line.strip()!r} "
                     "(expected 'm-by-n, nzmax: .. nnz: ..')") from None
    return m, n, nnz, triplet, csr


def _read_compressed(c: _Cursor, m: int, n: int, csr: bool) -> sp.spmatrix:
    word = "row" if csr else "col"
    outer = m if csr else n
    ptr = [0]
    idx: list[int] = []
    val: list[float] = []
    for j in range(outer):
        head = c.next_line(f"the header of {word} {j}").split()
        try:
            if head[0] != word or int(head[1]) != j:
                raise ValueError
            lo, hi = int(head[4]), int(head[6])
        except (IndexError, ValueError):
            raise c.fail(f"expected '{word} {j} : locations a to b', found "
                         f"{' '.join(head)!r}") from None
        if lo != ptr[-1]:
            raise c.fail(f"{word} {j} starts at location {lo}, expected {ptr[-1]}")
        for p in range(lo, hi + 1):
            ent = c.next_line(f"entry {p}").split()
            try:
                idx.append(int(ent[0]))
                val.append(float(ent[2]))
            except (IndexError, ValueError):
                raise c.fail(f"expected 'index : value' for entry {p}, found "
                             f"{' '.join(ent)!r}") from None
        ptr.append(hi + 1)
    cls = sp.csr_matrix if csr else sp.csc_matrix
    try:
        return cls((np.array(val, dtype=float), np.array(idx, dtype=np.int64),
                    np.array(ptr, dtype=np.int64)), shape=(m, n))
    except ValueError as exc:
        raise c.fail(f"invalid sparse structure ({exc})") from None


def _read_sparse(c: _Cursor, size0: int, size1: int) -> np.ndarray:
    origin = c.int("the sparse origin (1 triplet, 2 CSC, 3 CSR)")
    if origin == _NSM_HALF_TRIPLET:
        raise c.fail("sparse origin 4 (half triplet: the lower half of a symmetric matrix) is "
                     "not supported; siconos' own reader cannot read it back either. Write "
                     "the matrix in dense, CSC, CSR or full triplet storage")
    if origin not in (_NSM_TRIPLET, _NSM_CSC, _NSM_CSR):
        raise c.fail(f"unknown sparse origin {origin} (expected 1 triplet, 2 CSC, 3 CSR)")
    # fscanf leaves the end of the origin line; siconos' reader then takes the CSparse
    # version line and the size line with fgets.
    line = c.next_line("the CSparse version line")
    while "-by-" not in line:
        line = c.next_line("the CSparse size line 'm-by-n, ...'")
    m, n, nnz, triplet, csr = _parse_dims(c, line)
    if (m, n) != (size0, size1):
        raise c.fail(f"CSparse size {m}x{n} disagrees with the header {size0}x{size1}")
    if triplet:
        rows, cols, vals = [], [], []
        for p in range(nnz):
            ent = c.next_line(f"triplet entry {p}").replace(":", " ").split()
            try:
                rows.append(int(ent[0]))
                cols.append(int(ent[1]))
                vals.append(float(ent[2]))
            except (IndexError, ValueError):
                raise c.fail(f"expected 'i j : value' for triplet entry {p}, found "
                             f"{' '.join(ent)!r}") from None
        try:
            M = sp.coo_matrix((vals, (rows, cols)), shape=(m, n))
        except ValueError as exc:
            raise c.fail(f"invalid triplet entries ({exc})") from None
    else:
        M = _read_compressed(c, m, n, csr)
    return M.toarray()


def read_siconos_lcp(path: PathLike, *, symmetrize_rtol: float = 0.0,
                     psd_check: bool = True) -> LCP:
    """Read an LCP written by Siconos numerics (``linearComplementarity_printInFile``).

    Parameters
    ----------
    path : str or Path
        The ``.dat`` file.
    symmetrize_rtol : float
        Largest relative asymmetry replaced by the symmetric part (with a warning);
        default 0: a non-symmetric matrix raises (module docstring).
    psd_check : bool
        Passed to :class:`~lcpbench.LCP`.

    Returns
    -------
    LCP
        ``A = M`` (dense), ``b = q``; ``meta`` has ``family="siconos"``, ``storage`` and
        ``source``.

    Raises
    ------
    SiconosFormatError
        Naming the line and the item that does not follow the format.
    ValueError
        If the matrix is not symmetric (beyond ``symmetrize_rtol``) or not PSD.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise SiconosFormatError(f"{p}: cannot read the file as text ({exc})") from None
    c = _Cursor(text, p)
    n = c.int("the problem size n")
    storage = c.int("the storage type (0 dense, 1 sparse block, 2 sparse)")
    size0, size1 = c.int("size0 (rows)"), c.int("size1 (columns)")
    if size0 != size1 or size0 != n:
        raise c.fail(f"the matrix is {size0}x{size1} but the problem size is {n}; an LCP needs "
                     "an n x n matrix")
    if n < 0:
        raise c.fail(f"negative size {n}")
    readers = {_NM_DENSE: ("dense", _read_dense), _NM_SPARSE_BLOCK: ("sparse-block", _read_sbm),
               _NM_SPARSE: ("sparse", _read_sparse)}
    if storage not in readers:
        raise c.fail(f"unknown storage type {storage} (0 dense, 1 sparse block, 2 sparse)")
    name, reader = readers[storage]
    M = reader(c, size0, size1)
    q = np.array([c.float(f"q[{i}]") for i in range(size1)])
    return _build(M, q, p, "Siconos LCP", symmetrize_rtol, name=f"siconos/{p.stem}",
                  meta={"family": "siconos", "n": n, "storage": name, "source": str(p)},
                  psd_check=psd_check)


def write_siconos_lcp(path: PathLike, A, b, *, storage: str = "dense") -> Path:
    """Write ``0 <= z _|_ A z + b >= 0`` in the Siconos numerics LCP text format.

    Parameters
    ----------
    path : str or Path
    A : (n, n) array_like or sparse matrix
    b : (n,) array_like
    storage : {"dense", "csc", "triplet"}
        Dense storage is written exactly as siconos writes it; sparse storages follow
        CSparse's dump with exact (``%.17g``) values.

    Returns
    -------
    Path
    """
    if storage not in SICONOS_STORAGES:
        raise ValueError(f"storage {storage!r}: choose one of {', '.join(SICONOS_STORAGES)}")
    M = A.toarray() if sp.issparse(A) else np.asarray(A, dtype=np.float64)
    q = np.asarray(b, dtype=np.float64).reshape(-1)
    if M.ndim != 2 or M.shape[0] != M.shape[1] or M.shape[0] != q.shape[0]:
        raise ValueError(f"A of shape {M.shape} and b of length {q.shape[0]} do not make an "
                         "LCP; A must be (n, n) and b (n,)")
    if not (np.all(np.isfinite(M)) and np.all(np.isfinite(q))):
        raise ValueError("A and b must be finite to be written")
    n = M.shape[0]
    out = [f"{n}\n"]
    if storage == "dense":
        out.append(f"{_NM_DENSE}\n{n}\n{n}\n{n}\t{n}\n")
        flat = M.T.reshape(-1)                          # column-major, as siconos stores it
        for i, v in enumerate(flat):
            out.append(f"{v:32.24e} ")
            if (i + 1) % n == 0:
                out.append("\n")
    else:
        C = sp.csc_matrix(M) if storage == "csc" else sp.coo_matrix(M)
        origin = _NSM_CSC if storage == "csc" else _NSM_TRIPLET
        nnz = int(C.nnz)
        out.append(f"{_NM_SPARSE}\n{n}\n{n}\n{origin}\n")
        out.append("CSparse Version 3.2.0, lcpbench export.  Values in %.17g\n")
        if storage == "csc":
            norm1 = float(abs(C).sum(axis=0).max()) if nnz else 0.0
            out.append(f"{n}-by-{n}, nzmax: {nnz} nnz: {nnz}, 1-norm: {norm1:g}\n")
            for j in range(n):
                lo, hi = int(C.indptr[j]), int(C.indptr[j + 1])
                out.append(f"    col {j} : locations {lo} to {hi - 1}\n")
                for p_ in range(lo, hi):
                    out.append(f"      {int(C.indices[p_])} : {C.data[p_]:.17g}\n")
        else:
            out.append(f"triplet: {n}-by-{n}, nzmax: {nnz} nnz: {nnz}\n")
            for i, j, v in zip(C.row, C.col, C.data):
                out.append(f"    {int(i)} {int(j)} : {v:.17g}\n")
    out.extend(f"{v:32.24e} " for v in q)
    p = Path(path)
    p.write_text("".join(out))
    return p


# ---------------------------------------------------------------------- fclib
def _h5_scalar_int(g: h5py.Group, key: str, where: str) -> int:
    if key not in g:
        raise ValueError(f"{where}: dataset {key!r} is missing")
    return int(np.asarray(g[key][()]).reshape(-1)[0])


def _read_fclib_matrix(g: h5py.Group, where: str) -> sp.spmatrix:
    nzmax = _h5_scalar_int(g, "nzmax", where)
    m, n, nz = (_h5_scalar_int(g, k, where) for k in ("m", "n", "nz"))
    for key in ("p", "i", "x"):
        if key not in g:
            raise ValueError(f"{where}: dataset {key!r} is missing")
    P = np.asarray(g["p"][()], dtype=np.int64).reshape(-1)
    I = np.asarray(g["i"][()], dtype=np.int64).reshape(-1)
    X = np.asarray(g["x"][()], dtype=np.float64).reshape(-1)
    try:
        if nz >= 0:                     # triplet: i rows, p columns (CSparse convention)
            return sp.coo_matrix((X[:nz], (I[:nz], P[:nz])), shape=(m, n)).tocsr()
        if nz == -1:                    # compressed columns
            k = int(P[n])
            return sp.csc_matrix((X[:k], I[:k], P[:n + 1]), shape=(m, n)).tocsr()
        if nz == -2:                    # compressed rows
            k = int(P[m])
            return sp.csr_matrix((X[:k], I[:k], P[:m + 1]), shape=(m, n))
    except (ValueError, IndexError) as exc:
        raise ValueError(f"{where}: inconsistent sparse storage (nzmax {nzmax}, nz {nz}, "
                         f"m {m}, n {n}): {exc}") from None
    raise ValueError(f"{where}: unknown fclib storage nz = {nz} (>= 0 triplet, -1 CSC, -2 CSR)")


def _h5_string(g: h5py.Group, key: str) -> Optional[str]:
    if key not in g:
        return None
    v = g[key][()]
    if isinstance(v, np.ndarray):
        v = v.reshape(-1)[0] if v.size else b""
    return (v.decode(errors="replace") if isinstance(v, bytes) else str(v)).strip("\x00")


def read_fclib_local(path: PathLike, *,
                     symmetrize_rtol: float = FCLIB_DEFAULT_SYMMETRIZE_RTOL,
                     psd_check: bool = True) -> LCP:
    """The normal-contact LCP of an FCLIB local problem (``/fclib_local``).

    Parameters
    ----------
    path : str or Path
        The ``.hdf5`` file.
    symmetrize_rtol : float
        Largest relative asymmetry of ``W_nn`` that is symmetrised (with a warning);
        above it ``ValueError`` (default 1e-6, module docstring).
    psd_check : bool
        Passed to :class:`~lcpbench.LCP`.

    Returns
    -------
    LCP
        ``A = W[N, N]``, ``b = q[N]`` with ``N = {spacedim * k}`` (the normal of each
        contact); ``meta`` has ``family="fclib"``, ``spacedim``, ``contacts``, ``mu_min``,
        ``mu_max``, ``title``, ``description``, ``math_info`` and ``source``.

    Raises
    ------
    ValueError
        For a file that is not an FCLIB local problem, a missing dataset, or a problem
        with equality constraints (``V``, ``R``).
    """
    p = Path(path)
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise ValueError(f"{p}: cannot open as HDF5 ({exc}); is it an FCLIB file?") from None
    with f:
        if "fclib_local" not in f:
            kind = ("a global problem (/fclib_global)" if "fclib_global" in f
                    else f"groups {sorted(f.keys())}")
            raise ValueError(f"{p}: not an FCLIB local problem (no /fclib_local; found {kind})")
        g = f["fclib_local"]
        where = f"{p}: /fclib_local"
        if "V" in g or "R" in g:
            raise ValueError(f"{where} has equality constraints (V, R); its normal block is "
                             "not a plain LCP, so lcpbench does not import it")
        d = _h5_scalar_int(g, "spacedim", where)
        if d not in (2, 3):
            raise ValueError(f"{where}/spacedim is {d}; FCLIB uses 2 or 3")
        if "W" not in g:
            raise ValueError(f"{where}/W is missing")
        W = _read_fclib_matrix(g["W"], f"{where}/W")
        if W.shape[0] != W.shape[1] or W.shape[0] % d:
            raise ValueError(f"{where}/W has shape {W.shape}; it must be square with a size "
                             f"divisible by spacedim = {d}")
        vec = g.get("vectors")
        if vec is None or "q" not in vec or "mu" not in vec:
            raise ValueError(f"{where}/vectors must hold q and mu")
        q = np.asarray(vec["q"][()], dtype=np.float64).reshape(-1)
        mu = np.asarray(vec["mu"][()], dtype=np.float64).reshape(-1)
        nc = W.shape[0] // d
        if q.shape[0] != W.shape[0] or mu.shape[0] != nc:
            raise ValueError(f"{where}/vectors: q has {q.shape[0]} entries and mu {mu.shape[0]}; "
                             f"expected {W.shape[0]} and {nc}")
        info = g.get("info")
        texts = {k: (_h5_string(info, k) if info is not None else None)
                 for k in ("title", "description", "math_info")}
    N = np.arange(nc) * d
    Wnn = W[N][:, N]
    A = Wnn.toarray() if nc <= 2000 else Wnn.tocsr()
    meta = {"family": "fclib", "n": nc, "contacts": nc, "spacedim": d,
            "mu_min": float(mu.min()) if nc else 0.0, "mu_max": float(mu.max()) if nc else 0.0,
            "source": str(p), **{k: v for k, v in texts.items() if v is not None}}
    return _build(A, q[N], p, "FCLIB normal block W_nn", symmetrize_rtol,
                  name=f"fclib/{p.stem}", meta=meta, psd_check=psd_check)


def write_fclib_local(path: PathLike, W, q, mu, d: int, *, title: Optional[str] = None,
                      description: Optional[str] = None, math_info: Optional[str] = None,
                      storage: str = "csc") -> Path:
    """Write an FCLIB local problem (``/fclib_local``) as ``fclib_write_local`` lays it out.

    Parameters
    ----------
    path : str or Path
        Created if missing; an existing file must not hold ``/fclib_local`` yet.
    W : (m, m) array_like or sparse matrix
        The Delassus matrix, contact-major with the normal first in each contact.
    q : (m,) array_like
    mu : (m / d,) array_like
        Friction coefficients per contact.
    d : int
        Space dimension, 2 or 3.
    title, description, math_info : str, optional
        Written to ``/fclib_local/info`` when any is given.
    storage : {"csc", "csr", "triplet"}
        fclib matrix storage (``nz`` = -1, -2 or the number of entries).

    Returns
    -------
    Path
    """
    if d not in (2, 3):
        raise ValueError(f"d (spacedim) must be 2 or 3, got {d}")
    if storage not in ("csc", "csr", "triplet"):
        raise ValueError(f"storage {storage!r}: choose csc, csr or triplet")
    Ws = sp.csc_matrix(W, dtype=np.float64) if storage == "csc" else (
        sp.csr_matrix(W, dtype=np.float64) if storage == "csr" else
        sp.coo_matrix(W, dtype=np.float64))
    m, n = Ws.shape
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    mu = np.asarray(mu, dtype=np.float64).reshape(-1)
    if m != n or m % d:
        raise ValueError(f"W has shape {Ws.shape}; it must be square with a size divisible by "
                         f"d = {d}")
    if q.shape[0] != m or mu.shape[0] != m // d:
        raise ValueError(f"q has {q.shape[0]} entries and mu {mu.shape[0]}; expected {m} and "
                         f"{m // d}")
    p = Path(path)
    with h5py.File(p, "a") as f:
        if "fclib_local" in f:
            raise ValueError(f"{p}: a local problem has already been written to this file; "
                             "choose another path")
        g = f.create_group("fclib_local")
        def one(v: int) -> np.ndarray:          # H5LTmake_dataset_int with dims {1}
            return np.array([v], dtype=np.int32)

        g.create_dataset("spacedim", data=one(d))
        gw = g.create_group("W")
        if storage == "triplet":
            nnz = int(Ws.nnz)
            P, I, X, nz = Ws.col, Ws.row, Ws.data, nnz
        else:
            nnz = int(Ws.indptr[-1])
            P, I, X, nz = Ws.indptr, Ws.indices, Ws.data, (-1 if storage == "csc" else -2)
        for key, val in (("nzmax", nnz), ("m", m), ("n", n), ("nz", nz)):
            gw.create_dataset(key, data=one(val))
        gw.create_dataset("p", data=np.asarray(P, dtype=np.int32))
        gw.create_dataset("i", data=np.asarray(I, dtype=np.int32))
        gw.create_dataset("x", data=np.asarray(X, dtype=np.float64))
        gv = g.create_group("vectors")
        gv.create_dataset("q", data=q)
        gv.create_dataset("mu", data=mu)
        texts = {"title": title, "description": description, "math_info": math_info}
        if any(v is not None for v in texts.values()):
            gi = g.create_group("info")
            for key, val in texts.items():
                if val is not None:
                    raw = str(val).encode()
                    gi.create_dataset(key, data=np.array(raw, dtype=f"S{len(raw) + 1}"))
    return p


# ---------------------------------------------------------------------- plugins
def _files(path: str, patterns: tuple[str, ...], kind: str) -> list[Path]:
    p = Path(path)
    if p.is_dir():
        found = sorted({q for pat in patterns for q in p.glob(pat)})
        if not found:
            raise FileNotFoundError(f"{p}: no {kind} files ({', '.join(patterns)}) in the folder")
        return found
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such {kind} file or folder")
    return [p]


@dataclass(frozen=True)
class SiconosParams:
    """Parameters of siconos.

    Parameters
    ----------
    path : str
        A Siconos numerics LCP ``.dat`` file, or a folder of them (``*.dat``, sorted).
    symmetrize_rtol : float
        Largest relative asymmetry replaced by (A + A')/2 with a warning (default 0:
        non-symmetric files raise).
    """

    path: str = ""
    symmetrize_rtol: float = 0.0

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("path is required: siconos:path=FILE.dat (or a folder)")
        if not (self.symmetrize_rtol >= 0):
            raise ValueError(f"symmetrize_rtol must be >= 0, got {self.symmetrize_rtol}")


@register_problem("siconos", SiconosParams)
def siconos(p: SiconosParams) -> list[LCP]:
    """LCPs in the Siconos numerics text format (dense, sparse-block or CSparse storage)."""
    return [read_siconos_lcp(f, symmetrize_rtol=p.symmetrize_rtol)
            for f in _files(p.path, ("*.dat",), "Siconos .dat")]


@dataclass(frozen=True)
class FclibParams:
    """Parameters of fclib.

    Parameters
    ----------
    path : str
        An FCLIB local problem (``.hdf5``/``.h5``), or a folder of them (sorted).
    symmetrize_rtol : float
        Largest relative asymmetry of W_nn replaced by its symmetric part with a warning
        (default 1e-6); larger asymmetry raises.
    """

    path: str = ""
    symmetrize_rtol: float = FCLIB_DEFAULT_SYMMETRIZE_RTOL

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("path is required: fclib:path=FILE.hdf5 (or a folder)")
        if not (self.symmetrize_rtol >= 0):
            raise ValueError(f"symmetrize_rtol must be >= 0, got {self.symmetrize_rtol}")


@register_problem("fclib", FclibParams)
def fclib(p: FclibParams) -> list[LCP]:
    """Normal-contact LCPs of FCLIB local frictional-contact problems (HDF5)."""
    return [read_fclib_local(f, symmetrize_rtol=p.symmetrize_rtol)
            for f in _files(p.path, ("*.hdf5", "*.h5"), "FCLIB")]
