"""No ``converged`` that the framework's own product refutes.

Operators whose products are not float64-exact and that declare nothing (single
precision, an iterative solve at an undeclared tolerance): the drift bound of the PQN
solvers assumed float64 products, so their claims were accepted while the verification
refuted them. Now the accuracy is measured (float width, linearity, reproducibility) before
a drift bound is trusted, and the verification has the last word.
"""

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.sparse.linalg import LinearOperator, gmres

import lcpbench
from lcpbench import Operator, register_solver
from lcpbench.core.result import Status
from lcpbench.problems.synthetic import random_spd_matrix

PQN = ["mono-pqn", "bi-pqn:low=low", "multi-pqn:lows=[low,lower]"]


@dataclass(frozen=True)
class NoParams:
    """No parameters."""


def _planted(rng, A):
    n = A.shape[0]
    x = np.where(rng.random(n) < 0.5, rng.uniform(0.1, 2.0, n), 0.0)
    w = np.where(x == 0.0, rng.uniform(0.1, 2.0, n), 0.0)
    return w - A @ x


def _lcp(high, A, b):
    lows = {"low": Operator(A * (1 + 1e-3), cost=0.1), "lower": Operator(A * (1 + 1e-2), cost=0.01)}
    return lcpbench.LCP(Operator(high, cost=1.0), b, low=lows)


def _float32_case(seed):
    rng = np.random.default_rng(seed)
    A = random_spd_matrix(rng, 20, 1e3)
    A32 = A.astype(np.float32)
    op = LinearOperator((20, 20), matvec=lambda v: A32 @ v.astype(np.float32), dtype=np.float64)
    return _lcp(op, A, 100.0 * _planted(rng, A))


def _gmres_case(seed):
    rng = np.random.default_rng(seed)
    K = random_spd_matrix(rng, 20, 1e2)
    A = np.linalg.inv(K)
    A = (A + A.T) / 2

    def product(v):                              # A v = K^-1 v at an undeclared tolerance
        return gmres(K, v, rtol=1e-7, atol=0.0, maxiter=400)[0]

    op = LinearOperator((20, 20), matvec=product, dtype=np.float64)
    return _lcp(op, A, 1e3 * _planted(rng, A))


@pytest.mark.parametrize("solver", PQN)
@pytest.mark.parametrize("case", [_float32_case, _gmres_case])
def test_pqn_converged_is_never_refuted_by_the_verification(solver, case):
    # before: mono-, bi- and multi-PQN said 'converged' on all six, verified 1e2..1e5 x the
    # threshold
    for seed in (0, 1, 2):
        res = lcpbench.solve(case(seed), solver=solver, max_emvps=500)
        assert res.status != Status.converged or res.verified_kkt_abs <= res.threshold, \
            res.summary()
        assert not res.false_convergence


def test_the_message_says_how_accurate_the_operator_is_and_what_to_declare():
    res = lcpbench.solve(_float32_case(0), solver="mono-pqn", max_emvps=500)
    assert res.status == Status.stagnated
    assert "accurate to about 1e-07" in res.message
    assert "declare Operator(..., rtol=...)" in res.message
    assert res.info["operator_accuracy_source"] == "measured"
    assert res.info["operator_accuracy"] == pytest.approx(np.finfo(np.float32).eps)
    assert "narrower than float64" in res.info["operator_accuracy_note"]


def test_declared_accuracy_loosens_the_stop_test_and_converges():
    lcp = _float32_case(0)
    declared = lcpbench.LCP(Operator(lcp.A, rtol=1e-6), lcp.b, low=lcp.low)
    res = lcpbench.solve(declared, solver="mono-pqn", max_emvps=500)
    assert res.status == Status.converged and res.solved


