"""Tests of the relaxed GMRES driver of the boundary-integral mobility
(:func:`bim.gmres.relaxed_gmres`) and of the solves that use it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.linalg import LinearOperator, gmres
from threadpoolctl import threadpool_info, threadpool_limits

from lcpbench.problems.suspension.bim import BimConvergenceWarning, BimMobility
from lcpbench.problems.suspension.bim import solves as bim_solves
from lcpbench.problems.suspension.bim.gmres import relaxed_gmres
from lcpbench.toolkit.blas import one_blas_thread


def _cluster() -> tuple[np.ndarray, np.ndarray]:
    """Five polydisperse spheres, gaps 0.15-1.5 radii."""
    c = np.array([[0.0, 0.0, 0.0], [2.2, 0.1, -0.1], [0.8, 2.3, 0.4], [1.1, 0.9, 2.4],
                  [-2.6, 1.4, 0.3]])
    r = np.array([1.0, 1.05, 0.95, 1.1, 0.9])
    return c, r


def _relaxed_problem(n: int = 120, seed: int = 4):
    """A nonsymmetric well-conditioned ``A`` and a product whose rung k adds an error of
    relative size ``1e-10 * 10^k`` (five rungs), like the BIM tolerance ladder."""
    rng = np.random.default_rng(seed)
    A = np.eye(n) + 0.5 * rng.standard_normal((n, n)) / np.sqrt(n)
    E = rng.standard_normal((n, n)) / np.sqrt(n)
    log: list[tuple[int, np.ndarray]] = []

    def matvec(v: np.ndarray, k: int) -> np.ndarray:
        log.append((k, np.array(v)))
        return A @ v + 1e-10 * 10.0 ** k * (E @ v)

    return A, matvec, rng.standard_normal(n), rng.standard_normal(n), log


@pytest.mark.parametrize("restart", [60, 7])
def test_relaxes_but_checks_at_full_accuracy(restart):
    """Relaxed Krylov products, rung 0 for the start and end residuals, and the true
    residual meets rtol although late products carry errors up to 1e-6."""
    A, matvec, b, x0, log = _relaxed_problem()
    x, its, res = relaxed_gmres(matvec, b, x0, 1e-9, restart, 200, rungs=5, step=10.0)
    true = np.linalg.norm(b - A @ x) / np.linalg.norm(b)
    assert res <= 1e-9 and true <= 1.5e-9
    assert max(k for k, _ in log) > 0                      # relaxation was used
    assert log[0][0] == 0 and np.array_equal(log[0][1], x0)
    assert any(k == 0 and np.array_equal(v, x) for k, v in log)   # final residual, rung 0
    # without relaxation the same solve takes about as many iterations
    log.clear()
    _, its_exact, _ = relaxed_gmres(matvec, b, x0, 1e-9, restart, 200, rungs=1)
    assert all(k == 0 for k, _ in log)
    assert abs(its - its_exact) <= 2


def test_maxiter_counts_inner_iterations():
    _, matvec, b, x0, log = _relaxed_problem()
    x, its, res = relaxed_gmres(matvec, b, x0, 1e-14, 4, 10, rungs=1)
    assert its == 10
    assert res == pytest.approx(np.linalg.norm(b - matvec(x, 0)) / np.linalg.norm(b),
                                rel=1e-10)
    assert res > 1e-14
    assert all(k == 0 for k, _ in log)


def test_zero_start_and_converged_start():
    _, matvec, b, _, log = _relaxed_problem()
    x, its, res = relaxed_gmres(matvec, b, np.zeros(b.size), 1e-9, 60, 200, rungs=5,
                                step=10.0)
    assert res <= 1e-9 and its > 0
    log.clear()
    x2, its2, res2 = relaxed_gmres(matvec, b, x, 1e-9, 60, 200, rungs=5, step=10.0)
    assert its2 == 0 and len(log) == 1 and np.array_equal(x2, x) and res2 == res


def test_products_run_with_one_blas_thread():
    """numpy's vector work inside the solve must not start BLAS threads that compete with
    the parallel compiled kernels: every product sees BLAS limited to one thread."""
    _, matvec, b, x0, _ = _relaxed_problem(n=30)
    seen: list[int] = []

    def observed(v: np.ndarray, k: int) -> np.ndarray:
        seen.extend(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas")
        return matvec(v, k)

    with threadpool_limits(limits=2, user_api="blas"):      # two threads outside the solve
        relaxed_gmres(observed, b, x0, 1e-9, 60, 200)
        outside = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    assert seen and set(seen) == {1}
    assert set(outside) == {2}


def test_forward_adjoint_dot_product():
    """<y, M x> = <M' y, x> with both solves to eps 1e-12."""
    c, r = _cluster()
    A = BimMobility(c, r, p=4, eps_gmres=1e-12, mu=1.7)
    rng = np.random.default_rng(5)
    x, y = rng.standard_normal(6 * A.M), rng.standard_normal(6 * A.M)
    lhs, rhs = y @ (A @ x), A.rmatvec(y) @ x
    assert abs(lhs - rhs) <= 1e-9 * abs(lhs)
    assert A.adjoint_iterations[0] > 1 and A.adjoint_residuals[0] <= 1e-12
    assert A.gmres_iterations[0] > 1 and A.residuals[0] <= 1e-12


