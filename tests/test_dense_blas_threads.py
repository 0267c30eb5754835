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
    report, lemke_solve = SolverContext.report, dense.lemke_solve

    def observed_report(self, x, w):
        seen.extend(_blas_threads())
        return report(self, x, w)

    def observed_lemke_solve(*args):             # inside lemke, around its compiled run
        seen.extend(_blas_threads())
        return lemke_solve(*args)

    monkeypatch.setattr(SolverContext, "report", observed_report)
    monkeypatch.setattr(dense, "lemke_solve", observed_lemke_solve)
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


def test_one_blas_thread_enters_a_limit_only_when_blas_has_more_threads():
    from contextlib import nullcontext

    from lcpbench.toolkit.blas import one_blas_thread

    if not _blas_threads():
        pytest.fail("no BLAS library found by threadpoolctl")
    with threadpool_limits(limits=1, user_api="blas"):
        assert isinstance(one_blas_thread(), nullcontext)   # already one: nothing to enter
    with threadpool_limits(limits=2, user_api="blas"):
        ctx = one_blas_thread()
        assert not isinstance(ctx, nullcontext)
        with ctx:
            assert set(_blas_threads()) == {1}
        assert set(_blas_threads()) == {2}
