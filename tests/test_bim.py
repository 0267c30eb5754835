"""Tests of the boundary-integral sphere mobility (model="bim")."""

from __future__ import annotations

import importlib.util
import itertools
import pathlib

import numpy as np
import pytest

from lcpbench.problems.suspension.bim import (
    BimConvergenceWarning,
    BimMobility,
    bim_mobility,
)
from lcpbench.problems.suspension.bim.farfield import DirectSums, FmmSums
from lcpbench.problems.suspension.bim.harmonics import unit_field
from lcpbench.problems.suspension.bim.sphere_vsh import (
    expansion_coefficients,
    grid_levels,
    quadrature_errors,
    quadrature_radius,
    rigid_density,
    s_eigenvalue,
    sampled_basis,
    self_operators,
    sphere_grid,
    traction_eigenvalue,
    vsh_basis,
)

# some tests here set small block budgets on purpose (the on-the-fly path); the pair plan
# warns when a budget leaves pairs unblocked (bim/pairs.py)
pytestmark = pytest.mark.filterwarnings("ignore:near_block_mb = .* leaves:RuntimeWarning")

_SERIES = pathlib.Path(__file__).with_name("stokes_series.py")
_spec = importlib.util.spec_from_file_location("stokes_series_for_bim", _SERIES)
series = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(series)


def _dense(op) -> np.ndarray:
    return np.column_stack([op @ e for e in np.eye(op.shape[1])])


# ---- step 1: grid, VSH and spectral self operators -------------------------------------

@pytest.mark.parametrize("p", [1, 2, 5, 8])
def test_grid_quadrature_and_analysis(p):
    g = sphere_grid(p)
    assert g.size == 2 * p * (p + 1)
    assert abs(g.weights.sum() - 4 * np.pi) < 1e-13
    b = vsh_basis(p)
    # analysis inverts synthesis on every column that is not the aliased (n=m=p, sine) pair
    ok = ~((b.degree == p) & (b.order == p) & b.sine)
    if p == 1:
        ok[:] = True
    AB = b.A @ b.B
    assert np.abs(AB[np.ix_(ok, ok)] - np.eye(ok.sum())).max() < 1e-12


@pytest.mark.parametrize("p", [2, 4, 8])
def test_self_operator_eigenvalues_match_table(p):
    b = vsh_basis(p)
    so = self_operators(p)
    for k in range(b.B.shape[1]):
        if b.degree[k] == p and b.order[k] == p:
            continue
        kind, n, col = "VWX"[b.kind[k]], int(b.degree[k]), b.B[:, k]
        assert np.abs(so.S @ col - s_eigenvalue(kind, n) * col).max() < 1e-13
        assert np.abs(so.Kp @ col - traction_eigenvalue(kind, n) * col).max() < 1e-13
    # spot values of the table
    assert traction_eigenvalue("V", 1) == pytest.approx(9 / 15)
    assert s_eigenvalue("W", 1) == pytest.approx(2 / 3)
    assert s_eigenvalue("X", 1) == pytest.approx(1 / 3)


@pytest.mark.parametrize("p", [1, 3, 8])
def test_rigid_modes_and_constant_density(p):
    so = self_operators(p)
    F, T = np.array([1.0, -2.0, 0.5]), np.array([0.3, 1.0, -0.7])
    rigid = rigid_density(p, F, T).reshape(-1)
    # rigid densities are the null space of 1/2 + K' and are kept by L = B'C
    assert np.abs(so.Kp @ rigid).max() < 1e-14
    assert np.abs(so.L @ rigid - rigid).max() < 1e-14
    # S of a uniform density F/(4 pi) is the uniform velocity F/(6 pi)
    u = so.S @ rigid_density(p, F, np.zeros(3)).reshape(-1)
    assert np.abs(u.reshape(-1, 3) - F / (6 * np.pi)).max() < 1e-14
    # S of the torque density is the rotation T/(8 pi) x n
    u = so.S @ rigid_density(p, np.zeros(3), T).reshape(-1)
    assert np.abs(so.readout @ u - np.r_[0, 0, 0, T / (8 * np.pi)]).max() < 1e-14


