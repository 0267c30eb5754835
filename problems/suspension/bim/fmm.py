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

Which engine is faster depends on the number of spheres: ``far="auto"``
(:func:`resolve_far`) takes the FMM from :data:`FAR_CROSSOVER_M` spheres on, the
crossover measured by ``benchmarks/far_crossover.py``, when fmm3dpy is importable.
"""

from __future__ import annotations

import importlib.util

import numpy as np

__all__ = ["check_fmm", "fmm_traction", "fmm_traction_adjoint", "fmm_available", "resolve_far", "FAR_CROSSOVER_M",
           "FAR_ENGINES"]

FAR_ENGINES = ("auto", "direct", "fmm")
"""The far-field engines a boundary-integral mobility accepts."""

FAR_CROSSOVER_M = 40000
"""From how many spheres ``far="auto"`` takes the FMM: no crossover was measured up to 125
spheres (the FMM 300x slower than the direct sums per application with the pair-frame near
field, docs/benchmarks.md, "The far field's crossover"); the ratio extrapolated as growing
like M reaches 1 near 42,000 spheres, beyond this machine's memory for the pair plan."""
"""Spheres from which ``far="auto"`` takes the FMM.  Measured by ``python
benchmarks/far_crossover.py --m 2 3 4 5 6`` (p = 8, packed lattices; docs/benchmarks.md,
"Live step hygiene"): the FMM's traction-operator product took 83, 22, 17, 4.0 and 4.1
times the direct sums' at M = 8, 27, 64, 125 and 216 (ratios direct / fmm 0.012, 0.045,
0.057, 0.252, 0.241): no measured size has the crossover, and from 125 to 216 both grow
about like M, so it cannot be placed from these; 1000 is above every measured size (the
script's extrapolation ``M / ratio`` from 216 gives 896).  Rerun the script with larger
``--m`` to move it."""


def fmm_available() -> bool:
    """True when fmm3dpy can be imported (without importing it)."""
    return importlib.util.find_spec("fmm3dpy") is not None


def resolve_far(far: str, M: int) -> str:
    """The engine ``far`` names for ``M`` spheres: ``"auto"`` is ``"fmm"`` from
    :data:`FAR_CROSSOVER_M` spheres on when fmm3dpy is importable, else ``"direct"``;
    ``"direct"`` and ``"fmm"`` are themselves.

    Raises
    ------
    ValueError
        ``far`` is not one of :data:`FAR_ENGINES`.
    """
    if far not in FAR_ENGINES:
        raise ValueError(f"far = {far!r}; use 'direct' (compiled direct sums), 'fmm' "
                         "(fmm3dpy.stfmm3d, install the extra 'fmm') or 'auto' (the FMM "
                         f"from {FAR_CROSSOVER_M} spheres on when fmm3dpy is installed)")
    if far != "auto":
        return far
    return "fmm" if M >= FAR_CROSSOVER_M and fmm_available() else "direct"


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


def fmm_traction_adjoint(points: np.ndarray, normals: np.ndarray, trac_bar: np.ndarray,
                         eps: float) -> np.ndarray:
    """Transpose of :func:`fmm_traction` (points are sources and targets alike).

    The traction at ``x_k`` (normal ``n_k``) of a point force ``f`` at ``y`` is
    ``-(3/4 pi) (r.n_k) r (r.f) / |r|^5`` with ``r = x_k - y``; its transpose, the adjoint
    force at ``y`` of adjoint tractions ``b_k``, is ``(3/4 pi) sum_k r' (r'.b_k)(r'.n_k) /
    |r'|^5`` with ``r' = y - x_k``: the velocity of stresslets of strength ``b_k`` and
    orientation ``n_k``, which is fmm3dpy's stresslet normalisation (checked against the
    direct sum to 1e-15).  Self points are excluded, as in the forward FMM.

    Returns
    -------
    ndarray, shape (n, 3)
        Adjoint point forces at every point.
    """
    import fmm3dpy

    out = fmm3dpy.stfmm3d(eps=float(max(eps, 1e-15)), sources=np.ascontiguousarray(points.T),
                          strslet=np.ascontiguousarray(trac_bar.T),
                          strsvec=np.ascontiguousarray(normals.T), ifppreg=1)
    return np.ascontiguousarray(np.asarray(out.pot).reshape(3, -1).T)
