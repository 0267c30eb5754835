"""Live suspension backend: Stokes mobility of rigid spheres.

The mobility maps the forces and torques on ``M`` spheres to their
translational and angular velocities.  It is a ``(6M, 6M)`` operator acting
on per-sphere blocks: entries ``6i..6i+5`` of the input are
``(Fx, Fy, Fz, Tx, Ty, Tz)`` of sphere ``i`` and the same entries of the
output are ``(Ux, Uy, Uz, Wx, Wy, Wz)``.

Two models are available through :func:`mobility`:

``"rpy"``
    The generalised Rotne-Prager-Yamakawa mobility with overlap corrections
    (:func:`rpy_matrix`): analytic, dense, cheap, symmetric positive definite
    for any configuration, but only a far-field approximation near contact.
``"bim"``
    A boundary-integral Stokes solver whose accuracy is set by the
    spherical-harmonic order ``p`` and the GMRES tolerance ``eps_gmres``
    (the fidelity knobs of the method paper); it needs disjoint spheres.
"""

from __future__ import annotations

from scipy.sparse.linalg import LinearOperator, aslinearoperator

from .geometry import check_configuration, check_order, check_tolerance, check_viscosity
from .rpy import rpy_matrix

__all__ = ["MODELS", "mobility", "rpy_matrix"]

#: Names accepted by :func:`mobility`.
MODELS = ("rpy", "bim")


def mobility(centers, radii, model: str = "bim", p: int = 8, eps_gmres: float = 1e-8,
             mu: float = 1.0) -> LinearOperator:
    """Mobility operator of a configuration of rigid spheres.

    Parameters
    ----------
    centers, radii : array_like
        Sphere centres ``(M, 3)`` and radii (one, or one per sphere), as
        :func:`~lcpbench.problems.suspension.geometry.check_configuration` takes them.
    model : {"bim", "rpy"}, default "bim"
        ``"bim"``: boundary-integral solver (spheres must not overlap);
        ``"rpy"``: Rotne-Prager-Yamakawa with overlap corrections.
    p : int, default 8
        Spherical-harmonic order of the boundary-integral discretisation
        (``"bim"`` only; validated for every model).
    eps_gmres : float, default 1e-8
        Relative GMRES tolerance of the boundary-integral solve (``"bim"``
        only; validated for every model).
    mu : float, default 1.0
        Fluid viscosity.

    Returns
    -------
    scipy.sparse.linalg.LinearOperator, shape (6M, 6M)
        Maps per-sphere ``(Fx, Fy, Fz, Tx, Ty, Tz)`` blocks to
        ``(Ux, Uy, Uz, Wx, Wy, Wz)`` blocks (sphere ``i`` is entries
        ``6i..6i+5``).

    Raises
    ------
    ValueError
        Unknown model, ``p`` not an integer >= 1, ``eps_gmres`` not in (0, 1), non-positive ``mu``, or an invalid configuration
        (bad shapes, non-finite positions, non-positive radii, coincident
        centres; overlapping spheres for ``"bim"``).  The same inputs give the
        same errors whichever model is asked for.
    """
    if not isinstance(model, str) or model not in MODELS:
        raise ValueError(f"unknown mobility model {model!r}; choose one of "
                         + ", ".join(repr(m) for m in MODELS))
    p = check_order(p)
    eps_gmres = check_tolerance(eps_gmres)
    mu = check_viscosity(mu)
    centers, radii = check_configuration(centers, radii)
    if model == "rpy":
        return aslinearoperator(rpy_matrix(centers, radii, mu=mu))
    from .bim import bim_mobility
    return bim_mobility(centers, radii, p=p, eps_gmres=eps_gmres, mu=mu)
