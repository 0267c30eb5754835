"""Classical Gram-Schmidt against an orthonormal block, as two matrix-vector passes.

Shared by the GMRES cycle (:mod:`.gmres`: a new Arnoldi direction against the basis) and
the recycled spaces (:mod:`.recycle`: a new image against the kept images).
"""

from __future__ import annotations

import numpy as np

__all__ = ["orthogonalise"]


def orthogonalise(V: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float, float]:
    """``w`` made orthogonal to the orthonormal rows of ``V`` by classical Gram-Schmidt,
    repeated once when the first pass removed more than ``1 - 1/sqrt(2)`` of its norm
    (twice is enough: Kahan's rule).

    Returns the coefficients ``h`` (``w_in = h V + w_out``), ``||w_in||`` and ``||w_out||``;
    ``w`` is updated in place.
    """
    h0 = float(np.linalg.norm(w))
    h = V @ w
    w -= h @ V
    h1 = float(np.linalg.norm(w))
    if h1 < h0 / np.sqrt(2.0):
        g = V @ w
        w -= g @ V
        h += g
        h1 = float(np.linalg.norm(w))
    return h, h0, h1
