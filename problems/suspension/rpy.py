r"""Rotne-Prager-Yamakawa mobility for polydisperse, possibly overlapping spheres.

The generalised RPY mobility is the Stokes (Oseen) Green's function averaged
over the particles: a force on sphere ``j`` is spread uniformly over its
surface, a torque on sphere ``j`` is the curl of a force density spread
uniformly over its volume, and the velocity (angular velocity) of sphere ``i``
is the surface average of the fluid velocity (half the curl of its volume
average).  In Fourier space every block is

.. math::

    \mathsf{M}_{ij} = \int \frac{d^3k}{(2\pi)^3}\, e^{i k\cdot r_{ij}}\,
        w_i(k)^*\, \frac{I - \hat k \hat k}{\mu k^2}\, w_j(k),

so the full matrix is a Gram matrix of linearly independent weights with a
positive kernel: it is symmetric positive definite for *every* configuration,
including overlapping spheres and spheres inside one another.  Evaluating the
averages in closed form gives the formulas of

* Wajnryb, Mizerski, Zuk & Szymczak, "Generalization of the Rotne-Prager-
  Yamakawa mobility and shear disturbance tensors", J. Fluid Mech. 731 (2013) R3
  (equal spheres, overlap corrections), and
* Zuk, Wajnryb, Mizerski & Szymczak, "Rotne-Prager-Yamakawa approximation for
  different-sized particles in application to macromolecular bead models",
  J. Fluid Mech. 741 (2014) R5 (different radii, all three regimes).

They were re-derived for this module from the averaging definition above by
exact polynomial integration and agree term by term with the published ones;
the tests check them against a direct numerical evaluation of the Fourier
integral.

Conventions
-----------
Sphere ``i`` has centre ``R_i`` and radius ``a_i``; for a pair,
``r = |R_i - R_j|`` and ``rhat = (R_i - R_j) / r`` points from ``j`` to ``i``.
``(eps . rhat)`` is the antisymmetric matrix with entries
``eps_{klm} rhat_m``, so ``(eps . rhat) F = F x rhat``.  The 6x6 block of the
pair ``(i, j)`` is::

    [ U_i ]   [ tt_ij  tr_ij ] [ F_j ]
    [ W_i ] = [ rt_ij  rr_ij ] [ T_j ]

and it sits in rows ``6i..6i+5``, columns ``6j..6j+5`` of the matrix
(per-particle ordering Fx, Fy, Fz, Tx, Ty, Tz -> Ux, Uy, Uz, Wx, Wy, Wz).
``tr_ij = rt_ji^T``.  With viscosity ``mu`` and ``a, b`` the radii:

Self blocks (``i = j``): ``tt = I / (6 pi mu a)``, ``rr = I / (8 pi mu a^3)``,
``rt = tr = 0``.

Non-overlapping, ``r >= a_i + a_j``::

    tt = 1/(8 pi mu r) [(1 + (a_i^2 + a_j^2)/(3 r^2)) I + (1 - (a_i^2 + a_j^2)/r^2) rhat rhat]
    rr = -1/(16 pi mu r^3) [I - 3 rhat rhat]
    rt = 1/(8 pi mu r^2) (eps . rhat)

Partial overlap, ``|a_i - a_j| < r < a_i + a_j``::

    tt = 1/(6 pi mu a_i a_j) [ (16 r^3 (a_i + a_j) - ((a_i - a_j)^2 + 3 r^2)^2) / (32 r^3) I
                              + 3 ((a_i - a_j)^2 - r^2)^2 / (32 r^3) rhat rhat ]
    rr = 1/(8 pi mu a_i^3 a_j^3) [ (5 r^6 - 27 r^4 (a_i^2 + a_j^2) + 32 r^3 (a_i^3 + a_j^3)
                                    - 9 r^2 (a_i^2 - a_j^2)^2
                                    - (a_i - a_j)^4 (a_i^2 + 4 a_i a_j + a_j^2)) / (64 r^3) I
                                  + 3 ((a_i - a_j)^2 - r^2)^2 (a_i^2 + 4 a_i a_j + a_j^2 - r^2)
                                    / (64 r^3) rhat rhat ]
    rt = 1/(16 pi mu a_i^3 a_j) (a_i - a_j + r)^2 (a_j^2 + 2 a_j (a_i + r) - 3 (a_i - r)^2)
         / (8 r^2) (eps . rhat)

One sphere inside the other, ``r <= |a_i - a_j|`` (``a_> = max(a_i, a_j)``)::

    tt = I / (6 pi mu a_>)        rr = I / (8 pi mu a_>^3)
    rt = r / (8 pi mu a_i^3) (eps . rhat)   if a_i > a_j   (the rotating sphere is the larger)
    rt = 0                                  if a_i < a_j

``rt`` is not symmetric in ``a_i, a_j``: in ``rt_ij`` sphere ``i`` rotates and
sphere ``j`` carries the force.  Every block is continuous at ``r = a_i + a_j``
and at ``r = |a_i - a_j|``.
"""

