"""A low fidelity of the high's own order shares the high's set-up (BimMobility.at_tolerance)."""

import numpy as np
import pytest

from lcpbench.problems.suspension.bim import BimMobility
from lcpbench.problems.suspension.problem import build_contact_problem

CENTERS = np.array([[0.0, 0.0, 0.0], [2.15, 0.0, 0.0], [1.0, 1.9, 0.3], [-0.4, -1.2, 1.8]])


def test_twin_is_the_same_map_to_its_own_tolerance():
    high = BimMobility(CENTERS, 1.0, p=5, eps_gmres=1e-10)
    loose = high.at_tolerance(1e-3)
    same = high.at_tolerance(1e-10)
    x = np.linspace(-1.0, 2.0, 24)
    u = high @ x
    assert loose.plan is high.plan and loose.eps_gmres == 1e-3 and high.eps_gmres == 1e-10
    # same tolerance: the same product; looser: a few digits, and fewer GMRES products
    assert np.linalg.norm(same @ x - u) <= 1e-8 * np.linalg.norm(u)
    err = np.linalg.norm(loose @ x - u) / np.linalg.norm(u)
    assert 1e-12 < err < 1e-2
    assert loose.gmres_iterations[0] < high.gmres_iterations[0]
    # each keeps its own records and kept directions
    assert len(high.gmres_iterations) == 1 and len(loose.gmres_iterations) == 1
    assert 0 < loose.recycled_directions < high.recycled_directions
    # the transposed product of the twin agrees with the high's transposed product
    ut = high.T @ x
    assert np.linalg.norm(same.T @ x - ut) <= 1e-8 * np.linalg.norm(ut)


def test_a_low_of_the_high_order_reuses_the_high_mobility(monkeypatch):
    calls = []
    original = BimMobility.at_tolerance

    def spy(self, eps):
        calls.append((self.p, eps))
        return original(self, eps)

    monkeypatch.setattr(BimMobility, "at_tolerance", spy)
    F = np.tile([[0.5, -0.2, 0.1]], (4, 1))
    prob = build_contact_problem(CENTERS, 1.0, F, np.zeros((4, 3)), delta=0.5, model="bim",
                                 p=4, eps_gmres=1e-8, low=["p4e3", "p3e6"])
    n = prob.lcp.n
    assert n >= 1
    assert calls == [(4, 1e-3)]          # p4e3 is the high's twin; p3e6 has its own set-up
    A = np.column_stack([prob.lcp.A @ e for e in np.eye(n)])
    L = np.column_stack([prob.lcp.low["p4e3"] @ e for e in np.eye(n)])
    L3 = np.column_stack([prob.lcp.low["p3e6"] @ e for e in np.eye(n)])
    e_same_order = np.linalg.norm(L - A) / np.linalg.norm(A)
    e_lower_order = np.linalg.norm(L3 - A) / np.linalg.norm(A)
    assert e_same_order < 1e-2
    assert e_same_order < e_lower_order


def test_twin_refuses_a_bad_tolerance():
    high = BimMobility(CENTERS[:2], 1.0, p=3, eps_gmres=1e-8)
    with pytest.raises(ValueError, match="eps_gmres"):
        high.at_tolerance(2.0)


def test_operators_are_freed_without_the_cyclic_collector():
    """No reference cycle keeps a configuration's blocks and kept directions alive: a time
    stepper that drops its step's operators gets the memory back at once (with cycles a
    27-sphere simulation grew by 20-70 MB per step until it was killed)."""
    import gc
    import weakref

    gc.collect()
    gc.disable()
    try:
        op = BimMobility(CENTERS[:3], 1.0, p=3, eps_gmres=1e-8)
        x = np.linspace(1.0, 2.0, 18)
        op @ x
        op.T @ x
        op.matvec_rmatvec(x, x)
        twin = op.at_tolerance(1e-3)
        twin @ x
        twin.T @ x
        F = np.tile([[0.5, -0.2, 0.1]], (4, 1))
        prob = build_contact_problem(CENTERS, 1.0, F, np.zeros((4, 3)), delta=0.5,
                                     model="bim", p=3, eps_gmres=1e-8, low=["p3e3", "p2"])
        prob.lcp.A @ np.ones(prob.lcp.n)
        prob.lcp.low["p3e3"] @ np.ones(prob.lcp.n)
        refs = [weakref.ref(o) for o in (op, twin, prob.mobility, prob)]
        del op, twin, prob
        assert [r() is None for r in refs] == [True] * 4
    finally:
        gc.enable()


