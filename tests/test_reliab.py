"""Honest results under adversity: confirmed convergence, infeasibility, inexact operators,
operator exceptions, counted cost measurements, sparse validation at scale, time limits."""

import time
import tracemalloc
from dataclasses import dataclass

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

import lcpbench
from lcpbench import LCP, Operator, register_solver
from lcpbench.core.probes import ACCURACY_PROBES
from lcpbench.core.result import Status
from lcpbench.problems.inexact import inexact_lcp
from lcpbench.problems.infeasible import infeasible_lcp, unbounded_lcp
from lcpbench.toolkit import prox

MVP_SOLVERS = ["a-pgd", "bb-pgd", "l-bfgs-b", "minmap-newton", "mono-pqn", "zero-sr1"]
A2 = np.array([[2.0, 1.0], [1.0, 2.0]])
B2 = np.array([-1.0, 1.0])


@dataclass(frozen=True)
class NoParams:
    """No parameters."""


@register_solver("test-drifter", NoParams, listed=False)
def drifter(ctx, p):
    """Claims convergence at x = 1 with a made-up w = 0 (a drifted recurrence)."""
    x = np.ones(ctx.n)
    w = np.zeros(ctx.n)                       # not A x + b
    ctx.report(x, w)
    return ctx.finish(x, w, Status.converged, "trust me")


@register_solver("test-sleeper", NoParams, listed=False)
def sleeper(ctx, p):
    """Reports one iterate, then loops in Python without any product or report."""
    x = np.zeros(ctx.n)
    ctx.report(x, ctx.A @ x + ctx.b)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 60:
        sum(range(1000))
    return ctx.finish(x, ctx.b)


# ----------------------------------------------------------------------------- confirmation
def test_a_refuted_claim_is_stagnated_and_the_fresh_product_is_counted():
    res = lcpbench.solve(A2, B2, solver="test-drifter")
    assert res.status == Status.stagnated
    assert "refuted" in res.message and res.info["refuted_convergence"]
    assert res.mvps == 1 and res.info["confirmation_mvps"] == 1


def test_a_claim_at_the_last_product_costs_nothing_more():
    # bb-pgd computes w = A x + b at every iterate, so its claim is confirmed for free
    A = np.diag([1.0, 2.0, 3.0])
    res = lcpbench.solve(A, np.array([-1.0, 1.0, -3.0]), solver="bb-pgd", stop="kkt")
    assert res.status == Status.converged and res.solved
    assert "confirmation_mvps" not in res.info
    assert res.info["confirmed_kkt_abs"] <= res.threshold


@pytest.mark.parametrize("solver", MVP_SOLVERS)
def test_converged_is_never_refuted_by_the_verification(solver):
    rng = np.random.default_rng(3)
    for _ in range(5):
        J = rng.standard_normal((8, 8))
        res = lcpbench.solve(J @ J.T + 1e-3 * np.eye(8), rng.standard_normal(8), solver=solver)
        if res.status == Status.converged:
            assert res.verified_kkt_abs <= res.threshold


# ----------------------------------------------------------------------------- infeasible
@pytest.mark.parametrize("solver", MVP_SOLVERS + ["bi-pqn", "multi-pqn"])
def test_never_converged_on_infeasible_lcps(solver):
    from lcpbench.problems.random import with_perturbed_lows

    spec = {"bi-pqn": "bi-pqn:low=low", "multi-pqn": "multi-pqn:lows=[low,lower]"}.get(solver, solver)
    for seed in range(4):
        rng = np.random.default_rng(seed)
        for lcp in (infeasible_lcp(rng, int(rng.integers(2, 6))),
                    unbounded_lcp(rng, int(rng.integers(2, 6)))):
            res = lcpbench.solve(with_perturbed_lows(lcp, seed), solver=spec, max_emvps=300)
            assert res.status != Status.converged, res.summary()
            assert not res.solved


def test_infeasible_status_from_a_confirmed_null_direction():
    # x = t d along the null direction of A = diag(1, 0) with b'd < 0: a solver that walks
    # out along it ends with the framework's evidence
    @register_solver("test-walker", NoParams, listed=False)
    def walker(ctx, p):
        for t in (0.0, 1e3, 1e6, 1e12):
            x = np.array([1.0, t])
            w = ctx.A @ x + ctx.b
            ctx.report(x, w)
        return ctx.finish(x, w, Status.max_iter, "gave up")

    res = lcpbench.solve(np.diag([1.0, 0.0]), np.array([1.0, -1.0]), solver="test-walker")
    assert res.status == Status.infeasible
    assert "no solution" in res.message and "gave up" in res.message
    assert res.info["infeasibility_mvps"] == 1 and res.mvps == 5


