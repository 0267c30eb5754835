"""What the file-format importers share: the symmetry policy, building the LCP, input files.

Used by :mod:`lcpbench.problems.siconos` and :mod:`lcpbench.problems.fclib`.

Unsupported problems
    A file that holds a well-formed problem lcpbench does not solve (a non-symmetric or
    indefinite matrix, a Siconos MLCP) raises :class:`UnsupportedProblem`, a
    ``ValueError``. Reading one file, that is the error; reading a folder
    (:func:`read_supported`), such files are skipped and listed in one warning, and the
    rest are read. A malformed file is an error either way.

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
from collections.abc import Callable
from pathlib import Path
from typing import Union

import numpy as np
import scipy.sparse as sp

from lcpbench import LCP
from lcpbench.core.lcp import SYMMETRY_RTOL

__all__ = ["PathLike", "UnsupportedProblem", "symmetric_lcp", "input_files", "read_supported"]

PathLike = Union[str, Path]


class UnsupportedProblem(ValueError):
    """A well-formed file whose problem lcpbench does not solve.

    Parameters
    ----------
    message : str
        The full one-line message (names the file and what to do).
    reason : str
        A few words for the list of skipped files (``"MLCP"``, ``"not symmetric"``).
    """

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


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
        raise UnsupportedProblem(
            f"{what}: the matrix is not symmetric (max|A-A'| = {asym:.3g}, {rel:.3g} relative "
            f"to max|A|), but lcpbench solves symmetric LCPs. Pass symmetrize_rtol >= "
            f"{rel:.2g} to replace it by (A + A')/2 if the asymmetry is round-off",
            f"not symmetric, {rel:.2g} relative")
    warnings.warn(f"{what}: symmetrised the matrix (max|A-A'| = {asym:.3g}, {rel:.3g} relative "
                  f"to max|A|, within symmetrize_rtol = {symmetrize_rtol:g})", RuntimeWarning,
                  stacklevel=4)
    return (A + A.T) / 2



def symmetric_lcp(A, b, path: Path, what: str, symmetrize_rtol: float, **kw) -> LCP:
    """The LCP ``(A, b)`` read from ``path``, ``A`` checked or symmetrised by the policy above.

    Parameters
    ----------
    A : (n, n) ndarray or sparse matrix
    b : (n,) ndarray
    path : Path
        The file read, named in errors.
    what : str
        What the matrix is (``"Siconos LCP"``), named in errors.
    symmetrize_rtol : float
        Largest relative asymmetry replaced by ``(A + A') / 2`` with a warning.
    **kw
        Passed to :class:`~lcpbench.LCP` (name, meta, psd_check).

    Raises
    ------
    UnsupportedProblem
        If ``A`` is not symmetric beyond ``symmetrize_rtol``, or not positive semidefinite.
    ValueError
        If ``A`` or ``b`` is not a valid LCP matrix or vector otherwise.
    """
    A = _symmetric(A, f"{path}: {what}", symmetrize_rtol)
    try:
        return LCP(A, b, **kw)
    except (ValueError, TypeError) as exc:
        message = f"{path}: {what} is not a valid lcpbench LCP: {exc}"
        if isinstance(exc, ValueError) and kw.get("psd_check", True):
            try:        # valid but for semidefiniteness: an LCP lcpbench does not solve
                LCP(A, b, **{**kw, "psd_check": False})
            except (ValueError, TypeError):
                pass
            else:
                raise UnsupportedProblem(message, "not positive semidefinite") from None
        raise type(exc)(message) from None


def input_files(path: str, patterns: tuple[str, ...], kind: str) -> list[Path]:
    """``path`` itself, or the files in folder ``path`` matching ``patterns`` (sorted).

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist or the folder holds no matching file.
    """
    p = Path(path)
    if p.is_dir():
        found = sorted({q for pat in patterns for q in p.glob(pat)})
        if not found:
            raise FileNotFoundError(f"{p}: no {kind} files ({', '.join(patterns)}) in the folder")
        return found
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such {kind} file or folder")
    return [p]


def read_supported(files: list[Path], read: Callable[[Path], LCP], where: str) -> list[LCP]:
    """``read`` every file, skipping those whose problem lcpbench does not solve.

    Parameters
    ----------
    files : list of Path
        The folder's files, in order.
    read : callable
        Reads one file; raises :class:`UnsupportedProblem` for a file to skip.
    where : str
        What is read (``"siconos:path=FOLDER"``), named in the warning and the error.

    Returns
    -------
    list of LCP
        The files' LCPs; the skipped files are listed, each with its reason, in one
        ``UserWarning``.

    Raises
    ------
    ValueError
        If no file is left (the message lists the reasons), or as ``read`` raises for a
        malformed file.
    """
    lcps, skipped = [], []
    for f in files:
        try:
            lcps.append(read(f))
        except UnsupportedProblem as exc:
            skipped.append(f"{f.name} ({exc.reason})")
    if skipped and not lcps:
        raise ValueError(f"{where}: none of the {len(files)} file(s) is an LCP lcpbench solves "
                         f"(symmetric, positive semidefinite): {', '.join(skipped)}")
    if skipped:
        warnings.warn(f"{where}: skipped {len(skipped)} of {len(files)} files, problems "
                      f"lcpbench does not solve: {', '.join(skipped)}", UserWarning, stacklevel=3)
    return lcps