def test_split_low_keeps_near_pairs_and_truncates_far_ones():
    from lcpbench.problems.suspension.bim import split_mobility

    centers = np.vstack([CENTERS, [[4.6, 0.3, -0.2]]])
    high = BimMobility(centers, 1.0, p=6, eps_gmres=1e-10)
    x = np.linspace(-1.0, 2.0, 30)
    u = high @ x
    errs = []
    for q in (1, 2, 4, 6):
        low = split_mobility(high, q, 1e-10, decay=0.0)
        assert low.plan is high.plan and low.far_degree == q
        # which pairs are near: gap below half the source radius
        gaps = [np.linalg.norm(centers[i] - centers[j]) - 2.0
                for i, j in zip(high.plan.near.block_tgt, high.plan.near.block_src)]
        assert low.n_full_pairs == sum(g < 0.5 for g in gaps) > 0
        assert low.n_truncated_pairs == sum(g >= 0.5 for g in gaps) > 0
        errs.append(np.linalg.norm(low @ x - u) / np.linalg.norm(u))
    # a lower far-field degree is a coarser low; degree p truncates nothing these pairs use
    assert errs[0] > errs[1] > errs[2] > errs[3]
    assert errs[0] > 1e-3 and errs[3] < 1e-8
    # the degree falls with distance: less block work, no pair above far_degree
    fixed, falls = split_mobility(high, 4, 1e-10, decay=0.0), split_mobility(high, 4, 1e-10)
    assert falls.block_work < fixed.block_work
    assert max(falls.pairs_per_degree) == 4 and min(falls.pairs_per_degree) < 4
    assert set(fixed.pairs_per_degree) == {4}
    # every pair near: the split low is the high operator
    near_all = split_mobility(high, 1, 1e-10, near_gap=100.0)
    assert near_all.n_truncated_pairs == 0
    assert np.linalg.norm(near_all @ x - u) <= 1e-9 * np.linalg.norm(u)
    # the transpose is exact: <y, M x> = <M' y, x>, alone and in the paired product
    tight = split_mobility(high, 3, 1e-12)
    y = np.cos(np.arange(30.0))
    lhs, rhs = y @ (tight @ x), (tight.T @ y) @ x
    assert abs(lhs - rhs) <= 1e-9 * abs(lhs)
    u2, v2 = tight.matvec_rmatvec(x, y)
    assert np.allclose(u2, tight @ x, rtol=1e-9, atol=1e-13)
    assert np.allclose(v2, tight.T @ y, rtol=1e-9, atol=1e-13)
    # and it is the split's transpose, not the high's
    assert abs((high.T @ y) @ x - rhs) > 1e-6 * abs(rhs)
    with pytest.raises(ValueError, match="far_degree"):
        split_mobility(high, 7, 1e-3)
    with pytest.raises(ValueError, match="near_gap"):
        split_mobility(high, 2, 1e-3, near_gap=-1.0)
    with pytest.raises(ValueError, match="decay"):
        split_mobility(high, 2, 1e-3, decay=float("nan"))


