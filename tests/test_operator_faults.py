"""Operators that misbehave while the framework handles them, and plugins outside packages.

A dense solver's copy of a matrix-free A is formed by the framework: an operator that
raises or returns NaN there is a ``failed`` result, never an exception, and the copy is
made on the solve's clock. An operator that writes into its input never changes a
vector the framework keeps. Problem families named in ``LCPBENCH_PLUGINS`` are known to
``solve`` and ``run``, not only listed.
"""

import os
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from scipy.linalg import cho_factor, cho_solve
from scipy.sparse.linalg import LinearOperator

import lcpbench
from lcpbench import Status

DENSE_SOLVERS = ["pgs", "lemke", "clarabel", "proxqp", "osqp"]
A2 = np.array([[2.0, 1.0], [1.0, 2.0]])
B2 = np.array([-1.0, -1.0])


def _raising(v):
    raise RuntimeError("the mobility solve broke down")


@pytest.mark.parametrize("solver", DENSE_SOLVERS)
def test_an_operator_raising_while_the_dense_copy_is_formed_is_a_failed_result(solver):
    res = lcpbench.solve(LinearOperator((2, 2), matvec=_raising, dtype=float), B2,
                         solver=solver)
    assert res.status == Status.failed
    assert res.message.startswith(f"{solver} needs A as a dense matrix: forming it failed: ")
    assert "the mobility solve broke down" in res.message and not res.solved


@pytest.mark.parametrize("solver", DENSE_SOLVERS)
def test_a_nan_in_the_dense_copy_is_a_failed_operator(solver):
    def half_nan(v):
        y = A2 @ v
        return y * np.nan if v[1] != 0 else y

    res = lcpbench.solve(LinearOperator((2, 2), matvec=half_nan, dtype=float), B2, solver=solver)
    assert res.status == Status.failed
    assert res.message == ("operator returned non-finite values while the framework formed the "
                           f"dense copy of A (column 1) for {solver}")


def test_the_dense_copy_is_formed_inside_the_time_budget():
    n = 60
    M = np.diag(np.linspace(1.0, 2.0, n))

    def slow(v):
        time.sleep(0.05)                       # 60 columns: 3 s, three times the budget
        return M @ v

    t0 = time.perf_counter()
    res = lcpbench.solve(LinearOperator((n, n), matvec=slow, dtype=float), -np.ones(n),
                         solver="pgs", max_seconds=1.0)
    wall = time.perf_counter() - t0
    assert res.status == Status.timeout
    assert res.message.startswith("pgs needs A as a dense matrix: the time budget of 1 s ran out "
                                  "while forming it (")
    assert wall < 2.5                          # not the 3 s of the whole copy plus the solve
    assert res.time_s >= 1.0                   # the copy is on the solve's clock


def test_a_dense_copy_of_a_matrix_free_operator_in_blocks_is_the_matrix():
    rng = np.random.default_rng(3)
    G = rng.standard_normal((300, 300))
    M = G @ G.T + 300 * np.eye(300)
    b = -rng.standard_normal(300)
    res = lcpbench.solve(LinearOperator((300, 300), matvec=lambda v: M @ v, dtype=float), b,
                         solver="lemke")
    assert res.status == Status.converged and res.solved
    assert np.linalg.norm(np.minimum(res.x, M @ res.x + b)) < 1e-10


class Overwriting(LinearOperator):
    """``A^-1``-style operator that overwrites its input, as ``cho_solve(overwrite_b=True)``."""

    def __init__(self, M):
        super().__init__(np.float64, M.shape)
        self.M = M
        self.factor = cho_factor(np.linalg.inv(M))

    def _matvec(self, v):
        v = np.ravel(v)
        # (inv(M))^-1 v = M v, solved in place: the input array is overwritten
        return cho_solve(self.factor, v, overwrite_b=True, check_finite=False)


@pytest.mark.parametrize("solver", ["lemke", "clarabel", "pgs", "mono-pqn", "bb-pgd"])
def test_an_operator_that_writes_into_its_input_leaves_the_answer_alone(solver):
    M = np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 1.0], [0.0, 1.0, 2.0]])
    b = np.array([-1.0, -2.0, -1.0])
    op = Overwriting(M)
    probe = np.array([1.0, 2.0, 3.0])
    op.matvec(probe)
    assert not np.allclose(probe, [1.0, 2.0, 3.0])   # it does overwrite what it is given
    res = lcpbench.solve(op, b, solver=solver, stop="kkt", tol=1e-9)
    x = np.linalg.solve(M, -b)                       # interior solution: A x + b = 0
    assert np.allclose(res.x, x, atol=1e-6), res.x
    assert res.solved and res.verified["kkt_abs"] == pytest.approx(
        np.linalg.norm(np.minimum(res.x, M @ res.x + b)), abs=1e-12)


def test_an_operator_reusing_its_output_buffer_does_not_change_a_kept_product():
    M = np.array([[3.0, 1.0], [1.0, 2.0]])
    buf = np.zeros(2)

    def reuse(v):
        buf[:] = M @ np.ravel(v)
        return buf

    op = lcpbench.Operator(reuse, shape=(2, 2))
    y1 = op.matvec(np.array([1.0, 0.0]))
    op.matvec(np.array([0.0, 1.0]))
    assert y1.tolist() == [3.0, 1.0]
    assert op.last_product(np.array([0.0, 1.0])).tolist() == [1.0, 2.0]


PLUGIN = '''
from dataclasses import dataclass
import numpy as np
from lcpbench import LCP, register_problem


@dataclass(frozen=True)
class DiagParams:
    """Parameters.

    Parameters
    ----------
    n : int
        Size.
    """

    n: int = 4


@register_problem("plugin-diagonal", DiagParams)
def make(p):
    """Diagonal LCPs from a plugin file."""
    return [LCP(np.diag(np.arange(1.0, p.n + 1)), -np.ones(p.n), name="plugin-diagonal-0")]
'''


def _lcpbench(*args, cwd, env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lcpbench.cli", *args], capture_output=True,
                          text=True, cwd=cwd, env={**os.environ, **env}, timeout=300)


def test_a_problem_family_from_lcpbench_plugins_is_known_to_solve_and_run(tmp_path):
    (tmp_path / "diag_plugin.py").write_text(PLUGIN)
    env = {"LCPBENCH_PLUGINS": "diag_plugin.py"}
    solved = _lcpbench("solve", "--problem", "plugin-diagonal:n=5", "--solver", "bb-pgd",
                       "--stop", "kkt", "--json", cwd=tmp_path, env=env)
    assert solved.returncode == 0, solved.stderr
    assert '"solved": true' in solved.stdout
    ran = _lcpbench("run", "--problem", "plugin-diagonal:n=3", "--solver", "bb-pgd", "--out",
                    "r", "--quiet", "--no-report", cwd=tmp_path, env=env)
    assert ran.returncode == 0, ran.stderr
    rows = pd.read_csv(tmp_path / "r" / "results.csv")
    assert rows["problem"].str.startswith("plugin-diagonal").all() and len(rows) == 1


def test_a_dok_matrix_and_a_nested_list_with_low_cost_are_solved():
    import scipy.sparse as sp

    res = lcpbench.solve(sp.dok_matrix(A2), B2, stop="kkt")
    assert res.solved and np.allclose(res.x, [1 / 3, 1 / 3])
    res = lcpbench.solve(A2.tolist(), B2, solver="bi-pqn", low={"coarse": A2}, low_cost=0.1,
                         stop="kkt")
    assert res.solved and np.allclose(res.x, [1 / 3, 1 / 3])
