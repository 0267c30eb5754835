"""The coaxial pair table and its use by the pair plan (problems/suspension/bim/coaxial.py)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from sphere_cases import packed

from lcpbench.problems.suspension.bim import coaxial
from lcpbench.problems.suspension.bim.coaxial import (
    build_table,
    coaxial_blocks,
    coaxial_table,
    order_mask,
)
from lcpbench.problems.suspension.bim.kernels import real_block_columns, traction_response
from lcpbench.problems.suspension.bim.rotation import (
    degree_slices,
    rotate_blocks,
    wigner_directions,
)
from lcpbench.problems.suspension.bim.setup import BimSetup
from lcpbench.problems.suspension.bim.sphere_vsh import (
    expansion_factors,
    sampled_basis,
    sphere_grid,
    vsh_basis,
)


def _projected_block(ci, cj, a, p, q):
    """Reference: the traction on sphere i of every basis density on sphere j, evaluated
    in the lab frame on the (fine) grid of order q and projected onto degree p there."""
    b = vsh_basis(p)
    nv = b.B.shape[1]
    g = sphere_grid(q)
    flat = np.argmax(np.abs(b.to_complex), axis=0)
    cfac = b.to_complex[flat, np.arange(nv)]
    Nq = g.size
    resp = np.empty((Nq, 3, p + 1, p + 1, 3), dtype=np.complex128)
    traction_response(np.ascontiguousarray(ci + a * g.nodes), np.ascontiguousarray(g.nodes),
                      np.ascontiguousarray(np.tile(cj, (Nq, 1))), np.full(Nq, a), p,
                      np.ascontiguousarray(expansion_factors(p)), resp)
    Ep = np.empty((1, 3 * Nq, nv))
    real_block_columns(resp.reshape(Nq, -1, 3), flat, cfac, Ep)
    W = np.repeat(g.weights, 3)
    return sampled_basis(p, q).T @ (W[:, None] * Ep[0])


@pytest.mark.parametrize("p, distances", [(4, (1.02, 1.6, 4.0)), (8, (1.02,))])
def test_rotated_coaxial_block_is_the_pair_block_in_any_direction(p, distances):
    """Rotating the coaxial block into a direction gives that pair's block (the traction
    projected onto degree p, here on a lab-frame grid fine enough to be exact)."""
    rng = np.random.default_rng(p)
    a = 0.7
    for rho in distances:
        E = coaxial_blocks([rho], p)
        assert np.abs(E[0][~order_mask(p)]).max() <= 1e-14 * np.abs(E).max()
        u = rng.standard_normal((2, 3))
        u /= np.linalg.norm(u, axis=1)[:, None]
        got = rotate_blocks(np.repeat(E, 2, axis=0), wigner_directions(u, p), degree_slices(p))
        cj = np.array([0.3, -1.0, 2.0])
        for k in range(2):
            want = _projected_block(cj + a * (rho + 1) * u[k], cj, a, p, max(6 * p, 40))
            assert np.linalg.norm(got[k] - want) <= 1e-11 * np.linalg.norm(want)


def test_table_interpolates_the_coaxial_block():
    p = 4
    table = build_table(p, 5.0, progress=False)
    edges = table.edges
    # points between the Chebyshev nodes of every panel, and the panel ends
    rho = np.concatenate([edges, 0.5 * (edges[:-1] + edges[1:]) + 0.013 * np.diff(edges)])
    exact = coaxial_blocks(rho, p)
    err = np.linalg.norm(table.blocks(rho) - exact, axis=(1, 2)) / np.linalg.norm(exact, axis=(1, 2))
    assert err.max() <= 1e-10
    with pytest.raises(ValueError, match="range"):
        table.blocks([0.9])
    # entries asked for in another order are written in it: the same numbers, permuted
    # (pairs in any order, several per panel, some alone in theirs)
    nnz = table.coefs.shape[2]
    cols = np.random.default_rng(1).permutation(nnz)
    mixed = np.concatenate([rho[::-1], rho[:3]])
    for r in (mixed, np.sort(mixed)):
        want = table.values(r)[:, cols]
        assert np.abs(table.values(r, columns=cols) - want).max() <= 1e-14 * np.abs(want).max()
    # a subset of distinct entries is written as asked; repeated entries are refused
    sub = cols[:7]
    # (the same sums, in the BLAS's own order for each width: equal to rounding)
    full = table.values(rho)[:, sub]
    assert np.abs(table.values(rho, columns=sub) - full).max() <= 1e-14 * np.abs(full).max()
    with pytest.raises(ValueError, match="distinct"):
        table.values(rho, columns=np.zeros(nnz, dtype=int))


def test_setup_takes_equal_pairs_from_the_table_and_others_directly():
    p = 3
    c = packed(2)
    r = np.ones(len(c))
    r[0] = 0.9                                       # the pairs of sphere 0 are unequal
    kw = dict(p=p, mu=1.0, quad_tol=1e-10)
    table = BimSetup(c, r, pair_blocks="table", **kw).plan
    direct = BimSetup(c, r, pair_blocks="direct", **kw).plan
    fine = BimSetup(c, r, pair_blocks="direct", near_upsample=14.0, **kw).plan
    assert np.array_equal(table.near.block_src, direct.near.block_src)
    unequal = (table.near.block_src == 0) | (table.near.block_tgt == 0)
    zone = np.array([table._projected(i, j) for i, j in zip(table.near.block_tgt, table.near.block_src)])
    sel = zone & ~unequal
    assert table.near.n_table_blocks == int(sel.sum()) > 0 and (~zone).any()
    assert direct.near.n_table_blocks == 0
    # unequal and node-sampled pairs: the direct build itself
    assert np.array_equal(table.near.blocks[~sel], direct.near.blocks[~sel])
    # projected-zone pairs: the converged projection (the direct build on a fine grid)
    num = np.linalg.norm(table.near.blocks[sel] - fine.near.blocks[sel], axis=(1, 2))
    assert (num <= 1e-10 * np.linalg.norm(fine.near.blocks[sel], axis=(1, 2))).all()


def test_table_all_takes_node_sampled_pairs_from_the_table():
    """With "table-all" a node-sampled pair's block is the exact projection too."""
    p = 3
    c = packed(2)
    plan = BimSetup(c, 1.0, p=p, mu=1.0, quad_tol=1e-10, pair_blocks="table-all").plan
    assert plan.near.n_table_blocks == plan.near.n_block_pairs
    node = [k for k, (i, j) in enumerate(zip(plan.near.block_tgt, plan.near.block_src))
            if not plan._projected(i, j)]
    assert node
    b = vsh_basis(p)
    for k in node[:3]:
        i, j = plan.near.block_tgt[k], plan.near.block_src[k]
        want = b.A @ b.B @ _projected_block(c[i], c[j], 1.0, p, 40)
        assert np.linalg.norm(plan.near.blocks[k] - want) <= 1e-10 * np.linalg.norm(want)


