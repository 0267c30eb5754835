"""pgs and lemke run with BLAS on one thread, the toolkit's rule."""

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import lcpbench
import lcpbench.solvers.dense as dense
from lcpbench.core.context import SolverContext


def _blas_threads() -> list[int]:
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


@pytest.mark.parametrize("solver", ["pgs", "lemke"])
def test_dense_solvers_run_on_one_blas_thread(solver, monkeypatch):
    seen: list[int] = []
    report, solution = SolverContext.report, dense._Tableau.solution

    def observed_report(self, x, w):
        seen.extend(_blas_threads())
        return report(self, x, w)

    def observed_solution(self, ctx):            # inside lemke, after the compiled pivots
        seen.extend(_blas_threads())
        return solution(self, ctx)

    monkeypatch.setattr(SolverContext, "report", observed_report)
    monkeypatch.setattr(dense._Tableau, "solution", observed_solution)
    rng = np.random.default_rng(3)
    G = rng.standard_normal((40, 40))
    A = G @ G.T / 40 + np.eye(40)
    b = rng.standard_normal(40)
    with threadpool_limits(limits=2, user_api="blas"):      # two threads outside the solve
        res = lcpbench.solve(A, b, solver=solver)
        outside = _blas_threads()
    assert res.solved
    assert seen and set(seen) == {1}
    assert set(outside) == {2}