def test_compressed_split_low_cuts_block_singular_values():
    from lcpbench.problems.suspension.bim import split_mobility

    centers = np.vstack([CENTERS, [[4.6, 0.3, -0.2]]])
    high = BimMobility(centers, 1.0, p=6, eps_gmres=1e-10)
    x = np.linspace(-1.0, 2.0, 30)
    y = np.cos(np.arange(30.0))
    dense = split_mobility(high, 4, 1e-12)
    u = dense @ x
    # a cut far below the blocks' accuracy: the factored blocks are the dense ones
    exact = split_mobility(high, 4, 1e-12, rank_tol=1e-15)
    assert exact.n_factored_blocks == high.plan.near.blocks.shape[0]
    assert np.linalg.norm(exact @ x - u) <= 1e-9 * np.linalg.norm(u)
    # a cut at 1e-2: fewer terms than any block's size, less work, a small change
    cut = split_mobility(high, 4, 1e-12, rank_tol=1e-2)
    nv = high.plan.near.blocks.shape[1]
    assert 1 <= cut.mean_rank < nv / 2
    # fewer multiply-adds than the same blocks dense (the high's rotated form, which the
    # uncompressed split keeps, is cheaper still: docs/mobility.md)
    assert cut.near.groups[0].work < (cut.block_sizes ** 2).sum()
    assert dense.block_work < cut.block_work
    err = np.linalg.norm(cut @ x - u) / np.linalg.norm(u)
    assert 1e-8 < err < 1e-2
    # every block's cut really is at 1e-2 of its largest singular value: rebuild block 0
    g = cut.near.groups[0]
    first, second, off, rank, length = g.factors
    L, r, o = length[0], rank[0], off[0]
    E0 = second[o:o + r * L].reshape(r, L).T @ first[o:o + r * L].reshape(r, L)
    B0 = high.plan.near.blocks[0, :L, :L]
    s = np.linalg.svd(B0, compute_uv=False)
    assert r == int((s > 1e-2 * s[0]).sum())
    assert np.isclose(np.linalg.norm(E0 - B0, 2), s[r], rtol=1e-6)
    # the transpose of the factored low is exact
    lhs, rhs = y @ (cut @ x), (cut.T @ y) @ x
    assert abs(lhs - rhs) <= 1e-9 * abs(lhs)
    u2, v2 = cut.matvec_rmatvec(x, y)
    assert np.allclose(v2, cut.T @ y, rtol=1e-9, atol=1e-13)
    for bad in (0.0, 1.5, float("nan"), True, "a"):
        with pytest.raises(ValueError, match="rank_tol"):
            split_mobility(high, 4, 1e-3, rank_tol=bad)


def test_split_low_by_name_in_a_contact_problem():
    from lcpbench.problems.suspension.fidelity import parse_fidelity

    assert parse_fidelity("p8f4e3", 8, 1e-8).knobs() == {"model": "bim", "p": 8,
                                                          "eps_gmres": 1e-3, "far_degree": 4}
    with pytest.raises(ValueError, match="far-field degree"):
        parse_fidelity("p4f6e3", 8, 1e-8)
    assert parse_fidelity("p8f6r3e3", 8, 1e-8).knobs() == {
        "model": "bim", "p": 8, "eps_gmres": 1e-3, "far_degree": 6, "rank_tol": 1e-3}
    with pytest.raises(ValueError, match="far-field degree too"):
        parse_fidelity("p8r3e3", 8, 1e-8)
    with pytest.raises(ValueError, match="r0"):
        parse_fidelity("p8f6r0e3", 8, 1e-8)
    centers = np.vstack([CENTERS, [[4.6, 0.3, -0.2]]])
    F = np.tile([[0.5, -0.2, 0.1]], (5, 1))
    prob = build_contact_problem(centers, 1.0, F, np.zeros((5, 3)), delta=0.5, model="bim",
                                 p=4, eps_gmres=1e-8, low=["p4f4e6", "p3e6"])
    n = prob.lcp.n
    A = np.column_stack([prob.lcp.A @ e for e in np.eye(n)])
    L = np.column_stack([prob.lcp.low["p4f4e6"] @ e for e in np.eye(n)])
    L3 = np.column_stack([prob.lcp.low["p3e6"] @ e for e in np.eye(n)])
    assert prob.lcp.low["p4f4e6"].cost > 0
    assert np.linalg.norm(L - A) < np.linalg.norm(L3 - A)
    assert np.linalg.norm(L - A) < 5e-2 * np.linalg.norm(A)
