"""Krylov recycling of the boundary-integral solves (problems/suspension/bim/recycle.py)
and the paired forward/transposed product of the mobility."""

import numpy as np
import pytest

from lcpbench.problems.suspension.bim import BimMobility
from lcpbench.problems.suspension.bim import solves as bim_solves
from lcpbench.problems.suspension.bim.recycle import (
    _BREAKDOWN,
    _MAX_CHECKS,
    _ROUNDING,
    RecycledGCR,
    solve_together,
)
from lcpbench.problems.suspension.problem import build_contact_problem


def _matrix(n=60, seed=0):
    """A nonsymmetric second-kind matrix I + K with ||K|| < 1, like the traction operator."""
    rng = np.random.default_rng(seed)
    K = rng.standard_normal((n, n))
    return np.eye(n) + 0.9 * K / np.linalg.norm(K, 2)


def test_solves_to_the_true_residual_and_reuses_directions():
    G = _matrix()
    calls = []
    gcr = RecycledGCR(lambda v: calls.append(1) or G @ v, 60, capacity=500)
    rng = np.random.default_rng(1)
    b1, b2 = rng.standard_normal(60), rng.standard_normal(60)
    y1, its1, res1 = gcr.solve(b1, 1e-10, 200)
    assert np.linalg.norm(b1 - G @ y1) <= 1e-10 * np.linalg.norm(b1)
    assert res1 == pytest.approx(np.linalg.norm(b1 - G @ y1) / np.linalg.norm(b1), rel=1e-3,
                                 abs=1e-14)
    assert its1 > 5 and gcr.size == its1
    # a right-hand side in the span of what was solved needs no new product
    n_before = len(calls)
    y3, its3, _ = gcr.solve(2.0 * b1, 1e-10, 200)
    assert its3 == 0 and len(calls) == n_before
    assert np.allclose(y3, 2.0 * y1, rtol=1e-9, atol=1e-12)
    # a new right-hand side starts from the projection: fewer new directions than alone
    _, its2, _ = gcr.solve(b2, 1e-10, 200)
    _, its_alone, _ = RecycledGCR(lambda v: G @ v, 60, capacity=0).solve(b2, 1e-10, 200)
    assert its2 < its_alone


def test_capacity_drops_the_oldest_and_clear_forgets():
    G = _matrix()
    gcr = RecycledGCR(lambda v: G @ v, 60, capacity=7)
    gcr.solve(np.ones(60), 1e-10, 200)
    assert gcr.size == 7
    gcr.clear()
    assert gcr.size == 0
    y, its, _ = gcr.solve(np.ones(60), 1e-10, 200)
    assert its > 7 and np.linalg.norm(np.ones(60) - G @ y) <= 1e-10 * np.sqrt(60)


def test_unconverged_solve_reports_the_measured_residual():
    G = _matrix()
    gcr = RecycledGCR(lambda v: G @ v, 60, capacity=100)
    b = np.arange(60.0)
    y, its, res = gcr.solve(b, 1e-12, 3)
    assert its == 3
    assert res == pytest.approx(np.linalg.norm(b - G @ y) / np.linalg.norm(b), rel=1e-12)
    assert res > 1e-3


def test_solve_together_pairs_the_products_and_matches_separate_solves():
    G = _matrix(seed=3)
    rng = np.random.default_rng(4)
    b, z = rng.standard_normal(60), rng.standard_normal(60)
    fwd = RecycledGCR(lambda v: G @ v, 60, capacity=100)
    adj = RecycledGCR(lambda v: G.T @ v, 60, capacity=100)
    rounds = []

    def apply_many(vs):
        rounds.append([v is not None for v in vs])
        return [None if vs[0] is None else G @ vs[0], None if vs[1] is None else G.T @ vs[1]]

    (y, _, _), (w, _, _) = solve_together([(fwd, b), (adj, z)], apply_many, 1e-10, 200)
    assert np.linalg.norm(G @ y - b) <= 1e-10 * np.linalg.norm(b)
    assert np.linalg.norm(G.T @ w - z) <= 1e-10 * np.linalg.norm(z)
    both = sum(all(r) for r in rounds)
    assert both >= min(fwd.products, adj.products) - 1 and len(rounds) <= max(fwd.products,
                                                                               adj.products)


def _cluster():
    rng = np.random.default_rng(7)
    c = np.array([[0, 0, 0], [2.3, 0, 0], [0, 2.25, 0.1], [2.2, 2.4, 0.3]], float)
    return c + 0.02 * rng.standard_normal(c.shape)