def test_exterior_expansion_matches_quadrature_and_jump():
    """The compiled exterior expansion equals a fine direct quadrature off the
    sphere and tends to the spectral operators on it (S, and -1/2 + K' = table - 1)."""
    p, rng = 6, np.random.default_rng(3)
    b, so, g = vsh_basis(p), self_operators(p), sphere_grid(p)
    sig = b.B @ rng.standard_normal(b.B.shape[1])
    D = expansion_coefficients(p, sig[None])[0]
    work = np.empty((p + 3, p + 3), dtype=complex)
    u, G, gP = np.empty(3), np.empty((3, 3)), np.empty(3)
    # fine quadrature of the interpolated density (order 30 grid)
    Bq = sampled_basis(p, 30)
    gq = sphere_grid(30)
    f = gq.weights[:, None] * (Bq @ (b.A @ sig)).reshape(-1, 3)
    for x in (np.array([1.6, 0.3, -0.8]), np.array([3.0, 1.0, 2.0])):
        P = unit_field(x, D, p, work, u, G, gP)
        r = x[None, :] - gq.nodes
        d = np.linalg.norm(r, axis=1)
        rf = np.sum(r * f, axis=1)
        ud = (f / d[:, None] + (rf / d ** 3)[:, None] * r).sum(0) / (8 * np.pi)
        sd = -3 / (4 * np.pi) * np.einsum("k,ki,kj->ij", rf / d ** 5, r, r)
        assert np.abs(u - ud).max() < 1e-12 * np.abs(ud).max()
        assert np.abs(-P * np.eye(3) + G + G.T - sd).max() < 1e-12 * np.abs(sd).max()
    vel, trac = [], []
    for k in range(g.size):
        P = unit_field(g.nodes[k] * (1 + 1e-10), D, p, work, u, G, gP)
        vel.append(u.copy())
        trac.append((-P * np.eye(3) + G + G.T) @ g.nodes[k])
    scale = np.abs(sig).max()
    assert np.abs(np.ravel(vel) - so.S @ sig).max() < 1e-8 * scale
    assert np.abs(np.ravel(trac) - (so.Kp @ sig - sig)).max() < 1e-7 * scale


# ---- step 2: one sphere ------------------------------------------------------------------

# p = 10-12 take 6-8 s of CPU each (most of this file's time); p = 1-9 check the same
# exactness in the README's command, and .ci/run runs the rest.
@pytest.mark.parametrize("p", [*range(1, 10), *(pytest.param(p, marks=pytest.mark.slow)
                                                 for p in range(10, 13))])
def test_one_sphere_exact(p):
    ft = np.array([1.0, -2.0, 3.0, 0.5, 1.5, -1.0])
    for a, mu in ((1.0, 1.0), (0.3, 2.5), (4.0, 0.1)):
        A = bim_mobility([[0.1, 0.2, 0.3]], a, p=p, mu=mu)
        u = A @ ft
        exact = np.r_[ft[:3] / (6 * np.pi * mu * a), ft[3:] / (8 * np.pi * mu * a ** 3)]
        assert np.abs(u - exact).max() <= 1e-12 * np.abs(exact).max()


# ---- step 3/4: two spheres against the bispherical series --------------------------------

def _two_sphere_lambdas(d, p, axis=(1.0, 2.0, -0.5)):
    ax = np.asarray(axis) / np.linalg.norm(axis)
    A = bim_mobility(np.array([[0.0, 0.0, 0.0], d * ax]) + 0.3, 1.0, p=p, eps_gmres=1e-12)
    f = np.zeros(12)
    f[:3], f[6:9] = ax, ax
    lsj = 1.0 / (6 * np.pi * np.dot((A @ f)[:3], ax))
    f[6:9] = -ax
    lb = 1.0 / (6 * np.pi * np.dot((A @ f)[:3], ax))
    return lsj, lb


