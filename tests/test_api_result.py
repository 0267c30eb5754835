"""``lcpbench.solve`` builds its own result: the solver's SolveResult is read, never rewritten."""

from dataclasses import dataclass

import numpy as np

import lcpbench
from lcpbench import register_solver
from lcpbench.core.result import Status

_RETURNED = []


@dataclass(frozen=True)
class _NoParams:
    pass


@register_solver("test-keeps-its-result", _NoParams, listed=False)
def _keeps_its_result(ctx, p):
    """Claims convergence at a wrong point and keeps the object it returns."""
    x = np.array([5.0, 0.0])
    w = ctx.A @ x + ctx.b
    ctx.report(x, w)
    res = ctx.finish(x, np.zeros(2), Status.converged, "done")
    res.info["own"] = 1
    _RETURNED.append(res)
    return res


def test_the_solvers_result_is_left_as_the_solver_made_it():
    lcp = lcpbench.LCP(np.eye(2), np.array([-1.0, 1.0]))
    out = lcpbench.solve(lcp, solver="test-keeps-its-result")
    mine = _RETURNED[-1]
    # the framework's verdict: refuted (||min(x, Ax+b)|| = 4 at x = (5, 0))
    assert out.status == Status.stagnated and not out.solved
    assert out.solver == "test-keeps-its-result" and out.info["own"] == 1
    assert out.verified_kkt_abs == 4.0
    # the object the solver returned still says what the solver said
    assert out is not mine
    assert mine.status == Status.converged and mine.message == "done"
    assert mine.solver == "" and mine.verified == {} and not mine.solved