def test_measured_accuracy_of_the_kinds():
    from lcpbench.core.probes import measure_accuracy

    rng = np.random.default_rng(0)
    A = random_spd_matrix(rng, 30, 1e2)
    A32 = A.astype(np.float32)
    exact = measure_accuracy(Operator(LinearOperator((30, 30), matvec=lambda v: A @ v,
                                                     dtype=np.float64)))
    mixed = measure_accuracy(Operator(LinearOperator(
        (30, 30), matvec=lambda v: (A32 @ v.astype(np.float32)).astype(np.float64),
        dtype=np.float64)))
    assert exact.exact and exact.known and exact.source == "measured"
    assert 1e-9 < mixed.rtol < 1e-5 and not mixed.known        # float64 out, float32 inside
    assert "A(u+v) - Au - Av" in mixed.detail
    assert measure_accuracy(Operator(A)).source == "explicit"
    assert measure_accuracy(Operator(A, rtol=1e-4)).rtol == 1e-4


def test_an_exact_matrix_free_operator_pays_no_extra_counted_product():
    # the accuracy probe is uncounted: the same solve through a LinearOperator costs the
    # same MVPs as through the matrix
    rng = np.random.default_rng(4)
    A = random_spd_matrix(rng, 25, 1e3)
    b = _planted(rng, A)
    for solver in ("mono-pqn", "minmap-newton", "bb-pgd"):
        dense = lcpbench.solve(A, b, solver=solver)
        free = lcpbench.solve(LinearOperator((25, 25), matvec=lambda v: A @ v,
                                             dtype=np.float64), b, solver=solver)
        assert dense.status == free.status == Status.converged
        assert dense.mvps == free.mvps, solver


@register_solver("test-overconfident", NoParams, listed=False)
def overconfident(ctx, p):
    """Certifies a drift bound of 0 at x = 1 with the operator's own product and claims it."""
    x = np.ones(ctx.n)
    w = ctx.A @ x + ctx.b
    w32 = np.where(np.abs(w) < 1e-3, 0.0, w)           # a recurrence that rounded to 0
    ctx.certify(x, 0.0)
    ctx.report(x, w32)
    return ctx.finish(x, w32, Status.converged, "certified")


def test_a_certified_claim_on_an_inexact_operator_is_checked():
    # x = 1 solves A x + b = 0 up to float32 rounding of the products: the certificate is
    # accepted only when the accuracy is known (before: 'converged', verified 4e-6)
    rng = np.random.default_rng(5)
    A = random_spd_matrix(rng, 12, 10.0)
    A32 = A.astype(np.float32)
    b = -(A @ np.ones(12))
    op = LinearOperator((12, 12), matvec=lambda v: A32 @ v.astype(np.float32), dtype=np.float64)
    res = lcpbench.solve(op, b, solver="test-overconfident")
    assert res.status == Status.stagnated, res.summary()
    assert res.verified_kkt_abs > res.threshold
    assert "confirmed_by" not in res.info
    res = lcpbench.solve(A, b, solver="test-overconfident")       # exact: the bound holds
    assert res.info["confirmed_by"] == "drift bound"


class Noisy(LinearOperator):
    """``A v`` plus a relative 1e-6 random perturbation that differs at every call."""

    def __init__(self, A):
        super().__init__(np.float64, A.shape)
        self.M, self.rng = A, np.random.default_rng(0)

    def _matvec(self, v):
        y = self.M @ np.ravel(v)
        return y * (1 + 1e-6 * self.rng.standard_normal(y.shape))


@pytest.mark.parametrize("solver", ["mono-pqn", "bb-pgd", "l-bfgs-b", "zero-sr1"])
def test_products_that_are_not_reproducible_never_pass_by_chance(solver):
    rng = np.random.default_rng(6)
    A = random_spd_matrix(rng, 15, 1e2)
    b = 1e3 * _planted(rng, A)
    res = lcpbench.solve(Noisy(A), b, solver=solver, max_emvps=400)
    if res.status == Status.converged:
        again = np.linalg.norm(np.minimum(res.x, A @ res.x + b))
        assert res.verified_kkt_abs <= res.threshold and again <= 10 * res.threshold
