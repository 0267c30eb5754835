"""Exact Stokes-flow drag of two equal rigid spheres moving along their line of centres.

Reference values for validating mobility (Stokes) solvers. Two equal rigid spheres of radius
``a`` whose centres are a distance ``d`` apart move along the line of centres in unbounded
Stokes flow of viscosity ``mu``. Two axisymmetric modes are solved exactly in bispherical
coordinates ``(xi, eta)`` with the spheres on ``xi = +alpha`` and ``xi = -alpha``, where

    d = 2 a cosh(alpha).

Each sphere feels the drag ``F = 6 pi mu a U lambda`` with

* ``stimson_jeffery_lambda``: both spheres translate with the *same* velocity ``U``
  (Stimson & Jeffery 1926, Proc. R. Soc. A 111, 110; Happel & Brenner 1965, ch. 6),

      lambda_SJ = (4/3) sinh(alpha) sum_{n>=1} n (n+1) / ((2n-1)(2n+3))
                  * [1 - (4 sinh^2((n+1/2) alpha) - (2n+1)^2 sinh^2(alpha))
                         / (2 sinh((2n+1) alpha) + (2n+1) sinh(2 alpha))];

* ``brenner_lambda``: the spheres approach (or recede from) each other with equal and
  opposite velocities ``+U``, ``-U`` (Brenner 1961, Chem. Eng. Sci. 16, 242, the sphere moving
  normal to a plane *free* surface, which is the symmetry plane of this problem; Maude 1961,
  Br. J. Appl. Phys. 12, 293; the odd-in-xi bispherical solution, whose denominators are
  ``2 sinh((2n+1) alpha) - (2n+1) sinh(2 alpha)``),

      lambda_B = (4/3) sinh(alpha) sum_{n>=1} n (n+1) / ((2n-1)(2n+3))
                 * [(4 cosh^2((n+1/2) alpha) + (2n+1)^2 sinh^2(alpha))
                    / (2 sinh((2n+1) alpha) - (2n+1) sinh(2 alpha)) - 1].

Both series are summed in an exponentially scaled form (numerator and denominator of each
bracket multiplied by ``exp(-(2n+1) alpha)``), so large ``alpha`` cannot overflow and the
bracket is obtained without cancellation.

The module also gives an independent check of both series: :func:`reflection_lambda` solves the
same two problems by the exact method of reflections with Sampson's axisymmetric stream
function expansion about each sphere (no bispherical coordinates), and
:func:`far_field_lambda` is the classical power series of the method of reflections in
``a / d`` (Smoluchowski 1911; Happel & Brenner 1965, ch. 6; Batchelor 1976, J. Fluid
Mech. 74, 1; Jeffrey & Onishi 1984, J. Fluid Mech. 139, 261).

Both bispherical series agree with :func:`reflection_lambda` to about 1e-15 for
``d / a`` in {2.5, 3, 4, 6, 10} (see ``tests/test_stokes_series.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.polynomial import legendre as _legendre

__all__ = [
    "alpha_from_distance",
    "brenner_lambda",
    "distance_from_alpha",
    "far_field_coefficients",
    "far_field_lambda",
    "mobility_functions_along_axis",
    "reflection_lambda",
    "stimson_jeffery_lambda",
    "two_sphere_mobility_along_axis",
]

_REL_TOL = 1e-16
_MAX_TERMS = 10_000_000


def alpha_from_distance(d_over_a: float) -> float:
    """Bispherical coordinate ``alpha`` of the sphere surfaces for centre distance ``d / a``.

    Parameters
    ----------
    d_over_a : float
        Centre-to-centre distance over sphere radius; must be finite and > 2 (no overlap or
        contact).

    Returns
    -------
    float
        ``alpha = arccosh(d / (2 a))``, computed as ``log1p(g + sqrt(g (g + 2)))`` with
        ``g = d/(2a) - 1`` (the gap over the diameter) so that it stays accurate near contact.
    """
    s = float(d_over_a)
    if not math.isfinite(s) or s <= 2.0:
        raise ValueError(
            f"d_over_a must be a finite number > 2 (spheres apart), got {d_over_a!r}; "
            "pass the centre distance divided by the radius"
        )
    g = 0.5 * s - 1.0
    return math.log1p(g + math.sqrt(g * (g + 2.0)))


def distance_from_alpha(alpha: float) -> float:
    """Centre distance over radius, ``d / a = 2 cosh(alpha)``, for ``alpha > 0``."""
    if not math.isfinite(alpha) or alpha <= 0.0:
        raise ValueError(f"alpha must be a finite positive number, got {alpha!r}")
    return 2.0 * math.cosh(alpha)


def _check_terms(terms: int | None) -> int | None:
    if terms is None:
        return None
    if isinstance(terms, bool) or not isinstance(terms, (int, np.integer)) or terms < 1:
        raise ValueError(
            f"terms must be a positive integer or None (automatic), got {terms!r}"
        )
    return int(terms)


def _bracket_terms(alpha: float, n: np.ndarray, mode: str) -> np.ndarray:
    """Terms ``c_n * bracket_n`` of the two series, exponentially scaled (see module doc)."""
    m = 2.0 * n + 1.0
    e1 = np.exp(-m * alpha)  # exp(-(2n+1) alpha)
    e2 = e1 * e1
    # sinh^2(alpha) e^{-m alpha} and sinh(2 alpha) e^{-m alpha} without overflow (m >= 3)
    q = -math.expm1(-2.0 * alpha)  # 1 - e^{-2 alpha}
    sh2 = np.exp((2.0 - m) * alpha) * (0.25 * q * q)
    s2a = np.exp((2.0 - m) * alpha) * (
        0.5 * q * (2.0 - q)
    )  # sinh(2a) e^{-ma}: (e^{2a}-e^{-2a})/2
    common = m * m * sh2 + m * s2a
    if mode == "same":
        # 1 - R = (den - num)/den with den = 1 - e2 + m sinh(2a) e1,
        # num = 1 + e2 - 2 e1 - m^2 sinh^2(a) e1
        den = 1.0 - e2 + m * s2a
        bracket = (2.0 * e1 - 2.0 * e2 + common) / den
    else:
        # T = (num - den)/den with num = 1 + e2 + 2 e1 + m^2 sinh^2(a) e1,
        # den = 1 - e2 - m sinh(2a) e1
        den = 1.0 - e2 - m * s2a
        bracket = (2.0 * e1 + 2.0 * e2 + common) / den
    coef = n * (n + 1.0) / ((2.0 * n - 1.0) * (2.0 * n + 3.0))
    return coef * bracket


def _series(d_over_a: float, terms: int | None, mode: str) -> float:
    alpha = alpha_from_distance(d_over_a)
    terms = _check_terms(terms)
    pref = (4.0 / 3.0) * math.sinh(alpha)
    if terms is not None:
        n = np.arange(1, terms + 1, dtype=float)
        return float(pref * math.fsum(_bracket_terms(alpha, n, mode)))
    total: list[float] = []
    start, block = 1, 64
    while start <= _MAX_TERMS:
        n = np.arange(start, start + block, dtype=float)
        t = _bracket_terms(alpha, n, mode)
        total.extend(t.tolist())
        partial = math.fsum(total)
        small = np.nonzero(np.abs(t) <= _REL_TOL * abs(partial))[0]
        if small.size:
            # terms decrease monotonically (like n^2 e^{-2 n alpha}); stop at the first small one
            cut = len(total) - block + int(small[0]) + 1
            return float(pref * math.fsum(total[:cut]))
        start += block
        block = min(2 * block, 1 << 20)
    raise RuntimeError(
        f"series did not converge within {_MAX_TERMS} terms at d/a = {d_over_a!r}; "
        "the spheres are too close for this summation, increase d/a"
    )


def stimson_jeffery_lambda(d_over_a: float, terms: int | None = None) -> float:
    """Drag factor of two equal spheres translating together along their line of centres.

    Both spheres (radius ``a``, centre distance ``d``) move with the same velocity ``U`` along
    the line of centres; each feels the drag ``F = 6 pi mu a U lambda`` (Stimson & Jeffery,
    Proc. R. Soc. Lond. A 111, 110-116, 1926; Happel & Brenner, *Low Reynolds Number
    Hydrodynamics*, 1965, ch. 6):

        lambda = (4/3) sinh(alpha) sum_{n>=1} n (n+1) / ((2n-1)(2n+3))
                 [1 - (4 sinh^2((n+1/2) alpha) - (2n+1)^2 sinh^2 alpha)
                      / (2 sinh((2n+1) alpha) + (2n+1) sinh 2 alpha)],

    with ``d = 2 a cosh(alpha)``. ``lambda < 1`` (the spheres shield each other), tends to 1 as
    ``d -> inf`` and to 0.6451... at contact.

    Parameters
    ----------
    d_over_a : float
        Centre distance over radius, > 2.
    terms : int, optional
        Number of series terms. By default terms are added until one falls below 1e-16 of the
        partial sum.

    Returns
    -------
    float
        The drag factor ``lambda``.
    """
    return _series(d_over_a, terms, "same")


def brenner_lambda(d_over_a: float, terms: int | None = None) -> float:
    """Drag factor of two equal spheres moving towards each other along their line of centres.

    The spheres move with equal and opposite velocities (``+U`` and ``-U``, approaching or
    receding); each feels ``F = 6 pi mu a U lambda``. The plane midway between the spheres is a
    plane of symmetry with zero normal velocity and zero shear stress, so this is Brenner's
    sphere moving normal to a plane free surface (Brenner, Chem. Eng. Sci. 16, 242-251, 1961,
    free-surface result; Maude, Br. J. Appl. Phys. 12, 293, 1961):

        lambda = (4/3) sinh(alpha) sum_{n>=1} n (n+1) / ((2n-1)(2n+3))
                 [(4 cosh^2((n+1/2) alpha) + (2n+1)^2 sinh^2 alpha)
                  / (2 sinh((2n+1) alpha) - (2n+1) sinh 2 alpha) - 1],

    with ``d = 2 a cosh(alpha)``. ``lambda > 1``, tends to 1 as ``d -> inf`` and grows like
    ``a / (2 h) + (9/20) log(a / h)`` as the gap ``h = d - 2 a`` closes (lubrication).

    Parameters
    ----------
    d_over_a, terms
        As for :func:`stimson_jeffery_lambda`; near contact the default takes about
        ``18 / alpha`` terms, ``alpha ~ sqrt(h / a)``.

    Returns
    -------
    float
        The drag factor ``lambda``.
    """
    return _series(d_over_a, terms, "opposite")


def mobility_functions_along_axis(d_over_a: float) -> tuple[float, float]:
    """Axial self- and pair-mobility functions ``(A11, A12)`` of two equal spheres.

    For forces ``F1``, ``F2`` along the line of centres the sphere velocities are
    ``U1 = (A11 F1 + A12 F2) / (6 pi mu a)`` and ``U2 = (A12 F1 + A11 F2) / (6 pi mu a)``
    (Batchelor 1976, J. Fluid Mech. 74, 1; ``x11a``, ``x12a`` of Jeffrey & Onishi 1984 for
    equal spheres). The two exact modes give

        A11 + A12 = 1 / lambda_SJ,     A11 - A12 = 1 / lambda_B.

    ``d_over_a`` is the centre distance over the radius (> 2); the result ``(A11, A12)`` is
    dimensionless, in units of ``1 / (6 pi mu a)``.
    """
    m_sum = 1.0 / stimson_jeffery_lambda(d_over_a)
    m_diff = 1.0 / brenner_lambda(d_over_a)
    return 0.5 * (m_sum + m_diff), 0.5 * (m_sum - m_diff)


def two_sphere_mobility_along_axis(d_over_a: float) -> tuple[float, float]:
    """Translational mobilities of the two axial modes of two equal spheres (``a = mu = 1``).

    Let ``M`` be the 6x6 translational mobility matrix of two spheres of radius 1 in fluid of
    viscosity 1, ``U_i = sum_j M_ij F_j``, and ``e`` the unit vector from sphere 1 to sphere 2,
    centre distance ``d``. Then, with ``M_ij^par = e . M_ij . e``,

    * ``m_together = e.M11.e + e.M12.e = 1 / (6 pi lambda_SJ)``: applying the forces
      ``F1 = F2 = F e`` moves both spheres with ``U = m_together F`` along ``e``
      (Stimson & Jeffery);
    * ``m_apart = e.M11.e - e.M12.e = 1 / (6 pi lambda_B)``: applying ``F1 = -F e``,
      ``F2 = +F e`` (pulling the spheres apart; the reverse pushes them together) moves them
      with ``U1 = -m_apart F e``, ``U2 = +m_apart F e`` (Brenner / Maude).

    Both follow from ``U = F / (6 pi mu a lambda)``; ``e.M11.e = (m_together + m_apart) / 2``
    and ``e.M12.e = (m_together - m_apart) / 2``.

    Parameters
    ----------
    d_over_a : float
        Centre distance over radius, > 2.

    Returns
    -------
    tuple of float
        ``(m_together, m_apart)`` for ``a = mu = 1``. For other values divide by ``mu a``.
    """
    return (
        1.0 / (6.0 * math.pi * stimson_jeffery_lambda(d_over_a)),
        1.0 / (6.0 * math.pi * brenner_lambda(d_over_a)),
    )


# --------------------------------------------------------------------------------------------
# Independent check 1: exact method of reflections with Sampson's stream-function expansion.
# --------------------------------------------------------------------------------------------


def _legendre_table(nmax: int, zeta: np.ndarray) -> np.ndarray:
    """Legendre polynomials ``P_0..P_nmax`` at ``zeta`` (rows), by the three-term recurrence."""
    p = np.empty((nmax + 1,) + zeta.shape)
    p[0] = 1.0
    if nmax >= 1:
        p[1] = zeta
    for k in range(1, nmax):
        p[k + 1] = ((2 * k + 1) * zeta * p[k] - k * p[k - 1]) / (k + 1)
    return p


def _gegenbauer_table(nmax: int, zeta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gegenbauer functions ``G_n = (P_{n-2} - P_n)/(2n-1)`` and ``dG_n/dzeta = -P_{n-1}``.

    Rows are ``n = 2..nmax``. ``G_2 = (1 - zeta^2)/2``; ``r^2 G_2`` is the stream function of a
    unit uniform stream along the axis, with ``u_r = -(1/r^2) dpsi/dzeta`` and
    ``u_theta = -(1/(r sin theta)) dpsi/dr``.
    """
    p = _legendre_table(nmax, zeta)
    n = np.arange(2, nmax + 1)
    g = (p[n - 2] - p[n]) / (2 * n - 1)[:, None]
    dg = -p[n - 1]
    return g, dg


