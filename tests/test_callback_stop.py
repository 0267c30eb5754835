"""A callback may end a solve by raising ``StopIteration``, as in ``scipy.optimize``.

The solve then ends at the iterate the callback was shown, with status ``stopped``, the
operator's counts at that point and the framework's verification of that iterate.
"""

from dataclasses import dataclass

import numpy as np
import pytest
from lcp_cases import planted

import lcpbench
from lcpbench import LCP, Status, register_solver

MVP_SOLVERS = ["bb-pgd", "a-pgd", "mono-pqn", "zero-sr1", "l-bfgs-b", "minmap-newton"]


def _problem(seed=3):
    return LCP(*planted(60, 60, seed=seed, cond=1e3))


class _StopAfter:
    """Raises StopIteration on the first iterate with at least ``mvps`` products."""

    def __init__(self, mvps):
        self.mvps = mvps
        self.rows = []
        self.xs = []

    def __call__(self, row, x):
        self.rows.append(row)
        self.xs.append(np.array(x))
        if row["mvps"] >= self.mvps:
            raise StopIteration


@pytest.mark.parametrize("solver", MVP_SOLVERS)
def test_stop_iteration_ends_the_solve_at_that_iterate(solver):
    lcp = _problem()
    full = lcpbench.solve(lcp, solver=solver, tol=1e-10)
    assert full.status == Status.converged and full.mvps > 8
    stop = _StopAfter(mvps=4)
    res = lcpbench.solve(lcp, solver=solver, tol=1e-10, callback=stop)
    assert res.status == Status.stopped, res.summary()
    assert "callback" in res.message
    # the callback saw no iterate after the one it stopped at
    assert stop.rows[-1]["mvps"] >= 4
    assert len(res.history) == len(stop.rows)
    assert res.history["mvps"].iloc[-1] == stop.rows[-1]["mvps"]
    # the answer is the stopped iterate, verified by the framework
    np.testing.assert_array_equal(res.x, np.maximum(stop.xs[-1], 0.0))
    assert res.mvps < full.mvps
    assert not res.solved
    assert np.isfinite(res.verified_kkt_abs)


def test_bi_pqn_stops_on_request_and_counts_its_low_products():
    A, b = planted(50, 50, seed=5, cond=1e3)[:2]
    rng = np.random.default_rng(0)
    E = rng.standard_normal(A.shape) * 1e-2
    low = A + (E + E.T) / 2
    full = lcpbench.solve(A, b, solver="bi-pqn:low=low", low={"low": low},
                          low_cost={"low": 0.1}, tol=1e-10)
    stop = _StopAfter(mvps=2)
    res = lcpbench.solve(A, b, solver="bi-pqn:low=low", low={"low": low},
                         low_cost={"low": 0.1}, tol=1e-10, callback=stop)
    assert res.status == Status.stopped
    assert res.mvps == stop.rows[-1]["mvps"] < full.mvps
    assert res.emvps == pytest.approx(stop.rows[-1]["emvps"])


def test_a_stop_at_a_converged_iterate_keeps_converged():
    lcp = _problem()

    def stop_when_small(row, x):
        if row["kkt_abs"] <= 1e-6:
            raise StopIteration

    res = lcpbench.solve(lcp, solver="bb-pgd", tol=1e-6, callback=stop_when_small)
    assert res.status == Status.converged and res.solved


def test_stop_iteration_message_is_kept():
    def stop(row, x):
        raise StopIteration("enough for the plot")

    res = lcpbench.solve(_problem(), solver="mono-pqn", callback=stop)
    assert res.status == Status.stopped
    assert res.iterations == 0
    assert res.message.endswith("enough for the plot")


@dataclass(frozen=True)
class _DeafParams:
    iters: int = 50


@register_solver("test-deaf-to-stop", _DeafParams, listed=False)
def _deaf(ctx, p):
    """Projected gradient that ignores report's request to stop (a careless plugin)."""
    x = ctx.x0.copy()
    w = ctx.A @ x + ctx.b
    for _ in range(p.iters):
        ctx.report(x, w)
        x = np.maximum(x - 0.01 * w, 0.0)
        w = ctx.A @ x + ctx.b
    return ctx.finish(x, w, Status.max_iter, "ran all its iterations")


def test_a_solver_that_ignores_the_stop_is_ended_at_the_callbacks_iterate():
    stop = _StopAfter(mvps=3)
    res = lcpbench.solve(_problem(), solver="test-deaf-to-stop", callback=stop)
    assert res.status == Status.stopped
    assert len(stop.rows) == len(res.history)
    assert res.mvps <= 4
    np.testing.assert_array_equal(res.x, stop.xs[-1])


def test_other_exceptions_from_the_callback_still_fail_the_solve():
    def broken(row, x):
        raise KeyError("no such column")

    res = lcpbench.solve(_problem(), solver="bb-pgd", callback=broken)
    assert res.status == Status.failed and "KeyError" in res.message
