"""Solid harmonics and the exterior field of a sphere's single layer (compiled, numba).

Shared by the forward and the transposed kernels of the boundary-integral backend
(:mod:`kernels`, :mod:`kernels_adjoint`) and by the spherical-harmonic set-up
(:mod:`sphere_vsh`).

Everything here works on a *unit* sphere frame: a source sphere of centre ``c`` and
radius ``a`` is mapped to the unit sphere by ``xi = (x - c) / a``.  The single layer
of a traction density is then ``u(x) = (a / mu) u1(xi)`` while its stress (and
traction) is scale and viscosity free: ``stress(x) = stress1(xi)``.

Exterior fields are written with decaying solid harmonics
``I_l^m(x) = (l - m)! P_l^m(cos theta) exp(i m phi) / r^(l+1)`` (Condon-Shortley
phase), which obey the ladder relations

    d/dz I_l^m = -I_{l+1}^m,  (d/dx + i d/dy) I_l^m = I_{l+1}^{m+1},
    (d/dx - i d/dy) I_l^m = -I_{l+1}^{m-1},

so gradients and Hessians of every harmonic are again harmonics of degree
``l + 1`` and ``l + 2``.  With ``phi_nm = r^(-n-1) Y_n^m`` the single layer of a
vector-spherical-harmonic density on the unit sphere is (Corona & Veerapaneni,
JCP 2018, rewritten with Lamb's general solution)::

    V_n -> n/((2n+1)(2n+3)) grad phi
    W_n -> n/(4n+2) grad phi + n (alpha_n r^2 grad phi + beta_n x phi),  pressure n phi
    X_n -> 1/(2n+1) x cross grad phi

with ``alpha_n = -(n-2)/(2n(2n-1))`` and ``beta_n = (n+1)/(n(2n-1))``.  The
caller folds these factors into five complex coefficient sets per sphere
(``D[j, f, n, m]`` for f = Phi, chi, P_alpha, P_beta, P) so that the real
field is ``Re sum_{n, m >= 0} D[f, n, m] * (...)``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["solid_harmonics", "derivatives", "vsh_at", "cross_gradient",
           "field_buffers", "unit_field"]


@njit(cache=True, fastmath=False)
def solid_harmonics(x: float, y: float, z: float, L: int, out: np.ndarray) -> None:
    """Fill ``out[l, m]`` (0 <= m <= l <= L) with ``I_l^m`` at the point (x, y, z)."""
    r2 = x * x + y * y + z * z
    inv_r2 = 1.0 / r2
    out[0, 0] = 1.0 / np.sqrt(r2)
    xy = complex(x, y)
    for m in range(1, L + 1):
        out[m, m] = -(2 * m - 1) * xy * inv_r2 * out[m - 1, m - 1]
    for m in range(0, L + 1):
        if m + 1 <= L:
            out[m + 1, m] = (2 * m + 1) * z * out[m, m] * inv_r2
        for l in range(m + 1, L):
            out[l + 1, m] = ((2 * l + 1) * z * out[l, m]
                             - (l * l - m * m) * out[l - 1, m]) * inv_r2


@njit(cache=True, fastmath=False)
def _get(I: np.ndarray, l: int, m: int) -> complex:
    """``I_l^m`` for any integer m, using ``I_l^{-m} = (-1)^m conj(I_l^m)``."""
    if m >= 0:
        if m > l:
            return 0j
        return I[l, m]
    mm = -m
    if mm > l:
        return 0j
    v = I[l, mm].conjugate()
    if mm % 2 == 1:
        return -v
    return v


@njit(cache=True, fastmath=False)
def derivatives(I: np.ndarray, n: int, m: int) -> tuple:
    """Gradient ``(g0, g1, g2)`` and packed Hessian ``(xx, yy, zz, xy, xz, yz)`` of the
    solid harmonic ``I_n^m`` from the table ``I`` (degrees up to n + 2)."""
    ip = _get(I, n + 1, m + 1)
    im = _get(I, n + 1, m - 1)
    a2 = _get(I, n + 2, m + 2)
    a1 = _get(I, n + 2, m + 1)
    a0 = I[n + 2, m]
    b1 = _get(I, n + 2, m - 1)
    b2 = _get(I, n + 2, m - 2)
    return (0.5 * (ip - im), -0.5j * (ip + im), -I[n + 1, m],
            0.25 * (a2 - 2.0 * a0 + b2), -0.25 * (a2 + 2.0 * a0 + b2), a0,
            -0.25j * (a2 - b2), 0.5 * (b1 - a1), 0.5j * (a1 + b1))


@njit(cache=True, fastmath=False)
def vsh_at(xh: np.ndarray, p: int, knm: np.ndarray, Y: np.ndarray, V: np.ndarray) -> None:
    """Orthonormal ``Y_n^m`` and ``V_n^m = grad(r^(-n-1) Y_n^m)`` at a unit vector.

    Parameters
    ----------
    xh : ndarray, shape (3,)
        Point on the unit sphere.
    p : int
        Maximum degree.
    knm : ndarray, shape (p+1, p+1)
        ``K_nm`` such that ``r^(-n-1) Y_n^m = K_nm I_n^m``.
    Y : complex ndarray, shape (p+1, p+1)
        Output ``Y_n^m`` (m >= 0).
    V : complex ndarray, shape (p+1, p+1, 3)
        Output Cartesian components of ``V_n^m`` on the unit sphere.
    """
    I = np.zeros((p + 2, p + 2), dtype=np.complex128)
    solid_harmonics(xh[0], xh[1], xh[2], p + 1, I)
    for n in range(p + 1):
        for m in range(n + 1):
            k = knm[n, m]
            Y[n, m] = k * I[n, m]
            ip = _get(I, n + 1, m + 1)
            im = _get(I, n + 1, m - 1)
            V[n, m, 0] = k * 0.5 * (ip - im)
            V[n, m, 1] = k * (-0.5j) * (ip + im)
            V[n, m, 2] = -k * I[n + 1, m]


@njit(cache=True, fastmath=False)
def _sym3(h: np.ndarray) -> np.ndarray:
    """Real symmetric 3x3 matrix from packed (xx, yy, zz, xy, xz, yz) complex sums."""
    H = np.empty((3, 3))
    H[0, 0] = h[0].real
    H[1, 1] = h[1].real
    H[2, 2] = h[2].real
    H[0, 1] = h[3].real
    H[1, 0] = h[3].real
    H[0, 2] = h[4].real
    H[2, 0] = h[4].real
    H[1, 2] = h[5].real
    H[2, 1] = h[5].real
    return H


@njit(cache=True, fastmath=False)
def cross_gradient(x, H: np.ndarray, g: np.ndarray, i: int, j: int):
    """``d/dx_j`` of ``(x cross grad chi)_i`` at the point ``x``, from the gradient ``g``
    and Hessian ``H`` of chi: ``eps_ijl g_l + x_i1 H_i2,j - x_i2 H_i1,j`` (real or complex)."""
    i1 = (i + 1) % 3
    i2 = (i + 2) % 3
    val = x[i1] * H[i2, j] - x[i2] * H[i1, j]
    if j == i1:
        val += g[i2]
    elif j == i2:
        val -= g[i1]
    return val


@njit(cache=True, fastmath=False)
def field_buffers(p: int) -> tuple:
    """Zeroed work arrays of one evaluation of :func:`unit_field` (or of its transpose) at
    degree p: the harmonic table (p+3, p+3), a point, a vector, a 3 x 3 matrix and a
    vector (the roles of ``xi, u, G, gP``)."""
    return (np.zeros((p + 3, p + 3), dtype=np.complex128), np.zeros(3), np.zeros(3),
            np.zeros((3, 3)), np.zeros(3))


@njit(cache=True, fastmath=False)
def _accumulate(D: np.ndarray, p: int, I: np.ndarray, gF: np.ndarray, hF: np.ndarray,
                gC: np.ndarray, hC: np.ndarray, gA: np.ndarray, hA: np.ndarray,
                gB: np.ndarray, gPc: np.ndarray) -> tuple:
    """The sums of :func:`unit_field` over the degrees and orders: adds the gradients and
    Hessians of the solid harmonics weighted by the folded coefficients ``D`` to the
    accumulators, and returns the values ``(sum D_beta I, sum D_P I)``."""
    vB = 0j
    vP = 0j
    for n in range(p + 1):
        for m in range(n + 1):
            dF = D[0, n, m]
            dC = D[1, n, m]
            dA = D[2, n, m]
            dB = D[3, n, m]
            dP = D[4, n, m]
            g0, g1, g2, hxx, hyy, hzz, hxy, hxz, hyz = derivatives(I, n, m)
            gF[0] += dF * g0
            gF[1] += dF * g1
            gF[2] += dF * g2
            gC[0] += dC * g0
            gC[1] += dC * g1
            gC[2] += dC * g2
            gA[0] += dA * g0
            gA[1] += dA * g1
            gA[2] += dA * g2
            gB[0] += dB * g0
            gB[1] += dB * g1
            gB[2] += dB * g2
            gPc[0] += dP * g0
            gPc[1] += dP * g1
            gPc[2] += dP * g2
            v = I[n, m]
            vB += dB * v
            vP += dP * v
            hF[0] += dF * hxx
            hF[1] += dF * hyy
            hF[2] += dF * hzz
            hF[3] += dF * hxy
            hF[4] += dF * hxz
            hF[5] += dF * hyz
            hC[0] += dC * hxx
            hC[1] += dC * hyy
            hC[2] += dC * hzz
            hC[3] += dC * hxy
            hC[4] += dC * hxz
            hC[5] += dC * hyz
            hA[0] += dA * hxx
            hA[1] += dA * hyy
            hA[2] += dA * hzz
            hA[3] += dA * hxy
            hA[4] += dA * hxz
            hA[5] += dA * hyz
    return vB, vP


@njit(cache=True, fastmath=False)
def unit_field(xi: np.ndarray, D: np.ndarray, p: int, I: np.ndarray,
               u: np.ndarray, G: np.ndarray, gP: np.ndarray) -> float:
    """Velocity, velocity gradient and pressure of a unit-sphere single layer.

    Parameters
    ----------
    xi : ndarray, shape (3,)
        Evaluation point, ``|xi| > 1``.
    D : complex ndarray, shape (5, p+1, p+1)
        Folded coefficients (Phi, chi, P_alpha, P_beta, P), already multiplied by
        ``K_nm``.
    p : int
        Degree of the density.
    I : complex ndarray, shape (>= p+3, >= p+3)
        Work buffer for the solid harmonics.
    u, G, gP : ndarray, shapes (3,), (3, 3), (3,)
        Outputs: velocity (mu = 1), ``G[i, j] = d u_i / d x_j`` and the pressure
        gradient.

    Returns
    -------
    float
        The pressure (mu = 1).
    """
    solid_harmonics(xi[0], xi[1], xi[2], p + 2, I)
    # accumulators: gradients (3) and Hessians (xx, yy, zz, xy, xz, yz)
    gF = np.zeros(3, dtype=np.complex128)
    hF = np.zeros(6, dtype=np.complex128)
    gC = np.zeros(3, dtype=np.complex128)
    hC = np.zeros(6, dtype=np.complex128)
    gA = np.zeros(3, dtype=np.complex128)
    hA = np.zeros(6, dtype=np.complex128)
    gB = np.zeros(3, dtype=np.complex128)
    gPc = np.zeros(3, dtype=np.complex128)
    vB, vP = _accumulate(D, p, I, gF, hF, gC, hC, gA, hA, gB, gPc)
    x0 = xi[0]
    x1 = xi[1]
    x2 = xi[2]
    r2 = x0 * x0 + x1 * x1 + x2 * x2
    Fg = np.empty(3)
    Cg = np.empty(3)
    Ag = np.empty(3)
    Bg = np.empty(3)
    for k in range(3):
        Fg[k] = gF[k].real
        Cg[k] = gC[k].real
        Ag[k] = gA[k].real
        Bg[k] = gB[k].real
        gP[k] = gPc[k].real
    HF = _sym3(hF)
    HC = _sym3(hC)
    HA = _sym3(hA)
    Bv = vB.real
    # u = grad Phi + x cross grad chi + r^2 grad P_alpha + x P_beta
    u[0] = Fg[0] + (x1 * Cg[2] - x2 * Cg[1]) + r2 * Ag[0] + x0 * Bv
    u[1] = Fg[1] + (x2 * Cg[0] - x0 * Cg[2]) + r2 * Ag[1] + x1 * Bv
    u[2] = Fg[2] + (x0 * Cg[1] - x1 * Cg[0]) + r2 * Ag[2] + x2 * Bv
    xs = (x0, x1, x2)
    for i in range(3):
        for j in range(3):
            cross = cross_gradient(xs, HC, Cg, i, j)
            val = HF[i, j] + cross + 2.0 * xs[j] * Ag[i] + r2 * HA[i, j] + xs[i] * Bg[j]
            if i == j:
                val += Bv
            G[i, j] = val
    return vP.real