@pytest.mark.parametrize("d, tol", [(2.5, 1e-4), (3.0, 1e-6), (4.0, 1e-6), (6.0, 1e-6)])
def test_two_spheres_match_series_p8(d, tol):
    lsj, lb = _two_sphere_lambdas(d, 8)
    assert abs(lsj / series.stimson_jeffery_lambda(d) - 1) <= tol
    assert abs(lb / series.brenner_lambda(d) - 1) <= tol


def test_two_spheres_spectral_decay_in_p():
    d = 3.0
    exact = series.brenner_lambda(d)
    errs = [abs(_two_sphere_lambdas(d, p)[1] / exact - 1) for p in (2, 4, 6, 8)]
    assert all(e2 < 0.25 * e1 for e1, e2 in zip(errs, errs[1:])), errs


def _cluster(M, seed=0, spacing=2.3):
    rng = np.random.default_rng(seed)
    g = np.arange(2) * spacing
    c = np.array([[x, y, z] for x in g for y in g for z in g])[:M]
    return c + 0.05 * rng.standard_normal(c.shape), 1.0 + 0.1 * rng.random(M)


def test_cluster_near_symmetric_positive_definite():
    # 6 spheres, radii 1-1.1, smallest gap about 0.38: measured asymmetry 2.5e-4 at p = 6
    c, r = _cluster(6, spacing=2.6)
    A = bim_mobility(c, r, p=6, eps_gmres=1e-10)
    Md = _dense(A)
    asym = np.linalg.norm(Md - Md.T) / np.linalg.norm(Md)
    assert asym < 1e-3
    assert np.linalg.eigvalsh(0.5 * (Md + Md.T)).min() > 0
    assert len(A.gmres_iterations) == 36 and max(A.gmres_iterations) < 40


def test_translation_and_rotation_invariance():
    c, r = _cluster(4, seed=2, spacing=2.6)
    rng = np.random.default_rng(5)
    ft = rng.standard_normal(24)
    u0 = bim_mobility(c, r, p=6, eps_gmres=1e-12) @ ft
    u1 = bim_mobility(c + np.array([3.0, -1.0, 7.5]), r, p=6, eps_gmres=1e-12) @ ft
    assert np.abs(u1 - u0).max() < 1e-10 * np.abs(u0).max()
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    ftq = (ft.reshape(-1, 3) @ Q.T).reshape(-1)
    uq = bim_mobility(c @ Q.T, r, p=6, eps_gmres=1e-12) @ ftq
    back = (uq.reshape(-1, 3) @ Q).reshape(-1)
    # the grid is not rotation invariant: agreement is at discretisation accuracy
    assert np.abs(back - u0).max() < 1e-3 * np.abs(u0).max()


def test_far_pairs_use_direct_quadrature_consistently():
    c = np.array([[0.0, 0.0, 0.0], [40.0, 3.0, -2.0], [2.6, 0.4, 0.1]])
    A = BimMobility(c, 1.0, p=8, eps_gmres=1e-12)
    assert A.n_far_pairs > 0 and A.n_near_pairs > 0
    ft = np.random.default_rng(0).standard_normal(18)
    u = A @ ft
    # same configuration with every pair treated by expansions: no source grid is
    # accurate to a quadrature tolerance this tight at any distance
    B = BimMobility(c, 1.0, p=8, eps_gmres=1e-12, quad_tol=1e-300)
    assert B.n_far_pairs == 0 and B.n_near_pairs == 6
    assert np.abs(B @ ft - u).max() < 1e-11 * np.abs(u).max()


def test_warm_start_and_iterations_recorded():
    c, r = _cluster(3)
    A = bim_mobility(c, r, p=4, eps_gmres=1e-10)
    ft = np.random.default_rng(1).standard_normal(18)
    u1 = A @ ft
    u2 = A @ ft
    assert np.abs(u1 - u2).max() < 1e-8 * np.abs(u1).max()
    assert A.gmres_iterations[1] <= 1 < A.gmres_iterations[0]
    assert all(res < 1e-9 for res in A.residuals)
    assert np.all(A @ np.zeros(18) == 0)