def test_paired_product_equals_the_separate_products():
    c = _cluster()
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-11)
    B = BimMobility(c, 1.0, p=4, eps_gmres=1e-11, recycle=0)
    rng = np.random.default_rng(2)
    for _ in range(3):
        x, y = rng.standard_normal(24), rng.standard_normal(24)
        u, ua = A.matvec_rmatvec(x, y)
        assert np.abs(u - B @ x).max() <= 1e-9 * np.abs(u).max()
        assert np.abs(ua - B.rmatvec(y)).max() <= 1e-9 * np.abs(ua).max()
    assert len(A.gmres_iterations) == len(A.adjoint_iterations) == 3
    assert A.gmres_iterations[-1] < A.gmres_iterations[0]         # recycled
    with pytest.raises(ValueError, match="have 5 entries"):
        A.matvec_rmatvec(np.ones(5), np.ones(24))


def test_symmetrised_contact_operator_uses_the_paired_product():
    c = _cluster()
    F = np.tile([[0.0, 0.0, -1.0]], (4, 1))
    kw = dict(dt=0.1, delta=0.4, model="bim", p=4, eps_gmres=1e-10)
    prob = build_contact_problem(c, 1.0, F, None, symmetrize=True, **kw)
    assert prob.lcp.n > 0
    mob = prob.mobility
    paired = []
    mob_pair = mob.matvec_rmatvec
    mob.matvec_rmatvec = lambda x, y: paired.append(1) or mob_pair(x, y)
    v = np.linspace(0.5, 1.5, prob.lcp.n)
    Av = prob.lcp.A @ v
    assert paired == [1]
    D = prob.contacts.D
    ref = BimMobility(c, 1.0, p=4, eps_gmres=1e-10, recycle=0)
    f = D @ v
    expect = D.T @ (0.5 * (ref @ f + ref.rmatvec(f)))
    assert np.abs(Av - expect).max() <= 1e-8 * np.abs(expect).max()


def test_cold_products_start_empty_and_keep_the_directions():
    """Inside ``cold_products`` a product costs what a configuration's first product costs
    (no recycled directions); afterwards the kept directions are back."""
    c = _cluster()
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-10)
    x = np.linspace(1.0, 2.0, 24)
    u = A @ x
    first = A.gmres_iterations[-1]
    A @ x[::-1].copy()
    assert A.gmres_iterations[-1] < first                         # recycled: cheaper
    kept = A.recycled_directions
    with A.cold_products():
        u_cold = A @ x
        assert A.gmres_iterations[-1] == first                    # as the first product
        assert A.recycled_directions == first
    assert A.recycled_directions == kept                               # directions put back
    assert np.abs(u_cold - u).max() <= 1e-8 * np.abs(u).max()
    A @ x
    assert A.gmres_iterations[-1] <= 1                            # x's directions are kept


def test_measure_cost_times_every_repeat_cold_on_a_new_vector():
    """A cheap operator is timed on several products: each inside its own ``cold()``
    context, each on a different positive vector (no product served from memory)."""
    from contextlib import contextmanager

    from scipy.sparse.linalg import LinearOperator

    from lcpbench.core.operator import Operator
    from lcpbench.core.probes import measure_cost

    seen, state = [], {"cold": 0, "inside": False}

    def mv(v):
        seen.append((np.array(v, dtype=float).ravel(), state["inside"]))
        return 2.0 * np.asarray(v, dtype=float)

    @contextmanager
    def cold():
        state["cold"] += 1
        state["inside"] = True
        try:
            yield
        finally:
            state["inside"] = False

    op = Operator(LinearOperator((5, 5), matvec=mv, dtype=float), name="cheap")
    t = measure_cost(op, min_seconds=10.0, max_reps=7, cold=cold)
    assert t > 0 and len(seen) == 7 and state["cold"] == 7
    assert all(inside for _v, inside in seen)
    vs = np.array([v for v, _ in seen])
    assert (vs > 0).all()
    assert len({tuple(np.round(v, 12)) for v in vs}) == 7          # all different
    assert op.count == 0                                             # uncounted


