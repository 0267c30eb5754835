"""What the file-format importers share: the symmetry policy, building the LCP, input files.

Used by :mod:`lcpbench.problems.siconos` and :mod:`lcpbench.problems.fclib`.

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
from pathlib import Path
from typing import Union

import numpy as np
import scipy.sparse as sp

from lcpbench import LCP
from lcpbench.core.lcp import SYMMETRY_RTOL

__all__ = ["PathLike", "symmetric_lcp", "input_files"]

PathLike = Union[str, Path]


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
    ValueError
        If ``A`` is not symmetric beyond ``symmetrize_rtol`` or not a valid LCP matrix.
    """
    A = _symmetric(A, f"{path}: {what}", symmetrize_rtol)
    try:
        return LCP(A, b, **kw)
    except (ValueError, TypeError) as exc:
        raise type(exc)(f"{path}: {what} is not a valid lcpbench LCP: {exc}") from None


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

