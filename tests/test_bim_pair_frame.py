"""The table pairs' products in the pair frame (problems/suspension/bim/pair_frame.py)
against the per-pair rotated kernel and against the assembled blocks."""

from __future__ import annotations

import numpy as np
import pytest
from sphere_cases import packed as _packed

from lcpbench.problems.suspension.bim.coaxial import coaxial_table, order_mask, table_range
from lcpbench.problems.suspension.bim.pair_frame import LANES, PairFrame, coaxial_support
from lcpbench.problems.suspension.bim.setup import BimSetup


@pytest.fixture(scope="module")
def plan():
    """A packed 27-sphere lattice at p = 5 with one larger sphere (its pairs are built
    directly; the others are table pairs)."""
    r = np.ones(27)
    r[13] = 1.08
    return BimSetup(_packed(), r, p=5, mu=1.0, quad_tol=1e-10).plan


def _rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _reference(plan, coef, x):
    """Forward and transposed sums of the table pairs' assembled blocks."""
    pos = plan.near.rot_pos
    tgt, src = plan.near.block_tgt[pos], plan.near.block_src[pos]
    A = plan.near.rotated.assemble(np.arange(pos.size))
    fwd, tr = np.zeros_like(coef), np.zeros_like(coef)
    for k in range(pos.size):
        fwd[tgt[k]] += A[k] @ coef[src[k]]
        tr[src[k]] += A[k].T @ x[tgt[k]]
    return fwd, tr


def test_the_plan_holds_every_table_pair_in_the_pair_frame(plan):
    frame = plan.near.pair_frame
    assert frame is not None and frame.n_pairs == plan.near.rot_pos.size
    held = frame.tgt[frame.tgt >= 0]
    assert held.size == frame.n_pairs
    # a pair and its reverse share an item: every item is full (equal radii, both kept)
    assert frame.vals.shape[0] == -(-frame.n_pairs // (2 * LANES))


def test_coaxial_support_drops_only_structural_zeros():
    """The support is the table's reflection-symmetric pattern: a third of the
    equal-order entries at p = 8, and what it drops is rounding of exact zeros."""
    table = coaxial_table(8, table_range(8))
    keep = coaxial_support(table)
    assert keep.size == 2608 and int(order_mask(8).sum()) == 7969
    bound = np.abs(table.coefs).sum(axis=1).max(axis=0)
    dropped = np.setdiff1d(np.arange(bound.size), keep)
    assert bound[dropped].max() < 1e-13 * bound.max()
    assert bound[keep].min() > 1e-8 * bound.max()


@pytest.mark.parametrize("parallel", [True, False])
def test_products_agree_with_the_assembled_blocks(plan, parallel):
    frame = plan.near.pair_frame
    rng = np.random.default_rng(3)
    coef, x = rng.standard_normal((2, plan.M, frame.nv))
    fwd, tr = _reference(plan, coef, x)
    acc, bar = np.zeros_like(coef), np.zeros_like(coef)
    frame.forward(coef, acc, parallel=parallel)
    frame.transpose(x, bar, parallel=parallel)
    assert _rel(acc, fwd) <= 1e-12
    assert _rel(bar, tr) <= 1e-12
    acc2, bar2 = np.ones_like(coef), np.zeros_like(coef)
    frame.both(coef, acc2, x, bar2, parallel=parallel)
    assert _rel(acc2 - 1.0, fwd) <= 1e-12
    assert _rel(bar2, tr) <= 1e-12


def test_a_pair_without_its_reverse_is_applied_alone(plan):
    """Items with one direction only (the reverse not among the pairs) give that pair's
    block and nothing for the missing one."""
    pos = plan.near.rot_pos
    tgt, src = plan.near.block_tgt[pos], plan.near.block_src[pos]
    one = np.nonzero(tgt < src)[0][:5]
    u = plan.centers[tgt[one]] - plan.centers[src[one]]
    u /= np.linalg.norm(u, axis=1)[:, None]
    frame = PairFrame.from_table(u, plan._rho(tgt[one], src[one]), tgt[one], src[one],
                                 coaxial_table(5, table_range(5)), plan._output_map)
    A = plan.near.rotated.assemble(one)
    coef = np.random.default_rng(4).standard_normal((plan.M, frame.nv))
    ref = np.zeros_like(coef)
    for k, kk in enumerate(one):
        ref[tgt[kk]] += A[k] @ coef[src[kk]]
    acc = np.zeros_like(coef)
    frame.forward(coef, acc)
    assert _rel(acc, ref) <= 1e-12


def test_the_operator_uses_the_pair_frame_and_matches_the_rotated_kernel(plan):
    """The near field of the stored blocks with the pair frame equals the one through the
    per-pair rotated kernel (the frame switched off)."""
    from lcpbench.problems.suspension.bim.blocks import StoredBlocks

    near = StoredBlocks(plan)
    assert near.frame is plan.near.pair_frame
    coef = np.random.default_rng(5).standard_normal((plan.M, plan.near.pair_frame.nv))
    got = near.apply(coef)
    old = StoredBlocks(plan)
    old.frame = None
    assert _rel(got, old.apply(coef)) <= 1e-12


def test_the_panel_kernels_file_is_the_generated_source():
    """panel_kernels.py is what panel_source.render() writes (edit the generator, not the
    generated file)."""
    from lcpbench.problems.suspension.bim import panel_source

    assert panel_source.target().read_text() == panel_source.render()


def test_the_vectoriser_settings_are_restored():
    from numba import config

    from lcpbench.problems.suspension.bim.panel_kernels import vectorising

    before = config.SLP_VECTORIZE, config.LOOP_VECTORIZE
    with pytest.raises(RuntimeError), vectorising():
        assert (config.SLP_VECTORIZE, config.LOOP_VECTORIZE) == (1, 0)
        raise RuntimeError
    assert (config.SLP_VECTORIZE, config.LOOP_VECTORIZE) == before


def test_the_panel_order_keeps_each_orders_coaxial_rows_together():
    """In the panel's order the coaxial entries couple rows of one order and type only,
    and those rows are contiguous: a permutation of the coefficients."""
    from lcpbench.problems.suspension.bim.pair_frame import _layout, _panel_order
    from lcpbench.problems.suspension.bim.sphere_vsh import vsh_basis

    p = 8
    order = _panel_order(_layout(p))
    nv = int(order_mask(p).shape[0])
    assert np.array_equal(np.sort(order), np.arange(nv))
    inv = np.argsort(order)
    table = coaxial_table(p, table_range(p))
    rows, cols = np.nonzero(order_mask(p))
    keep = coaxial_support(table)
    basis = vsh_basis(p)
    m = np.abs(np.asarray(basis.order))[order]
    # the rows of each order form one contiguous run of the panel
    assert np.all(np.diff(m) >= 0)
    assert np.array_equal(m[inv[rows[keep]]], m[inv[cols[keep]]])
