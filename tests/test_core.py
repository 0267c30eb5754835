"""The core contracts: counted operators, E-MVPs, verification, budgets, monitor."""

import time
from dataclasses import dataclass

import numpy as np
import pytest
import scipy.sparse as sp
from lcp_cases import planted
from scipy.sparse.linalg import LinearOperator, aslinearoperator

import lcpbench
from lcpbench import LCP, Budget, Operator, Status, register_solver
from lcpbench.core.operator import apply_uncounted, dense_uncounted
from lcpbench.core.residuals import (
    all_residuals,
    complementarity_gap,
    fischer_burmeister,
    kkt_abs,
    kkt_abs_inf,
    kkt_rel,
    make_stop_rule,
    objective,
)


def _spd(n=6, seed=0):
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((n, n))
    return G @ G.T + n * np.eye(n)


def _forms(A):
    """The same matrix as every operator input type the core accepts."""
    n = A.shape[0]
    return {
        "ndarray": A,
        "sparse": sp.csr_matrix(A),
        "LinearOperator": aslinearoperator(A),
        "matvec-only LinearOperator": LinearOperator((n, n), matvec=lambda v: A @ v),
        "callable": (lambda v: A @ v),
    }


@pytest.mark.parametrize("kind", list(_forms(np.eye(2))))
def test_every_input_type_counts_vectors_and_block_columns(kind):
    A = _spd()
    form = _forms(A)[kind]
    op = Operator(form, shape=A.shape if kind == "callable" else None)
    v = np.arange(1.0, 7.0)
    np.testing.assert_allclose(op @ v, A @ v)
    assert op.count == 1
    X = np.random.default_rng(1).standard_normal((6, 4))
    X[:, 2] = 0.0                                   # a zero column costs nothing
    np.testing.assert_allclose(op @ X, A @ X)
    assert op.count == 1 + 3
    np.testing.assert_allclose(op.matmat(np.zeros((6, 3))), 0.0)
    np.testing.assert_allclose(op @ np.zeros(6), 0.0)
    assert op.count == 4                            # A 0 = 0 is free
    np.testing.assert_allclose(op.T @ v, A @ v)     # symmetric: adjoint is counted too
    assert op.count == 5
    assert op.seconds > 0 and op.measured_cost == pytest.approx(op.seconds / 5)


def test_uncounted_apply_and_dense_do_not_count():
    A = _spd()
    for kind, form in _forms(A).items():
        op = Operator(form, shape=A.shape if kind == "callable" else None)
        np.testing.assert_allclose(apply_uncounted(op, np.ones(6)), A @ np.ones(6))
        np.testing.assert_allclose(dense_uncounted(op), A)
        assert op.count == 0 and op.seconds == 0.0


def test_copy_shares_matrix_but_not_counters():
    op = Operator(_spd(), cost=2.0)
    op @ np.ones(6)
    c = op.copy()
    assert c.count == 0 and c.declared_cost == 2.0 and op.count == 1


def test_no_solver_module_uses_the_uncounted_apply():
    import pathlib

    import lcpbench.solvers as pkg
    for path in pathlib.Path(pkg.__file__).parent.glob("*.py"):
        text = path.read_text()
        assert "apply_uncounted" not in text and "dense_uncounted" not in text, path.name


def test_emvps_are_sum_of_count_times_cost_over_high_cost():
    A = _spd()
    lcp = LCP(Operator(A, cost=1.0), np.ones(6),
              low={"p4": Operator(A, cost=0.1), "rpy": Operator(A, cost=0.01)})
    lcp.A @ np.ones(6)
    lcp.A @ np.ones((6, 2))
    lcp.low["p4"] @ np.ones((6, 5))
    lcp.low["rpy"] @ np.ones(6)
    assert lcp.emvps() == pytest.approx(3 + 5 * 0.1 + 0.01)


def test_result_counts_come_from_the_operators():
    lcp = LCP(*planted(40, 40, seed=3, cond=20.0))
    res = lcpbench.solve(lcp, solver="bb-pgd", tol=1e-8)
    assert res.mvps == res.history["mvps"].iloc[-1]
    assert res.emvps == pytest.approx(res.mvps)     # one operator: E-MVPs = MVPs
    hi = lcp.operators()["high"]
    assert hi.count == 0                             # every solve uses fresh counters


@dataclass(frozen=True)
class _LiarParams:
    """Parameters of the liar.

    Parameters
    ----------
    lie : str
        ``w`` claims a w that makes any x look optimal; ``x`` returns a wrong x
        with its true w but claims convergence.
    """

    lie: str = "w"


@register_solver("test-liar", _LiarParams, listed=False)
def _liar(ctx, p):
    """Claims convergence without solving."""
    x = np.ones(ctx.n)
    w = np.zeros(ctx.n) if p.lie == "w" else ctx.A @ x + ctx.b
    ctx.report(x, w)
    return ctx.finish(x, w, Status.converged, "trust me")


@pytest.mark.parametrize("lie", ["w", "x"])
def test_a_lying_solver_is_caught_by_verification(lie, true_residual):
    lcp = LCP(*planted(20, 20, seed=1))
    res = lcpbench.solve(lcp, solver=f"test-liar:lie={lie}")
    assert res.status == Status.stagnated           # a fresh product refutes the claim ...
    assert "refuted" in res.message
    assert not res.solved                           # ... and the verified residual agrees
    assert res.verified_kkt_abs == pytest.approx(true_residual(lcp, res.x), rel=1e-12)
    assert res.verified_kkt_abs > 1e-3


@dataclass(frozen=True)
class _GreedyParams:
    """block: columns per product."""

    block: int = 1


@register_solver("test-greedy", _GreedyParams, listed=False)
def _greedy(ctx, p):
    """Multiplies forever; only the budget stops it."""
    rng = np.random.default_rng(0)
    while True:
        ctx.A @ rng.standard_normal((ctx.n, p.block))


