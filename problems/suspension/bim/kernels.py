"""Compiled (numba) kernels of the forward boundary-integral product.

The traction on target points of exterior expansions (:func:`traction_expansion`) and of
point forces (:func:`direct_traction_ranges` and its builds), the Faxen read-off of the
rigid velocities (:func:`center_readout`), the near-field block responses
(:func:`traction_response`) and the small dense per-sphere products of every product
(:func:`dense_rows`, :func:`apply_blocks`, :func:`apply_lowrank`,
:func:`synthesize_forces`).  Their exact transposes are in :mod:`kernels_adjoint`
(:func:`apply_lowrank` is its own, with its factors swapped); the solid harmonics and the
unit-sphere field they share are in :mod:`harmonics`.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .harmonics import cross_gradient, derivatives, field_buffers, solid_harmonics, unit_field
from .jit import parallel_and_serial, variant

__all__ = ["PARALLEL_WORK", "point_force_weight", "traction_expansion", "center_readout",
           "traction_response", "direct_traction_ranges", "direct_traction_ranges_serial",
           "direct_traction_skip", "dense_rows", "apply_blocks", "apply_blocks_serial",
           "apply_lowrank", "apply_lowrank_serial",
           "real_block_columns",
           "synthesize_forces", "synthesize_forces_serial"]

_C0 = -3.0 / (4.0 * np.pi)
"""Factor of the traction of a point force (mu = 1)."""

PARALLEL_WORK = 4e6
"""Products with fewer multiply-adds than this run in the serial build of a kernel: a
parallel launch costs milliseconds on a loaded machine, so small products (few spheres,
low p) run serially."""


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
        I, xi, u, G, gP = field_buffers(p)
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
        I, xi, u, G, gP = field_buffers(p)
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
                derivatives(I, n, m)
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
                for j in range(3):
                    Gc[i, j] = cross_gradient(x, H, g, i, j)
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
def traction_response(tgt_pts: np.ndarray, tgt_nrm: np.ndarray, centers: np.ndarray,
                      radii: np.ndarray, p: int, fac: np.ndarray, out: np.ndarray) -> None:
    """Traction at each target of the single layer of every complex VSH coefficient.

    ``out[t, kind, n, m, :]`` is the complex traction (normal ``tgt_nrm[t]``) at
    ``tgt_pts[t]`` of the unit-coefficient density ``C[kind, n, m] = 1`` on the sphere
    (``centers[t]``, ``radii[t]``), one source sphere per target so that many near-field
    blocks are built in one parallel call; ``fac`` (5, 3, p+1, p+1) folds C into the
    harmonics Phi, chi, P_alpha, P_beta and P.  The real traction of a density is
    ``Re sum C * out``.  Used to build the dense near-field blocks.
    """
    T = tgt_pts.shape[0]
    for t in prange(T):
        x = np.empty(3)
        for c in range(3):
            x[c] = (tgt_pts[t, c] - centers[t, c]) / radii[t]
        _response_at(x, tgt_nrm[t], p, fac, out[t])


@njit(inline="always")
def point_force_weight(r0: float, r1: float, r2: float, a0: float, a1: float, a2: float,
                       b0: float, b1: float, b2: float, skip: bool) -> float:
    """``-(3/4 pi) (r.a) (r.b) / |r|^5`` for ``r = x - y = (r0, r1, r2)``: times ``r``, the
    traction at x (normal ``b``) of a point force ``a`` at y, mu = 1.  Symmetric in a and b,
    so the transposed sum uses it too.  0 for ``r = 0`` when ``skip``.  Inlined, so it takes
    the fastmath setting of the kernel that calls it."""
    rr = r0 * r0 + r1 * r1 + r2 * r2
    if skip and rr == 0.0:
        return 0.0
    inv = 1.0 / np.sqrt(rr)
    inv2 = inv * inv
    ra = r0 * a0 + r1 * a1 + r2 * a2
    rb = r0 * b0 + r1 * b1 + r2 * b2
    return _C0 * ra * rb * inv2 * inv2 * inv


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
                w = point_force_weight(r0, r1, r2, src_fx[s], src_fy[s], src_fz[s],
                                       n0, n1, n2, skip)
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

@njit(parallel=True, cache=True)
def real_block_columns(resp: np.ndarray, flat: np.ndarray, cfac: np.ndarray,
                       out: np.ndarray) -> None:
    """Near-field block rows from complex responses, in one pass.

    ``resp`` is ``(P * Nq, K, 3)`` (pair-major targets, complex coefficient index, traction
    component) as :func:`traction_response` writes it; ``out[k, 3 q + i, c] =
    Re(resp[k Nq + q, flat[c], i] * cfac[c])`` for pair ``k``, node ``q`` and real VSH
    coefficient ``c`` (what a reshape, transpose, column selection and real part give, without
    the copies)."""
    P, rows, nv = out.shape
    Nq = rows // 3
    for t in prange(P * Nq):
        k = t // Nq
        q = t - k * Nq
        for i in range(3):
            r = 3 * q + i
            for c in range(nv):
                z = resp[t, flat[c], i] * cfac[c]
                out[k, r, c] = z.real


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


def _apply_lowrank_impl(first: np.ndarray, second: np.ndarray, off: np.ndarray,
                        rank: np.ndarray, length: np.ndarray, ptr: np.ndarray,
                        blk: np.ndarray, inp: np.ndarray, coef: np.ndarray,
                        out: np.ndarray) -> None:
    """Products with blocks stored as sums of rank-one terms.

    Block k acts on the first ``L = length[k]`` coefficients and is
    ``sum_a u_a v_a'`` over ``a < rank[k]``, with ``v_a = first[o : o + L]`` and
    ``u_a = second[o : o + L]``, ``o = off[k] + a L`` (ragged rows, flat storage).  Adds
    ``out[i, :L] += sum_a u_a (v_a . coef[inp[k], :L])`` over the blocks ``k = blk[kk]``,
    ``kk`` in ``range(ptr[i], ptr[i+1])``.  With ``first = v`` and ``second = u``, blocks
    sorted by target, this is :func:`apply_blocks` of the factored blocks; with the two
    swapped and the blocks taken by source, it is its transpose."""
    M = ptr.size - 1
    nv = coef.shape[1]
    for i in prange(M):
        acc = np.zeros(nv)
        for kk in range(ptr[i], ptr[i + 1]):
            k = blk[kk]
            c = coef[inp[k]]
            L = length[k]
            for a in range(rank[k]):
                o = off[k] + a * L
                v = first[o:o + L]              # contiguous views: the loops vectorise
                u = second[o:o + L]             # (measured 5x faster than flat indexing)
                s = 0.0
                for b in range(L):
                    s += v[b] * c[b]
                for b in range(L):
                    acc[b] += s * u[b]
        for b in range(nv):
            out[i, b] += acc[b]


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


# Parallel and serial builds of the same loops (see PARALLEL_WORK).
apply_blocks, apply_blocks_serial = parallel_and_serial(_apply_blocks_impl)
apply_lowrank, apply_lowrank_serial = parallel_and_serial(_apply_lowrank_impl)
synthesize_forces, synthesize_forces_serial = parallel_and_serial(_synthesize_forces_impl)
direct_traction_ranges, direct_traction_ranges_serial = parallel_and_serial(_direct_traction_ranges_impl)
direct_traction_skip = njit(parallel=True, fastmath=False, cache=True)(variant(_direct_traction_ranges_impl, "exact"))


def dense_rows(X: np.ndarray, W: np.ndarray) -> np.ndarray:
    """``X @ W`` for the small dense products of every product (per-sphere self operators,
    preconditioner, spherical-harmonic analysis and synthesis) by BLAS.  Inside the
    solves BLAS runs on one thread (the solvers hold it there with threadpoolctl, beside
    the parallel compiled kernels; its speed against a compiled row loop:
    ``benchmarks/live_operator.py``, docs/benchmarks.md)."""
    return np.ascontiguousarray(X) @ W
