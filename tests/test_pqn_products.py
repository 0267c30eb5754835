"""PQN's products of the new point (``products=iterate``) and the pair
storage's sweeps: what is applied, when the difference is given up, and that the
pairs' products with the gradient come from the pair update."""

from __future__ import annotations

import numpy as np
import pytest

import lcpbench
import lcpbench.toolkit.quasinewton as qn
from lcpbench.toolkit.quasinewton import DiagonalBFGS, ModelPairs, SecantMemory


def _lcp_matrix(n=60, seed=0):
    rng = np.random.default_rng(seed)
    M = rng.standard_normal((n, n))
    A = M @ M.T / n + 0.05 * np.eye(n)
    b = rng.standard_normal(n)
    return A, b


class _Recorder:
    """``A v`` that keeps every input it was applied to."""

    def __init__(self, A):
        self.A, self.inputs = A, []

    def __call__(self, v):
        self.inputs.append(np.array(v, dtype=float))
        return self.A @ v


def _solve(solver, rtol=0.0, seed=0, tol=1e-10):
    A, b = _lcp_matrix(seed=seed)
    rec = _Recorder(A)
    op = lcpbench.Operator(rec, shape=A.shape, rtol=rtol)
    return lcpbench.solve(lcpbench.LCP(op, b), solver=solver, tol=tol), rec, (A, b)


@pytest.mark.parametrize("solver", ["mono-pqn", "bi-pqn"])
def test_iterate_products_apply_the_operator_to_points_not_directions(solver):
    """The paper's products are of directions (entries of both signs); products=iterate
    applies A to the new points, which are >= 0, and reaches the same answer."""
    extra = ",low=low" if solver == "bi-pqn" else ""
    A, b = _lcp_matrix(seed=1)
    runs = {}
    for mode in ("paper", "iterate"):
        rec = _Recorder(A)
        op = lcpbench.Operator(rec, shape=A.shape, rtol=0.0, cost=1.0)
        low_rec = _Recorder(A + 0.01 * np.diag(np.diag(A)))
        low = lcpbench.Operator(low_rec, shape=A.shape, name="low", cost=0.1, rtol=0.0)
        res = lcpbench.solve(lcpbench.LCP(op, b, low={"low": low}),
                             solver=f"{solver}:products={mode}{extra}", tol=1e-10)
        assert res.status.value == "converged" and res.solved
        runs[mode] = (res, rec.inputs)
        if solver == "bi-pqn":     # the subproblems' low products are of points too
            lofi = sum(res.lofi_mvps.values())
            negative = sum(np.min(v) < 0 for v in low_rec.inputs)
            if mode == "paper":
                assert res.info["low_iterate_products"] == 0 and negative >= lofi // 2
            else:
                assert res.info["low_iterate_products"] >= lofi // 2
                assert negative <= lofi - res.info["low_iterate_products"]
    paper_in, iterate_in = runs["paper"][1], runs["iterate"][1]
    res = runs["iterate"][0]
    made = res.info["iterate_products"]
    # directions have entries of both signs; points of the feasible set have none < 0:
    # only the products made after the switch to directions (near the end) may have
    assert sum(np.min(v) < 0 for v in paper_in) >= runs["paper"][0].mvps // 2
    assert sum(np.min(v) < 0 for v in iterate_in) <= res.mvps - made
    assert made >= res.mvps // 2 and made >= 3
    np.testing.assert_allclose(res.w, A @ res.x + b, rtol=0, atol=1e-8)
    x_p, x_i = runs["paper"][0].x, res.x
    assert np.linalg.norm(x_i - x_p) <= 1e-7 * np.linalg.norm(x_p)


def test_iterate_products_fall_back_to_directions_when_the_difference_is_inaccurate():
    """A declared accuracy of 1e-5 makes the difference's error bound pass difference_tol as
    the steps shrink: the solver switches to products of p and still converges."""
    res, rec, (A, b) = _solve("mono-pqn:products=iterate,difference_tol=0.01", rtol=1e-5,
                              tol=1e-6)
    assert res.status.value == "converged" and res.solved
    k = res.info["iterate_switched"]
    assert k is not None and k < res.info["iterate_products"] + 1
    errors = res.info["iterate_errors"]
    assert errors[k - 1] > 0.1 * 0.01 and all(e <= 0.1 * 0.01 for e in errors[:k - 1])
    # after the switch the operator sees directions again (an input with a negative entry)
    assert any(np.min(v) < 0 for v in rec.inputs[1 + k:])


def test_iterate_products_need_a_known_accuracy():
    """An operator of unknown (here single-precision) accuracy gets the paper's products."""
    A, b = _lcp_matrix(seed=2)
    op = lcpbench.Operator(lambda v: (A.astype(np.float32) @ v.astype(np.float32)),
                           shape=A.shape)
    res = lcpbench.solve(lcpbench.LCP(op, b), solver="mono-pqn:products=iterate", tol=1e-4)
    assert res.info["products"].startswith("paper (")
    assert "iterate_products" not in res.info


def test_paper_products_are_the_default_and_unchanged():
    res, rec, _ = _solve("mono-pqn")
    assert res.info["products"] == "paper"
    assert len(rec.inputs) >= 3 and any(np.min(v) < 0 for v in rec.inputs[1:])


# ------------------------------------------------------------------ pair storage
def _pairs(n, r, seed=0):
    rng = np.random.default_rng(seed)
    A, _ = _lcp_matrix(n, seed)
    S = [rng.standard_normal(n) for _ in range(r)]
    return A, S, [A @ s for s in S]


def test_gradient_products_come_from_the_pair_update(monkeypatch):
    """After add_pair(s, y, g) the two-loop's W g costs no sweep over the pairs; when g is
    the previous g plus y (the gradient recurrence) the update makes no product with g
    either, and W g equals the direct products."""
    n = 200
    A, S, Y = _pairs(n, 6)
    model = DiagonalBFGS(n)
    g = np.random.default_rng(3).standard_normal(n)
    model.add_pair(S[0], Y[0], g)
    calls = []
    real = qn.row_products
    monkeypatch.setattr(qn, "row_products", lambda W, vs: calls.append(
        sum(np.asarray(v).reshape(-1, n).shape[0] for v in vs)) or real(W, vs))
    for s, y in zip(S[1:], Y[1:]):
        g = g + y
        model.add_pair(s, y, g)
        Wg = model.products_with(g)
        _, W, _, _, _ = model.compact()
        np.testing.assert_allclose(Wg, W @ g, rtol=1e-12, atol=1e-12 * np.abs(W @ g).max())
    assert calls == [4] * 5                  # the Gram rows only: no product with g


def test_secant_memory_of_a_model_holds_its_pairs_as_read_only_views():
    n = 50
    _, S, Y = _pairs(n, 5, seed=5)
    model = DiagonalBFGS(n)
    model.set_pairs(S, Y)
    mem = ModelPairs(model).memory(n)
    assert (mem.n, mem.rank) == (n, 5)
    np.testing.assert_array_equal(mem.S, np.column_stack(S))
    np.testing.assert_array_equal(mem.Y, np.column_stack(Y))
    with pytest.raises(ValueError):
        mem.S[0, 0] = 1.0
    again = SecantMemory(mem.S, mem.Y)        # the (n, r) form round-trips
    np.testing.assert_array_equal(again.S, mem.S)
