"""Products to a requested accuracy (``Operator.product_within``) and PQN's loose products of
points (``products=iterate,relax=``): the hook, the boundary-integral
operator's looser solves, and that loose products never decide a claim."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

import lcpbench
from problems.suspension.bim import BimMobility
from problems.suspension.operators import ContactOperator
from tests.sphere_cases import packed


def _lcp_matrix(n=60, seed=0):
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((n, n))
    return M @ M.T / n + 0.05 * np.eye(n), rng.standard_normal(n)


class _Loose(LinearOperator):
    """``A v`` with an error of exactly the accuracy in force, ``rtol ||A v||`` along a fixed
    direction (the worst an accuracy allows), and a work hook that charges a Krylov solve's
    cost: ``log(rtol) / log(0.5)`` applications per product."""

    def __init__(self, A, base_rtol, seed=3):
        super().__init__(dtype=np.float64, shape=A.shape)
        self.A, self.base = A, base_rtol
        d = np.random.default_rng(seed).standard_normal(A.shape[0])
        self.d = d / np.linalg.norm(d)
        self.now = base_rtol
        self.asked: list = []
        self.apps = 0.0

    @contextlib.contextmanager
    def at_accuracy(self, rtol):
        saved, self.now = self.now, max(rtol, self.base)
        self.asked.append(rtol)
        try:
            yield
        finally:
            self.now = saved

    def _matvec(self, v):
        y = self.A @ np.ravel(v)
        self.apps += np.ceil(np.log(self.now) / np.log(0.5))
        return y + self.now * np.linalg.norm(y) * self.d

    def work(self):
        return self.apps


def _operator(A, rtol, name="high", cost=1.0):
    impl = _Loose(A, rtol)
    return lcpbench.Operator(impl, name=name, rtol=rtol, work=impl.work, cost=cost), impl


def test_product_within_reaches_the_operator_and_is_not_reused():
    A, _ = _lcp_matrix()
    op, impl = _operator(A, 1e-10)
    v = np.ones(A.shape[0])
    assert op.relaxable
    y = op.product_within(v, 1e-3)
    assert impl.asked == [1e-3] and op.count == 1 and op.loose == 1
    err = np.linalg.norm(y - A @ v) / np.linalg.norm(A @ v)
    assert 0.5e-3 < err < 2e-3                    # made to the accuracy asked, not the default
    assert op.last_product(v) is None             # a loose product never confirms a claim
    assert op.applications == np.ceil(np.log(1e-3) / np.log(0.5))
    # no looser than the operator's own accuracy: the ordinary (remembered) product
    y2 = op.product_within(v, 1e-12)
    assert impl.asked == [1e-3] and op.count == 2 and op.loose == 1
    np.testing.assert_array_equal(op.last_product(v), y2)
    for bad in (0.0, 1.0, np.nan):
        with pytest.raises(ValueError, match="requested accuracy"):
            op.product_within(v, bad)


def test_product_within_on_a_matrix_is_the_exact_product():
    A, _ = _lcp_matrix()
    op = lcpbench.Operator(A)
    v = np.arange(A.shape[0], dtype=float)
    assert not op.relaxable
    np.testing.assert_array_equal(op.product_within(v, 1e-2), A @ v)
    assert op.loose == 0 and op.count == 1


@pytest.mark.parametrize("solver", ["mono-pqn", "bi-pqn"])
def test_loose_products_converge_to_the_verified_answer_with_less_work(solver):
    """Errors of the full size each requested accuracy allows, in one fixed direction: the
    loose solve is still verified to the same answer and made looser products that tighten
    as it converges; Mono-PQN's work hook charged fewer applications than at full accuracy."""
    A, b = _lcp_matrix(seed=1)
    ref = lcpbench.solve(lcpbench.LCP(A, b), solver="mono-pqn", tol=1e-10)
    extra = ",low=low" if solver == "bi-pqn" else ""
    out = {}
    for relax in (0.0, 0.1):
        op, impl = _operator(A, 1e-11)
        low, low_impl = _operator(A + 0.01 * np.diag(np.diag(A)), 1e-9, name="low", cost=0.1)
        res = lcpbench.solve(lcpbench.LCP(op, b, low={"low": low}),
                             solver=f"{solver}:products=iterate,relax={relax}{extra}", tol=1e-10)
        assert res.status.value == "converged" and res.solved
        np.testing.assert_allclose(res.x, ref.x, rtol=0, atol=1e-7 * np.linalg.norm(ref.x))
        out[relax] = (res, impl, low_impl)
    full, loose = out[0.0], out[0.1]
    assert full[1].asked == [] and full[0].info["loose_products"] == []
    asked = loose[0].info["loose_products"]
    assert asked and all(1e-11 < r <= 0.1 for r in asked)
    assert loose[0].info["relax"] == 0.1
    if solver == "mono-pqn":
        assert len(asked) >= 3 and asked[-1] < asked[0]     # tightened as the residual fell
        assert loose[0].applications < full[0].applications
    else:   # the subproblems' low products are loose too (Bi-PQN gains little: docs)
        assert loose[0].info["low_loose_products"] > 0 and loose[2].asked


def test_relax_needs_an_operator_that_offers_looser_products():
    A, b = _lcp_matrix(seed=2)
    res = lcpbench.solve(lcpbench.LCP(lcpbench.Operator(A, rtol=1e-12), b),
                         solver="mono-pqn:products=iterate,relax=0.1", tol=1e-10)
    assert res.solved and res.info["relax"] == 0.0 and res.info["loose_products"] == []


def test_bim_products_at_a_looser_accuracy():
    """``BimMobility.at_accuracy`` stops the solve earlier (fewer applications, an error of
    about the accuracy asked) and restores the tolerance; the contact operator keeps loose
    products out of the cache of the position update."""
    c = packed(2, spacing=2.4, jitter=0.2, seed=1)
    mob = BimMobility(c, 1.0, p=4, eps_gmres=1e-10, recycle=0)
    f = np.random.default_rng(0).standard_normal(6 * len(c))
    exact = mob.matvec(f)
    its_full = mob.gmres_iterations[-1]
    with mob.at_accuracy(1e-3):
        assert mob.solve_tol == 1e-3
        loose = mob.matvec(f)
    assert mob.solve_tol == 1e-10
    assert mob.gmres_iterations[-1] < its_full and mob.residuals[-1] <= 1e-3
    err = np.linalg.norm(loose - exact) / np.linalg.norm(exact)
    assert 1e-9 < err < 1e-2
    with mob.at_accuracy(1e-14):                  # never tighter than eps_gmres
        assert mob.solve_tol == 1e-10
    with pytest.raises(ValueError):
        mob.at_accuracy(2.0).__enter__()          # refused on entry
    # the contact operator: a loose product is not what velocity() later returns
    n = 6
    D = sp.random(6 * len(c), n, density=0.3, random_state=1, format="csc")
    dmd = ContactOperator(D, mob, symmetrize=False)
    v = np.ones(n)
    with dmd.operator().at_accuracy(1e-3):
        dmd.matvec(v)
    solves = dmd.solves
    u = dmd.velocity(v)
    assert dmd.solves == solves + 1               # solved again, at full accuracy
    np.testing.assert_allclose(u, mob.matvec(D @ v), rtol=1e-7, atol=1e-12)