@pytest.mark.parametrize("block", [1, 7])
def test_emvp_budget_is_enforced_by_the_operator(block):
    lcp = LCP(*planted(10, 10, seed=0))
    res = lcpbench.solve(lcp, solver=f"test-greedy:block={block}", max_emvps=50)
    assert res.status == Status.budget
    assert res.mvps <= 50                           # the product that would cross is refused


@dataclass(frozen=True)
class _SleepyParams:
    """nap: seconds per iteration."""

    nap: float = 0.02


@register_solver("test-sleepy", _SleepyParams, listed=False)
def _sleepy(ctx, p):
    """Reports a non-solution slowly until the time budget stops it."""
    x = np.zeros(ctx.n)
    while True:
        time.sleep(p.nap)
        x = x + 1.0
        if ctx.report(x, ctx.A @ x + ctx.b):
            return ctx.finish(x, ctx.A @ x + ctx.b)


def test_time_budget_stops_the_solver():
    lcp = LCP(*planted(10, 10, seed=0))
    res = lcpbench.solve(lcp, solver="test-sleepy", max_seconds=0.1, max_emvps=1e6)
    assert res.status == Status.timeout and "time budget" in res.message
    # Not before the budget ran out, and at the first check after it: iteration k has
    # slept >= k * 0.02 s, so the product of iteration 6 is refused at the latest, however
    # slow the machine (bounds that hold by construction, not timings).
    assert res.time_s > 0.1
    assert res.iterations <= 4


def test_iteration_cap():
    lcp = LCP(*planted(10, 10, seed=0))
    res = lcpbench.solve(lcp, solver="test-sleepy:nap=0", max_iter=5, max_emvps=1e6)
    assert res.status == Status.max_iter and res.iterations == 5


def test_monitor_records_every_iterate_without_counting():
    lcp = LCP(*planted(30, 30, seed=2))
    seen = []
    res = lcpbench.solve(lcp, solver="bb-pgd", callback=lambda row, x: seen.append(row["mvps"]))
    assert len(seen) == len(res.history) == res.iterations + 1
    # the verified column costs uncounted products only: the counts equal the MVPs
    assert res.history["kkt_abs_verified"].notna().all()
    assert res.mvps == res.history["mvps"].iloc[-1]
    np.testing.assert_allclose(res.history["kkt_abs_verified"].iloc[-1], res.verified_kkt_abs,
                               rtol=1e-6, atol=1e-14)


def test_matrix_free_history_is_not_verified_per_iterate():
    A = _spd(8)
    res = lcpbench.solve(aslinearoperator(A), np.ones(8) - 4, solver="bb-pgd")
    assert res.history["kkt_abs_verified"].isna().all()
    assert res.solved


def test_empty_problem_is_converged_at_zero_cost():
    res = lcpbench.solve(np.zeros((0, 0)), np.zeros(0))
    assert res.status == Status.converged and res.solved and res.mvps == 0 and res.x.shape == (0,)


def test_residuals_on_a_known_point():
    x = np.array([1.0, 0.0, 2.0])
    w = np.array([0.5, -1.0, 0.0])
    b = np.array([1.0, -1.0, -3.0])
    assert kkt_abs(x, w) == pytest.approx(np.linalg.norm([0.5, -1.0, 0.0]))
    assert kkt_abs_inf(x, w) == 1.0
    assert complementarity_gap(x, w) == pytest.approx(0.5)
    assert fischer_burmeister(x, w) > 0
    assert fischer_burmeister(np.array([1.0, 0.0]), np.array([0.0, 3.0])) == pytest.approx(0.0)
    # the QP objective 1/2 x'Ax + b'x from w = A x + b, for a known A: x'Ax = 6, b'x = -5
    A = np.array([[2.0, 1.0, 0.0], [1.0, 3.0, 0.0], [0.0, 0.0, 1.0]])
    assert objective(x, A @ x + b, b) == pytest.approx(0.5 * 6.0 - 5.0)
    assert objective(np.zeros(3), b, b) == 0.0
    assert np.isnan(kkt_rel(1.0, None))           # undefined at the first iterate
    assert kkt_rel(1.0, 1.0) == 0.0 and kkt_rel(0.0, 0.0) == 0.0
    assert kkt_rel(0.5, 1.0) == pytest.approx(0.5)  # |e_k - e_k-1| / max(e_k, e_k-1)
    r = all_residuals(x, w, b)
    assert r["infeas_x"] == 0.0 and r["infeas_w"] == pytest.approx(1.0)
    assert r["comp_gap"] == pytest.approx(0.5)


def test_stop_rules():
    b = np.full(4, 3.0)
    paper = make_stop_rule("paper", 1e-6)
    kkt = make_stop_rule("kkt", 1e-6)
    assert kkt.threshold(b) == pytest.approx(1e-6 * (1 + np.linalg.norm(b)))
    assert kkt.check(1e-9, 1e-12, b) == "converged"
    assert kkt.check(1e-3, 1e-12, b) is None        # no relative rule for kkt
    assert paper.check(1e-3, 1e-12, b) == "stagnated"
    assert paper.check(1e-12, 0.5, b) == "converged"
    with pytest.raises(ValueError, match="stop"):
        make_stop_rule("fast", 1e-6)
    with pytest.raises(ValueError, match="tol"):
        make_stop_rule("paper", -1.0)


def test_budget_validation():
    with pytest.raises(ValueError, match="max_emvps"):
        Budget(max_emvps=0)
    with pytest.raises(ValueError, match="max_seconds"):
        Budget(max_seconds=-1)
    with pytest.raises(ValueError, match="max_iter"):
        Budget(max_iter=0)