class _ReflectionOperator:
    """Stream function of sphere ``j``'s singular expansion seen on the surface of sphere ``i``.

    Sampson's general axisymmetric Stokes stream function about a centre is
    ``sum_n (A_n r^n + B_n r^(1-n) + C_n r^(n+2) + D_n r^(3-n)) G_n(zeta)`` (Sampson 1891;
    Happel & Brenner 1965, ch. 4); the singular part about sphere ``j`` (``B_n``, ``D_n``) is evaluated with
    its radial derivative at Gauss-Legendre nodes on sphere ``i`` (radius 1, centre at axial
    offset ``offset`` from ``j``) and projected on ``G_n`` with the weight ``1 / (1 - zeta^2)``.
    """

    def __init__(self, offset: float, nmax: int, nodes: int) -> None:
        zeta, w = _legendre.leggauss(nodes)
        sin_t = np.sqrt(1.0 - zeta * zeta)
        z_rel = offset + zeta  # axial position of the node relative to centre j
        varpi = sin_t
        r = np.hypot(varpi, z_rel)
        zeta_j = z_rel / r
        g_j, dg_j = _gegenbauer_table(nmax, zeta_j)
        n = np.arange(2, nmax + 1)[:, None]
        self.nmax = nmax
        cols_val, cols_der = [], []
        for power in (1 - n, 3 - n):  # B_n then D_n
            val = r**power * g_j
            d_r = power * r ** (power - 1) * g_j
            d_zeta = r**power * dg_j
            d_z = d_r * zeta_j + d_zeta * varpi**2 / r**3
            d_varpi = d_r * varpi / r - d_zeta * z_rel * varpi / r**3
            cols_val.append(val)
            cols_der.append(d_z * zeta + d_varpi * sin_t)  # d/dr on sphere i
        g_i, _ = _gegenbauer_table(nmax, zeta)
        norm = (n * (n - 1) * (2 * n - 1) / 2.0) * g_i * (w / (1.0 - zeta * zeta))
        # projections: rows n (target), columns (B_2..B_N, D_2..D_N) of the source
        self.val = norm @ np.hstack([c.T for c in cols_val])
        self.der = norm @ np.hstack([c.T for c in cols_der])


