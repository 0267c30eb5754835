"""The Siconos numerics LCP text format (``.dat``): reader and writer.

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

Non-symmetric matrices follow the symmetry policy of :mod:`lcpbench.problems.formats`
(default here: refuse, since siconos' collection holds genuinely non-symmetric LCPs).

MLCP files. Siconos' mixed LCPs (``mixedLinearComplementarity_printInFile``: two
storage flags, ``n`` equality and ``m`` complementarity rows, the block rows, then
the matrix; or the older ``n m NbLines`` layout) sit beside the LCPs in its test data
and can start like a small LCP. A file is read as an LCP only when no line of numbers
follows ``q`` (a remark may start with one); otherwise, when it has an MLCP's layout it is refused as an MLCP
(:class:`~lcpbench.problems.formats.UnsupportedProblem`, naming the file), and a
file with numbers after ``q`` that is no MLCP is refused as malformed.
"""

from __future__ import annotations

import builtins
from pathlib import Path
from typing import Optional

import numpy as np
import scipy.sparse as sp

from lcpbench import LCP
from lcpbench.sets import human_bytes, read_budget

from .formats import PathLike, UnsupportedProblem, symmetric_lcp

__all__ = ["read_siconos_lcp", "write_siconos_lcp", "SiconosFormatError", "SICONOS_STORAGES"]

#: Storage names accepted by :func:`write_siconos_lcp`.
SICONOS_STORAGES = ("dense", "csc", "triplet")

_NM_DENSE, _NM_SPARSE_BLOCK, _NM_SPARSE = 0, 1, 2
_NSM_TRIPLET, _NSM_CSC, _NSM_CSR, _NSM_HALF_TRIPLET = 1, 2, 3, 4


class SiconosFormatError(ValueError):
    """A Siconos ``.dat`` file does not follow the numerics format."""