def test_nonconvergence_is_reported():
    c, r = _cluster()
    A = BimMobility(c, r, p=4, eps_gmres=1e-12, maxiter=2, recycle=0)
    with pytest.warns(BimConvergenceWarning, match="relative residual"):
        A @ np.ones(6 * A.M)
    assert A.gmres_iterations == [2] and A.residuals[0] > 1e-12
    with pytest.warns(BimConvergenceWarning, match="adjoint GMRES did not converge"):
        A.rmatvec(np.ones(6 * A.M))
    assert A.adjoint_iterations == [2]
    B = BimMobility(c, r, p=4, eps_gmres=1e-12, maxiter=2, recycle=0, on_failure="raise")
    with pytest.raises(RuntimeError, match="relative residual"):
        B @ np.ones(6 * B.M)


def _scipy_relaxed_gmres(matvec, b, x0, rtol, restart, maxiter, *, rungs=1, step=100.0,
                         relax=1.0):
    """The relaxed GMRES driver as it was before the block orthogonalisation: one
    ``scipy.sparse.linalg.gmres`` call (modified Gram-Schmidt, one dot product and one
    update per basis vector) per restart cycle.  The oracle of the products below."""
    b = np.asarray(b, dtype=float)
    n = b.size
    nb = float(np.linalg.norm(b))
    x = np.array(x0, dtype=float)
    if nb == 0.0:
        return np.zeros(n), 0, 0.0
    m = max(1, min(int(restart), n))
    # rung: accuracy of the next product; then: rung after it (set when that product is
    # scipy's initial residual b - A x0); its / cycle: inner iterations, total and in cycle
    state = {"rung": 0, "then": None, "its": 0, "cycle": 0, "restart": m}
    cache: dict = {}                        # last product: input copy, rung, output

    def product(v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=float).reshape(-1)
        rung = state["rung"]
        if state["then"] is not None:
            state["rung"], state["then"] = state["then"], None
        if rung == 0 and cache.get("rung") == 0 and np.array_equal(cache["x"], v):
            return cache["y"].copy()
        y = np.asarray(matvec(v, rung), dtype=float).reshape(-1)
        cache.update(x=v.copy(), rung=rung, y=y)
        return y.copy()

    def rung_for(est: float) -> int:
        k = 0
        while k + 1 < rungs and est * step ** (k + 1) <= relax:
            k += 1
        return k

    def callback(pr_norm: float) -> None:
        state["its"] += 1
        state["cycle"] += 1
        ends = pr_norm <= rtol * (1 + 1e-8) or state["cycle"] >= state["restart"]
        state["rung"] = 0 if ends else rung_for(float(pr_norm))

    def residual(z: np.ndarray) -> float:
        state["rung"], state["then"] = 0, None
        return float(np.linalg.norm(b - product(z))) / nb

    op = LinearOperator((n, n), matvec=product, dtype=np.float64)
    with one_blas_thread():
        res = residual(x)
        while res > rtol and state["its"] < maxiter:
            state["cycle"] = 0
            state["restart"] = min(m, maxiter - state["its"])
            if x.any():                     # scipy first forms b - A x0: rung 0 (cached)
                state["rung"], state["then"] = 0, rung_for(res)
            else:                           # scipy starts from r = b, no product
                state["rung"], state["then"] = rung_for(res), None
            its_before = state["its"]
            x, _ = gmres(op, b, x0=x.copy(), rtol=rtol, atol=0.0, restart=state["restart"],
                         maxiter=1, callback=callback, callback_type="pr_norm")
            x = np.asarray(x, dtype=float).reshape(-1)
            res = residual(x)
            if state["its"] == its_before:  # scipy took no step: stop rather than loop
                break
    return x, state["its"], res


def _packed_lattice() -> np.ndarray:
    """Eight unit spheres on a 2x2x2 lattice, gaps 0.1-0.3 radii (slightly shaken)."""
    rng = np.random.default_rng(8)
    grid = np.array([[i, j, k] for i in range(2) for j in range(2) for k in range(2)], float)
    return 2.2 * grid + 0.05 * rng.uniform(-1.0, 1.0, (8, 3))


def test_products_agree_with_the_scipy_cycle_on_a_packed_lattice(monkeypatch):
    """Forward and transposed products without recycling, each solved by the block
    orthogonalisation and by the earlier scipy-based cycle: the same iterations and the
    same products to 1e-12 relative (GMRES tolerance 1e-8, relaxed ladder)."""
    c = _packed_lattice()
    ft = np.random.default_rng(3).standard_normal((3, 6 * len(c)))
    new = BimMobility(c, 1.0, p=4, eps_gmres=1e-8, recycle=0)
    old = BimMobility(c, 1.0, p=4, eps_gmres=1e-8, recycle=0)
    assert len(new.tolerance_ladder) > 1                       # the relaxed path is taken
    u_new = [new @ f for f in ft] + [new.rmatvec(f) for f in ft]
    monkeypatch.setattr(bim_solves, "relaxed_gmres", _scipy_relaxed_gmres)
    u_old = [old @ f for f in ft] + [old.rmatvec(f) for f in ft]
    assert new.gmres_iterations == old.gmres_iterations
    assert new.adjoint_iterations == old.adjoint_iterations
    for a, b in zip(u_new, u_old):
        assert np.linalg.norm(a - b) <= 1e-12 * np.linalg.norm(b)
