"""Near-field blocks kept in rotated form (problems/suspension/bim/kernels_rotated.py) and
the default ``pair_blocks="table-all"`` of the pair plan."""

from __future__ import annotations

import numpy as np
import pytest
from sphere_cases import packed as _packed

from lcpbench.problems.suspension.bim import kernels as kn
from lcpbench.problems.suspension.bim import kernels_adjoint as ka
from lcpbench.problems.suspension.bim import kernels_rotated as kr
from lcpbench.problems.suspension.bim.blocks import StoredBlocks
from lcpbench.problems.suspension.bim.coaxial import order_mask
from lcpbench.problems.suspension.bim.kernels_rotated import PlanBlocks
from lcpbench.problems.suspension.bim.setup import BimSetup


@pytest.fixture(scope="module")
def plan():
    """A packed 27-sphere lattice at p = 5 with one larger sphere (its pairs are built
    directly and kept assembled; the others are table pairs in rotated form)."""
    r = np.ones(27)
    r[13] = 1.08
    return BimSetup(_packed(), r, p=5, mu=1.0, quad_tol=1e-10).plan


def _assembled(plan):
    return np.asarray(plan.near.blocks[np.arange(plan.near.n_block_pairs)])


def test_default_keeps_table_pairs_in_rotated_form(plan):
    assert plan.pair_blocks == "table-all"
    assert isinstance(plan.near.blocks, PlanBlocks)
    assert 0 < plan.near.n_table_blocks < plan.near.n_block_pairs
    # a pair and its reverse share one row of coaxial entries (the block depends on the
    # distance alone); only their rotations differ
    rot = plan.near.rotated
    assert rot.D.shape[0] == plan.near.n_table_blocks
    assert rot.vals.shape == (plan.near.n_table_blocks // 2, int(order_mask(5).sum()))
    t, s = plan.near.block_tgt[plan.near.rot_pos], plan.near.block_src[plan.near.rot_pos]
    where = {(a, b): k for k, (a, b) in enumerate(zip(t.tolist(), s.tolist()))}
    assert all(rot.vrow[k] == rot.vrow[where[(b, a)]] for (a, b), k in where.items())
    assert np.unique(rot.vrow).size == rot.vals.shape[0]
    nv = plan.near.blocks.shape[1]
    dense = plan.near.n_block_pairs - plan.near.n_table_blocks
    # memory per pair: Wigner matrices + coaxial entries, far below an assembled block
    assert plan.near.block_bytes == plan.near.rotated.nbytes + dense * nv * nv * 8
    assert plan.near.rotated.nbytes < 0.3 * plan.near.n_table_blocks * nv * nv * 8


def test_lazy_blocks_index_like_an_array(plan):
    full = _assembled(plan)
    k = int(plan.near.rot_pos[3])
    assert np.array_equal(plan.near.blocks[k], full[k])
    idx = np.array([int(plan.near.dense_pos[0]), k, 0])
    assert np.array_equal(plan.near.blocks[idx, :10, :7], full[idx, :10, :7])
    assert np.array_equal(plan.near.blocks[2:5], full[2:5])
    # the assembled rotated blocks are those of pair_blocks="table" where both apply
    ref = BimSetup(plan.centers, plan.radii, p=5, mu=1.0, quad_tol=1e-10,
                   pair_blocks="table").plan
    assert np.array_equal(ref.near.block_tgt, plan.near.block_tgt)
    zone = np.array([plan._projected(i, j) for i, j in zip(plan.near.block_tgt, plan.near.block_src)])
    sel = zone & (plan.radii[plan.near.block_tgt] == plan.radii[plan.near.block_src])
    assert sel.sum() > 10
    err = np.linalg.norm(full[sel] - ref.near.blocks[sel], axis=(1, 2))
    assert (err <= 1e-12 * np.linalg.norm(ref.near.blocks[sel], axis=(1, 2))).all()


def _reference_products(plan, coef, x):
    A = _assembled(plan)
    fwd = np.zeros_like(coef)
    tr = np.zeros_like(coef)
    for k in range(A.shape[0]):
        fwd[plan.near.block_tgt[k]] += A[k] @ coef[plan.near.block_src[k]]
        tr[plan.near.block_src[k]] += A[k].T @ x[plan.near.block_tgt[k]]
    return fwd, tr


def _rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def test_stored_blocks_products_match_the_assembled_blocks(plan):
    rng = np.random.default_rng(0)
    nv = plan.near.blocks.shape[1]
    coef = rng.standard_normal((plan.M, nv))
    ob = rng.standard_normal((plan.M, 3 * plan.N))
    x = ob @ plan.near.block_synth_T
    fwd, tr = _reference_products(plan, coef, x)
    near = StoredBlocks(plan)
    assert _rel(near.apply(coef), fwd @ plan.near.block_synth) <= 1e-12
    bar = np.zeros_like(coef)
    near.add_transpose(ob, bar)
    assert _rel(bar, tr) <= 1e-12
    bar2, out = np.zeros_like(coef), np.ones((plan.M, 3 * plan.N))
    near.apply_both(coef, ob, bar2, out)
    assert _rel(out - 1.0, fwd @ plan.near.block_synth) <= 1e-12
    assert _rel(bar2, tr) <= 1e-12
    assert near.nbytes == plan.near.block_bytes


@pytest.mark.parametrize("parallel", [True, False])
def test_rotated_kernels_serial_and_parallel(plan, parallel):
    """The compiled kernels on the rotated pairs alone, against their assembled blocks."""
    rot, pos = plan.near.rotated, plan.near.rot_pos
    tgt, src = plan.near.block_tgt[pos], plan.near.block_src[pos]
    A = rot.assemble(np.arange(pos.size))
    rng = np.random.default_rng(1)
    nv = A.shape[1]
    coef, x = rng.standard_normal((2, plan.M, nv))
    fwd, tr, parts = np.zeros_like(coef), np.zeros_like(coef), np.empty((pos.size, nv))
    for k in range(pos.size):
        fwd[tgt[k]] += A[k] @ coef[src[k]]
        parts[k] = A[k].T @ x[tgt[k]]
        tr[src[k]] += parts[k]
    tptr = np.searchsorted(tgt, np.arange(plan.M + 1)).astype(np.int64)
    order = np.argsort(src, kind="stable").astype(np.int64)
    sptr = np.searchsorted(src[order], np.arange(plan.M + 1)).astype(np.int64)
    sfx = "" if parallel else "_serial"
    acc = np.zeros_like(coef)
    getattr(kr, "rotated_forward" + sfx)(rot.form, tptr, src, coef, acc)
    assert _rel(acc, fwd) <= 1e-12
    bar = np.zeros_like(coef)
    getattr(kr, "rotated_transpose" + sfx)(rot.form, sptr, order, tgt, x, bar)
    assert _rel(bar, tr) <= 1e-12
    acc2, part = np.zeros_like(coef), np.full((pos.size, nv), np.nan)
    getattr(kr, "rotated_both" + sfx)(rot.form, tptr, src, coef, acc2, x, part)
    assert _rel(acc2, fwd) <= 1e-12
    assert _rel(part, parts) <= 1e-12


def test_budget_counts_blocks_in_rotated_form():
    """A budget that holds a few assembled blocks holds about six times as many in
    rotated form (p = 5)."""
    c = _packed(2)
    nv = 3 * 36 - 2
    mb = 20 * nv * nv * 8 / 2 ** 20
    with pytest.warns(RuntimeWarning, match="near_block_mb"):
        direct = BimSetup(c, 1.0, p=5, mu=1.0, quad_tol=1e-10, near_block_mb=mb,
                          pair_blocks="direct").plan
    assert direct.near.n_block_pairs == 20
    rotated = BimSetup(c, 1.0, p=5, mu=1.0, quad_tol=1e-10, near_block_mb=mb).plan
    assert rotated.near.n_block_pairs > 40
    assert rotated.near.block_bytes <= mb * 2 ** 20


def test_pairs_beyond_the_budget_are_the_same_table_blocks_rotated_on_the_fly():
    """Over budget, table pairs keep their (table) blocks, rotated at every product, not
    a different discretisation: products equal those of the full budget."""
    c = _packed(2)
    full = BimSetup(c, 1.0, p=5, mu=1.0, quad_tol=1e-10).plan
    with pytest.warns(RuntimeWarning, match="near_block_mb"):
        small = BimSetup(c, 1.0, p=5, mu=1.0, quad_tol=1e-10, near_block_mb=0.2).plan
    assert 0 < small.near.n_stored_blocks < small.near.n_block_pairs == full.near.n_block_pairs
    assert small.expansions.fly_idx.size == 0 and small.expansions.flyn_idx.size == 0
    assert small.near.fly_pairs.rho.size == small.near.n_block_pairs - small.near.n_stored_blocks
    want = full.near.blocks[:, :9, :9]          # equal to rounding: the BLAS sums each width
    assert np.abs(small.near.blocks[:, :9, :9] - want).max() <= 1e-14 * np.abs(want).max()
    rng = np.random.default_rng(2)
    coef = rng.standard_normal((full.M, full.near.blocks.shape[1]))
    ob = rng.standard_normal((full.M, 3 * full.N))
    a, b = StoredBlocks(full), StoredBlocks(small)
    assert _rel(b.apply(coef), a.apply(coef)) <= 1e-13
    bar_a, bar_b = np.zeros_like(coef), np.zeros_like(coef)
    a.add_transpose(ob, bar_a)
    b.add_transpose(ob, bar_b)
    assert _rel(bar_b, bar_a) <= 1e-13
    out_b, both_b = np.zeros_like(ob), np.zeros_like(coef)
    b.apply_both(coef, ob, both_b, out_b)
    assert _rel(out_b, a.apply(coef)) <= 1e-13 and _rel(both_b, bar_a) <= 1e-13


def test_mobility_with_no_block_budget_equals_the_stored_table_blocks():
    from lcpbench.problems.suspension.bim.operator import BimMobility

    c = _packed(2)
    ft = np.random.default_rng(4).standard_normal(6 * len(c))
    A = BimMobility(c, 1.0, p=4, eps_gmres=1e-11)
    with pytest.warns(RuntimeWarning, match="near_block_mb"):
        B = BimMobility(c, 1.0, p=4, eps_gmres=1e-11, near_block_mb=0)
    assert B.plan.near.n_stored_blocks == 0 and B.plan.near.n_block_pairs == A.plan.near.n_block_pairs
    ua, ub = A @ ft, B @ ft
    assert np.abs(ua - ub).max() <= 1e-9 * np.abs(ua).max()


_BUILDS = [(kr, f"rotated_{n}", f"rotated_{n}_serial") for n in ("forward", "transpose", "both")]
_BUILDS += [(kn, n, n + "_serial") for n in ("apply_blocks", "apply_lowrank", "synthesize_forces",
                                            "direct_traction_ranges")]
_BUILDS += [(kn, "direct_traction_ranges", "direct_traction_skip")]
_BUILDS += [(ka, n, n + "_serial") for n in ("direct_traction_adjoint", "apply_blocks_adjoint",
                                            "apply_blocks_both")]
_BUILDS += [(ka, "direct_traction_adjoint", "direct_traction_adjoint_skip")]


@pytest.mark.parametrize("module,par_name,ser_name", _BUILDS,
                         ids=[b[2] for b in _BUILDS])
def test_serial_and_parallel_builds_have_their_own_cache_entries(module, par_name, ser_name):
    """numba caches a compiled function on disk under its qualified name and signature,
    whatever ``parallel`` and ``fastmath`` say: two builds of one kernel must differ in
    name, or either can be loaded for the other (the parallel one then runs on one
    thread)."""
    par, ser = getattr(module, par_name), getattr(module, ser_name)
    assert par.targetoptions != ser.targetoptions
    assert par.py_func.__qualname__ != ser.py_func.__qualname__
    files = par._cache._cache_file, ser._cache._cache_file
    assert files[0]._cache_path == files[1]._cache_path                   # same folder
    assert files[0]._index_name != files[1]._index_name                   # own entries


def test_split_low_keeps_table_pairs_in_rotated_form_truncated_by_degree(plan):
    """The distance-split low of a rotated-form high truncates each table pair in rotated
    form (degree <= q of its rotation and coaxial entries), never assembling it: its
    blocks are the leading parts of the high's, and its products, forward and
    transposed, equal those of the split built on assembled blocks; pairs the high
    rotates at each product (over its budget) are truncated the same way."""
    import copy

    from lcpbench.problems.suspension.bim.split import SplitBlocks

    def assembled_copy(plan):
        """The plan with every block assembled (the same values, stored dense)."""
        out = copy.copy(plan)
        out.near = copy.copy(plan.near)
        out.near.blocks = plan.near.blocks[np.arange(len(plan.near.blocks))]
        out.near.rotated = out.near.fly_pairs = None
        return out

    c = _packed(2)
    full = BimSetup(c, 1.0, p=5, mu=1.0, quad_tol=1e-10).plan
    full_ref = assembled_copy(full)
    with pytest.warns(RuntimeWarning, match="near_block_mb"):
        small = BimSetup(c, 1.0, p=5, mu=1.0, quad_tol=1e-10, near_block_mb=0.2).plan
    mixed = plan                                 # one larger sphere: its pairs kept dense
    kw = dict(far_degree=3, near_gap=0.5, decay=0.5, rank_tol=None)
    rng = np.random.default_rng(5)
    for plan, assembled, dense in ((full, full_ref, False), (small, full_ref, False),
                                   (mixed, assembled_copy(mixed), True)):
        coef = rng.standard_normal((plan.M, plan.near.blocks.shape[1]))
        ob = rng.standard_normal((plan.M, 3 * plan.N))
        ref = SplitBlocks(assembled, **kw)
        assert all(g.rotated is None for g in ref.groups)
        bar_ref = np.zeros_like(coef)
        ref.add_transpose(ob, bar_ref)
        split = SplitBlocks(plan, **kw)
        rot = [g for g in split.groups if g.rotated is not None]
        # per degree (-1: full) a group in rotated form, and with unequal radii one of
        # the directly built (dense) blocks
        assert len(rot) >= 2 and (len(split.groups) > len(rot)) == dense
        assert {g.sel.size for g in rot} == {g.sel.size for g in ref.groups}
        for g in rot:
            k = np.nonzero(np.isin(plan.near.block_tgt * plan.M + plan.near.block_src,
                                   g.tgt * plan.M + g.src))[0]
            n = g.sel.size
            blocks = g.rotated.assemble(np.arange(k.size))
            assert blocks.shape == (k.size, n, n)
            assert _rel(blocks, assembled.near.blocks[k, :n, :n]) <= 1e-13
        assert split.n_truncated_pairs == ref.n_truncated_pairs > 0
        # fewer multiply-adds than the same blocks truncated assembled
        assert sum(g.work for g in split.groups) < sum(g.work for g in ref.groups)
        assert _rel(split.apply(coef), ref.apply(coef)) <= 1e-13
        bar = np.zeros_like(coef)
        split.add_transpose(ob, bar)
        assert _rel(bar, bar_ref) <= 1e-13
