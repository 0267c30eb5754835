"""Per-sphere grid, vector spherical harmonics and spectral self operators.

Grid of order p: ``p + 1`` Gauss-Legendre nodes in ``cos(theta)`` times ``2p``
equispaced longitudes, so ``N = 2p(p+1)`` nodes and ``6p(p+1)`` unknowns per
sphere for a vector density stored node-major as ``(N, 3)`` Cartesian values.

Vector spherical harmonics (orthonormal ``Y_n^m``, Condon-Shortley phase)::

    V_n = grad_s Y_n - (n+1) Y_n n,   W_n = grad_s Y_n + n Y_n n,   X_n = n x grad_s Y_n

The real orthonormal basis of degree <= p (cosine and sine versions of each
``m > 0``) is sampled on the grid (matrix ``B``).  Degree-p, order-p sine
harmonics are partly invisible on ``2p`` longitudes (``V`` and ``W`` of
``Y_p^{p,sin}`` coincide on the grid), so analysis is the minimum-norm
weighted least-squares fit ``A = pinv(W^(1/2) B) W^(1/2)``: it is exact on the
band-limited space, and for the aliased pair it assigns the tangential field
``grad_s Y`` the correct eigenvalue ``(n lambda_V + (n+1) lambda_W)/(2n+1)``.
For p = 1 that pair is the rigid translation along y, so there the ``V``
column is dropped and the grid function is read as ``W_1`` (rigid modes exact).

Self operators are ``B diag(lambda) A + c (I - B A)`` where ``I - B A`` is the
quadrature-orthogonal complement of the band-limited space ("aliasing
complement"): ``c = 0`` for the single layer S (its velocity is unresolved
and carries no rigid motion) and ``c = 1`` for ``1/2 I + K'`` (keeps the
second-kind operator an identity there, so GMRES sees no spurious small
eigenvalues).  Eigenvalues on the unit sphere, mu = 1:

    S:       V: n/((2n+1)(2n+3))          W: (n+1)/((2n+1)(2n-1))   X: 1/(2n+1)
    1/2+K':  V: (2n^2+4n+3)/((2n+1)(2n+3)) W: 2(n^2-1)/(4n^2-1)      X: (n-1)/(2n+1)
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import warnings
from dataclasses import dataclass
from functools import cache
from math import factorial
from pathlib import Path
from typing import Optional

import numpy as np

from .harmonics import vsh_at

__all__ = ["SphereGrid", "VSHBasis", "SelfOperators", "sphere_grid", "vsh_basis",
           "self_operators", "s_eigenvalue", "traction_eigenvalue", "knm_table",
           "rigid_density", "net_force_torque", "expansion_coefficients", "default_quad_tol",
           "grid_levels", "sampled_basis", "upsampling_matrix", "quadrature_errors", "quadrature_radius",
           "RHO_GRID", "expansion_factors", "coefficient_matrix", "quadrature_cache_dir",
           "QUADRATURE_CACHE_VERSION"]

TYPES = ("V", "W", "X")


def _check_p(p: int) -> int:
    if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 1:
        raise ValueError(f"spherical-harmonic order p = {p!r} must be an integer >= 1")
    return int(p)


def s_eigenvalue(kind: str, n: int) -> float:
    """Eigenvalue of the unit-sphere single layer (mu = 1) on ``V_n``, ``W_n`` or ``X_n``."""
    if kind == "V":
        return n / ((2 * n + 1) * (2 * n + 3))
    if kind == "W":
        return (n + 1) / ((2 * n + 1) * (2 * n - 1))
    if kind == "X":
        return 1.0 / (2 * n + 1)
    raise ValueError(f"unknown VSH kind {kind!r}; use 'V', 'W' or 'X'")


def traction_eigenvalue(kind: str, n: int) -> float:
    """Eigenvalue of the interior traction operator ``1/2 I + K'`` on the unit sphere.

    The exterior traction ``-1/2 I + K'`` has the same eigenvalue minus one.
    """
    if kind == "V":
        return (2 * n * n + 4 * n + 3) / ((2 * n + 1) * (2 * n + 3))
    if kind == "W":
        return 2.0 * (n * n - 1) / (4 * n * n - 1)
    if kind == "X":
        return (n - 1) / (2 * n + 1)
    raise ValueError(f"unknown VSH kind {kind!r}; use 'V', 'W' or 'X'")


def knm_table(p: int) -> np.ndarray:
    """``K_nm`` with ``r^(-n-1) Y_n^m = K_nm I_n^m`` (see kernels), n, m <= p."""
    K = np.zeros((p + 1, p + 1))
    for n in range(p + 1):
        for m in range(n + 1):
            K[n, m] = np.sqrt((2 * n + 1) / (4 * np.pi) / (factorial(n - m) * factorial(n + m)))
    return K


@dataclass(frozen=True)
class SphereGrid:
    """Quadrature grid on the unit sphere.

    Attributes
    ----------
    p : int
        Order.
    nodes : ndarray, shape (N, 3)
        Unit vectors (also the outward normals), N = 2p(p+1), latitude-major.
    weights : ndarray, shape (N,)
        Quadrature weights, summing to 4 pi.
    """
    p: int
    nodes: np.ndarray
    weights: np.ndarray

    @property
    def size(self) -> int:
        return self.nodes.shape[0]


@cache
def sphere_grid(p: int) -> SphereGrid:
    """The (p+1) Gauss-Legendre x 2p uniform grid of order p (cached)."""
    p = _check_p(p)
    x, wx = np.polynomial.legendre.leggauss(p + 1)
    phi = np.pi * np.arange(2 * p) / p
    ct = np.repeat(x, 2 * p)
    st = np.sqrt(1.0 - ct * ct)
    ph = np.tile(phi, p + 1)
    nodes = np.stack([st * np.cos(ph), st * np.sin(ph), ct], axis=1)
    weights = np.repeat(wx, 2 * p) * (np.pi / p)
    nodes.setflags(write=False)
    weights.setflags(write=False)
    return SphereGrid(p, nodes, weights)


@dataclass(frozen=True)
class VSHBasis:
    """Real orthonormal VSH of degree <= p sampled on the grid of order p.

    Attributes
    ----------
    B : ndarray, shape (3N, nv)
        Synthesis: column k holds basis function k at the nodes (node-major xyz).
    A : ndarray, shape (nv, 3N)
        Analysis (minimum-norm weighted least squares).
    kind, degree, order : ndarray, shape (nv,)
        Type index (0 = V, 1 = W, 2 = X), n and m of each column.
    sine : ndarray of bool, shape (nv,)
        Column built from the sine (Im) part.
    to_complex : complex ndarray, shape (3 (p+1)^2, nv)
        Maps real coefficients to complex ones ``C[kind, n, m]`` (m >= 0, flattened)
        such that the density is ``Re sum C[kind, n, m] VSH[Y_n^m]``.
    """
    p: int
    B: np.ndarray
    A: np.ndarray
    kind: np.ndarray
    degree: np.ndarray
    order: np.ndarray
    sine: np.ndarray
    to_complex: np.ndarray


def _complex_vsh_on_grid(p: int, q: int) -> tuple[np.ndarray, np.ndarray]:
    """Complex ``Y_n^m`` (N, p+1, p+1) and ``V_n^m`` (N, p+1, p+1, 3), n <= p, at the
    nodes of the grid of order q."""
    g = sphere_grid(q)
    K = knm_table(p)
    N = g.size
    Y = np.zeros((N, p + 1, p + 1), dtype=np.complex128)
    V = np.zeros((N, p + 1, p + 1, 3), dtype=np.complex128)
    for k in range(N):
        vsh_at(np.ascontiguousarray(g.nodes[k]), p, K, Y[k], V[k])
    return Y, V


def _sample_basis(p: int, q: int) -> tuple[np.ndarray, list]:
    """Real orthonormal VSH of degree <= p sampled on the grid of order q.

    Returns the (3 N_q, nv) matrix and per column (kind, n, m, sine, flat, cfac),
    where ``flat`` indexes ``C[kind, n, m]`` and ``cfac`` is the complex factor.
    """
    g = sphere_grid(q)
    Y, V = _complex_vsh_on_grid(p, q)
    xh = g.nodes
    cols, meta = [], []
    for n in range(p + 1):
        for t in range(3):
            if n == 0 and t > 0:
                continue               # W_0 = X_0 = 0
            for m in range(n + 1):
                Vc = V[:, n, m, :]
                if t == 0:
                    F = Vc
                    norm = np.sqrt((n + 1) * (2 * n + 1))
                elif t == 1:
                    F = Vc + (2 * n + 1) * Y[:, n, m, None] * xh
                    norm = np.sqrt(n * (2 * n + 1))
                else:
                    F = np.cross(xh, Vc)
                    norm = np.sqrt(n * (n + 1))
                flat = t * (p + 1) ** 2 + n * (p + 1) + m
                parts = [(False, F.real, 1.0 / norm)] if m == 0 else [
                    (False, np.sqrt(2.0) * F.real, np.sqrt(2.0) / norm),
                    (True, np.sqrt(2.0) * F.imag, -1j * np.sqrt(2.0) / norm)]
                for is_sin, vals, cfac in parts:
                    if p == 1 and t == 0 and n == 1 and is_sin:
                        # on the p = 1 grid V_1 and W_1 of Y_1^{1,sin} coincide;
                        # keep W_1 so rigid translation along y stays exact
                        continue
                    cols.append(vals.reshape(-1) / norm)
                    meta.append((t, n, m, is_sin, flat, cfac))
    return np.stack(cols, axis=1), meta


@cache
def vsh_basis(p: int) -> VSHBasis:
    """Sampled real orthonormal VSH basis and its analysis matrix (cached per p)."""
    p = _check_p(p)
    g = sphere_grid(p)
    B, meta = _sample_basis(p, p)
    sw = np.repeat(np.sqrt(g.weights), 3)
    A = np.linalg.pinv(sw[:, None] * B, rcond=1e-10) * sw[None, :]
    to_complex = np.zeros((3 * (p + 1) ** 2, B.shape[1]), dtype=np.complex128)
    for k, (_t, _n, _m, _s, flat, cfac) in enumerate(meta):
        to_complex[flat, k] = cfac
    for arr in (B, A, to_complex):
        arr.setflags(write=False)
    kind, deg, order, sine = (np.array([mt[i] for mt in meta]) for i in range(4))
    return VSHBasis(p, B, A, kind, deg, order, sine.astype(bool), to_complex)


@dataclass(frozen=True)
class SelfOperators:
    """Dense unit-sphere self operators on the grid of order p (mu = 1, a = 1).

    Attributes
    ----------
    S : ndarray, shape (3N, 3N)
        Single layer (complement eigenvalue 0).  For radius a and viscosity mu
        multiply by a / mu.
    Kp : ndarray, shape (3N, 3N)
        Interior traction ``1/2 I + K'`` (complement eigenvalue 1); scale free.
    C : ndarray, shape (6, 3N)
        Net force and torque of a unit-sphere density (exact for the
        band-limited interpolant).
    L : ndarray, shape (3N, 3N)
        ``B' C``: rigid-body part (net force and torque put back as rigid
        densities); scale free.
    precond : ndarray, shape (3N, 3N)
        ``inv(Kp + L)``, the one-body preconditioner.
    readout : ndarray, shape (6, 3N)
        Unit-sphere rigid read-off of a velocity field: mean velocity and
        ``3/(8 pi) sum w x_hat cross u``; for radius a divide the rotation rows by a.
    """
    p: int
    S: np.ndarray
    Kp: np.ndarray
    C: np.ndarray
    L: np.ndarray
    precond: np.ndarray
    readout: np.ndarray


def rigid_density(p: int, F: np.ndarray, T: np.ndarray, a: float = 1.0) -> np.ndarray:
    """``B'(F, T) = F/(4 pi a^2) + 3 T x n/(8 pi a^3)`` at the nodes, shape (N, 3)."""
    g = sphere_grid(p)
    F = np.asarray(F, dtype=float)
    T = np.asarray(T, dtype=float)
    return F[None, :] / (4 * np.pi * a * a) + 3.0 * np.cross(T[None, :], g.nodes) / (8 * np.pi * a ** 3)


