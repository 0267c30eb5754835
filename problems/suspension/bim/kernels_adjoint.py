"""Compiled (numba) transposes of the forward boundary-integral kernels (:mod:`kernels`).

The discrete mobility is only nearly symmetric, so the exact transpose of every linear
piece of the forward product is needed (``BimMobility.rmatvec``).  The expansion pieces
are linear in the folded coefficients D (complex, the real field being
``Re sum D * harmonics``); their transposes return ``Dbar`` with
``sum(w * output) = Re sum(D * Dbar)`` (a bilinear, not Hermitian, pairing), and the
caller maps ``Dbar`` back to grid densities with the coefficient matrix.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .harmonics import derivatives, field_buffers, solid_harmonics
from .jit import parallel_and_serial, variant
from .kernels import point_force_weight

__all__ = ["unit_field_adjoint", "traction_expansion_adjoint", "center_readout_adjoint",
           "direct_traction_adjoint", "direct_traction_adjoint_serial",
           "direct_traction_adjoint_skip", "apply_blocks_adjoint", "apply_blocks_adjoint_serial",
           "apply_blocks_both", "apply_blocks_both_serial"]

@njit(cache=True, fastmath=False)
def unit_field_adjoint(xi: np.ndarray, p: int, I: np.ndarray, wu: np.ndarray, wG: np.ndarray,
                       wgP: np.ndarray, wP: float, Dbar: np.ndarray) -> None:
    """Transpose of :func:`harmonics.unit_field` with respect to its coefficients ``D``.

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
            g0, g1, g2, hxx, hyy, hzz, hxy, hxz, hyz = derivatives(I, n, m)
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
    """Transpose of :func:`kernels.traction_expansion`.

    Targets come in blocks of ``blk_size`` consecutive points (one block per target
    sphere); source sphere j is seen by the blocks ``src_blk[src_ptr[j]:src_ptr[j+1]]``.
    Adds to ``Dbar[j]`` (complex, (5, p+1, p+1)) the adjoint coefficients of the
    tractions weighted by ``trac_bar`` (parallel over source spheres, no races).
    """
    M = src_ptr.size - 1
    for j in prange(M):
        I, xi, wu, wG, wgP = field_buffers(p)       # wu, wgP stay zero
        inv_a = 1.0 / radii[j]
        for k in range(src_ptr[j], src_ptr[j + 1]):
            b = src_blk[k]
            for t in range(b * blk_size, (b + 1) * blk_size):
                for c in range(3):
                    xi[c] = (tgt_pts[t, c] - centers[j, c]) * inv_a
                nn = (tgt_nrm[t, 0], tgt_nrm[t, 1], tgt_nrm[t, 2])
                vv = (trac_bar[t, 0], trac_bar[t, 1], trac_bar[t, 2])
                # traction (-P + G + G^T) n weighted by v: -P (n.v) + sum G_ab (v_a n_b + n_a v_b)
                wP = -(nn[0] * vv[0] + nn[1] * vv[1] + nn[2] * vv[2])
                for a in range(3):
                    for c in range(3):
                        wG[a, c] = vv[a] * nn[c] + nn[a] * vv[c]
                unit_field_adjoint(xi, p, I, wu, wG, wgP, wP, Dbar[j])


@njit(parallel=True, fastmath=False, cache=True)
def center_readout_adjoint(centers: np.ndarray, radii: np.ndarray, ubar: np.ndarray, p: int,
                           mu: float, Dbar: np.ndarray) -> None:
    """Transpose of :func:`kernels.center_readout`: adds to ``Dbar[j]`` (complex,
    (5, p+1, p+1)) the adjoint coefficients of the Faxen read-off on every other sphere i
    weighted by ``ubar[i]`` (U, Omega); parallel over source spheres j."""
    M = centers.shape[0]
    for j in prange(M):
        I, xi, wu, wG, wgP = field_buffers(p)       # unset entries of wG stay zero
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
    """Transpose of :func:`kernels.direct_traction_ranges` (``skip=False``) and of
    :func:`kernels.direct_traction_skip` (``skip=True``: targets that coincide with the
    source are left out; use the non-fastmath build :func:`direct_traction_adjoint_skip`).

    The point-force-to-traction kernel ``-(3/4 pi) (r.n) r r^T / |r|^5`` is a symmetric
    3 x 3 matrix, so the adjoint force at source s is the same kernel applied to the
    adjoint traction ``b`` of every target that sees s.  Group g is one contiguous
    source range ``grp_start[g]:grp_stop[g]`` (one sphere on one grid level) with its
    target spheres ``grp_tgt[grp_ptr[g]:grp_ptr[g+1]]`` (targets ``i n_per`` to
    ``(i+1) n_per``); groups must not overlap (parallel over groups).  Adds to ``f*``.
    """
    G = grp_start.size
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
                    w = point_force_weight(r0, r1, r2, nx[t], ny[t], nz[t],
                                           bx[t], by[t], bz[t], skip)
                    f0 += w * r0
                    f1 += w * r1
                    f2 += w * r2
            fx[s] += f0
            fy[s] += f1
            fz[s] += f2


def _apply_blocks_adjoint_impl(E: np.ndarray, src_ptr: np.ndarray, order: np.ndarray,
                               tgt: np.ndarray, out_bar: np.ndarray,
                               coef_bar: np.ndarray) -> None:
    """Transpose of :func:`kernels.apply_blocks`:
    ``coef_bar[j] += sum_k E[k]^T out_bar[tgt[k]]`` over the blocks
    ``k = order[src_ptr[j]:src_ptr[j+1]]`` whose source is sphere j."""
    rows, nv = E.shape[1], E.shape[2]
    for j in prange(src_ptr.size - 1):
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


def _apply_blocks_both_impl(E: np.ndarray, tgt_ptr: np.ndarray, src: np.ndarray,
                            coef: np.ndarray, out: np.ndarray, out_bar: np.ndarray,
                            part_bar: np.ndarray) -> None:
    """:func:`kernels.apply_blocks` and its transpose in one pass over the blocks:
    ``out[i] += E[k] @ coef[src[k]]`` and ``part_bar[k] = E[k]^T out_bar[i]`` for the
    blocks ``k`` in ``range(tgt_ptr[i], tgt_ptr[i+1])``.  The blocks are read from memory
    once for both products (the products are memory bound); the caller adds
    ``part_bar[k]`` to the adjoint coefficients of sphere ``src[k]``."""
    M = tgt_ptr.size - 1
    rows = E.shape[1]
    nv = E.shape[2]
    for i in prange(M):
        acc = np.zeros(rows)
        for k in range(tgt_ptr[i], tgt_ptr[i + 1]):
            c = coef[src[k]]
            pk = part_bar[k]
            for b in range(nv):
                pk[b] = 0.0
            for a in range(rows):
                s = 0.0
                x = out_bar[i, a]
                for b in range(nv):
                    e = E[k, a, b]
                    s += e * c[b]
                    pk[b] += e * x
                acc[a] += s
        for a in range(rows):
            out[i, a] += acc[a]


direct_traction_adjoint, direct_traction_adjoint_serial = parallel_and_serial(_direct_traction_adjoint_impl)
direct_traction_adjoint_skip = njit(parallel=True, fastmath=False, cache=True)(variant(_direct_traction_adjoint_impl, "exact"))
apply_blocks_adjoint, apply_blocks_adjoint_serial = parallel_and_serial(_apply_blocks_adjoint_impl)
apply_blocks_both, apply_blocks_both_serial = parallel_and_serial(_apply_blocks_both_impl)