def test_nonconvergence_is_reported():
    c, r = _cluster(2)
    A = BimMobility(c, r, p=4, eps_gmres=1e-12, maxiter=1, recycle=0)
    with pytest.warns(BimConvergenceWarning, match="relative residual"):
        A @ np.ones(12)
    B = BimMobility(c, r, p=4, eps_gmres=1e-12, maxiter=1, recycle=0, on_failure="raise")
    with pytest.raises(RuntimeError, match="relative residual"):
        B @ np.ones(12)


@pytest.mark.parametrize("kwargs, match", [
    (dict(p=0), "p = 0"), (dict(p=2.5), "p = 2.5"), (dict(p=True), "p = True"),
    (dict(eps_gmres=0.0), "eps_gmres"), (dict(eps_gmres=float("nan")), "eps_gmres"),
    (dict(eps_gmres="x"), "eps_gmres"), (dict(mu=-1.0), "mu"),
])
def test_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        bim_mobility([[0, 0, 0], [3, 0, 0]], 1.0, **kwargs)


def test_bad_configurations():
    with pytest.raises(ValueError, match="overlap"):
        bim_mobility([[0, 0, 0], [1.5, 0, 0]], 1.0, p=2)
    with pytest.raises(ValueError, match="shape"):
        bim_mobility([[0, 0]], 1.0, p=2)
    with pytest.raises(ValueError, match="radii"):
        bim_mobility([[0, 0, 0]], -1.0, p=2)
    A = bim_mobility([[0, 0, 0], [3, 0, 0]], 1.0, p=2)
    with pytest.raises(ValueError, match="finite"):
        A @ np.full(12, np.nan)


# ---- accuracy-driven near/far split, source-grid levels, FMM far field ---------------------

@pytest.mark.parametrize("p", [4, 8])
def test_quadrature_radius_criterion(p):
    """Just beyond the measured radius of every source grid, direct quadrature agrees with
    the exact expansion to quad_tol (fresh densities and directions); well inside it does not."""
    tol = 1e-8
    for q in grid_levels(p):
        r = quadrature_radius(p, q, tol)
        errs = quadrature_errors(p, q, np.array([r, 1.1 * r, 2.0 * r]), seed=7)
        assert errs.max() <= tol, (q, r, errs)
        assert quadrature_errors(p, q, np.array([0.7 * r]), seed=7)[0] > 0.05 * tol
    radii = [quadrature_radius(p, q, tol) for q in grid_levels(p)]
    assert all(b <= a for a, b in itertools.pairwise(radii))     # finer grids reach closer


def _random_cluster(M, seed, box):
    rng = np.random.default_rng(seed)
    c = [rng.uniform(0, box, 3)]
    while len(c) < M:
        x = rng.uniform(0, box, 3)
        if min(np.linalg.norm(x - y) for y in c) > 2.3:
            c.append(x)
    return np.array(c)


def test_levels_and_blocks_agree_with_all_expansions():
    """The product with grid levels + blocks + on-the-fly expansions equals the product with
    exact expansions for every pair, to quad_tol."""
    c = _random_cluster(6, 3, 9.0)
    # node sampling for both, so that only the quadrature split differs (the projected
    # near field differs from node sampling by the order-p discretisation error)
    # the direct build (pair_blocks="direct"): table blocks are the exact projection, not
    # node sampling (tests/test_bim_coaxial.py compares them)
    A = BimMobility(c, 1.0, p=6, eps_gmres=1e-8, near_block_mb=0.3, near_upsample=1,
                    pair_blocks="direct")
    assert A.n_block_pairs > 0 and A.plan.expansions.fly_idx.size > 0 and A.n_far_pairs > 0
    assert sum(v > 0 for v in A.pairs_per_level.values()) >= 2
    s = np.random.default_rng(0).standard_normal(A.M * 3 * A.N)
    s = (vsh_basis(6).B @ vsh_basis(6).A @ s.reshape(A.M, -1).T).T.reshape(-1)
    B = BimMobility(c, 1.0, p=6, eps_gmres=1e-8, near_upsample=1, quad_tol=1e-300,
                    pair_blocks="direct")
    # stored blocks act in coefficients (their output's nodal complement never reaches a
    # velocity, bim/pairs.py), so compare the outputs' degree <= p parts
    Ap = vsh_basis(6).A
    ya, yb = ((Ap @ y.reshape(A.M, -1).T).T for y in (A.apply_bie(s), B.apply_bie(s)))
    assert np.abs(ya - yb).max() <= 20 * A.quad_tol * np.abs(s).max()