def _solve_sphere(val: np.ndarray, der: np.ndarray, u: float) -> np.ndarray:
    """Singular coefficients ``(B_n, D_n)`` of a unit sphere moving with ``u`` in a given field.

    ``val``/``der`` are the ``G_n`` projections of the incident stream function and its radial
    derivative on the sphere; no slip requires total ``psi = u r^2 G_2`` and
    ``d psi/dr = 2 u r G_2`` at ``r = 1``, i.e. per ``n``:
    ``B + D = u delta_n2 - val_n`` and ``(1-n) B + (3-n) D = 2 u delta_n2 - der_n``.
    """
    nmax = val.shape[0] + 1
    n = np.arange(2, nmax + 1, dtype=float)
    rhs1 = -val.copy()
    rhs2 = -der.copy()
    rhs1[0] += u
    rhs2[0] += 2.0 * u
    # solve [[1, 1], [1-n, 3-n]] [B, D] = [rhs1, rhs2]; determinant 2
    d = (rhs2 - (1.0 - n) * rhs1) / 2.0
    b = rhs1 - d
    return np.concatenate([b, d])


def reflection_lambda(
    d_over_a: float,
    mode: str,
    nmax: int = 40,
    nodes: int = 96,
    tol: float = 1e-14,
    max_reflections: int = 500,
) -> float:
    """Drag factor of two equal spheres by the exact method of reflections (no bispherical series).

    Each sphere carries Sampson's singular stream-function expansion about its own centre
    (``B_n r^(1-n) + D_n r^(3-n)`` times ``G_n(zeta)``, ``n = 2..nmax``). Starting from the
    isolated translating spheres (Stokes' solution ``B_2 = -u/2``, ``D_2 = 3u/2``), each sphere
    in turn reflects the current field of the other so that no slip holds on its own surface
    (Jacobi iteration of the reflections) until the coefficients change by less than ``tol``.
    The force a sphere exerts on the fluid is ``4 pi mu D_2`` (its Stokeslet), so
    ``lambda = (2/3) D_2 / u`` for ``a = 1``.

    Parameters
    ----------
    d_over_a : float
        Centre distance over radius, > 2 (convergence slows near contact; use >= 2.2).
    mode : {"together", "apart"}
        ``"together"``: same velocity (Stimson-Jeffery); ``"apart"``: opposite velocities
        (Brenner / Maude).
    nmax : int
        Highest Gegenbauer order kept on each sphere.
    nodes : int
        Gauss-Legendre nodes on each sphere for the projections.
    tol : float
        Stopping tolerance on the change of all coefficients in one reflection.
    max_reflections : int
        Upper bound on the number of reflection sweeps.

    Returns
    -------
    float
        The drag factor ``lambda``.
    """
    s = float(d_over_a)
    alpha_from_distance(s)  # validates the distance
    if mode not in ("together", "apart"):
        raise ValueError(f"mode must be 'together' or 'apart', got {mode!r}")
    if nmax < 2 or nodes < nmax + 1:
        raise ValueError(
            f"need nmax >= 2 and nodes > nmax, got nmax={nmax}, nodes={nodes}"
        )
    u1 = 1.0
    u2 = 1.0 if mode == "together" else -1.0
    on2 = _ReflectionOperator(
        s, nmax, nodes
    )  # sphere 1's field on sphere 2 (2 is at +d)
    on1 = _ReflectionOperator(-s, nmax, nodes)  # sphere 2's field on sphere 1
    c1 = _solve_sphere(np.zeros(nmax - 1), np.zeros(nmax - 1), u1)
    c2 = _solve_sphere(np.zeros(nmax - 1), np.zeros(nmax - 1), u2)
    for _ in range(max_reflections):
        new1 = _solve_sphere(on1.val @ c2, on1.der @ c2, u1)
        new2 = _solve_sphere(on2.val @ c1, on2.der @ c1, u2)
        change = max(np.max(np.abs(new1 - c1)), np.max(np.abs(new2 - c2)))
        c1, c2 = new1, new2
        if change < tol:
            return float((2.0 / 3.0) * c1[nmax - 1] / u1)
    raise RuntimeError(
        f"reflections did not converge in {max_reflections} sweeps at d/a = {s}; "
        "increase max_reflections or the distance"
    )