from __future__ import annotations

import numpy as np

from .geometry import check_configuration, check_viscosity

__all__ = ["rpy_matrix"]

#: Rows of the output assembled per chunk; bounds the temporaries to about
#: ``_CHUNK * M * 9`` doubles per array.
_CHUNK = 128


def _regions(r: np.ndarray, ai: np.ndarray, aj: np.ndarray):
    """Empty coefficient arrays and the three regimes of a pair at distance ``r``.

    ``far``: disjoint spheres (``r >= ai + aj``); ``inside``: one sphere inside the
    other (``r <= |ai - aj|``); ``ovl``: overlapping otherwise.
    """
    far = r >= ai + aj
    inside = ~far & (r <= np.abs(ai - aj))
    return np.empty_like(r), np.empty_like(r), far, ~far & ~inside, inside


def _translation_coefficients(r: np.ndarray, ai: np.ndarray, aj: np.ndarray
                              ) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients ``(c_I, c_rr)`` of ``tt = c_I I + c_rr rhat rhat`` for ``mu = 1``."""
    cI, cr, far, ovl, inside = _regions(r, ai, aj)

    x, p, q = r[far], ai[far], aj[far]
    s2 = p * p + q * q
    cI[far] = (1.0 + s2 / (3.0 * x * x)) / (8.0 * np.pi * x)
    cr[far] = (1.0 - s2 / (x * x)) / (8.0 * np.pi * x)

    x, p, q = r[ovl], ai[ovl], aj[ovl]
    d2 = (p - q) ** 2
    x3 = x ** 3
    pref = 1.0 / (6.0 * np.pi * p * q)
    cI[ovl] = pref * (16.0 * x3 * (p + q) - (d2 + 3.0 * x * x) ** 2) / (32.0 * x3)
    cr[ovl] = pref * 3.0 * (d2 - x * x) ** 2 / (32.0 * x3)

    big = np.maximum(ai[inside], aj[inside])
    cI[inside] = 1.0 / (6.0 * np.pi * big)
    cr[inside] = 0.0
    return cI, cr


def _rotation_coefficients(r: np.ndarray, ai: np.ndarray, aj: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients ``(c_I, c_rr)`` of ``rr = c_I I + c_rr rhat rhat`` for ``mu = 1``."""
    cI, cr, far, ovl, inside = _regions(r, ai, aj)

    x = r[far]
    x3 = x ** 3
    cI[far] = -1.0 / (16.0 * np.pi * x3)
    cr[far] = 3.0 / (16.0 * np.pi * x3)

    x, p, q = r[ovl], ai[ovl], aj[ovl]
    x2 = x * x
    x3 = x2 * x
    pq = p * p + 4.0 * p * q + q * q
    pref = 1.0 / (8.0 * np.pi * p ** 3 * q ** 3 * 64.0 * x3)
    cI[ovl] = pref * (5.0 * x3 * x3 - 27.0 * x2 * x2 * (p * p + q * q)
                      + 32.0 * x3 * (p ** 3 + q ** 3) - 9.0 * x2 * (p * p - q * q) ** 2
                      - (p - q) ** 4 * pq)
    cr[ovl] = pref * 3.0 * ((p - q) ** 2 - x2) ** 2 * (pq - x2)

    big = np.maximum(ai[inside], aj[inside])
    cI[inside] = 1.0 / (8.0 * np.pi * big ** 3)
    cr[inside] = 0.0
    return cI, cr


