"""Optional far-field engine: fmm3dpy's Stokes FMM (extra ``fmm``).

:func:`fmm_traction` sums the traction of point forces over *all* source
points (every sphere's native grid), the self point excluded, with
``fmm3dpy.stfmm3d``.  Its normalisation is the Stokeslet with mu = 1,
``u = (1/8 pi)(delta/r + r r^T/r^3) f`` and pressure ``(1/4 pi) r.f/r^3``,
the same single layer as the rest of the backend, so the traction is
``-p n + (grad u + grad u^T) n`` (symmetric, so the index convention of the
gradient does not matter).  The caller removes the pairs that need more than
native-grid quadrature (and the sphere's own points) by direct summation and
adds their accurate values: the usual FMM near-field correction.

The FMM pays off only for large systems (on 2 cores roughly beyond 50-100k
points, i.e. several hundred spheres at p = 8); below that the compiled direct
sum is faster.
"""

from __future__ import annotations

import numpy as np

__all__ = ["check_fmm", "fmm_traction"]


def check_fmm() -> None:
    """Raise ImportError with an installation hint if fmm3dpy is missing."""
    try:
        import fmm3dpy  # noqa: F401
    except ImportError as exc:                       # pragma: no cover - depends on the venv
        raise ImportError("far='fmm' needs fmm3dpy: install the extra, "
                          "pip install 'lcpbench[fmm]', or use far='direct'") from exc


def fmm_traction(points: np.ndarray, normals: np.ndarray, forces: np.ndarray,
                 eps: float) -> np.ndarray:
    """Traction at every source point of all the other point forces (mu = 1).

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Source points, also the targets.
    normals : ndarray, shape (n, 3)
        Normal at each point for the traction.
    forces : ndarray, shape (n, 3)
        Point forces (density times quadrature weight).
    eps : float
        Requested relative precision of the FMM.

    Returns
    -------
    ndarray, shape (n, 3)
        ``sum_{m != k} sigma(x_k; y_m, f_m) n_k``.
    """
    import fmm3dpy

    out = fmm3dpy.stfmm3d(eps=float(max(eps, 1e-15)),
                          sources=np.ascontiguousarray(points.T),
                          stoklet=np.ascontiguousarray(forces.T), ifppreg=3)
    n = points.shape[0]
    G = np.asarray(out.grad).reshape(3, 3, n)       # the nd = 1 axis comes first
    pre = np.asarray(out.pre).reshape(n)
    S = G + G.transpose(1, 0, 2)
    nT = normals.T
    trac = np.einsum("ijn,jn->in", S, nT) - pre[None, :] * nT
    return np.ascontiguousarray(trac.T)