def test_fmm_far_field_matches_direct():
    c = _random_cluster(10, 4, 14.0)
    ft = np.random.default_rng(2).standard_normal(60)
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-9)
    F = BimMobility(c, 1.0, p=4, eps_gmres=1e-9, far="fmm")
    s = np.random.default_rng(1).standard_normal(A.M * 3 * A.N)
    assert np.abs(F.apply_bie(s) - A.apply_bie(s)).max() <= 1e-9 * np.abs(s).max()
    ua, uf = A @ ft, F @ ft
    assert np.abs(uf - ua).max() <= 1e-8 * np.abs(ua).max()
    with pytest.raises(ValueError, match="far"):
        BimMobility(c, 1.0, p=4, far="tree")
    # the strategies: the direct sums follow the tolerance ladder on coarse grids, the FMM
    # is not relaxed and sums every native point (minus the pairs it must not include)
    assert (A.setup.far, F.setup.far) == ("direct", "fmm")
    assert isinstance(A.setup.far_field, DirectSums) and isinstance(F.setup.far_field, FmmSums)
    assert len(A.tolerance_ladder) > 1 and len(F.tolerance_ladder) == 1
    assert F.plan.quadrature.lvl_spheres[F.plan.quadrature.native].size == F.M
    assert F.setup.far_field.removed is not None and F.setup.far_field.removed[2].size


def test_relaxed_gmres_reaches_true_residual():
    """Relaxed products (looser quadrature late in GMRES) still give a full-accuracy
    residual below eps_gmres and the same mobility as a much tighter solve."""
    c = _random_cluster(8, 5, 8.0)
    ft = np.random.default_rng(3).standard_normal(48)
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-8)
    assert len(A.tolerance_ladder) == 7 and A.tolerance_ladder[0] == pytest.approx(1e-10)
    u = A @ ft
    assert A.residuals[-1] <= 1e-8
    ref = BimMobility(c, 1.0, p=4, eps_gmres=1e-12) @ ft
    assert np.abs(u - ref).max() <= 1e-7 * np.abs(ref).max()


def _dense_bie(A: BimMobility) -> np.ndarray:
    n = A.M * 3 * A.N
    return np.column_stack([A.apply_bie(A.precondition(e)) for e in np.eye(n)])


@pytest.mark.parametrize("p", [4, 6])
def test_projected_near_field_keeps_the_operator_definite(p):
    """Two spheres 0.01a apart along a grid axis: a node of each grid faces the other
    sphere.  Sampling the peaked near traction there (near_upsample=1) gives the
    preconditioned operator eigenvalues with negative real part (GMRES stalled on
    packed lattices); projecting it from the order-2p grid keeps them positive, and
    the same for a generic orientation."""
    for axis in ([1.0, 0.0, 0.0], [1.0, 1.0, 1.0]):
        e = np.array(axis) / np.linalg.norm(axis)
        c = np.array([[0.0, 0.0, 0.0], 2.01 * e])
        lam = np.linalg.eigvals(_dense_bie(BimMobility(c, 1.0, p=p))).real.min()
        assert lam > 0.15, (axis, lam)
    c = np.array([[0.0, 0.0, 0.0], [2.01, 0.0, 0.0]])
    # node sampling of the direct build (the table's blocks are the exact projection)
    node = BimMobility(c, 1.0, p=p, near_upsample=1, pair_blocks="direct")
    assert np.linalg.eigvals(_dense_bie(node)).real.min() < 0


