"""Rotations of the real orthonormal vector spherical harmonics of :mod:`.sphere_vsh`.

A rotation ``Q`` acts on a vector field on the unit sphere by ``(Q.f)(x) = Q f(Q^T x)``.
Every kind of the basis (``V``, ``W``, ``X``) is built from a scalar harmonic ``Y`` by
operators that commute with rotations (the surface gradient, multiplication by the normal,
the cross product with the normal), so the coefficients of each (kind, degree n) rotate with
the real Wigner matrix of the scalar harmonics of degree n, and ``D(Q)`` (``nv x nv``,
``coef(Q.f) = D(Q) coef(f)``) is block diagonal with one ``(2n+1) x (2n+1)`` block per
(kind, n), the same for the three kinds.

The real Wigner matrix of degree n is composed of rotations about z (closed form: the
cosine and sine harmonics of order m turn by ``m alpha``) and one fixed quarter turn ``P``
that takes the z axis to the y axis, so that a rotation about y is ``P Rz P^T``; the
matrix of ``P`` is computed once per degree by exact quadrature of the real scalar
harmonics at the turned nodes.  Every rotation used here is ``Q = Rz(phi) Ry(theta)``
(maps +z to the direction with polar angle theta and azimuth phi), vectorised over many
directions; a general ``Q`` is split into z-y-z Euler angles.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numba import njit, prange

from .harmonics import vsh_at
from .sphere_vsh import knm_table, sphere_grid, vsh_basis

__all__ = ["real_harmonics", "degree_slices", "wigner_z", "wigner_quarter",
           "wigner_directions", "wigner_euler", "euler_angles", "vsh_rotation",
           "rotate_blocks", "frame_of"]


def real_harmonics(points: np.ndarray, p: int) -> np.ndarray:
    """Real orthonormal scalar harmonics of degree <= p at unit vectors.

    Parameters
    ----------
    points : ndarray, shape (K, 3)
        Unit vectors.
    p : int
        Largest degree.

    Returns
    -------
    ndarray, shape (K, (p+1)^2)
        Per degree n the 2n+1 functions ``Y_n^0, sqrt2 Re Y_n^1, sqrt2 Im Y_n^1, ...``
        (the order of the columns of each (kind, n) in :func:`.sphere_vsh.vsh_basis`).
    """
    K = knm_table(p)
    out = np.empty((points.shape[0], (p + 1) ** 2))
    Y = np.empty((p + 1, p + 1), dtype=np.complex128)
    V = np.empty((p + 1, p + 1, 3), dtype=np.complex128)
    for k in range(points.shape[0]):
        vsh_at(np.ascontiguousarray(points[k], dtype=float), p, K, Y, V)
        for n in range(p + 1):
            row = out[k, n * n:(n + 1) ** 2]
            row[0] = Y[n, 0].real
            row[1::2] = np.sqrt(2.0) * Y[n, 1:n + 1].real
            row[2::2] = np.sqrt(2.0) * Y[n, 1:n + 1].imag
    return out


def degree_slices(p: int) -> list[np.ndarray]:
    """Per degree n, the basis columns of degree n as an array ``(kinds, 2n+1)`` of
    indices into the ``nv`` coefficients of :func:`.sphere_vsh.vsh_basis` (p >= 2)."""
    b = vsh_basis(p)
    out = []
    for n in range(p + 1):
        rows = []
        for t in range(3):
            idx = np.nonzero((b.degree == n) & (b.kind == t))[0]
            if idx.size:
                if idx.size != 2 * n + 1:
                    raise ValueError(f"the VSH basis of order p = {p} lacks columns of degree "
                                     f"{n}; rotations need p >= 2")
                rows.append(idx)
        out.append(np.array(rows, dtype=np.int64))
    return out


def wigner_z(alpha: np.ndarray, n: int) -> np.ndarray:
    """Real Wigner matrices of degree n of rotations by ``alpha`` about z, ``(..., 2n+1,
    2n+1)``."""
    alpha = np.asarray(alpha, dtype=float)
    D = np.zeros(alpha.shape + (2 * n + 1, 2 * n + 1))
    D[..., 0, 0] = 1.0
    for m in range(1, n + 1):
        c, s = np.cos(m * alpha), np.sin(m * alpha)
        i, j = 2 * m - 1, 2 * m
        D[..., i, i] = c
        D[..., j, j] = c
        D[..., j, i] = s
        D[..., i, j] = -s
    return D


@cache
def wigner_quarter(p: int) -> tuple[np.ndarray, ...]:
    """Per degree n <= p, the real Wigner matrix of the quarter turn ``P`` (about x by
    -pi/2, taking +z to +y), by quadrature of ``Y_j(x) Y_k(P^T x)`` on a grid exact for
    degree 2p (computed once per p)."""
    g = sphere_grid(p + 1)
    P = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]).T   # Rx(-pi/2)
    Yx = real_harmonics(g.nodes, p)
    Yr = real_harmonics(g.nodes @ P, p)          # rows: Y(P^T x)
    out = []
    for n in range(p + 1):
        sl = slice(n * n, (n + 1) ** 2)
        D = (Yx[:, sl] * g.weights[:, None]).T @ Yr[:, sl]
        D.setflags(write=False)
        out.append(D)
    return tuple(out)


def wigner_euler(alpha: np.ndarray, beta: np.ndarray, gamma: np.ndarray,
                 p: int) -> list[np.ndarray]:
    """Real Wigner matrices of ``Rz(alpha) Ry(beta) Rz(gamma)``, per degree n <= p, each
    ``(K, 2n+1, 2n+1)`` for K angle triples."""
    quarter = wigner_quarter(p)
    out = []
    for n in range(p + 1):
        P = quarter[n]
        Dy = P @ wigner_z(beta, n) @ P.T
        out.append(wigner_z(alpha, n) @ Dy @ wigner_z(gamma, n))
    return out


def wigner_directions(u: np.ndarray, p: int) -> list[np.ndarray]:
    """Real Wigner matrices (per degree n <= p, ``(K, 2n+1, 2n+1)``) of the rotations
    ``Rz(phi) Ry(theta)`` taking +z to the unit vectors ``u`` (K, 3)."""
    u = np.asarray(u, dtype=float).reshape(-1, 3)
    theta = np.arctan2(np.hypot(u[:, 0], u[:, 1]), u[:, 2])
    phi = np.arctan2(u[:, 1], u[:, 0])
    return wigner_euler(phi, theta, np.zeros_like(phi), p)


def frame_of(u: np.ndarray) -> np.ndarray:
    """The rotations ``Rz(phi) Ry(theta)`` (K, 3, 3) of :func:`wigner_directions`."""
    u = np.asarray(u, dtype=float).reshape(-1, 3)
    theta = np.arctan2(np.hypot(u[:, 0], u[:, 1]), u[:, 2])
    phi = np.arctan2(u[:, 1], u[:, 0])
    cp, sp, ct, st = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
    Q = np.zeros((u.shape[0], 3, 3))
    Q[:, 0, 0], Q[:, 0, 1], Q[:, 0, 2] = cp * ct, -sp, cp * st
    Q[:, 1, 0], Q[:, 1, 1], Q[:, 1, 2] = sp * ct, cp, sp * st
    Q[:, 2, 0], Q[:, 2, 2] = -st, ct
    return Q


def euler_angles(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """z-y-z Euler angles ``(alpha, beta, gamma)`` with ``Q = Rz(alpha) Ry(beta) Rz(gamma)``
    for rotations ``Q`` (K, 3, 3)."""
    Q = np.asarray(Q, dtype=float).reshape(-1, 3, 3)
    beta = np.arctan2(np.hypot(Q[:, 0, 2], Q[:, 1, 2]), Q[:, 2, 2])
    alpha = np.arctan2(Q[:, 1, 2], Q[:, 0, 2])
    gamma = np.arctan2(Q[:, 2, 1], -Q[:, 2, 0])
    pole = np.hypot(Q[:, 0, 2], Q[:, 1, 2]) < 1e-12      # beta = 0 or pi: alpha + gamma only
    if pole.any():
        alpha = np.where(pole, np.arctan2(-Q[:, 0, 1], Q[:, 1, 1]), alpha)
        gamma = np.where(pole, 0.0, gamma)
        beta = np.where(pole, np.where(Q[:, 2, 2] > 0, 0.0, np.pi), beta)
    return alpha, beta, gamma


def vsh_rotation(Q: np.ndarray, p: int) -> np.ndarray:
    """``D(Q)`` (K, nv, nv) with ``coef(Q.f) = D(Q) coef(f)`` in the real VSH basis of
    :func:`.sphere_vsh.vsh_basis` (p >= 2), for rotations ``Q`` of shape (K, 3, 3) or
    (3, 3).  Orthogonal, and ``D(Q1 Q2) = D(Q1) D(Q2)``."""
    Q = np.asarray(Q, dtype=float)
    single = Q.ndim == 2
    Qs = Q.reshape(-1, 3, 3)
    if not np.allclose(Qs @ np.swapaxes(Qs, 1, 2), np.eye(3), atol=1e-10) or \
            not np.allclose(np.linalg.det(Qs), 1.0, atol=1e-10):
        raise ValueError("Q must be a rotation (orthogonal, determinant +1)")
    Dn = wigner_euler(*euler_angles(Qs), p)
    nv = vsh_basis(p).B.shape[1]
    D = np.zeros((Qs.shape[0], nv, nv))
    for n, rows in enumerate(degree_slices(p)):
        for idx in rows:
            D[:, idx[:, None], idx[None, :]] = Dn[n]
    return D[0] if single else D


def rotate_blocks(E: np.ndarray, Dn: list[np.ndarray], slices: list[np.ndarray], *,
                  left_matrix: np.ndarray | None = None,
                  pattern: np.ndarray | None = None) -> np.ndarray:
    """``L D E D^T`` for stacks of blocks ``E`` and rotations given per degree (``Dn[n]`` of
    shape (K, 2n+1, 2n+1), ``slices`` from :func:`degree_slices`), using the block-diagonal
    structure of ``D``; ``L`` is ``left_matrix`` (identity when None; only its rows that
    differ from the identity are applied).

    ``E`` is (K, nv, nv), or with ``pattern`` (an (nv, nv) bool mask) the (K, nnz) values
    of the masked entries in row-major order (the coaxial table's equal-order entries),
    never expanded.  The basis is degree-major (per degree the kinds, per kind the orders),
    so the columns of each (kind, degree) are one contiguous range; the products run in
    compiled code, in parallel over the blocks.
    """
    p = len(slices) - 1
    lo = np.empty(p + 1, dtype=np.int64)
    kinds = np.empty(p + 1, dtype=np.int64)
    for n, rows in enumerate(slices):
        lo[n], kinds[n] = int(rows[0, 0]), rows.shape[0]
        if not np.array_equal(rows.reshape(-1), np.arange(lo[n], lo[n] + rows.size)):
            raise ValueError("the basis is not degree-major; rotations need it")
    nv = int(lo[-1] + kinds[-1] * (2 * p + 1))
    K = E.shape[0]
    if pattern is None:
        pattern = np.ones((nv, nv), dtype=bool)
        vals = np.ascontiguousarray(E.reshape(K, -1), dtype=float)
    else:
        vals = np.ascontiguousarray(E, dtype=float)
    ptr = np.concatenate([[0], np.cumsum(pattern.sum(axis=1))]).astype(np.int64)
    idx = np.nonzero(pattern)[1].astype(np.int64)
    D = np.zeros((K, p + 1, 2 * p + 1, 2 * p + 1))
    for n in range(p + 1):
        D[:, n, :2 * n + 1, :2 * n + 1] = Dn[n]
    if left_matrix is None:
        dev = np.zeros(0, dtype=np.int64)
        L = np.zeros((0, nv))
    else:
        dev = np.nonzero(np.abs(left_matrix - np.eye(nv)).max(axis=1) > 1e-12)[0]
        L = np.ascontiguousarray(left_matrix[dev])
    out = np.empty((K, nv, nv))
    _rotate(vals, ptr, idx, D, np.stack([lo, kinds], axis=1), dev.astype(np.int64), L, out)
    return out


@njit(parallel=True, cache=True)
def _rotate(vals: np.ndarray, ptr: np.ndarray, idx: np.ndarray, D: np.ndarray,
            layout: np.ndarray, dev: np.ndarray, L: np.ndarray, out: np.ndarray) -> None:
    """``out[k] = L D_k E_k D_k^T`` with ``E_k`` given by its values ``vals[k]`` on the
    rows ``ptr`` / columns ``idx`` pattern; ``layout[n]`` is the first column of degree n
    and its number of kinds (see :func:`rotate_blocks`)."""
    K, nv, _ = out.shape
    lo, kinds = layout[:, 0], layout[:, 1]
    for k in prange(K):
        tmp = np.zeros((nv, nv))
        ek = vals[k]
        for n in range(lo.size):                          # left: D E
            w = 2 * n + 1
            for t in range(kinds[n]):
                base = lo[n] + t * w
                for a in range(w):
                    for b in range(w):
                        d = D[k, n, a, b]
                        row = base + b
                        for j in range(ptr[row], ptr[row + 1]):
                            tmp[base + a, idx[j]] += d * ek[j]
        res = out[k]
        for r in range(nv):                               # right: (D E) D^T
            for n in range(lo.size):
                w = 2 * n + 1
                for t in range(kinds[n]):
                    base = lo[n] + t * w
                    for a in range(w):
                        acc = 0.0
                        for b in range(w):
                            acc += tmp[r, base + b] * D[k, n, a, b]
                        res[r, base + a] = acc
        if dev.size:
            rows = np.zeros((dev.size, nv))
            for i in range(dev.size):
                for j in range(nv):
                    x = L[i, j]
                    if x != 0.0:
                        for c in range(nv):
                            rows[i, c] += x * res[j, c]
            for i in range(dev.size):
                for c in range(nv):
                    res[dev[i], c] = rows[i, c]