# --------------------------------------------------------------------------------------------
# Independent check 2: far-field power series of the method of reflections.
# --------------------------------------------------------------------------------------------

# Axial mobility functions of two equal spheres in powers of x = a/d (method of reflections):
#   A11 = 1 - (15/4) x^4 + (11/2) x^6 + O(x^8)         (A11 is even in x)
#   A12 = (3/2) x - x^3 + 0 x^5 + (75/4) x^7 + O(x^9)  (A12 is odd in x)
# A12 to x^3 is the Faxen law applied to the Stokeslet + degenerate quadrupole of a translating
# sphere (Smoluchowski 1911; Rotne-Prager); -(15/4) x^4 is the stresslet induced on the other
# sphere (Batchelor 1976, J. Fluid Mech. 74, 1); the x^6 and x^7 terms are the
# lambda = 1 cases of x11a = 1 - 60 l^3/(1+l)^4 s^-4 + 32 l^3 (15 - 4 l^2)/(1+l)^6 s^-6 and
# x12a = (3/2) s^-1 - 2 (1+l^2)/(1+l)^2 s^-3 + 1200 l^3/(1+l)^6 s^-7 (Jeffrey & Onishi 1984,
# J. Fluid Mech. 139, 261, far-field mobility series; s = d/a for equal spheres). The test
# suite re-derives all of them numerically from reflection_lambda, which shares no formula
# with these coefficients.
_A11 = {0: (1, 1), 4: (-15, 4), 6: (11, 2)}
_A12 = {1: (3, 2), 3: (-1, 1), 5: (0, 1), 7: (75, 4)}
_FAR_FIELD_MAX_ORDER = 7