class _Cursor:
    """Whitespace tokens and whole lines of a text file, as fscanf and fgets see them."""

    def __init__(self, text: str, path: Path):
        self.lines = text.splitlines()
        self.path = path
        self.line = 0
        self.toks: list[str] = self.lines[0].split() if self.lines else []
        self.tok = 0

    def fail(self, msg: str, line: Optional[int] = None) -> SiconosFormatError:
        line = self.line if line is None else line
        return SiconosFormatError(f"{self.path}, line {line + 1}: {msg}. The file does not "
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

    def _number(self, what: str, convert, kind: str):
        t = self.token(what)
        try:
            return convert(t)
        except ValueError:
            raise self.fail(f"expected {kind} for {what}, found {t!r}") from None

    def int(self, what: str) -> int:
        return self._number(what, int, "an integer")

    def float(self, what: str) -> float:
        return self._number(what, float, "a number")

    def next_token(self) -> tuple[Optional[str], builtins.int]:
        """The token after the ones read and its line (0-based), or None at the end of the
        file; nothing is read."""
        if self.tok < len(self.toks):
            return self.toks[self.tok], self.line
        for k in range(self.line + 1, len(self.lines)):
            toks = self.lines[k].split()
            if toks:
                return toks[0], k
        return None, len(self.lines)

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


def _leading_numbers(tokens: list[str]) -> list[float]:
    """The numbers at the start of ``tokens``, up to the first word that is not one."""
    out = []
    for t in tokens:
        try:
            out.append(float(t))
        except ValueError:
            break
    return out


def _is_count(v: float) -> bool:
    return v >= 0 and v == int(v)


def _mlcp_sizes(text: str) -> Optional[tuple[int, int]]:
    """``(n, m)`` when ``text`` has the layout of a Siconos MLCP file, else None.

    Current layout: storage flags ``st1 st2`` (0 or 1), ``n``, ``m``; with ``st1`` the
    block rows ``0 .. n+m`` (increasing), one flag per block and a matrix header
    ``storage size0 size1`` with ``size1 = n + m``; with ``st2`` alone the blocks
    ``A B C D a b`` (``(n+m)^2 + n + m`` numbers). Older layout: ``n m NbLines``, then
    ``NbLines (n + m + 1)`` numbers.
    """
    v = _leading_numbers(text.split())
    if len(v) < 4 or not all(_is_count(x) for x in v[:4]):
        return None
    st1, st2, n, m = (int(x) for x in v[:4])
    if st1 in (0, 1) and st2 in (0, 1) and (st1 or st2) and n + m > 0:
        if st1:
            rows: list[int] = []
            k = 4
            while k < len(v) and len(rows) <= n + m and _is_count(v[k]):
                rows.append(int(v[k]))
                k += 1
                if rows[-1] >= n + m:
                    break
            blocks = len(rows) - 1
            if blocks >= 1 and rows[0] == 0 and rows[-1] == n + m and \
                    all(a < b for a, b in zip(rows, rows[1:])) and \
                    len(v) >= k + blocks + 3:
                storage, size1 = v[k + blocks], v[k + blocks + 2]
                if storage in (0, 1, 2) and size1 == n + m:
                    return n, m
        elif len(v) - 4 >= (n + m) ** 2 + n + m:
            return n, m
    n, m, lines = (int(x) for x in v[:3])
    if lines >= m and n + m > 0 and len(v) - 3 == lines * (n + m + 1):
        return n, m
    return None


def _refuse_mlcp(text: str, p: Path) -> None:
    """Raise :class:`UnsupportedProblem` when the file is a Siconos MLCP."""
    sizes = _mlcp_sizes(text)
    if sizes is not None:
        raise UnsupportedProblem(
            f"{p}: a Siconos MLCP file (mixed LCP with n = {sizes[0]} equality and m = "
            f"{sizes[1]} complementarity rows), not an LCP; lcpbench solves symmetric LCPs "
            "and does not import MLCPs (a folder import skips such files)", "MLCP")


def _read_lcp(c: _Cursor) -> tuple[int, str, np.ndarray, np.ndarray]:
    """``(n, storage name, M, q)`` of the LCP the cursor is at."""
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
    need, budget = 8 * size0 * size1, read_budget()
    if need > budget:           # every storage is read into a dense n x n matrix
        raise c.fail(f"the {size0}x{size1} matrix takes {human_bytes(need)} as a dense "
                     f"matrix, over the read budget of {human_bytes(budget)}; if the file is "
                     "trusted, raise it with LCPBENCH_READ_BUDGET (e.g. LCPBENCH_READ_BUDGET="
                     "16G)")
    M = reader(c, size0, size1)
    q = np.array([c.float(f"q[{i}]") for i in range(size1)])
    return n, name, M, q


def read_siconos_lcp(path: PathLike, *, symmetrize_rtol: float = 0.0,
                     psd_check: bool = True) -> LCP:
    """Read an LCP written by Siconos numerics (``linearComplementarity_printInFile``).

    Parameters
    ----------
    path : str or Path
        The ``.dat`` file.
    symmetrize_rtol : float
        Largest relative asymmetry of ``M`` replaced by ``(M + M') / 2`` with a warning;
        default 0, so a non-symmetric matrix raises (module docstring).
    psd_check : bool
        Refuse a matrix that is not positive semidefinite. Both follow the policy of
        :func:`lcpbench.problems.formats.symmetric_lcp`, shared with the FCLIB reader.

    Returns
    -------
    LCP
        ``A = M`` (dense), ``b = q``; ``meta`` has ``family="siconos"``, ``storage`` and
        ``source``.

    Raises
    ------
    SiconosFormatError
        Naming the line and the item that does not follow the format.
    UnsupportedProblem
        A ``ValueError``: the file is a Siconos MLCP, or its matrix is not symmetric
        (beyond ``symmetrize_rtol``) or not positive semidefinite.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise SiconosFormatError(f"{p}: cannot read the file as text ({exc})") from None
    c = _Cursor(text, p)
    try:
        n, name, M, q = _read_lcp(c)
    except SiconosFormatError:
        _refuse_mlcp(text, p)
        raise
    after, line = c.next_token()
    rest = c.lines[line].split()[c.tok if line == c.line else 0:] if after is not None else []
    if rest and len(_leading_numbers(rest)) == len(rest):     # data, not a remark
        _refuse_mlcp(text, p)
        raise c.fail(f"a number ({after}) follows the {n} entries of q: the file holds more "
                     f"than an LCP of size {n}", line)
    return symmetric_lcp(M, q, p, "Siconos LCP", symmetrize_rtol, name=f"siconos/{p.stem}",
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
