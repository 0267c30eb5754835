"""Evidence of infeasibility for slowly diverging solvers: the span of the known directions.

A-PGD (a fixed step 1/L) and min-map Newton (Krylov steps on a singular system) never
walk far enough for their iterate or their last step alone to be a null direction to
the rounding of A along it; the framework searches the span of the recent steps and of
the directions solvers offer with their products, and confirms the best non-negative
combination with one counted product (two when the candidate has tiny entries: without
them first). Never on a problem that has a solution.
"""

from dataclasses import dataclass

import numpy as np
import pytest

import lcpbench
from lcpbench import register_solver
from lcpbench.core.result import Status
from lcpbench.problems.infeasible import infeasible_lcp, unbounded_lcp
from lcpbench.problems.synthetic import random_spd_matrix


@dataclass(frozen=True)
class NoParams:
    """No parameters."""


def _families(count: int = 12):
    for gen in (infeasible_lcp, unbounded_lcp):
        for seed in range(count):
            rng = np.random.default_rng(seed)
            yield gen(rng, int(rng.integers(2, 21)))


@pytest.mark.usefixtures("one_blas_thread")
@pytest.mark.parametrize("solver, least", [("a-pgd", 20), ("minmap-newton", 19)])
def test_slow_solvers_reach_infeasible_with_one_extra_product(solver, least):
    # before the span search both ended 'budget' or 'stagnated' on every one of these; since
    # the certificate asks A d to vanish to the rounding of A along d (not to 1e-10 ||A||)
    # a few approximate directions no longer count (24 and 20 before, 21 and 20 measured)
    found = 0
    for lcp in _families():
        res = lcpbench.solve(lcp, solver=solver, max_emvps=300)
        assert res.status != Status.converged
        assert res.mvps <= 300 + 2          # the candidate without its tiny entries, then itself
        if res.status == Status.infeasible:
            found += 1
            assert res.info["infeasibility_mvps"] in (1, 2)
            assert "no solution" in res.message and "every feasible point" in res.message
            d = np.asarray(lcp.meta.get("direction", []))
            if d.size:                                  # the planted certificate agrees
                assert float(lcp.b @ d) < 0.0
    assert found >= least, f"{solver}: infeasible on {found} of 24"


@register_solver("test-slow-walker", NoParams, listed=False)
def slow_walker(ctx, p):
    """Walks along a null direction by unit steps while a range component decays by 1/2.

    ``A = diag(1, 1, 0)``: the iterates ``(2^-k, 2^-k, k)`` never get far (``||A x|| / ||x||``
    is about ``1 / k``), their last step ``(-2^-k, -2^-k, 1)`` has a negative part, but a
    combination of two steps is exactly ``e_3``.
    """
    for k in range(12):
        x = np.array([2.0 ** -k, 2.0 ** -k, float(k)])
        if ctx.report(x, ctx.A @ x + ctx.b):
            break
    return ctx.finish(x, ctx.A @ x + ctx.b, Status.max_iter, "walked")


def test_span_of_recent_steps_gives_the_null_direction():
    A = np.diag([1.0, 1.0, 0.0])
    b = np.array([0.5, 0.5, -1.0])
    res = lcpbench.solve(A, b, solver="test-slow-walker")
    assert res.status == Status.infeasible, res.summary()
    assert res.info["infeasibility_mvps"] == 1
    assert "walked" in res.message


@register_solver("test-offerer", NoParams, listed=False)
def offerer(ctx, p):
    """Computes ``A e_n`` once, offers ``(e_n, A e_n)`` and gives up at ``x = 0``."""
    e = np.zeros(ctx.n)
    e[-1] = 1.0
    ctx.offer_direction(e, ctx.A @ e)
    x = np.zeros(ctx.n)
    ctx.report(x, ctx.b)
    return ctx.finish(x, ctx.b, Status.stagnated, "gave up")


def test_an_offered_direction_with_its_product_is_evidence():
    A = np.diag([2.0, 1.0, 0.0])
    res = lcpbench.solve(A, np.array([1.0, 1.0, -1.0]), solver="test-offerer")
    assert res.status == Status.infeasible
    assert res.mvps == 2 and res.info["infeasibility_mvps"] == 1
    # the same offer on a solvable problem (b_3 >= 0) proves nothing
    res = lcpbench.solve(A, np.array([1.0, 1.0, 1.0]), solver="test-offerer")
    assert res.status != Status.infeasible and "infeasibility_mvps" not in res.info


def test_offer_direction_ignores_wrong_shapes_and_non_finite_values():
    from lcpbench.core.context import Budget, Monitor, SolverContext
    from lcpbench.core.residuals import make_stop_rule

    ctx = SolverContext(lcpbench.LCP(np.eye(2), np.ones(2)), make_stop_rule("paper", 1e-8),
                        Budget(), Monitor())
    ctx.offer_direction(np.ones(3), np.ones(3))
    ctx.offer_direction(np.array([np.nan, 1.0]), np.ones(2))
    ctx.offer_direction(np.zeros(2), np.zeros(2))
    assert ctx.offered == []
    ctx.offer_direction(np.array([1.0, 0.0]), np.array([1.0, 0.0]))
    assert len(ctx.offered) == 1