def test_gmres_converges_on_a_touching_lattice_at_even_p():
    """3 x 3 x 3 cubic lattice with 0.01a gaps along the axes (54 node-facing contacts):
    converged in few iterations at p = 4 (stalled above 1e-4 with node sampling)."""
    g = np.arange(3) * 2.01
    c = np.array([[x, y, z] for x in g for y in g for z in g])
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-8, maxiter=120, on_failure="raise")
    A @ np.random.default_rng(0).standard_normal(6 * 27)
    assert A.residuals[-1] <= 1e-8 and A.gmres_iterations[-1] <= 60


def test_projected_blocks_equal_on_the_fly_projection():
    c = _random_cluster(5, 5, 6.0)
    ft = np.random.default_rng(4).standard_normal(30)
    # the direct build: its blocks are the on-the-fly projection stored
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-11, pair_blocks="direct")
    B = BimMobility(c, 1.0, p=4, eps_gmres=1e-11, near_block_mb=0, pair_blocks="direct")
    assert A.n_block_pairs > 0 and B.n_block_pairs == 0 and B.plan.expansions.fly_idx.size > 0
    ua, ub = A @ ft, B @ ft
    assert np.abs(ua - ub).max() <= 1e-9 * np.abs(ua).max()


def test_blocks_in_coefficients_leave_node_sampled_products_unchanged():
    """Stored blocks keep only their output's degree <= p part (bim/pairs.py); with node-sampled
    near fields the nodal output has more, and the mobility must not see it: the product
    equals the one with every pair evaluated on the fly at the nodes."""
    c = _random_cluster(5, 5, 6.0)
    ft = np.random.default_rng(5).standard_normal(30)
    # the direct build: node-sampled blocks (the table's are the exact projection)
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-12, near_upsample=1, pair_blocks="direct")
    B = BimMobility(c, 1.0, p=4, eps_gmres=1e-12, near_upsample=1, near_block_mb=0,
                    pair_blocks="direct")
    assert A.n_block_pairs > 0 and B.n_block_pairs == 0 and B.plan.expansions.fly_idx.size > 0
    s = np.random.default_rng(6).standard_normal(A.M * 3 * A.N)
    nodal = np.abs(A.apply_bie(s) - B.apply_bie(s)).max() / np.abs(s).max()
    assert nodal > 1e-8                        # the blocks' nodal outputs do differ ...
    ua, ub = A @ ft, B @ ft
    assert np.abs(ua - ub).max() <= 1e-10 * np.abs(ua).max()    # ... the velocities do not


def test_preconditioned_operator_drops_only_the_identity_self_part():
    """GMRES's operator ``G y`` adds ``y`` for the self part (the one-sphere preconditioner
    inverts it exactly) and, with every pair blocked, reads the coefficients of ``P y`` in
    one product: the same values as applying the whole operator to ``P y``, whether the
    pairs are blocked, on the fly or summed directly."""
    c = _random_cluster(5, 5, 6.0)
    y = np.random.default_rng(8).standard_normal(5 * 3 * sphere_grid(4).size)
    # no budget, direct build: the pairs on the fly (the table's are rotated on the fly)
    for kw, blocked in (({}, True), ({"near_block_mb": 0, "pair_blocks": "direct"}, False)):
        A = BimMobility(c, 1.0, p=4, eps_gmres=1e-12, **kw)
        plan = A.plan
        assert (A.n_block_pairs == 20) == blocked
        assert bool(plan.expansions.fly_idx.size or plan.expansions.flyn_idx.size or plan.quadrature.n_src) != blocked
        ref = A.apply_bie(A.precondition(y))
        got = A.apply_preconditioned(y)
        assert np.abs(got - ref).max() <= 1e-11 * np.abs(ref).max()
        # the interactions are really there: G is not the identity
        assert np.abs(got - y).max() > 1e-3 * np.abs(y).max()
    one = BimMobility(np.zeros((1, 3)), 1.0, p=4)
    y1 = y[:3 * sphere_grid(4).size]
    assert np.allclose(one.apply_preconditioned(y1), one.apply_bie(one.precondition(y1)),
                       rtol=1e-11, atol=1e-12)


def test_near_upsample_is_checked():
    with pytest.raises(ValueError, match="near_upsample"):
        BimMobility(np.zeros((1, 3)), 1.0, p=3, near_upsample=0)
