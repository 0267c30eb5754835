"""What the framework costs around a solve: its own products, the problem checks, the history."""

from dataclasses import dataclass

import numpy as np
import pytest
from lcp_cases import planted
from scipy.sparse.linalg import LinearOperator

import lcpbench
from lcpbench import LCP, Operator, Status, register_solver
from lcpbench.core import lcp as lcp_module
from lcpbench.core.specs import CheckedParams
from lcpbench.run.runner import result_fields


def _counting(A: np.ndarray) -> tuple[LinearOperator, list]:
    """A matrix-free copy of ``A`` that counts every product it is asked for."""
    calls = [0]

    def matvec(v):
        calls[0] += 1
        return A @ v

    def matmat(V):
        calls[0] += V.shape[1]
        return A @ V

    return LinearOperator(A.shape, matvec=matvec, matmat=matmat, dtype=np.float64), calls


def _framework_counted(res) -> int:
    return res.info.get("confirmation_mvps", 0) + res.info.get("infeasibility_mvps", 0)


@pytest.mark.parametrize("solver", ["bb-pgd", "mono-pqn", "minmap-newton"])
def test_every_product_the_operator_sees_is_in_the_result(solver):
    A, b = planted(25, seed=1)
    op, calls = _counting(A)
    res = lcpbench.solve(op, b, solver=solver)
    solver_own = res.mvps - _framework_counted(res)
    assert calls[0] == solver_own + res.framework_mvps
    # an operator that declares nothing is probed and verified twice: never for free
    assert res.framework_mvps >= 2
    assert result_fields(res)["framework_mvps"] == res.framework_mvps


def test_bb_pgd_on_a_declared_exact_operator_costs_at_most_one_framework_product():
    A, b = planted(40, seed=2)
    lin, calls = _counting(A)
    res = lcpbench.solve(Operator(lin, rtol=0.0), b, solver="bb-pgd", stop="kkt")
    assert res.status is Status.converged and res.solved
    assert res.framework_mvps <= 1
    assert res.info["verified_by"] == "the operator's last product"
    assert calls[0] == res.mvps - _framework_counted(res) + res.framework_mvps
    # the reused product is the operator's: the verified residual is A x + b at the answer
    np.testing.assert_allclose(res.verified_kkt_abs,
                               np.linalg.norm(np.minimum(res.x, A @ res.x + b)), atol=1e-14)


def test_verify_false_returns_the_claim_unverified_without_a_product():
    A, b = planted(30, seed=3)
    lin, calls = _counting(A)
    res = lcpbench.solve(lin, b, solver="bb-pgd", stop="kkt", verify=False)
    assert res.status is Status.converged and res.info["unverified"] is True
    assert not res.solved and np.isnan(res.verified_kkt_abs)
    checked = lcpbench.solve(lin, b, solver="bb-pgd", stop="kkt")
    assert checked.solved and "unverified" not in checked.info
    assert checked.framework_mvps > res.framework_mvps
    np.testing.assert_array_equal(res.x, checked.x)


def test_a_matrix_is_checked_once_per_operator(monkeypatch):
    A, b = planted(30, seed=4)
    tests = []
    real = lcp_module._semidefinite
    monkeypatch.setattr(lcp_module, "_semidefinite",
                        lambda *a: tests.append(1) or real(*a))
    op = Operator(A)
    for _ in range(3):
        assert lcpbench.solve(op, b, solver="bb-pgd").status is not Status.failed
    assert len(tests) == 1
    lcpbench.solve(A, b, solver="bb-pgd")          # a bare array: a new operator, checked
    assert len(tests) == 2
    lcpbench.solve(A, b, solver="bb-pgd", psd=True)     # declared: not checked
    assert len(tests) == 2


def test_the_cholesky_test_tells_semidefinite_from_indefinite():
    rng = np.random.default_rng(5)
    Q = np.linalg.qr(rng.standard_normal((40, 40)))[0]
    singular = Q @ np.diag(np.r_[np.zeros(5), np.linspace(1, 3, 35)]) @ Q.T
    LCP(singular, np.ones(40))                                  # PSD, singular: accepted
    lam = np.r_[-1e-4, np.linspace(1, 3, 39)]
    indefinite = Q @ np.diag(lam) @ Q.T
    indefinite = (indefinite + indefinite.T) / 2
    with pytest.raises(ValueError, match="not positive semidefinite .smallest eigenvalue -0.0001"):
        LCP(indefinite, np.ones(40))
    LCP(indefinite, np.ones(40), psd_check=False)              # declared: built anyway
    lcpbench.solve(indefinite, np.ones(40), solver="bb-pgd", psd=True)


def test_the_history_table_is_built_when_read():
    A, b = planted(20, seed=6)
    res = lcpbench.solve(A, b, solver="bb-pgd")
    assert callable(res.__dict__["_history"])                 # not yet a table
    h = res.history
    assert len(h) == res.iterations + 1 and res.__dict__["_history"] is h
    # the verified column, filled by one block product after the solve, is A x + b's
    assert h["kkt_abs_verified"].notna().all()
    # one uncounted column per iterate, tallied apart from the products the answer needs
    assert res.info["history_mvps"] == len(h)
    assert res.framework_mvps <= 1
    np.testing.assert_allclose(h["kkt_abs_verified"].iloc[-1], res.verified_kkt_abs,
                               rtol=1e-6, atol=1e-14)     # a block product rounds apart
    big = lcpbench.solve(*planted(600, seed=0), solver="bb-pgd", max_iter=5)
    assert big.history["kkt_abs_verified"].isna().all() and big.framework_mvps <= 1


@dataclass(frozen=True)
class _ExtraParams(CheckedParams):
    """Parameters of the test solver.

    Parameters
    ----------
    mode : str
        What to pass to ``ctx.report``: ``number``, ``text`` or ``clash``.
    """

    mode: str = "number"


@register_solver("test-report-extra", _ExtraParams, listed=False)
def _report_extra(ctx, p):
    x = np.zeros(ctx.n)
    w = ctx.b.copy()
    for k in range(3):
        extra = {"number": {"step": 0.5 * k}, "text": {"note": "x"},
                 "clash": {"mvps": 1.0}}[p.mode]
        ctx.report(x, w, **extra)
    return ctx.finish(x, w)


def test_report_records_extra_numbers_as_history_columns():
    A, b = planted(5, seed=7)
    res = lcpbench.solve(A, b, solver="test-report-extra")
    assert res.history["step"].tolist() == [0.0, 0.5, 1.0]


@pytest.mark.parametrize("mode, message", [
    ("text", "TypeError: ctx.report(..., note='x'): extra values are recorded as history "
             "columns and must be real numbers; put other records in ctx.info"),
    ("clash", "TypeError: ctx.report(..., mvps=...): 'mvps' is a column the framework "
              "records itself; give the solver's own value another name")])
def test_report_rejects_what_it_cannot_record(mode, message):
    A, b = planted(5, seed=7)
    res = lcpbench.solve(A, b, solver=f"test-report-extra:mode={mode}")
    assert res.status is Status.failed and res.message == message
