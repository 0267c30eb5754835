"""Tests of the transposed boundary-integral mobility (``BimMobility.rmatvec``).

The discrete BIM mobility is only nearly symmetric, so ``rmatvec`` must be the exact
transpose of the discrete map, piece by piece: dot-product tests ``<y, A x> = <A' y, x>``.
"""

from __future__ import annotations

import numpy as np
import pytest

from lcpbench.problems.suspension.bim import BimMobility

# some tests here set small block budgets on purpose (the on-the-fly path); the pair plan
# warns when a budget leaves pairs unblocked (bim/pairs.py)
pytestmark = pytest.mark.filterwarnings("ignore:near_block_mb = .* leaves:RuntimeWarning")


def _cluster(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Six spheres in an 8-wide box, a companion 0.05 from the first (where the discrete
    mobility is clearly not symmetric) and three distant spheres; radii 0.8-1.1.

    At eps_gmres = 1e-12 this gives stored blocks, on-the-fly expansion pairs and direct
    pairs on two (p = 4) or three (p = 6) source-grid levels."""
    rng = np.random.default_rng(seed)
    c = [rng.uniform(0, 8.0, 3)]
    while len(c) < 6:
        x = rng.uniform(0, 8.0, 3)
        if min(np.linalg.norm(x - y) for y in c) > 2.3:
            c.append(x)
    c = np.vstack([c, [[18.0, 3.0, 2.0], [40.0, -5.0, 9.0], [8.0, 30.0, -6.0]]])
    r = 0.8 + 0.3 * np.random.default_rng(seed).random(len(c))
    away = c[0] - c[:6].mean(axis=0)
    away /= np.linalg.norm(away)
    c = np.vstack([c, c[0] + (r[0] + 0.9 + 0.05) * away])
    r = np.r_[r, 0.9]
    gaps = np.linalg.norm(c[:, None] - c[None], axis=2) - r[:, None] - r[None]
    assert np.sort(gaps[np.triu_indices(len(c), 1)])[0] == pytest.approx(0.05)
    return c, r


_BLOCK_MB = {3: 0.05, 4: 0.2, 6: 0.6}       # room for a few blocks, the rest on the fly


def _dot_error(lhs: float, rhs: float) -> float:
    return abs(lhs - rhs) / abs(lhs)


def _check_structure(A: BimMobility, min_levels: int) -> None:
    assert A.n_block_pairs > 0, "no stored near blocks"
    assert A.plan.expansions.fly_idx.size > 0, "no on-the-fly expansion pairs"
    assert sum(v > 0 for v in A.pairs_per_level.values()) >= min_levels, A.pairs_per_level


@pytest.mark.parametrize("p, eps", [(4, 1e-12), (6, 1e-12), (4, 1e-8), (6, 1e-8)])
def test_pieces_are_transposes(p, eps):
    """R', A_bie', P' and Bt' against their forward pieces to 1e-12 (eps 1e-8 has a looser
    quadrature tolerance: coarse, native and upsampled source grids all occur)."""
    c, r = _cluster()
    A = BimMobility(c, r, p=p, eps_gmres=eps, mu=1.7, near_block_mb=_BLOCK_MB[p])
    _check_structure(A, 2)
    rng = np.random.default_rng(p)
    n = A.M * 3 * A.N
    x, y = rng.standard_normal(n), rng.standard_normal(n)
    u = rng.standard_normal(6 * A.M)
    T = A.adjoint_pieces
    assert _dot_error(y @ A.apply_bie(x), T.apply_bie(y) @ x) <= 1e-12
    assert _dot_error(u @ A.velocities(x).reshape(-1), T.velocities(u) @ x) <= 1e-12
    assert _dot_error(y @ A.precondition(x), T.precondition(y) @ x) <= 1e-12
    assert _dot_error(y @ A.rhs(u), T.rhs(y) @ u) <= 1e-12


def test_pieces_with_coarse_grids_and_node_sampling():
    """Looser quadrature (truncated coarse source grids) and near_upsample=1 (no projection)."""
    c, r = _cluster(5)
    A = BimMobility(c, r, p=6, eps_gmres=1e-6, mu=0.4, near_block_mb=0.6, near_upsample=1)
    assert A.pairs_per_level[3] + A.pairs_per_level[5] > 0, A.pairs_per_level
    _check_structure(A, 3)
    rng = np.random.default_rng(11)
    n = A.M * 3 * A.N
    x, y = rng.standard_normal(n), rng.standard_normal(n)
    assert _dot_error(y @ A.apply_bie(x), A.adjoint_pieces.apply_bie(y) @ x) <= 1e-12


@pytest.mark.parametrize("p", [4, 6])
def test_mobility_dot_product(p):
    """<y, M x> = <M' y, x> to 1e-9 with eps_gmres = 1e-12 (polydisperse, mu != 1), while
    M' y differs from M y by the discrete asymmetry."""
    c, r = _cluster()
    A = BimMobility(c, r, p=p, eps_gmres=1e-12, mu=1.7, near_block_mb=_BLOCK_MB[p])
    _check_structure(A, 2)
    rng = np.random.default_rng(20 + p)
    x, y = rng.standard_normal(6 * A.M), rng.standard_normal(6 * A.M)
    Mx, Mty = A @ x, A.rmatvec(y)
    assert _dot_error(y @ Mx, Mty @ x) <= 1e-9
    assert len(A.adjoint_iterations) == 1 and A.adjoint_iterations[0] > 1
    assert A.adjoint_residuals[0] <= 1e-11
    My = A @ y
    assert np.abs(Mty - My).max() > 1e-5 * np.abs(My).max()      # M is not symmetric


def test_packed_lattice_dot_product():
    """3 x 3 x 3 lattice with 0.01a gaps (every pair a stored block), where the discrete
    mobility is far from symmetric: the transpose still passes the dot-product test."""
    g = np.arange(3) * 2.01
    c = np.array([[x, y, z] for x in g for y in g for z in g])
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-12, maxiter=300, on_failure="raise")
    rng = np.random.default_rng(7)
    x, y = rng.standard_normal(162), rng.standard_normal(162)
    Mx = A @ x
    assert _dot_error(y @ Mx, A.rmatvec(y) @ x) <= 1e-9
    assert _dot_error(y @ Mx, (A @ y) @ x) > 1e-4