class _ThreePassGCR(RecycledGCR):
    """The recycled solve as it was before the fused projections (the oracle below): each
    projection three passes (``h = C v``, ``U' h``, ``C' h``), the directions updated after
    each Gram-Schmidt pass."""

    def _project(self, v):
        k = self._filled
        if k == 0:
            return np.zeros(self.n), np.zeros(self.n)
        h = self._C[:k] @ v
        return h @ self._U[:k], h @ self._C[:k]

    def iterate(self, b: np.ndarray, rtol: float, maxiter: int,
                x0: np.ndarray | None = None):
        """The solve of :meth:`solve` as a generator: it yields every vector whose product
        it needs and is sent the product back; its return value is ``(y, iterations,
        residual)``.  :func:`solve_together` drives several at once."""
        b = np.asarray(b, dtype=np.float64).reshape(-1)
        nb = float(np.linalg.norm(b))
        if nb == 0.0:
            return np.zeros(self.n), 0, 0.0
        keep = self.capacity > 0
        self._reserve(self.capacity if keep else max(int(maxiter), 1))
        y, r = np.zeros(self.n), b.copy()
        if x0 is not None and np.any(x0):
            guess = np.array(x0, dtype=np.float64).reshape(-1)
            r0 = b - self._image((yield guess))
            if float(np.linalg.norm(r0)) < nb:          # the guess helps: start from it
                y, r = guess, r0
        k = self._filled
        h = self._C[:k] @ r
        if k:
            y += h @ self._U[:k]
            r -= h @ self._C[:k]
        # sum of |coefficients| of y in the directions: bounds the rounding drift
        weight = float(np.abs(h).sum())
        its = checks = 0
        stalled = force = False       # force: after a refuted check, one new direction
        res = 1.0
        try:
            while True:
                while ((force or float(np.linalg.norm(r)) > rtol * nb) and its < maxiter
                       and not stalled):
                    force = False
                    u = r / float(np.linalg.norm(r))
                    c = self._image((yield u))
                    its += 1
                    nc0 = float(np.linalg.norm(c))
                    du, dc = self._project(c)
                    u -= du
                    c -= dc
                    nc = float(np.linalg.norm(c))
                    if nc < nc0 / np.sqrt(2.0):              # twice is enough (Kahan)
                        du, dc = self._project(c)
                        u -= du
                        c -= dc
                        nc = float(np.linalg.norm(c))
                    if not nc > _BREAKDOWN * nc0:
                        stalled = True
                        break
                    c /= nc
                    u /= nc
                    alpha = float(c @ r)
                    y += alpha * u
                    r -= alpha * c
                    weight += abs(alpha)
                    self._add(u, c)
                res = float(np.linalg.norm(r)) / nb
                drift = _ROUNDING * self._filled * weight / nb
                if res <= rtol and drift <= 0.1 * rtol:
                    break             # the recurrence is the true residual to << rtol
                # measure the truth (the recurrence may have drifted, or the solve stopped)
                r = b - self._image((yield y))
                res = float(np.linalg.norm(r)) / nb
                checks += 1
                if res <= rtol or its >= maxiter or stalled or checks >= _MAX_CHECKS:
                    break
                force = True
                # fold the true residual back onto every direction (no product), go on
                du, dc = self._project(r)
                y += du
                r -= dc
        finally:
            if not keep:
                self.clear()
        return y, its, res


def test_recycled_products_agree_with_the_three_pass_projections(monkeypatch):
    """A row of forward and transposed products of one operator on a packed 2x2x2 lattice
    (each recycling the directions of the ones before), with the fused projections and with
    the earlier three-pass ones: the same products made and the same results to 1e-12."""
    rng = np.random.default_rng(8)
    grid = np.array([[i, j, k] for i in range(2) for j in range(2) for k in range(2)], float)
    c = 2.2 * grid + 0.05 * rng.uniform(-1.0, 1.0, (8, 3))
    ft = rng.standard_normal((4, 48))
    new = BimMobility(c, 1.0, p=4, eps_gmres=1e-8)
    u_new = [new @ f for f in ft] + [new.rmatvec(f) for f in ft]
    monkeypatch.setattr(bim_solves, "RecycledGCR", _ThreePassGCR)
    old = BimMobility(c, 1.0, p=4, eps_gmres=1e-8)
    assert isinstance(old.solves.forward_space, _ThreePassGCR)
    u_old = [old @ f for f in ft] + [old.rmatvec(f) for f in ft]
    assert new.gmres_iterations == old.gmres_iterations
    assert new.adjoint_iterations == old.adjoint_iterations
    assert new.gmres_iterations[-1] < new.gmres_iterations[0]       # directions were reused
    for a, b in zip(u_new, u_old):
        assert np.linalg.norm(a - b) <= 1e-12 * np.linalg.norm(b)
