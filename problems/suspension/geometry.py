"""Validation of sphere configurations shared by the mobility models and scenes.

Every public entry point of the suspension backend checks its input here, so
the errors are the same whichever model is asked for.
"""

from __future__ import annotations

import numbers

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["check_configuration", "check_viscosity", "check_order", "check_tolerance",
           "pair_gaps", "check_no_overlap"]


def check_configuration(centers, radii) -> tuple[np.ndarray, np.ndarray]:
    """Validate sphere centres and radii.

    Parameters
    ----------
    centers : array_like, shape (M, 3)
        Sphere centres.
    radii : float or array_like, shape (M,)
        One radius for all spheres or one per sphere.

    Returns
    -------
    centers : ndarray, shape (M, 3), float64
    radii : ndarray, shape (M,), float64

    Raises
    ------
    ValueError
        Wrong shapes, non-finite positions, non-positive radii, or two
        coincident centres (the pair is named).
    """
    c = np.asarray(centers, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"centers must have shape (M, 3), got {c.shape}; "
                         "pass one row (x, y, z) per sphere")
    M = c.shape[0]
    if M == 0:
        raise ValueError("centers is empty; a configuration needs at least one sphere")
    bad = ~np.isfinite(c).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"centers[{i}] = {c[i].tolist()} is not finite; "
                         "every position must be a finite number")
    r = np.asarray(radii, dtype=np.float64)
    if r.ndim == 0:
        r = np.full(M, float(r))
    if r.shape != (M,):
        raise ValueError(f"radii must be a scalar or have shape ({M},), got {r.shape}")
    bad = ~(np.isfinite(r) & (r > 0))
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"radii[{i}] = {r[i]} must be a finite positive number")
    if M > 1:
        tol = 1e-12 * float(r.min())
        pairs = cKDTree(c).query_pairs(tol, output_type="ndarray")
        if len(pairs):
            i, j = (int(v) for v in pairs[0])
            raise ValueError(f"spheres {i} and {j} have coincident centres {c[i].tolist()}; "
                             "every sphere needs its own position")
    return c, r


def check_viscosity(mu) -> float:
    """Validate the fluid viscosity: a finite positive number."""
    mu = float(mu)
    if not (np.isfinite(mu) and mu > 0):
        raise ValueError(f"mu = {mu} must be a finite positive viscosity")
    return mu


# Wrong types raise ValueError too (not TypeError): callers get one exception type for
# every bad parameter, whichever model or fidelity they ask for.
def check_order(p) -> int:
    """Validate a spherical-harmonic order: an integer >= 1 (bool refused)."""
    if isinstance(p, (bool, np.bool_)) or not isinstance(p, (int, np.integer)) or p < 1:
        raise ValueError(f"p = {p!r} must be an integer spherical-harmonic order >= 1 (8 is "
                         "high fidelity away from contact, 3-6 are typical low fidelities)")
    return int(p)


def check_tolerance(eps_gmres) -> float:
    """Validate a relative GMRES tolerance: a finite number in (0, 1) (bool refused)."""
    real = isinstance(eps_gmres, numbers.Real) and not isinstance(eps_gmres, (bool, np.bool_))
    e = float(eps_gmres) if real else float("nan")
    if not (np.isfinite(e) and 0 < e < 1):
        raise ValueError(f"eps_gmres = {eps_gmres!r} must be a finite number in (0, 1), "
                         "e.g. 1e-8 (relative GMRES residual)")
    return e


def pair_gaps(centers: np.ndarray, radii: np.ndarray, delta: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of spheres whose surface gap is at most ``delta``.

    Parameters
    ----------
    centers : ndarray, shape (M, 3)
    radii : ndarray, shape (M,)
    delta : float
        Gap threshold (may be negative to find overlaps only).

    Returns
    -------
    pairs : ndarray, shape (P, 2), int
        Index pairs ``i < j``, sorted lexicographically.
    gaps : ndarray, shape (P,)
        ``|c_i - c_j| - r_i - r_j`` for each pair.
    """
    if len(centers) < 2:
        return np.empty((0, 2), dtype=np.intp), np.empty(0)
    reach = 2.0 * float(radii.max()) + max(float(delta), 0.0)
    pairs = cKDTree(centers).query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return np.empty((0, 2), dtype=np.intp), np.empty(0)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    d = np.linalg.norm(centers[pairs[:, 0]] - centers[pairs[:, 1]], axis=1)
    gaps = d - radii[pairs[:, 0]] - radii[pairs[:, 1]]
    keep = gaps <= delta
    return pairs[keep].astype(np.intp), gaps[keep]


def check_no_overlap(centers: np.ndarray, radii: np.ndarray, model: str) -> None:
    """Raise naming the worst overlapping pair, if any two spheres overlap."""
    pairs, gaps = pair_gaps(centers, radii, 0.0)
    over = gaps < 0
    if over.any():
        k = int(np.argmin(gaps))
        i, j = (int(v) for v in pairs[k])
        raise ValueError(f"model {model!r}: spheres {i} and {j} overlap by {-gaps[k]:.3g} "
                         f"(gap {gaps[k]:.3g}, {int(over.sum())} overlapping pair(s)); the "
                         "boundary integral model needs disjoint spheres; use model='rpy' "
                         "or separate them")