def test_no_infeasible_claim_on_a_solvable_problem_with_a_large_solution():
    # eigenvalue 1e-6: the solution is large, but a solution exists
    A = np.diag([1.0, 1e-6])
    res = lcpbench.solve(A, np.array([1.0, -1.0]), solver="bb-pgd", max_emvps=20)
    assert res.status != Status.infeasible


# ----------------------------------------------------------------------------- inexact
def test_inexact_operator_loosens_the_stop_test_and_says_so():
    lcp = inexact_lcp(np.random.default_rng(0), 30, 1e-6)
    assert lcp.A.rtol == 1e-6 and lcp.fresh().A.rtol == 1e-6
    res = lcpbench.solve(lcp, solver="mono-pqn", tol=1e-12, max_emvps=2000)
    floor = 10 * 1e-6 * np.linalg.norm(lcp.b)
    assert res.threshold == pytest.approx(floor)
    assert res.info["accuracy_floor"] == pytest.approx(floor)
    if res.status == Status.converged:
        assert "rtol=1e-06" in res.message
        assert res.verified_kkt_abs <= res.threshold


def test_operator_rtol_is_validated():
    with pytest.raises(ValueError, match="rtol"):
        Operator(np.eye(2), rtol=2.0)


# ----------------------------------------------------------------------------- exceptions
class Flaky(LinearOperator):
    """Raises on product number ``bad`` (1-based), else applies ``A``."""

    def __init__(self, A, bad):
        super().__init__(np.float64, A.shape)
        self.M, self.bad, self.calls = A, bad, 0

    def _matvec(self, x):
        self.calls += 1
        if self.calls == self.bad:
            raise FloatingPointError("solver inside the operator blew up")
        return self.M @ np.ravel(x)


@pytest.mark.parametrize("solver", MVP_SOLVERS)
def test_operator_exceptions_become_failed_results_naming_the_message(solver):
    res = lcpbench.solve(Flaky(A2, bad=1), B2, solver=solver)
    assert res.status == Status.failed
    assert "solver inside the operator blew up" in res.message and "'high'" in res.message


def test_operator_raising_only_in_the_verification_is_a_failed_result():
    probe = Flaky(A2, bad=10 ** 9)
    done = lcpbench.solve(probe, B2, solver="bb-pgd", stop="kkt")
    calls = probe.calls                     # the solve's products plus the verification
    res = lcpbench.solve(Flaky(A2, bad=calls), B2, solver="bb-pgd", stop="kkt")
    assert done.solved and res.status == Status.failed
    assert "verification failed" in res.message and "blew up" in res.message


def test_a_low_operator_of_the_wrong_length_is_named():
    class Short(LinearOperator):
        def __init__(self):
            super().__init__(np.float64, (2, 2))

        def _matvec(self, x):
            return np.ones(3)

    res = lcpbench.solve(A2, B2, solver="bi-pqn", low={"p4": Short()})
    assert res.status == Status.failed
    assert "operator 'p4'" in res.message and "size 3" in res.message


# ----------------------------------------------------------------------------- counting
class Counting(LinearOperator):
    def __init__(self, A):
        super().__init__(np.float64, A.shape)
        self.M, self.calls = A, 0

    def _matvec(self, x):
        self.calls += 1
        return self.M @ np.ravel(x)


def test_cost_measurement_is_a_counted_product():
    rng = np.random.default_rng(1)
    J = rng.standard_normal((20, 20))
    A = J @ J.T / 20 + np.eye(20)
    high, low = Counting(A), Counting(A + 1e-3 * np.eye(20))
    # a declared cost: E-MVPs then do not depend on timings, and solve has nothing to warn about
    res = lcpbench.solve(high, rng.standard_normal(20), solver="bi-pqn", low={"low": low},
                         low_cost=0.1)
    # every application of the high operator is a counted MVP, except the framework's
    # uncounted ones: the verification product and, for an operator that declares no
    # accuracy, the probe that measures it (before a drift bound is trusted)
    assert res.info["operator_accuracy_source"] == "measured"
    assert res.info["operator_accuracy"] == 0.0          # a float64 product: exact
    assert high.calls == res.mvps + 1 + ACCURACY_PROBES
    assert low.calls == res.lofi_mvps["low"]


# ----------------------------------------------------------------------------- sparse
def _tridiagonal(n):
    off = -np.ones(n - 1)
    return sp.diags([off, 2.5 * np.ones(n), off], [-1, 0, 1], format="csr")


