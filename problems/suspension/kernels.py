"""Compiled (numba) kernels of the boundary-integral Stokes backend.

Everything here works on a *unit* sphere frame unless stated: a source
sphere of centre ``c`` and radius ``a`` is mapped to the unit sphere by
``xi = (x - c) / a``.  The single layer of a traction density is then
``u(x) = (a / mu) u1(xi)`` while its stress (and traction) is scale and
viscosity free: ``stress(x) = stress1(xi)``.

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
from numba import njit, prange

__all__ = ["solid_harmonics", "vsh_at", "unit_field", "traction_expansion",
           "center_readout", "direct_traction_ranges",
           "direct_traction_skip", "rows_times", "apply_blocks", "synthesize_forces",
           "orthogonalize", "combine_rows", "rows_times_serial", "apply_blocks_serial",
           "synthesize_forces_serial", "direct_traction_ranges_serial", "traction_response_batch",
           "unit_field_adjoint", "traction_expansion_adjoint", "center_readout_adjoint",
           "direct_traction_adjoint", "direct_traction_adjoint_serial",
           "direct_traction_adjoint_skip", "apply_blocks_adjoint",
           "apply_blocks_adjoint_serial"]

_FOUR_PI = 4.0 * np.pi


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
def _derivatives(I: np.ndarray, n: int, m: int) -> tuple:
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
    vB = 0j
    vP = 0j
    for n in range(p + 1):
        for m in range(n + 1):
            dF = D[0, n, m]
            dC = D[1, n, m]
            dA = D[2, n, m]
            dB = D[3, n, m]
            dP = D[4, n, m]
            g0, g1, g2, hxx, hyy, hzz, hxy, hxz, hyz = _derivatives(I, n, m)
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
        i1 = (i + 1) % 3
        i2 = (i + 2) % 3
        for j in range(3):
            # d/dx_j of (x cross grad chi)_i = eps_ijl dchi_l + x_i1 H_i2,j - x_i2 H_i1,j
            cross = xs[i1] * HC[i2, j] - xs[i2] * HC[i1, j]
            if j == i1:
                cross += Cg[i2]
            elif j == i2:
                cross -= Cg[i1]
            val = HF[i, j] + cross + 2.0 * xs[j] * Ag[i] + r2 * HA[i, j] + xs[i] * Bg[j]
            if i == j:
                val += Bv
            G[i, j] = val
    return vP.real


@njit(parallel=True, fastmath=False, cache=True)
def traction_expansion(tgt_pts: np.ndarray, tgt_nrm: np.ndarray, tgt_sphere: np.ndarray,
                       nbr_ptr: np.ndarray, nbr_idx: np.ndarray, centers: np.ndarray,
                       radii: np.ndarray, D: np.ndarray, p: int, out: np.ndarray) -> None:
    """Add to ``out[t]`` the traction (normal ``tgt_nrm[t]``) at ``tgt_pts[t]`` of the
    single layers of the spheres ``nbr_idx[nbr_ptr[i]:nbr_ptr[i+1]]``, i = tgt_sphere[t],
    evaluated with their exact exterior expansions."""
    T = tgt_pts.shape[0]
    for t in prange(T):
        i = tgt_sphere[t]
        I = np.empty((p + 3, p + 3), dtype=np.complex128)
        xi = np.empty(3)
        u = np.empty(3)
        G = np.empty((3, 3))
        gP = np.empty(3)
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        n0 = tgt_nrm[t, 0]
        n1 = tgt_nrm[t, 1]
        n2 = tgt_nrm[t, 2]
        for k in range(nbr_ptr[i], nbr_ptr[i + 1]):
            j = nbr_idx[k]
            inv_a = 1.0 / radii[j]
            for c in range(3):
                xi[c] = (tgt_pts[t, c] - centers[j, c]) * inv_a
            P = unit_field(xi, D[j], p, I, u, G, gP)
            s00 = -P + 2.0 * G[0, 0]
            s11 = -P + 2.0 * G[1, 1]
            s22 = -P + 2.0 * G[2, 2]
            s01 = G[0, 1] + G[1, 0]
            s02 = G[0, 2] + G[2, 0]
            s12 = G[1, 2] + G[2, 1]
            f0 += s00 * n0 + s01 * n1 + s02 * n2
            f1 += s01 * n0 + s11 * n1 + s12 * n2
            f2 += s02 * n0 + s12 * n1 + s22 * n2
        out[t, 0] += f0
        out[t, 1] += f1
        out[t, 2] += f2


@njit(parallel=True, fastmath=False, cache=True)
def center_readout(centers: np.ndarray, radii: np.ndarray, D: np.ndarray, p: int,
                   mu: float, out: np.ndarray) -> None:
    """Add to ``out[i]`` the rigid velocity (U, Omega) that the single layers of all
    other spheres induce on sphere i, read off exactly with Faxen's laws:
    U = u(c) + a^2/6 lap u(c) (the surface mean) and Omega = curl u(c) / 2
    (equal to 3/(8 pi a^4) times the integral of (y - c) x u)."""
    M = centers.shape[0]
    for i in prange(M):
        I = np.empty((p + 3, p + 3), dtype=np.complex128)
        xi = np.empty(3)
        u = np.empty(3)
        G = np.empty((3, 3))
        gP = np.empty(3)
        acc = np.zeros(6)
        for j in range(M):
            if j == i:
                continue
            aj = radii[j]
            for c in range(3):
                xi[c] = (centers[i, c] - centers[j, c]) / aj
            unit_field(xi, D[j], p, I, u, G, gP)
            fac = (radii[i] / aj) ** 2 / 6.0
            for c in range(3):
                acc[c] += aj / mu * (u[c] + fac * gP[c])
            acc[3] += 0.5 / mu * (G[2, 1] - G[1, 2])
            acc[4] += 0.5 / mu * (G[0, 2] - G[2, 0])
            acc[5] += 0.5 / mu * (G[1, 0] - G[0, 1])
        for c in range(6):
            out[i, c] += acc[c]


@njit(cache=True, fastmath=False)
def _response_at(x: np.ndarray, nv: np.ndarray, p: int, fac: np.ndarray,
                 out_t: np.ndarray) -> None:
    """Traction (normal ``nv``) at the unit-frame point ``x`` of every unit VSH
    coefficient: ``out_t[kind, n, m, :]`` (see :func:`traction_response`)."""
    I = np.empty((p + 3, p + 3), dtype=np.complex128)
    solid_harmonics(x[0], x[1], x[2], p + 2, I)
    r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
    xn = x[0] * nv[0] + x[1] * nv[1] + x[2] * nv[2]
    g = np.empty(3, dtype=np.complex128)
    H = np.empty((3, 3), dtype=np.complex128)
    tf = np.empty((5, 3), dtype=np.complex128)
    Gc = np.empty((3, 3), dtype=np.complex128)
    for n in range(p + 1):
        for m in range(n + 1):
            g[0], g[1], g[2], H[0, 0], H[1, 1], H[2, 2], H[0, 1], H[0, 2], H[1, 2] = \
                _derivatives(I, n, m)
            H[1, 0] = H[0, 1]
            H[2, 0] = H[0, 2]
            H[2, 1] = H[1, 2]
            v = I[n, m]
            gn = g[0] * nv[0] + g[1] * nv[1] + g[2] * nv[2]
            for i in range(3):
                Hn_i = H[i, 0] * nv[0] + H[i, 1] * nv[1] + H[i, 2] * nv[2]
                # Phi: G = H
                tf[0, i] = 2.0 * Hn_i
                # P_alpha: G_ij = 2 x_j g_i + r^2 H_ij
                tf[2, i] = 2.0 * g[i] * xn + 2.0 * x[i] * gn + 2.0 * r2 * Hn_i
                # P_beta: G_ij = delta_ij v + x_i g_j
                tf[3, i] = 2.0 * v * nv[i] + x[i] * gn + g[i] * xn
                # P: pressure v
                tf[4, i] = -v * nv[i]
            # chi: G_ij = eps_ijl g_l + (x cross H_{:, j})_i ; traction (G + G^T) n
            for i in range(3):
                i1 = (i + 1) % 3
                i2 = (i + 2) % 3
                for j in range(3):
                    val = x[i1] * H[i2, j] - x[i2] * H[i1, j]
                    if j == i1:
                        val += g[i2]
                    elif j == i2:
                        val -= g[i1]
                    Gc[i, j] = val
            for i in range(3):
                tf[1, i] = ((Gc[i, 0] + Gc[0, i]) * nv[0] + (Gc[i, 1] + Gc[1, i]) * nv[1]
                            + (Gc[i, 2] + Gc[2, i]) * nv[2])
            for k in range(3):
                for i in range(3):
                    acc = 0j
                    for f in range(5):
                        acc += fac[f, k, n, m] * tf[f, i]
                    out_t[k, n, m, i] = acc


@njit(parallel=True, fastmath=False, cache=True)
def traction_response(tgt_pts: np.ndarray, tgt_nrm: np.ndarray, center: np.ndarray,
                      radius: float, p: int, fac: np.ndarray, out: np.ndarray) -> None:
    """Traction at each target of the single layer of every complex VSH coefficient.

    ``out[t, kind, n, m, :]`` is the complex traction (normal ``tgt_nrm[t]``) at
    ``tgt_pts[t]`` of the unit-coefficient density ``C[kind, n, m] = 1`` on the
    sphere (``center``, ``radius``); ``fac`` (5, 3, p+1, p+1) folds C into the
    harmonics Phi, chi, P_alpha, P_beta and P.  The real traction of a density
    is ``Re sum C * out``.  Used to build the dense near-field blocks.
    """
    T = tgt_pts.shape[0]
    for t in prange(T):
        x = np.empty(3)
        for c in range(3):
            x[c] = (tgt_pts[t, c] - center[c]) / radius
        _response_at(x, tgt_nrm[t], p, fac, out[t])


@njit(parallel=True, fastmath=False, cache=True)
def traction_response_batch(tgt_pts: np.ndarray, tgt_nrm: np.ndarray, centers: np.ndarray,
                            radii: np.ndarray, p: int, fac: np.ndarray, out: np.ndarray) -> None:
    """As :func:`traction_response` with one source sphere (``centers[t]``, ``radii[t]``)
    per target, so that many near-field blocks are built in one parallel call."""
    T = tgt_pts.shape[0]
    for t in prange(T):
        x = np.empty(3)
        for c in range(3):
            x[c] = (tgt_pts[t, c] - centers[t, c]) / radii[t]
        _response_at(x, tgt_nrm[t], p, fac, out[t])


def _direct_traction_ranges_impl(tgt_pts: np.ndarray, tgt_nrm: np.ndarray, tgt_sphere: np.ndarray,
                           pair_ptr: np.ndarray, src_start: np.ndarray, src_stop: np.ndarray,
                           src_x: np.ndarray, src_y: np.ndarray, src_z: np.ndarray,
                           src_fx: np.ndarray, src_fy: np.ndarray, src_fz: np.ndarray,
                           out: np.ndarray, skip: bool) -> None:
    """Add to ``out[t]`` the traction of point forces by direct summation (vectorised).

    Target ``t`` on sphere ``i = tgt_sphere[t]`` receives the point forces
    ``src_f*[s]`` at ``src_*[s]`` for ``s`` in ``range(src_start[k], src_stop[k])``,
    ``k`` in ``range(pair_ptr[i], pair_ptr[i+1])``: one contiguous source range per
    interacting sphere (its quadrature nodes at the grid order chosen for the
    pair, density times weight already folded in).  Sources are stored as
    separate coordinate arrays so that the inner loop is a SIMD reduction.
    Sources must not coincide with targets, unless ``skip`` (the build
    :func:`direct_traction_skip`, without fastmath): then coinciding sources are left
    out, the convention of point-source FMMs whose near part it removes.
    """
    T = tgt_pts.shape[0]
    c0 = -3.0 / _FOUR_PI
    for t in prange(T):
        i = tgt_sphere[t]
        x0 = tgt_pts[t, 0]
        x1 = tgt_pts[t, 1]
        x2 = tgt_pts[t, 2]
        n0 = tgt_nrm[t, 0]
        n1 = tgt_nrm[t, 1]
        n2 = tgt_nrm[t, 2]
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        for k in range(pair_ptr[i], pair_ptr[i + 1]):
            for s in range(src_start[k], src_stop[k]):
                r0 = x0 - src_x[s]
                r1 = x1 - src_y[s]
                r2 = x2 - src_z[s]
                rr = r0 * r0 + r1 * r1 + r2 * r2
                if skip and rr == 0.0:
                    continue
                inv = 1.0 / np.sqrt(rr)
                inv2 = inv * inv
                rf = r0 * src_fx[s] + r1 * src_fy[s] + r2 * src_fz[s]
                rn = r0 * n0 + r1 * n1 + r2 * n2
                w = c0 * rf * rn * inv2 * inv2 * inv
                f0 += w * r0
                f1 += w * r1
                f2 += w * r2
        out[t, 0] += f0
        out[t, 1] += f1
        out[t, 2] += f2


# ---- small dense products of the BIM operator, kept out of BLAS --------------------------
# The BIM product alternates numba-parallel sums with small dense products; on few cores
# BLAS threads and numba threads then spin against each other (measured: a 27 x 432 x 432
# product 100x slower right after a parallel numba call).  These loops avoid that.

def _rows_times_impl(X: np.ndarray, W: np.ndarray, out: np.ndarray) -> None:
    """``out[r] += X[r] @ W`` for every row r (parallel over rows)."""
    R, n = X.shape
    m = W.shape[1]
    for r in prange(R):
        acc = np.zeros(m)
        for k in range(n):
            x = X[r, k]
            if x != 0.0:
                for j in range(m):
                    acc[j] += x * W[k, j]
        for j in range(m):
            out[r, j] += acc[j]


def _apply_blocks_impl(E: np.ndarray, tgt_ptr: np.ndarray, src: np.ndarray, coef: np.ndarray,
                 out: np.ndarray) -> None:
    """``out[i] += sum_k E[k] @ coef[src[k]]`` over the blocks ``k`` in
    ``range(tgt_ptr[i], tgt_ptr[i+1])`` (blocks sorted by target sphere i)."""
    M = tgt_ptr.size - 1
    rows = E.shape[1]
    nv = E.shape[2]
    for i in prange(M):
        acc = np.zeros(rows)
        for k in range(tgt_ptr[i], tgt_ptr[i + 1]):
            c = coef[src[k]]
            for a in range(rows):
                s = 0.0
                for b in range(nv):
                    s += E[k, a, b] * c[b]
                acc[a] += s
        for a in range(rows):
            out[i, a] += acc[a]


def _synthesize_forces_impl(coef: np.ndarray, spheres: np.ndarray, BT: np.ndarray,
                      scale: np.ndarray, base: int, fx: np.ndarray, fy: np.ndarray,
                      fz: np.ndarray) -> None:
    """Point forces on a source grid from VSH coefficients: for the k-th sphere
    ``j = spheres[k]``, ``f = (coef[j] @ BT) * scale[k]`` (node-major xyz, ``nq`` nodes)
    written to ``f*[base + k nq + node]``."""
    K = spheres.size
    nv, m = BT.shape
    nq = m // 3
    for k in prange(K):
        j = spheres[k]
        acc = np.zeros(m)
        for b in range(nv):
            c = coef[j, b]
            for a in range(m):
                acc[a] += c * BT[b, a]
        o = base + k * nq
        for node in range(nq):
            w = scale[k, node]
            fx[o + node] = acc[3 * node] * w
            fy[o + node] = acc[3 * node + 1] * w
            fz[o + node] = acc[3 * node + 2] * w


@njit(cache=True, fastmath=False)
def orthogonalize(V: np.ndarray, k: int, w: np.ndarray, h: np.ndarray) -> float:
    """Classical Gram-Schmidt, applied twice, of ``w`` against the rows ``V[:k]``
    (in place); ``h[:k]`` receives the projections and the norm of the result is
    returned.  Serial on purpose: GMRES vector work stays off BLAS threads."""
    n = w.size
    for j in range(k):
        h[j] = 0.0
    for _ in range(2):
        for j in range(k):
            c = 0.0
            for t in range(n):
                c += V[j, t] * w[t]
            h[j] += c
            for t in range(n):
                w[t] -= c * V[j, t]
    s = 0.0
    for t in range(n):
        s += w[t] * w[t]
    return np.sqrt(s)


@njit(cache=True, fastmath=False)
def combine_rows(V: np.ndarray, y: np.ndarray, x: np.ndarray) -> None:
    """``x += y @ V[:y.size]`` (serial)."""
    n = x.size
    for j in range(y.size):
        c = y[j]
        for t in range(n):
            x[t] += c * V[j, t]


# Parallel and serial builds of the same loops: a parallel launch costs milliseconds on a
# loaded machine, so small products (few spheres, low p) run serially.
rows_times = njit(parallel=True, fastmath=True, cache=True)(_rows_times_impl)
rows_times_serial = njit(fastmath=True, cache=True)(_rows_times_impl)
apply_blocks = njit(parallel=True, fastmath=True, cache=True)(_apply_blocks_impl)
apply_blocks_serial = njit(fastmath=True, cache=True)(_apply_blocks_impl)
synthesize_forces = njit(parallel=True, fastmath=True, cache=True)(_synthesize_forces_impl)
synthesize_forces_serial = njit(fastmath=True, cache=True)(_synthesize_forces_impl)
direct_traction_ranges = njit(parallel=True, fastmath=True, cache=True)(_direct_traction_ranges_impl)
direct_traction_ranges_serial = njit(fastmath=True, cache=True)(_direct_traction_ranges_impl)
direct_traction_skip = njit(parallel=True, fastmath=False, cache=True)(_direct_traction_ranges_impl)


# ---- transposed (adjoint) kernels ------------------------------------------------------------
# The discrete mobility is only nearly symmetric, so the exact transpose of every linear piece
# of the forward product is needed (BimMobility.rmatvec).  The expansion pieces are linear in
# the folded coefficients D (complex, the real field being Re sum D * harmonics); their adjoint
# returns Dbar with sum(w * output) = Re sum(D * Dbar) (a bilinear, not Hermitian, pairing),
# and the caller maps Dbar back to grid densities with the coefficient matrix.

@njit(cache=True, fastmath=False)
def unit_field_adjoint(xi: np.ndarray, p: int, I: np.ndarray, wu: np.ndarray, wG: np.ndarray,
                       wgP: np.ndarray, wP: float, Dbar: np.ndarray) -> None:
    """Transpose of :func:`unit_field` with respect to its coefficients ``D``.

    Adds to ``Dbar`` (complex, shape (5, p+1, p+1)) the coefficients such that
    ``Re sum(D * Dbar) = wu . u + sum(wG * G) + wgP . gP + wP * P`` for every ``D``, where
    ``u, G, gP, P`` are the outputs of ``unit_field(xi, D, p, ...)``.
    """
    solid_harmonics(xi[0], xi[1], xi[2], p + 2, I)
    x = (xi[0], xi[1], xi[2])
    r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2]
    # adjoints of the real aggregates of unit_field
    Fb = np.empty(3)
    Cb = np.empty(3)
    Ab = np.empty(3)
    Bb = np.zeros(3)
    HFb = np.empty((3, 3))
    HCb = np.zeros((3, 3))
    HAb = np.empty((3, 3))
    for i in range(3):
        Fb[i] = wu[i]
        Ab[i] = r2 * wu[i]
    # (x cross Cg) . wu = Cg . (wu cross x)
    Cb[0] = wu[1] * x[2] - wu[2] * x[1]
    Cb[1] = wu[2] * x[0] - wu[0] * x[2]
    Cb[2] = wu[0] * x[1] - wu[1] * x[0]
    Bv = wu[0] * x[0] + wu[1] * x[1] + wu[2] * x[2]
    for i in range(3):
        i1 = (i + 1) % 3
        i2 = (i + 2) % 3
        for j in range(3):
            w = wG[i, j]
            HFb[i, j] = w
            HAb[i, j] = r2 * w
            HCb[i2, j] += x[i1] * w
            HCb[i1, j] -= x[i2] * w
            if j == i1:
                Cb[i2] += w
            elif j == i2:
                Cb[i1] -= w
            Ab[i] += 2.0 * x[j] * w
            Bb[j] += x[i] * w
        Bv += wG[i, i]
    # packed Hessian adjoints (xx, yy, zz, xy, xz, yz)
    hF = np.empty(6)
    hC = np.empty(6)
    hA = np.empty(6)
    for H, h in ((HFb, hF), (HCb, hC), (HAb, hA)):
        h[0] = H[0, 0]
        h[1] = H[1, 1]
        h[2] = H[2, 2]
        h[3] = H[0, 1] + H[1, 0]
        h[4] = H[0, 2] + H[2, 0]
        h[5] = H[1, 2] + H[2, 1]
    for n in range(p + 1):
        for m in range(n + 1):
            g0, g1, g2, hxx, hyy, hzz, hxy, hxz, hyz = _derivatives(I, n, m)
            v = I[n, m]
            Dbar[0, n, m] += (Fb[0] * g0 + Fb[1] * g1 + Fb[2] * g2
                              + hF[0] * hxx + hF[1] * hyy + hF[2] * hzz
                              + hF[3] * hxy + hF[4] * hxz + hF[5] * hyz)
            Dbar[1, n, m] += (Cb[0] * g0 + Cb[1] * g1 + Cb[2] * g2
                              + hC[0] * hxx + hC[1] * hyy + hC[2] * hzz
                              + hC[3] * hxy + hC[4] * hxz + hC[5] * hyz)
            Dbar[2, n, m] += (Ab[0] * g0 + Ab[1] * g1 + Ab[2] * g2
                              + hA[0] * hxx + hA[1] * hyy + hA[2] * hzz
                              + hA[3] * hxy + hA[4] * hxz + hA[5] * hyz)
            Dbar[3, n, m] += Bb[0] * g0 + Bb[1] * g1 + Bb[2] * g2 + Bv * v
            Dbar[4, n, m] += wgP[0] * g0 + wgP[1] * g1 + wgP[2] * g2 + wP * v


@njit(parallel=True, fastmath=False, cache=True)
def traction_expansion_adjoint(tgt_pts: np.ndarray, tgt_nrm: np.ndarray, blk_size: int,
                               src_ptr: np.ndarray, src_blk: np.ndarray, centers: np.ndarray,
                               radii: np.ndarray, trac_bar: np.ndarray, p: int,
                               Dbar: np.ndarray) -> None:
    """Transpose of :func:`traction_expansion`.

    Targets come in blocks of ``blk_size`` consecutive points (one block per target
    sphere); source sphere j is seen by the blocks ``src_blk[src_ptr[j]:src_ptr[j+1]]``.
    Adds to ``Dbar[j]`` (complex, (5, p+1, p+1)) the adjoint coefficients of the
    tractions weighted by ``trac_bar`` (parallel over source spheres, no races).
    """
    M = src_ptr.size - 1
    for j in prange(M):
        I = np.empty((p + 3, p + 3), dtype=np.complex128)
        xi = np.empty(3)
        wu = np.zeros(3)
        wgP = np.zeros(3)
        wG = np.empty((3, 3))
        inv_a = 1.0 / radii[j]
        for k in range(src_ptr[j], src_ptr[j + 1]):
            b = src_blk[k]
            for t in range(b * blk_size, (b + 1) * blk_size):
                for c in range(3):
                    xi[c] = (tgt_pts[t, c] - centers[j, c]) * inv_a
                nv0 = tgt_nrm[t, 0]
                nv1 = tgt_nrm[t, 1]
                nv2 = tgt_nrm[t, 2]
                v0 = trac_bar[t, 0]
                v1 = trac_bar[t, 1]
                v2 = trac_bar[t, 2]
                # traction (-P + G + G^T) n weighted by v: -P (n.v) + sum G_ab (v_a n_b + n_a v_b)
                wP = -(nv0 * v0 + nv1 * v1 + nv2 * v2)
                nn = (nv0, nv1, nv2)
                vv = (v0, v1, v2)
                for a in range(3):
                    for c in range(3):
                        wG[a, c] = vv[a] * nn[c] + nn[a] * vv[c]
                unit_field_adjoint(xi, p, I, wu, wG, wgP, wP, Dbar[j])


@njit(parallel=True, fastmath=False, cache=True)
def center_readout_adjoint(centers: np.ndarray, radii: np.ndarray, ubar: np.ndarray, p: int,
                           mu: float, Dbar: np.ndarray) -> None:
    """Transpose of :func:`center_readout`: adds to ``Dbar[j]`` (complex, (5, p+1, p+1))
    the adjoint coefficients of the Faxen read-off on every other sphere i weighted by
    ``ubar[i]`` (U, Omega); parallel over source spheres j."""
    M = centers.shape[0]
    for j in prange(M):
        I = np.empty((p + 3, p + 3), dtype=np.complex128)
        xi = np.empty(3)
        wu = np.empty(3)
        wgP = np.empty(3)
        wG = np.zeros((3, 3))
        aj = radii[j]
        for i in range(M):
            if i == j:
                continue
            for c in range(3):
                xi[c] = (centers[i, c] - centers[j, c]) / aj
            fac = (radii[i] / aj) ** 2 / 6.0
            for c in range(3):
                wu[c] = aj / mu * ubar[i, c]
                wgP[c] = aj / mu * fac * ubar[i, c]
            h = 0.5 / mu
            wG[2, 1] = h * ubar[i, 3]
            wG[1, 2] = -h * ubar[i, 3]
            wG[0, 2] = h * ubar[i, 4]
            wG[2, 0] = -h * ubar[i, 4]
            wG[1, 0] = h * ubar[i, 5]
            wG[0, 1] = -h * ubar[i, 5]
            unit_field_adjoint(xi, p, I, wu, wG, wgP, 0.0, Dbar[j])


def _direct_traction_adjoint_impl(tx: np.ndarray, ty: np.ndarray, tz: np.ndarray,
                                  nx: np.ndarray, ny: np.ndarray, nz: np.ndarray,
                                  bx: np.ndarray, by: np.ndarray, bz: np.ndarray, n_per: int,
                                  grp_ptr: np.ndarray, grp_tgt: np.ndarray,
                                  grp_start: np.ndarray, grp_stop: np.ndarray,
                                  src_x: np.ndarray, src_y: np.ndarray, src_z: np.ndarray,
                                  fx: np.ndarray, fy: np.ndarray, fz: np.ndarray,
                                  skip: bool) -> None:
    """Transpose of :func:`direct_traction_ranges` (``skip=False``) and of
    :func:`direct_traction_skip` (``skip=True``: targets that coincide with the source
    are left out; use the non-fastmath build :func:`direct_traction_adjoint_skip`).

    The point-force-to-traction kernel ``-(3/4 pi) (r.n) r r^T / |r|^5`` is a symmetric
    3 x 3 matrix, so the adjoint force at source s is the same kernel applied to the
    adjoint traction ``b`` of every target that sees s.  Group g is one contiguous
    source range ``grp_start[g]:grp_stop[g]`` (one sphere on one grid level) with its
    target spheres ``grp_tgt[grp_ptr[g]:grp_ptr[g+1]]`` (targets ``i n_per`` to
    ``(i+1) n_per``); groups must not overlap (parallel over groups).  Adds to ``f*``.
    """
    G = grp_start.size
    c0 = -3.0 / _FOUR_PI
    for g in prange(G):
        for s in range(grp_start[g], grp_stop[g]):
            y0 = src_x[s]
            y1 = src_y[s]
            y2 = src_z[s]
            f0 = 0.0
            f1 = 0.0
            f2 = 0.0
            for k in range(grp_ptr[g], grp_ptr[g + 1]):
                i = grp_tgt[k]
                for t in range(i * n_per, (i + 1) * n_per):
                    r0 = tx[t] - y0
                    r1 = ty[t] - y1
                    r2 = tz[t] - y2
                    rr = r0 * r0 + r1 * r1 + r2 * r2
                    if skip and rr == 0.0:
                        continue
                    inv = 1.0 / np.sqrt(rr)
                    inv2 = inv * inv
                    rn = r0 * nx[t] + r1 * ny[t] + r2 * nz[t]
                    rb = r0 * bx[t] + r1 * by[t] + r2 * bz[t]
                    w = c0 * rn * rb * inv2 * inv2 * inv
                    f0 += w * r0
                    f1 += w * r1
                    f2 += w * r2
            fx[s] += f0
            fy[s] += f1
            fz[s] += f2


def _apply_blocks_adjoint_impl(E: np.ndarray, src_ptr: np.ndarray, order: np.ndarray,
                               tgt: np.ndarray, out_bar: np.ndarray, coef_bar: np.ndarray) -> None:
    """Transpose of :func:`apply_blocks`: ``coef_bar[j] += sum_k E[k]^T out_bar[tgt[k]]`` over
    the blocks ``k = order[src_ptr[j]:src_ptr[j+1]]`` whose source is sphere j."""
    M = src_ptr.size - 1
    rows = E.shape[1]
    nv = E.shape[2]
    for j in prange(M):
        acc = np.zeros(nv)
        for kk in range(src_ptr[j], src_ptr[j + 1]):
            k = order[kk]
            i = tgt[k]
            a = 0
            while a + 4 <= rows:                   # four rows per pass over acc
                x0 = out_bar[i, a]
                x1 = out_bar[i, a + 1]
                x2 = out_bar[i, a + 2]
                x3 = out_bar[i, a + 3]
                for b in range(nv):
                    acc[b] += (E[k, a, b] * x0 + E[k, a + 1, b] * x1
                               + E[k, a + 2, b] * x2 + E[k, a + 3, b] * x3)
                a += 4
            while a < rows:
                x0 = out_bar[i, a]
                for b in range(nv):
                    acc[b] += E[k, a, b] * x0
                a += 1
        for b in range(nv):
            coef_bar[j, b] += acc[b]


direct_traction_adjoint = njit(parallel=True, fastmath=True, cache=True)(_direct_traction_adjoint_impl)
direct_traction_adjoint_serial = njit(fastmath=True, cache=True)(_direct_traction_adjoint_impl)
direct_traction_adjoint_skip = njit(parallel=True, fastmath=False, cache=True)(_direct_traction_adjoint_impl)
apply_blocks_adjoint = njit(parallel=True, fastmath=True, cache=True)(_apply_blocks_adjoint_impl)
apply_blocks_adjoint_serial = njit(fastmath=True, cache=True)(_apply_blocks_adjoint_impl)