@pytest.mark.usefixtures("one_blas_thread")
@pytest.mark.parametrize("solver", ["a-pgd", "minmap-newton", "bb-pgd", "zero-sr1"])
def test_never_infeasible_on_solvable_problems(solver):
    rng = np.random.default_rng(7)
    for i in range(12):
        n = int(rng.integers(2, 21))
        if i % 3 == 0:          # singular PSD with a planted solution: null directions exist
            J = rng.standard_normal((n, max(1, n // 2)))
            A = J @ J.T
            x = np.where(rng.random(n) < 0.5, rng.uniform(0, 1, n), 0.0)
            b = -A @ x + np.where(x > 0, 0.0, rng.uniform(0, 1, n))
        elif i % 3 == 1:        # ill-conditioned SPD: a large solution, small curvature
            A = random_spd_matrix(rng, n, 1e8)
            b = rng.standard_normal(n)
        else:                   # a tiny eigenvalue along a direction with b'd < 0
            A = np.diag(np.r_[np.ones(n - 1), 1e-8])
            b = np.r_[np.ones(n - 1), -1.0]
        res = lcpbench.solve(A, b, solver=solver, max_emvps=300)
        assert res.status != Status.infeasible, (i, res.summary())


def test_a_pgd_on_a_zero_matrix():
    # A = 0: the power estimate of L is 0; A-PGD used to fail, now any step is safe
    res = lcpbench.solve(np.zeros((3, 3)), np.array([1.0, -1.0, 2.0]), solver="a-pgd")
    assert res.status == Status.infeasible, res.summary()
    assert res.info["zero_curvature"]
    res = lcpbench.solve(np.zeros((3, 3)), np.array([1.0, 0.0, 2.0]), solver="a-pgd")
    assert res.status == Status.converged and res.solved


def test_the_windows_of_known_directions_shrink_for_large_n():
    from scipy.sparse.linalg import LinearOperator

    from lcpbench.core.context import RECENT_ITERATES, WINDOW_FLOATS, Budget, Monitor, SolverContext
    from lcpbench.core.residuals import make_stop_rule

    n = WINDOW_FLOATS // 10
    op = LinearOperator((n, n), matvec=lambda v: v, dtype=np.float64)
    ctx = SolverContext(lcpbench.LCP(op, np.ones(n)), make_stop_rule("paper", 1e-8),
                        Budget(), Monitor())
    for k in range(RECENT_ITERATES):
        x = np.full(n, float(k))
        ctx.report(x, x + 1.0)
        ctx.offer_direction(x + 1.0, x + 1.0)
    assert len(ctx.recent) == len(ctx.offered) == 10
    assert float(ctx.recent[-1][0][0]) == RECENT_ITERATES - 1


def test_reference_of_an_inexact_operator_is_symmetrised_and_says_how_much():
    from lcpbench.core.context import accuracy_floor
    from lcpbench.problems.inexact import exact_product, inexact_lcp

    lcp = inexact_lcp(np.random.default_rng(1), 40, 1e-6)
    ref = lcpbench.reference(lcp)
    assert ref.accepted
    assert 0.0 < ref.details["asymmetry"] < 1e-6 and ref.details["operator_rtol"] == 1e-6
    x = ref.x
    exact = float(np.linalg.norm(np.minimum(x, exact_product(lcp, x) + lcp.b)))
    assert exact <= accuracy_floor(lcp)


@register_solver("test-near-walker", NoParams, listed=False)
def near_walker(ctx, p):
    """Walks towards the large solution ``(0, 1 / eps)`` of ``A = diag(1, eps)`` and stops short."""
    eps = 1e-12
    x = np.array([1.0, 0.0])                  # one product along e_1: ||A|| >= 1 is known
    ctx.report(x, ctx.A @ x + ctx.b)
    for t in (0.5, 0.9, 0.999):
        x = np.array([0.0, t / eps])
        w = ctx.A @ x + ctx.b
        ctx.report(x, w)
    return ctx.finish(x, w, Status.max_iter, "stopped short")


def test_no_infeasible_when_the_iterate_is_as_far_out_as_the_bound():
    # A solvable problem (x = (0, 1e12)) whose A has an eigenvalue 1e-12 ||A||: e_2 passes the
    # screening against 1e-10 ||A||, but A e_2 = 1e-12 e_2 is not zero to the rounding of A
    # along e_2 (before: 'infeasible' on this solvable problem)
    A = np.diag([1.0, 1e-12])
    res = lcpbench.solve(A, np.array([1.0, -1.0]), solver="test-near-walker")
    assert res.status == Status.max_iter, res.summary()
    assert "not zero to the rounding of A along d" in res.info["infeasibility_rejected"]
    assert res.info["infeasibility_mvps"] in (1, 2)     # without its tiny entries, then itself