def net_force_torque(p: int, sigma: np.ndarray, a: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``C sigma``: net force and torque (about the centre) of a grid density (N, 3)."""
    ft = self_operators(p).C @ np.asarray(sigma, dtype=float).reshape(-1)
    return a * a * ft[:3], a ** 3 * ft[3:]


def _quadrature_moments(q: int) -> np.ndarray:
    """Net force and torque functionals (6, 3N) by plain quadrature on grid q."""
    g = sphere_grid(q)
    N = g.size
    C = np.zeros((6, 3 * N))
    eye = np.eye(3)
    for c in range(3):
        C[:3, c::3] = g.weights[None, :] * eye[c][:, None]
        C[3:, c::3] = (g.weights[:, None] * np.cross(g.nodes, eye[c])).T
    return C


def _rigid_matrices(p: int) -> tuple[np.ndarray, np.ndarray]:
    """Matrices of ``C`` (6, 3N) and ``B'`` (3N, 6) on the unit sphere.

    ``C`` integrates the band-limited interpolant exactly (through the VSH
    coefficients), which for p >= 2 equals plain grid quadrature; on the p = 1
    grid (all nodes in the xz plane) plain quadrature of degree-2 moments is
    not exact, the coefficient route is.
    """
    b = vsh_basis(p)
    q = max(p, 2)
    Bq, _ = _sample_basis(p, q)
    C = _quadrature_moments(q) @ Bq @ b.A
    eye = np.eye(3)
    Bp = np.zeros((3 * sphere_grid(p).size, 6))
    for c in range(3):
        Bp[:, c] = rigid_density(p, eye[c], np.zeros(3)).reshape(-1)
        Bp[:, 3 + c] = rigid_density(p, np.zeros(3), eye[c]).reshape(-1)
    return C, Bp


@cache
def self_operators(p: int) -> SelfOperators:
    """Build (once per p) the dense self operators of the unit sphere."""
    p = _check_p(p)
    b = vsh_basis(p)
    kinds = [TYPES[t] for t in b.kind]
    lam_s = np.array([s_eigenvalue(k, int(n)) for k, n in zip(kinds, b.degree)])
    lam_k = np.array([traction_eigenvalue(k, int(n)) for k, n in zip(kinds, b.degree)])
    proj = b.B @ b.A
    n3 = proj.shape[0]
    S = (b.B * lam_s[None, :]) @ b.A
    Kp = (b.B * lam_k[None, :]) @ b.A + (np.eye(n3) - proj)
    C, Bp = _rigid_matrices(p)
    L = Bp @ C
    precond = np.linalg.inv(Kp + L)
    R = np.empty((6, n3))
    R[:3] = C[:3] / (4 * np.pi)
    R[3:] = 3.0 / (8 * np.pi) * C[3:]
    for arr in (S, Kp, C, L, precond, R):
        arr.setflags(write=False)
    return SelfOperators(p, S, Kp, C, L, precond, R)


@cache
def expansion_factors(p: int) -> np.ndarray:
    """Factors (5, 3, p+1, p+1) folding (C_V, C_W, C_X) into (Phi, chi, P_alpha, P_beta, P)."""
    n = np.arange(p + 1, dtype=float)[:, None] * np.ones((1, p + 1))
    K = knm_table(p)
    f = np.zeros((5, 3, p + 1, p + 1))
    f[0, 0] = n / ((2 * n + 1) * (2 * n + 3))            # V -> grad phi
    f[0, 1] = n / (4 * n + 2)                             # W -> grad phi
    f[1, 2] = 1.0 / (2 * n + 1)                           # X -> x cross grad phi
    f[2, 1] = -(n - 2) / (2 * (2 * n - 1))                # W -> n alpha_n r^2 grad phi
    f[3, 1] = (n + 1) / (2 * n - 1)                       # W -> n beta_n x phi
    f[4, 1] = n                                           # W -> pressure n phi
    f *= K[None, None]
    f.setflags(write=False)
    return f


@cache
def coefficient_matrix(p: int) -> np.ndarray:
    """Complex ``(5 (p+1)^2, 3N)`` matrix: grid density -> folded expansion coefficients."""
    b = vsh_basis(p)
    Q = (b.to_complex @ b.A).reshape(3, p + 1, p + 1, -1)
    F = np.einsum("fknm,knmx->fnmx", expansion_factors(p), Q).reshape(5 * (p + 1) ** 2, -1)
    F = np.ascontiguousarray(F.T)
    F.setflags(write=False)
    return F


def expansion_coefficients(p: int, sigma: np.ndarray) -> np.ndarray:
    """Folded exterior-expansion coefficients of unit-sphere grid densities.

    Parameters
    ----------
    p : int
        Order of the grid.
    sigma : ndarray, shape (M, 3N)
        One density per sphere (node-major xyz values).

    Returns
    -------
    D : complex ndarray, shape (M, 5, p+1, p+1)
        Coefficients of the harmonics Phi, chi, P_alpha, P_beta and P used by
        :func:`harmonics.unit_field` (for the single layer with mu = 1 on the unit
        sphere; the density's own units carry through).
    """
    sigma = np.asarray(sigma, dtype=float)
    return (sigma @ coefficient_matrix(p)).reshape(-1, 5, p + 1, p + 1)


# ---- accuracy of direct quadrature between spheres -----------------------------------------

def default_quad_tol(eps_gmres: float) -> float:
    """Default accuracy of the quadrature between spheres: ``eps_gmres / 100``.

    The quadrature error is then far below the GMRES tolerance and, for every
    p <= 16 and gap >= 0.1a, below the order-p discretisation error of the
    density (docs/mobility.md), so the pair split does not show in the result.
    Clamped to [1e-15, 1e-4].
    """
    return float(min(max(eps_gmres / 100.0, 1e-15), 1e-4))


def grid_levels(p: int) -> tuple[int, ...]:
    """Source-grid orders tried for direct quadrature between spheres, coarsest first:
    ``ceil(p/2), ceil(3p/4)`` if at least 3 (truncated densities, enough for distant
    spheres at loose tolerances), the
    native ``p`` and the upsampled ``p+2, ..., 2p``."""
    p = _check_p(p)
    coarse = {q for q in (-(-p // 2), -(-3 * p // 4)) if 3 <= q < p}
    return tuple(sorted(coarse | set(range(p, 2 * p + 1, 2)) | {2 * p}))


@cache
def sampled_basis(p: int, q: int) -> np.ndarray:
    """``(3 N_q, nv)``: the real VSH basis of degree <= p (columns of ``vsh_basis(p).B``)
    sampled on the grid of order q.  For ``q < p`` the columns of degree > q are zero
    (the density is truncated to degree q before sampling, so that the coarse grid
    does not alias it)."""
    p, q = _check_p(p), _check_p(q)
    Bq, _ = _sample_basis(p, q)
    if q < p:
        Bq[:, vsh_basis(p).degree > q] = 0.0
    Bq.setflags(write=False)
    return Bq


@cache
def upsampling_matrix(p: int, q: int) -> np.ndarray:
    """``(3 N_q, 3 N_p)`` matrix sampling the band-limited (degree <= p) interpolant of an
    order-p grid density on the grid of order q (spherical-harmonic synthesis; for
    ``q < p`` truncated to degree q first)."""
    U = sampled_basis(p, q) @ vsh_basis(p).A
    U.setflags(write=False)
    return U


@cache
def projection_matrix(p: int, q: int) -> np.ndarray:
    """``(3 N_p, 3 N_q)``: values on the order-q grid (q >= p) -> their L2 projection onto
    the VSH of degree <= p, sampled on the order-p grid.

    Used for the near field between close spheres: the traction a close sphere induces
    is sharply peaked (width ~ sqrt(gap)) and has content far beyond degree p.
    Sampling it at the order-p nodes (Nystrom) aliases that content into the
    resolved modes, and a node facing the neighbour (the lattice scene's axis-aligned
    contacts hit one for even p) makes the discrete operator indefinite and GMRES
    stall.  Projecting it (a Galerkin treatment of the near field, quadrature on
    the finer order-q grid) keeps the spectrum of the second-kind operator."""
    p, q = _check_p(p), _check_p(q)
    if q < p:
        raise ValueError(f"projection from order {q} to order {p} needs q >= p")
    g = sphere_grid(q)
    Sq = sampled_basis(p, q)
    sw = np.repeat(np.sqrt(g.weights), 3)
    Aq = np.linalg.pinv(sw[:, None] * Sq, rcond=1e-10) * sw[None, :]
    P = np.ascontiguousarray(vsh_basis(p).B @ Aq)
    P.setflags(write=False)
    return P


RHO_GRID = 1.02 * 1.04 ** np.arange(153)
"""Distances (source radii, from the source centre) at which quadrature errors are measured."""


def quadrature_samples(p: int, seed: int, n_densities: int = 4) -> tuple[np.ndarray, ...]:
    """Random band-limited unit-sphere densities ``(K, 3N)`` with max |sigma| = 1, target
    directions (the 144 nodes of the order-8 grid, rotated by a random rotation so that
    they do not line up with the source grid) and random unit normals."""
    rng = np.random.default_rng(seed)
    b = vsh_basis(p)
    sig = (b.B @ rng.standard_normal((b.B.shape[1], n_densities))).T
    sig /= np.abs(sig).max(axis=1, keepdims=True)
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    pts = sphere_grid(8).nodes @ Q.T
    nrm = rng.standard_normal(pts.shape)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return np.ascontiguousarray(sig), np.ascontiguousarray(pts), np.ascontiguousarray(nrm)


def quadrature_errors(p: int, q: int, rho: np.ndarray, seed: int = 1) -> np.ndarray:
    """Measured max traction error (per unit max |sigma|) of direct quadrature on the grid of
    order q of degree-p densities on the unit sphere, at distances ``rho`` from the centre,
    against the exact exterior expansion (:func:`kernels.traction_expansion`)."""
    from .kernels import direct_traction_ranges, traction_expansion
    p, q = _check_p(p), _check_p(q)
    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    sig, dirs, nrm0 = quadrature_samples(p, seed)
    K, T0 = sig.shape[0], dirs.shape[0]
    # targets: every (rho, density, direction); "sphere" index = density index
    tgt = np.ascontiguousarray((rho[:, None, None, None] * dirs[None, None]).repeat(K, axis=1)
                               .reshape(-1, 3))
    nrm = np.ascontiguousarray(np.broadcast_to(nrm0, (rho.size, K, T0, 3)).reshape(-1, 3))
    which = np.ascontiguousarray(np.broadcast_to(np.arange(K)[None, :, None],
                                                 (rho.size, K, T0)).reshape(-1))
    ptr = np.arange(K + 1, dtype=np.int64)
    ex = np.zeros((tgt.shape[0], 3))
    traction_expansion(tgt, nrm, which, ptr, np.arange(K, dtype=np.int64), np.zeros((K, 3)),
                       np.ones(K), expansion_coefficients(p, sig), p, ex)
    gq = sphere_grid(q)
    Nq = gq.size
    fq = (sig @ upsampling_matrix(p, q).T).reshape(K, Nq, 3) * gq.weights[None, :, None]
    nodes = np.tile(gq.nodes, (K, 1))
    start = np.arange(K, dtype=np.int64) * Nq
    dr = np.zeros_like(ex)
    direct_traction_ranges(tgt, nrm, which, ptr, start, start + Nq,
                           *(np.ascontiguousarray(nodes[:, c]) for c in range(3)),
                           *(np.ascontiguousarray(fq.reshape(-1, 3)[:, c]) for c in range(3)), dr,
                           False)
    return np.abs(dr - ex).reshape(rho.size, -1).max(axis=1)


QUADRATURE_CACHE_VERSION = 1
"""Version of the measured quadrature-error tables kept on disk; raise it when
:func:`quadrature_errors` changes what it measures (old files are then rebuilt)."""


def quadrature_cache_dir() -> Path:
    """Where the quadrature-error tables are kept: ``$XDG_CACHE_HOME/lcpbench/quadrature``
    (``XDG_CACHE_HOME`` defaults to ``~/.cache``)."""
    base = os.environ.get("XDG_CACHE_HOME") or ""
    root = Path(base) if base.strip() and Path(base).is_absolute() else Path.home() / ".cache"
    return root / "lcpbench" / "quadrature"


def _table_path(p: int, q: int, seed: int) -> Path:
    """The file of one table, keyed by ``(p, q, RHO_GRID, seed, version)``."""
    grid = hashlib.sha256(np.ascontiguousarray(RHO_GRID).tobytes()).hexdigest()[:16]
    return (quadrature_cache_dir()
            / f"p{p}-q{q}-seed{seed}-v{QUADRATURE_CACHE_VERSION}-rho{grid}.npz")


def _read_table(path: Path, p: int, q: int, seed: int) -> Optional[np.ndarray]:
    """The table stored in ``path`` if it is the one asked for, else None (with a warning
    naming the file when it exists but does not match)."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as f:
            key = tuple(int(f[k]) for k in ("p", "q", "seed", "version"))
            rho, err = np.asarray(f["rho"], dtype=float), np.asarray(f["errors"], dtype=float)
        ok = (key == (p, q, seed, QUADRATURE_CACHE_VERSION) and rho.shape == RHO_GRID.shape
              and np.array_equal(rho, RHO_GRID) and err.shape == RHO_GRID.shape
              and bool(np.all(np.isfinite(err) & (err >= 0))))
        why = "its key or values do not match"
    except Exception as exc:                      # truncated, not an npz, missing member
        ok, why = False, f"{type(exc).__name__}: {exc}"
    if ok:
        return err
    warnings.warn(f"quadrature-error table {path} is not valid ({why}); measuring it again "
                  "and replacing the file", RuntimeWarning, stacklevel=3)
    return None


def _write_table(path: Path, p: int, q: int, seed: int, err: np.ndarray) -> None:
    """Store a table atomically (temporary file beside it, fsync, rename); a cache that
    cannot be written is skipped with a warning (the table is then measured per process)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, p=p, q=q, seed=seed, version=QUADRATURE_CACHE_VERSION,
                         rho=RHO_GRID, errors=err)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError as exc:
        warnings.warn(f"cannot keep the quadrature-error table in {path.parent} ({exc}); it "
                      "will be measured again by the next process (set XDG_CACHE_HOME to a "
                      "writable folder)", RuntimeWarning, stacklevel=3)


@cache
def _error_table(p: int, q: int, seed: int = 0) -> np.ndarray:
    """:func:`quadrature_errors` on :data:`RHO_GRID`: once per process, and once per
    machine through the disk cache (:func:`quadrature_cache_dir`), validated on read."""
    path = _table_path(p, q, seed)
    err = _read_table(path, p, q, seed)
    if err is None:
        err = quadrature_errors(p, q, RHO_GRID, seed=seed)
        _write_table(path, p, q, seed, err)
    err.setflags(write=False)
    return err


def quadrature_radius(p: int, q: int, tol: float) -> float:
    """Distance (in source radii, from the source centre) beyond which direct quadrature on
    the grid of order q of a degree-p density is accurate to ``tol`` (per unit max |sigma|).

    Measured, not modelled: the traction of four random band-limited densities in 144
    directions is compared with the exact exterior expansion at the distances
    :data:`RHO_GRID` (1.02 to ~400 radii, 4 % apart; once per ``(p, q)``, kept in memory
    and on disk, :func:`quadrature_cache_dir`); the
    radius is the grid distance just above the farthest one where the error exceeds
    ``tol / 4`` (a factor 4 margin for densities other than the samples).  ``inf`` when that happens at the last grid distance.
    """
    p, q = _check_p(p), _check_p(q)
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"quadrature tolerance {tol!r} must be a positive number, e.g. 1e-10")
    bad = np.nonzero(_error_table(p, q) > 0.25 * tol)[0]
    if bad.size == 0:
        return float(RHO_GRID[0])
    k = int(bad[-1]) + 1
    return float(RHO_GRID[k]) if k < RHO_GRID.size else float("inf")
