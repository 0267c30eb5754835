"""No "infeasible" on a problem that has a solution.

A definite matrix whose smallest eigenvector is positive is not singular along it, however
its products round; a matrix-free operator that is not symmetric gives no Farkas certificate.
"""

import numpy as np
import pytest
from scipy.sparse.linalg import LinearOperator

import lcpbench
from lcpbench.core.claims import _exact_quadratic
from lcpbench.core.result import Status
from lcpbench.problems.infeasible import unbounded_lcp


def _definite(lam_small: float, lam_big: float) -> np.ndarray:
    V = np.array([[1.0, 1.0], [1.0, -1.0]]) / np.sqrt(2.0)
    A = V @ np.diag([lam_small, lam_big]) @ V.T
    return (A + A.T) / 2


def test_two_by_two_definite_is_never_infeasible():
    # eigenvalues 1 and 1e15, solution (1, 1): PGS used to answer "no solution"
    A = _definite(1.0, 1e15)
    b = -A @ np.ones(2)
    for solver in ("pgs", "a-pgd", "bb-pgd", "lemke", "l-bfgs-b", "minmap-newton"):
        res = lcpbench.solve(lcpbench.LCP(A, b), solver=solver)
        assert res.status != Status.infeasible, (solver, res.message)
    res = lcpbench.solve(lcpbench.LCP(A, b), solver="pgs")
    assert "definite along d" in res.info["infeasibility_rejected"] or \
        "not zero to the rounding" in res.info["infeasibility_rejected"]


# two seeds by default; the other four (about 4 s each) in the slow run
@pytest.mark.parametrize("seed", [0, 1] + [pytest.param(k, marks=pytest.mark.slow)
                                           for k in range(2, 6)])
def test_ill_conditioned_definite_with_positive_small_eigenvector(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 10))
    v = np.abs(rng.standard_normal(n)) + 0.1
    v /= np.linalg.norm(v)
    Q, _ = np.linalg.qr(np.column_stack([v, rng.standard_normal((n, n - 1))]))
    lam = np.concatenate([[1.0], 10 ** rng.uniform(0, 14, n - 1)])
    A = (Q * lam) @ Q.T
    A = (A + A.T) / 2
    b = -A @ np.abs(rng.standard_normal(n))
    for solver in ("pgs", "a-pgd", "bb-pgd", "lemke", "minmap-newton", "zero-sr1"):
        res = lcpbench.solve(lcpbench.LCP(A, b), solver=solver)
        assert res.status != Status.infeasible, (solver, res.message)


def test_nonsymmetric_operator_gives_no_certificate():
    M = np.array([[0.0, 2.0], [0.0, 1.0]])
    op = LinearOperator((2, 2), matvec=lambda v: M @ v, dtype=float)
    res = lcpbench.solve(lcpbench.LCP(op, np.array([-1.0, -1.0])), solver="lemke")
    assert res.status != Status.infeasible
    assert "not symmetric" in res.message


def test_true_null_direction_still_certified():
    found = 0
    for seed in range(6):
        rng = np.random.default_rng(seed)
        res = lcpbench.solve(unbounded_lcp(rng, int(rng.integers(2, 21))), solver="a-pgd",
                             max_emvps=300)
        found += res.status == Status.infeasible
    assert found == 6


def test_exact_quadratic_is_exact_where_floats_cancel():
    A = _definite(1.0, 1e15)
    d = np.full(2, 1.0 / np.sqrt(2.0))
    q = _exact_quadratic(A, d)
    assert q is not None and abs(q - 1.0) < 0.2       # float d'(A d) is off by about 0.1