def _coupling_coefficient(r: np.ndarray, ai: np.ndarray, aj: np.ndarray) -> np.ndarray:
    """Coefficient ``c`` of ``rt_ij = c (eps . rhat_ij)`` for ``mu = 1``.

    Sphere ``i`` (radius ``ai``) rotates, sphere ``j`` (radius ``aj``) carries
    the force.
    """
    c = np.empty_like(r)
    far = r >= ai + aj
    inside = ~far & (r <= np.abs(ai - aj))
    ovl = ~far & ~inside

    c[far] = 1.0 / (8.0 * np.pi * r[far] ** 2)

    x, p, q = r[ovl], ai[ovl], aj[ovl]
    c[ovl] = ((p - q + x) ** 2 * (q * q + 2.0 * q * (p + x) - 3.0 * (p - x) ** 2)
              / (128.0 * np.pi * p ** 3 * q * x * x))

    x, p, q = r[inside], ai[inside], aj[inside]
    c[inside] = np.where(p > q, x / (8.0 * np.pi * p ** 3), 0.0)
    return c


def _cross_matrices(rhat: np.ndarray) -> np.ndarray:
    """``(eps . rhat)`` for an array of unit vectors: shape ``(..., 3)`` -> ``(..., 3, 3)``."""
    E = np.zeros(rhat.shape[:-1] + (3, 3))
    x, y, z = rhat[..., 0], rhat[..., 1], rhat[..., 2]
    E[..., 0, 1] = z
    E[..., 0, 2] = -y
    E[..., 1, 0] = -z
    E[..., 1, 2] = x
    E[..., 2, 0] = y
    E[..., 2, 1] = -x
    return E


def rpy_matrix(centers, radii, mu: float = 1.0) -> np.ndarray:
    """Dense generalised Rotne-Prager-Yamakawa mobility matrix.

    Parameters
    ----------
    centers : array_like, shape (M, 3)
        Sphere centres. Spheres may overlap or lie inside one another;
        centres must be distinct.
    radii : float or array_like, shape (M,)
        One radius for all spheres or one per sphere (polydisperse).
    mu : float, default 1.0
        Fluid viscosity.

    Returns
    -------
    ndarray, shape (6M, 6M)
        Symmetric positive definite mobility mapping per-sphere blocks
        ``(Fx, Fy, Fz, Tx, Ty, Tz)`` to ``(Ux, Uy, Uz, Wx, Wy, Wz)``; the block
        of sphere ``i`` is entries ``6i..6i+5``.  See the module docstring for
        the formulas, their source and the sign conventions.

    Raises
    ------
    ValueError
        Bad shapes, non-finite positions, non-positive radii, coincident
        centres or a non-positive viscosity.

    Notes
    -----
    Cost and memory are O(M^2): about ``288 M^2`` bytes for the result (a
    little under 300 MB at M = 1000), assembled in row chunks so temporaries
    stay small.
    """
    c, a = check_configuration(centers, radii)
    mu = check_viscosity(mu)
    M = len(a)
    out = np.empty((M, 6, M, 6))
    for start in range(0, M, _CHUNK):
        stop = min(start + _CHUNK, M)
        d = c[start:stop, None, :] - c[None, :, :]          # R_i - R_j, (m, M, 3)
        r = np.linalg.norm(d, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            rhat = np.where(r[..., None] > 0, d / r[..., None], 0.0)
        ai = np.broadcast_to(a[start:stop, None], r.shape)
        aj = np.broadcast_to(a[None, :], r.shape)
        rr_outer = rhat[..., :, None] * rhat[..., None, :]
        eye = np.eye(3)

        tI, tR = _translation_coefficients(r, ai, aj)
        out[start:stop, :3, :, :3] = np.moveaxis(
            tI[..., None, None] * eye + tR[..., None, None] * rr_outer, 2, 1)
        wI, wR = _rotation_coefficients(r, ai, aj)
        out[start:stop, 3:, :, 3:] = np.moveaxis(
            wI[..., None, None] * eye + wR[..., None, None] * rr_outer, 2, 1)
        E = _cross_matrices(rhat)
        rt = _coupling_coefficient(r, ai, aj)                # sphere i rotates
        tr = _coupling_coefficient(r, aj, ai)                # sphere j rotates
        out[start:stop, 3:, :, :3] = np.moveaxis(rt[..., None, None] * E, 2, 1)
        out[start:stop, :3, :, 3:] = np.moveaxis(tr[..., None, None] * E, 2, 1)
    out /= mu
    return out.reshape(6 * M, 6 * M)
