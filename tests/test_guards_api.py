"""``lcpbench.solve`` never raises for a valid call: a dense A too large is a failed result."""

import numpy as np
import pytest
import scipy.sparse as sp

import lcpbench
from lcpbench.core import guards

A2 = np.array([[2.0, 1.0], [1.0, 2.0]])
B2 = np.array([-1.0, 1.0])


def _spd(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((n, n))
    return M @ M.T / n + np.eye(n), rng.standard_normal(n)


def test_dense_solver_on_a_huge_sparse_matrix_is_failed_not_memoryerror():
    n = 1_000_000
    res = lcpbench.solve(sp.identity(n, format="csr"), -np.ones(n), solver="lemke")
    assert res.status == lcpbench.Status.failed and not res.solved
    assert res.message.startswith(f"lemke needs A as a dense matrix: n = {n} takes about "
                                  "7.28 TiB")
    assert res.mvps == 0 and res.x.shape == (n,)


def test_dense_limit_refuses_then_force_solves(monkeypatch):
    A, b = _spd(20)
    monkeypatch.setattr(guards, "DENSE_LIMIT_BYTES", 1000.0)     # 20 x 20 doubles are 3200 B
    monkeypatch.delenv(guards.FORCE_ENV, raising=False)
    res = lcpbench.solve(A, b, solver="lemke")
    assert res.status == lcpbench.Status.failed
    assert "over the limit of 1e+03 B" in res.message or "over the limit of 1000 B" in \
        res.message, res.message
    assert "force=True" in res.message
    forced = lcpbench.solve(A, b, solver="lemke", force=True)
    assert forced.status == lcpbench.Status.converged and forced.solved
    monkeypatch.setenv(guards.FORCE_ENV, "1")                    # a `run --force` worker
    assert lcpbench.solve(A, b, solver="lemke").solved
    # MVP-only solvers never form the dense A, so the limit does not concern them
    monkeypatch.delenv(guards.FORCE_ENV)
    assert lcpbench.solve(A, b, solver="bb-pgd", stop="kkt").solved


def test_matrix_free_dense_copy_counts_the_identity_too(monkeypatch):
    A, b = _spd(20)
    monkeypatch.setattr(guards, "DENSE_LIMIT_BYTES", 5000.0)     # 3200 B explicit, 6400 B free
    monkeypatch.delenv(guards.FORCE_ENV, raising=False)
    assert lcpbench.solve(A, b, solver="lemke").solved
    res = lcpbench.solve(lambda v: A @ v, b, solver="lemke")
    assert res.status == lcpbench.Status.failed and "6.25 KiB" in res.message


def test_memoryerror_while_forming_the_dense_matrix_is_a_failed_result(monkeypatch):
    import lcpbench.core.api as api

    def no_memory(op):
        raise MemoryError("Unable to allocate")

    monkeypatch.setattr(api, "dense_uncounted", no_memory)     # where the copy is formed
    res = lcpbench.solve(A2, B2, solver="lemke")
    assert res.status == lcpbench.Status.failed
    assert "ran out of memory" in res.message and "MVP-only" in res.message


@pytest.mark.parametrize("keyword, meant", [("tolerance", "tol"), ("maxiter", "max_iter"),
                                            ("timeout", "max_seconds"), ("x_0", "x0"),
                                            ("max_emvp", "max_emvps")])
def test_a_misspelt_solve_keyword_is_named(keyword, meant):
    with pytest.raises(TypeError) as err:
        lcpbench.solve(A2, B2, **{keyword: 1e-6})
    msg = str(err.value)
    assert msg.startswith(f"unknown keyword {keyword!r}. Did you mean {meant}?"), msg
    assert "mono-pqn's own parameters: memory" in msg


def test_solver_parameters_still_pass_and_unknown_ones_keep_the_solver_message():
    assert lcpbench.solve(A2, B2, solver="mono-pqn", memory=3).solved
    with pytest.raises(TypeError, match="unknown parameter 'reference' for 'mono-pqn'"):
        lcpbench.solve(A2, B2, reference=True)
    assert lcpbench.solve(A2, B2, solver="bb-pgd", reference="gll", stop="kkt").solved