def test_dense_transpose_three_spheres():
    c = np.array([[0.0, 0.0, 0.0], [2.3, 0.4, -0.2], [0.9, 2.4, 0.5]])
    r = np.array([1.0, 1.1, 0.9])
    A = BimMobility(c, r, p=3, eps_gmres=1e-12, mu=2.0, near_block_mb=_BLOCK_MB[3])
    E = np.eye(18)
    Md = np.column_stack([A @ e for e in E])
    Mt = np.column_stack([A.rmatvec(e) for e in E])
    scale = np.abs(Md).max()
    assert np.abs(Mt - Md.T).max() <= 1e-9 * scale
    assert np.abs(Md - Md.T).max() > 1e-6 * scale                # the check is not vacuous
    # scipy's adjoint and transpose views use the same product
    y = np.arange(18.0)
    assert np.allclose(A.T @ y, Mt @ y, rtol=1e-9, atol=1e-9 * scale * 18)
    assert np.allclose(A.H @ y, Mt @ y, rtol=1e-9, atol=1e-9 * scale * 18)


def test_fmm_adjoint_dot_product():
    """far="fmm": the adjoint transposes the sums the FMM approximates by direct sums, so the
    dot-product test holds to the FMM tolerance.  Two spheres ~200 radii away give pairs on
    the native grid (the FMM's share) besides upsampled, blocked and on-the-fly pairs."""
    c, r = _cluster()
    c = np.vstack([c, [[230.0, 10.0, -5.0], [-20.0, 210.0, 40.0]]])
    r = np.r_[r, 1.2, 0.9]
    F = BimMobility(c, r, p=4, eps_gmres=1e-9, mu=1.3, far="fmm", near_block_mb=0.2)
    assert F.pairs_per_level[4] > 0 and F.pairs_per_level[8] > 0
    _check_structure(F, 2)
    rg = np.random.default_rng(9)
    n = F.M * 3 * F.N
    s, t = rg.standard_normal(n), rg.standard_normal(n)
    assert _dot_error(t @ F.apply_bie(s), F.adjoint_pieces.apply_bie(t) @ s) <= 1e-11
    x, y = rg.standard_normal(6 * F.M), rg.standard_normal(6 * F.M)
    assert _dot_error(y @ (F @ x), F.rmatvec(y) @ x) <= 1e-8
    D = BimMobility(c, r, p=4, eps_gmres=1e-9, mu=1.3, near_block_mb=0.2)
    ref = D.rmatvec(y)
    assert np.abs(F.rmatvec(y) - ref).max() <= 1e-8 * np.abs(ref).max()


def test_one_sphere_adjoint_equals_forward():
    A = BimMobility([[0.5, -1.0, 2.0]], 0.7, p=5, mu=3.0)
    ft = np.array([1.0, -2.0, 3.0, 0.5, 1.5, -1.0])
    assert np.abs(A.rmatvec(ft) - A @ ft).max() <= 1e-13 * np.abs(A @ ft).max()
    # G' is the identity for one sphere: the first direction solves it exactly
    assert A.adjoint_iterations == [1]


def test_adjoint_warm_start_zero_input_and_separate_history():
    c, r = _cluster()
    A = BimMobility(c[:4], r[:4], p=4, eps_gmres=1e-10)
    rng = np.random.default_rng(1)
    x, y = rng.standard_normal(24), rng.standard_normal(24)
    u1 = A @ x
    v1 = A.rmatvec(y)
    v2 = A.rmatvec(y)
    u2 = A @ x
    assert np.abs(v1 - v2).max() <= 1e-8 * np.abs(v1).max()
    assert A.adjoint_iterations[1] <= 1 < A.adjoint_iterations[0]
    assert A.gmres_iterations[1] <= 1 < A.gmres_iterations[0]     # forward history untouched
    assert np.abs(u1 - u2).max() <= 1e-8 * np.abs(u1).max()
    assert np.all(A.rmatvec(np.zeros(24)) == 0)


def test_adjoint_nonconvergence_is_reported():
    c, r = _cluster()
    A = BimMobility(c[:2], r[:2], p=4, eps_gmres=1e-12, maxiter=1, recycle=0)
    with pytest.warns(Warning, match="adjoint GMRES did not converge"):
        A.rmatvec(np.ones(12))
    B = BimMobility(c[:2], r[:2], p=4, eps_gmres=1e-12, maxiter=1, recycle=0, on_failure="raise")
    with pytest.raises(RuntimeError, match="relative residual"):
        B.rmatvec(np.ones(12))


def test_bad_input():
    A = BimMobility([[0, 0, 0], [3, 0, 0]], 1.0, p=2)
    y = np.ones(12)
    y[4] = np.nan
    with pytest.raises(ValueError, match="NaN or inf"):
        A.rmatvec(y)
    with pytest.raises(ValueError, match="have 7 entries; a mobility of 2 spheres needs 12"):
        A.matvec_rmatvec(np.ones(12), np.ones(7))