def test_sparse_validation_stays_sparse():
    A = _tridiagonal(5000)
    tracemalloc.start()
    lcp = LCP(A, np.ones(5000))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert lcp.n == 5000
    assert peak < 150e6                        # dense would be 200 MB


def test_sparse_validation_still_catches_asymmetry_and_non_finite():
    A = _tridiagonal(3000).tolil()
    A[0, 1] = 5.0
    with pytest.raises(ValueError, match="not symmetric"):
        LCP(A.tocsr(), np.ones(3000))
    A = _tridiagonal(3000).tolil()
    A[7, 7] = np.inf
    with pytest.raises(ValueError, match=r"entry \(7, 7\)"):
        LCP(A.tocsr(), np.ones(3000))


def test_psd_check_is_relative_to_the_matrix_scale():
    with pytest.raises(ValueError, match="not positive semidefinite"):
        LCP(-1e-9 * np.eye(3), np.ones(3))
    LCP(1e-9 * np.eye(3), np.ones(3))


@pytest.mark.slow
@pytest.mark.parametrize("solver", MVP_SOLVERS + ["bi-pqn"])
def test_mvp_solvers_at_n_20000_sparse_and_linear_operator_within_a_memory_bound(solver):
    n = 20000
    A = _tridiagonal(n)
    b = -np.ones(n)
    lop = LinearOperator((n, n), matvec=lambda v: A @ v, dtype=np.float64)
    for high in (A, lop):
        low = {"low": A + 1e-3 * sp.eye(n)} if solver == "bi-pqn" else None
        tracemalloc.start()
        res = lcpbench.solve(high, b, solver=solver + (":low=low" if low else ""), low=low,
                             low_cost=0.1 if low else None, max_emvps=60)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert res.status != Status.failed, res.message
        assert peak < 300e6                    # a dense copy alone would be 3.2 GB


# ----------------------------------------------------------------------------- small inputs
def test_numpy_float_tolerance_and_complex_warm_start():
    res = lcpbench.solve(A2, B2, tol=np.float32(1e-8))
    assert res.solved
    with pytest.raises(TypeError, match="complex"):
        lcpbench.solve(A2, B2, x0=np.array([1 + 1j, 0]))
    with pytest.raises(TypeError, match="complex"):
        LCP(A2, B2, x0=np.array([1 + 1j, 0]))


# ----------------------------------------------------------------------------- time
def test_max_seconds_reaches_a_loop_without_products():
    res = lcpbench.solve(A2, B2, solver="test-sleeper", max_seconds=0.3)
    assert res.status == Status.timeout
    assert "time budget" in res.message


def test_budget_exhaustion_has_its_own_status():
    rng = np.random.default_rng(0)
    J = rng.standard_normal((30, 30))
    res = lcpbench.solve(J @ J.T + 1e-6 * np.eye(30), rng.standard_normal(30), solver="a-pgd",
                         max_emvps=5)
    assert res.status == Status.budget and res.emvps <= 5


def test_prox_fallback_steps_are_capped(monkeypatch):
    seen = []
    real = prox._prox_fallback

    def spy(y, d, U, V, iters, tol):
        seen.append(iters)
        return real(y, d, U, V, iters, tol)

    monkeypatch.setattr(prox, "_prox_fallback", spy)
    rng = np.random.default_rng(0)
    n, r = 50, 3
    z, info = prox.weighted_prox(rng.standard_normal(n), np.ones(n), rng.standard_normal((n, r)),
                                 np.zeros((n, 0)), max_iter=0)
    assert info.fallback and seen == [prox.FALLBACK_ITERS] and prox.FALLBACK_ITERS <= 500
    assert np.all(z >= 0)


def test_no_refuted_convergence_on_rank1_tiny_lcps():
    """Rank-1 LCPs with n = 2..4, many without a solution (the iterates run far out along the
    null direction and back): a converged claim must survive the verification."""
    from lcpbench.problems.random import with_perturbed_lows

    specs = ("mono-pqn", "bi-pqn:low=low", "multi-pqn:lows=[low,lower]")
    claims = 0
    for i in range(150):
        rng = np.random.default_rng([0, i, 3])
        n = int(rng.integers(2, 5))
        u = rng.standard_normal(n) * 10 ** rng.uniform(-2, 2)
        lcp = with_perturbed_lows(LCP(np.outer(u, u), rng.standard_normal(n)), seed=i)
        for spec in specs:
            res = lcpbench.solve(lcp, solver=spec, max_emvps=1000)
            if res.status == Status.converged:
                claims += 1
                assert res.verified_kkt_abs <= res.threshold, (i, res.summary())
    assert claims > 100                     # the feasible half is still solved