def far_field_coefficients(mode: str, order: int = 6) -> list:
    """Exact coefficients ``c_k`` of ``lambda = sum_k c_k (a/d)^k`` from the method of reflections.

    ``lambda = 1 / (A11 +- A12)`` (``+`` for ``"together"``, ``-`` for ``"apart"``) expanded in
    powers of ``x = a/d`` with the reflection series of the mobility functions listed in the
    module source (Smoluchowski; Batchelor 1976; Jeffrey & Onishi 1984). For ``"together"``
    this reproduces the classical reflection series (Happel & Brenner 1965, ch. 6)
    ``1 - 3/2 x + 9/4 x^2 - 19/8 x^3 + 93/16 x^4 - 387/32 x^5 + ...``.

    Parameters
    ----------
    mode : {"together", "apart"}
        Same velocities (Stimson-Jeffery) or opposite velocities (Brenner).
    order : int
        Highest power of ``a/d`` kept, 0..7.

    Returns
    -------
    list of fractions.Fraction
        ``[c_0, ..., c_order]``.
    """
    from fractions import Fraction

    if mode not in ("together", "apart"):
        raise ValueError(f"mode must be 'together' or 'apart', got {mode!r}")
    if (
        isinstance(order, bool)
        or not isinstance(order, (int, np.integer))
        or not (0 <= order <= _FAR_FIELD_MAX_ORDER)
    ):
        raise ValueError(
            f"order must be an integer in 0..{_FAR_FIELD_MAX_ORDER} (mobility coefficients are "
            f"known to (a/d)^{_FAR_FIELD_MAX_ORDER}), got {order!r}"
        )
    sign = 1 if mode == "together" else -1
    mob = [Fraction(0)] * (order + 1)
    for k, (p, q) in _A11.items():
        if k <= order:
            mob[k] += Fraction(p, q)
    for k, (p, q) in _A12.items():
        if k <= order:
            mob[k] += sign * Fraction(p, q)
    # reciprocal of a power series with mob[0] = 1: c_0 = 1, c_k = -sum_{j=1..k} mob[j] c_{k-j}
    coef = [Fraction(1)]
    for k in range(1, order + 1):
        coef.append(-sum(mob[j] * coef[k - j] for j in range(1, k + 1)))
    return coef


def far_field_lambda(d_over_a: float, mode: str, order: int = 6) -> float:
    """Drag factor from the method-of-reflections power series truncated at ``(a/d)^order``.

    Parameters
    ----------
    d_over_a : float
        Centre distance over radius, > 2 (the series is asymptotic for ``d >> a``).
    mode, order
        As for :func:`far_field_coefficients`.

    Returns
    -------
    float
        ``sum_{k <= order} c_k (a/d)^k`` with :func:`far_field_coefficients`.
    """
    alpha_from_distance(d_over_a)
    x = 1.0 / float(d_over_a)
    return float(
        sum(float(c) * x**k for k, c in enumerate(far_field_coefficients(mode, order)))
    )