def test_bad_pair_blocks_value():
    with pytest.raises(ValueError, match="pair_blocks = 'rotated'.*'direct'.*'table'.*'table-all'"):
        BimSetup(packed(2), 1.0, p=3, mu=1.0, quad_tol=1e-8, pair_blocks="rotated")


def test_memory_budget_that_leaves_pairs_unblocked_warns_once():
    c = packed(2)
    with pytest.warns(RuntimeWarning, match=r"leaves \d+ of \d+ near pairs.*raise near_block_mb"
                      ) as rec:
        plan = BimSetup(c, 1.0, p=3, mu=1.0, quad_tol=1e-8, near_block_mb=0.1).plan
    assert len([w for w in rec if "near_block_mb" in str(w.message)]) == 1
    assert 0 < plan.near.n_block_pairs < plan.expansions.n_near_pairs + plan.near.n_block_pairs
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        BimSetup(c, 1.0, p=3, mu=1.0, quad_tol=1e-8)            # every candidate fits


def test_table_cache_is_read_back_and_a_bad_file_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(coaxial, "_MEMORY", {})
    p, rho_max = 3, 2.0
    first = coaxial_table(p, rho_max)
    files = list((tmp_path / "lcpbench" / "pair-tables").glob("*.npz"))
    assert len(files) == 1
    assert not list(files[0].parent.glob("*.tmp*"))            # written atomically

    def refuse(*args, **kwargs):
        raise AssertionError("the table was rebuilt instead of read")

    monkeypatch.setattr(coaxial, "_MEMORY", {})
    monkeypatch.setattr(coaxial, "build_table", refuse)
    again = coaxial_table(p, rho_max)
    assert np.array_equal(again.coefs, first.coefs)
    monkeypatch.undo()

    good = files[0].read_bytes()
    for bad in (b"not an npz file", good[:len(good) // 2],      # garbage, truncated
                None):                                           # a file of the wrong shape
        monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
        monkeypatch.setattr(coaxial, "_MEMORY", {})
        if bad is None:
            with open(files[0], "rb") as fh:
                z = dict(np.load(fh, allow_pickle=False))
            np.savez(files[0], key=z["key"], edges=z["edges"], coefs=z["coefs"][:, :-1])
        else:
            files[0].write_bytes(bad)
        with pytest.warns(RuntimeWarning, match="does not match"):
            rebuilt = coaxial_table(p, rho_max)
        assert np.array_equal(rebuilt.coefs, first.coefs)
        monkeypatch.setattr(coaxial, "_MEMORY", {})
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert np.array_equal(coaxial_table(p, rho_max).coefs, first.coefs)   # fixed


@pytest.mark.slow
def test_mobility_with_table_blocks_matches_the_direct_build():
    """Whole mobility products on a packed 2x2x2 lattice (gaps ~0.26a) at p = 6: the table's
    operator and the direct build's differ by the direct build's orientation-dependent
    error in the projected zone (measured 1.8e-6 here, 5.5e-8 at p = 8, docs/mobility.md)."""
    from lcpbench.problems.suspension.bim.blocks import StoredBlocks
    from lcpbench.problems.suspension.bim.operator import BimMobility
    from lcpbench.problems.suspension.bim.recycle import KrylovBudget

    c = packed(2, jitter=0.1)
    ft = np.random.default_rng(7).standard_normal(6 * len(c))
    out = {}
    for mode in ("direct", "table"):
        setup = BimSetup(c, 1.0, p=6, mu=1.0, quad_tol=1e-12, pair_blocks=mode)
        op = object.__new__(BimMobility)
        op._assemble(setup, StoredBlocks(setup.plan), eps_gmres=1e-10, on_failure="raise",
                     maxiter=500, recycle=0, krylov=KrylovBudget(0))
        out[mode] = op @ ft
    assert setup.plan.near.n_table_blocks > 0
    diff = np.linalg.norm(out["table"] - out["direct"]) / np.linalg.norm(out["direct"])
    assert 1e-9 < diff < 1e-5
