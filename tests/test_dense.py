"""Dense solvers pgs and lemke: convergence, exactness, honest counts, edge cases."""

import numpy as np
import pytest
from lcp_cases import planted

import lcpbench
from lcpbench import LCP, Status


# ---------------------------------------------------------------------------- pgs
@pytest.mark.parametrize("omega", [1.0, 1.3])
@pytest.mark.parametrize("seed", range(2))
def test_pgs_converges_spd(omega, seed):
    A, b = planted(30, seed=seed, cond=20.0)
    res = lcpbench.solve(A, b, solver=f"pgs:omega={omega}", stop="kkt", tol=1e-9)
    assert res.status is Status.converged and res.solved, res.summary()
    assert res.mvp_only is False
    # x0 = 0: the initial w is free, then exactly one counted MVP per sweep.
    assert res.mvps == res.info["sweeps"] == res.iterations
    ref = lcpbench.reference(LCP(A, b))
    np.testing.assert_allclose(res.w, ref.w, atol=1e-7)


def test_pgs_budget_and_warm_start():
    A, b = planted(30, seed=3, cond=1e3)
    res = lcpbench.solve(A, b, solver="pgs", stop="kkt", tol=1e-12, max_emvps=3)
    assert res.status is Status.budget and res.mvps <= 3
    ref = lcpbench.reference(LCP(A, b))
    res = lcpbench.solve(A, b, solver="pgs", stop="kkt", tol=1e-7, x0=ref.x)
    assert res.solved and res.mvps == 1 and res.info["sweeps"] == 0


def test_pgs_omega_validated():
    A, b = planted(4)
    with pytest.raises(ValueError):
        lcpbench.solve(A, b, solver="pgs:omega=2")


# ---------------------------------------------------------------------------- lemke
@pytest.mark.parametrize("n", [1, 2, 5, 20, 60])
@pytest.mark.parametrize("rank", [None, 3])
def test_lemke_exact(n, rank):
    for seed in range(2):
        A, b = planted(n, rank=None if rank is None else min(rank, n), seed=seed)
        if np.all(b >= 0):
            b[0] = -1.0
        res = lcpbench.solve(A, b, solver="lemke", stop="kkt", tol=1e-10)
        assert res.status is Status.converged and res.solved, res.summary()
        assert res.mvps == 1 and res.mvp_only is False
        assert res.info["pivots"] >= 1
        ref = lcpbench.reference(LCP(A, b))
        scale = max(1.0, np.linalg.norm(ref.w))
        assert np.linalg.norm(res.w - ref.w) <= 1e-8 * scale
        assert abs(res.verified["objective"] - ref.objective) <= 1e-9 * max(1.0, abs(ref.objective))


@pytest.mark.parametrize("scale", [1e-12, 1e8])
def test_lemke_scale_free(scale):
    for rank in (None, 5):
        A, b = planted(40, rank=rank, seed=7)
        res = lcpbench.solve(A * scale, b * scale, solver="lemke", stop="kkt", tol=1e-10 * scale)
        assert res.status is Status.converged and res.solved, res.summary()


def test_lemke_all_inactive_is_immediate():
    A, b = planted(6, seed=1)
    res = lcpbench.solve(A, np.abs(b), solver="lemke")
    assert res.status is Status.converged and res.mvps == 0 and res.info["pivots"] == 0
    assert np.all(res.x == 0)


def test_lemke_empty_problem():
    res = lcpbench.solve(np.zeros((0, 0)), np.zeros(0), solver="lemke")
    assert res.status is Status.converged and res.x.shape == (0,)


def test_lemke_ray_termination_reported_as_infeasible():
    # w_2 = 0 x + (-1) can never be >= 0: the LCP has no solution.
    A = np.diag([1.0, 0.0])
    b = np.array([1.0, -1.0])
    res = lcpbench.solve(A, b, solver="lemke")
    assert res.status is Status.infeasible and "ray" in res.message
    assert not res.solved


def test_lemke_pivot_limit():
    A, b = planted(30, seed=0)
    res = lcpbench.solve(A, b, solver="lemke:max_pivots=2")
    assert res.status is Status.max_iter and res.info["pivots"] == 2


def _python_lemke_path(A, b):
    """Lemke's scheme I in plain numpy (no lexicographic rule, no refactoring), for
    comparing the compiled pivots' path on instances without ties."""
    n = len(b)
    s = float(np.max(np.abs(A)))
    T = np.hstack([np.eye(n), -A / s, -np.ones((n, 1))])
    rhs, basis = b / s, list(range(n))
    entering, row, pivots = 2 * n, int(np.argmin(b)), 0
    while True:
        col = T[:, entering].copy()
        if pivots:
            ok = col > 1e-12
            ratios = np.where(ok, rhs / np.where(ok, col, 1.0), np.inf)
            row = int(np.argmin(ratios))
        piv = col[row]
        T[row] /= piv
        rhs[row] /= piv
        for i in range(n):
            if i != row:
                rhs[i] -= col[i] * rhs[row]
                T[i] -= col[i] * T[row]
        leaving, basis[row] = basis[row], entering
        pivots += 1
        if leaving == 2 * n:
            return pivots
        entering = leaving + n if leaving < n else leaving - n


@pytest.mark.parametrize("seed", range(3))
def test_lemke_compiled_pivots_follow_the_textbook_path(seed):
    A, b = planted(40, seed=seed)
    res = lcpbench.solve(A, b, solver="lemke", stop="kkt", tol=1e-10)
    assert res.solved and res.info["pivots"] == _python_lemke_path(A, b)
    # refactoring the basis inverse every 3 pivots changes rounding only, not the path
    again = lcpbench.solve(A, b, solver="lemke:refactor_every=3", stop="kkt", tol=1e-10)
    assert again.info["pivots"] == res.info["pivots"]
    np.testing.assert_allclose(again.x, res.x, atol=1e-10)


def test_pgs_compiled_sweep_is_gauss_seidel():
    from lcpbench.solvers.dense_kernels import pgs_sweep

    A, b = planted(12, seed=4)
    x = np.linspace(0.0, 1.0, 12)
    want = x.copy()
    for i in range(12):                      # the sweep in Python, row by row
        want[i] = max(0.0, want[i] - 1.3 / A[i, i] * (A[i] @ want + b[i]))
    pgs_sweep(A, b, x, np.arange(12), 1.3 / np.diag(A))
    np.testing.assert_allclose(x, want, rtol=1e-14, atol=1e-15)


def test_lemke_final_solution_is_refined_or_handed_to_a_factorisation():
    from lcpbench.solvers.dense_kernels import _refined_basic_solution, basis_matrix
    rng = np.random.default_rng(3)
    n = 6
    M = rng.standard_normal((n, n))
    M = M @ M.T + n * np.eye(n)
    q = rng.standard_normal(n)
    basis = np.array([0, n + 1, 2, n + 3, 2 * n, 5])       # w, z and z0 columns
    B = basis_matrix(M, basis)
    exact = np.linalg.solve(B, q)
    drifted = np.linalg.inv(B) * (1 + 1e-6 * rng.standard_normal((n, n)))
    np.testing.assert_allclose(_refined_basic_solution(M, q, basis, drifted), exact,
                               rtol=1e-12, atol=1e-14)
    # an inverse too far off for refinement: the caller must factorise
    assert _refined_basic_solution(M, q, basis, np.zeros((n, n))).size == 0
