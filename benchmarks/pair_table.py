"""Near-field block build from the coaxial pair table against the direct build, in one run.

Usage::

    python benchmarks/pair_table.py                 # packed paper-lattice, 27 and 64 spheres, p = 8
    python benchmarks/pair_table.py --m 3 --p 8 --reference-p 12

For every lattice side ``m`` the ``paper-lattice`` scene is stepped ``--pack`` times with
the RPY mobility (cheap) until it has packed (closest gaps 0.3a), as
benchmarks/live_operator.py does.  On that configuration, at order ``--p`` and the
quadrature tolerance of ``eps_gmres`` 1e-8:

* the block build (:meth:`PairPlan._block_values` of the plan's stored pairs), direct,
  from the table for the projected zone (``"table"``) and for every equal-radius pair
  (``"table-all"``), per configuration and per block, and the whole set-up
  (:class:`BimSetup`) direct and ``"table"``;
* the agreement of the blocks and of three mobility products (``eps_gmres`` 1e-10) built
  on either set of blocks, and, with ``--reference-p``, of each against the direct build
  at that higher order (the discretisation error both approximate);
* the applied cost of the stored blocks per product, assembled (what the operator does)
  against a rotate / coaxial / rotate-back prototype (numpy, batched per degree);
* the table's build time (from an empty cache), its range and its size on disk.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import packed_lattice

from lcpbench.problems.suspension.bim import coaxial
from lcpbench.problems.suspension.bim.blocks import StoredBlocks
from lcpbench.problems.suspension.bim.operator import BimMobility
from lcpbench.problems.suspension.bim.rotation import degree_slices, wigner_directions
from lcpbench.problems.suspension.bim.setup import BimSetup
from lcpbench.problems.suspension.bim.sphere_vsh import default_quad_tol
from lcpbench.toolkit.blas import one_blas_thread


def mobility(setup: BimSetup, eps: float) -> BimMobility:
    """A mobility operator on a given set-up (the constructor builds its own)."""
    op = object.__new__(BimMobility)
    op._assemble(setup, StoredBlocks(setup.plan), eps_gmres=eps, on_failure="warn",
                 maxiter=500, recycle=0)
    return op


def products(setup: BimSetup, F: np.ndarray) -> np.ndarray:
    op = mobility(setup, 1e-10)
    return np.column_stack([op @ F[:, k] for k in range(F.shape[1])])


def timed(fn, *args, **kwargs):
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t


def rotated_apply(plan, coef: np.ndarray, Dn: list, coax: np.ndarray) -> np.ndarray:
    """Prototype of the rotated form: per block ``D (E_coax (D^T x_j))`` (K, nv), as if
    every stored pair came from the table."""
    x = coef[plan.block_src]                                   # (K, nv)
    K = x.shape[0]
    y = np.empty_like(x)
    ranges = [(int(r[0, 0]), int(r[0, 0]) + r.size, r.shape[0]) for r in degree_slices(plan.p)]
    for n, (lo, hi, k) in enumerate(ranges):                   # D^T x, per degree
        y[:, lo:hi] = np.matmul(x[:, lo:hi].reshape(K, k, 2 * n + 1),
                                Dn[n]).reshape(K, -1)
    z = np.einsum("kab,kb->ka", coax, y)                       # coaxial block (m-sparse)
    out = np.empty_like(z)
    for n, (lo, hi, k) in enumerate(ranges):                   # D z
        out[:, lo:hi] = np.matmul(z[:, lo:hi].reshape(K, k, 2 * n + 1),
                                  np.swapaxes(Dn[n], 1, 2)).reshape(K, -1)
    return out


def apply_costs(setup: BimSetup, repeat: int = 5) -> tuple[float, float, float]:
    """Seconds per product of the assembled blocks (the operator's compiled kernel) and of
    the rotated prototype over the same pairs (numpy, summed by target), and the
    prototype's agreement with the assembled table blocks (``L`` aside: ``B L = B``)."""
    plan = setup.plan
    rng = np.random.default_rng(1)
    coef = rng.standard_normal((plan.M, plan.blocks.shape[1]))
    near = StoredBlocks(plan)
    u = setup.centers[plan.block_tgt] - setup.centers[plan.block_src]
    rho = plan._rho(plan.block_tgt, plan.block_src)
    u /= np.linalg.norm(u, axis=1)[:, None]
    Dn = wigner_directions(u, plan.p)
    coax = coaxial.coaxial_table(plan.p, coaxial.table_range(plan.p)).blocks(rho)
    with one_blas_thread():
        near.apply(coef)
        t0 = time.perf_counter()
        for _ in range(repeat):
            near.apply(coef)
        t1 = time.perf_counter()
        for _ in range(repeat):
            acc = np.zeros_like(coef)
            np.add.at(acc, plan.block_tgt, rotated_apply(plan, coef, Dn, coax))
        t2 = time.perf_counter()
    got = rotated_apply(plan, coef, Dn, coax) @ plan.block_synth
    want = np.einsum("kab,kb->ka", plan.blocks, coef[plan.block_src]) @ plan.block_synth
    zone = np.array([plan._projected(i, j) for i, j in zip(plan.block_tgt, plan.block_src)])
    agree = (np.linalg.norm(got[zone] - want[zone]) / np.linalg.norm(want[zone])
             if zone.any() else float("nan"))
    return (t1 - t0) / repeat, (t2 - t1) / repeat, float(agree)


def one_configuration(m: int, p: int, pack: int, ref_p: int | None) -> None:
    scene = packed_lattice(m, pack, scene="paper-lattice")
    c, r = scene.centers, scene.radii
    kw = dict(p=p, mu=1.0, quad_tol=default_quad_tol(1e-8))
    coaxial.coaxial_table(p, coaxial.table_range(p))           # built or read before timing
    for mode in ("direct", "table"):                           # compiled code and caches warm
        BimSetup(c[:2], r[:2], pair_blocks=mode, **kw)
    direct, t_sd = timed(BimSetup, c, r, pair_blocks="direct", **kw)
    table, t_st = timed(BimSetup, c, r, pair_blocks="table", **kw)
    plan = table.plan
    blocked = list(zip(plan.block_tgt.tolist(), plan.block_src.tolist()))
    zone = [(i, j) for i, j in blocked if plan._projected(i, j)]
    with one_blas_thread():
        _, t_d = timed(direct.plan._block_values, blocked)
        _, t_t = timed(plan._block_values, blocked)
        _, z_d = timed(direct.plan._block_values, zone)
        _, z_t = timed(plan._block_values, zone)
    nb = len(blocked)
    rel = (np.linalg.norm(plan.blocks - direct.plan.blocks, axis=(1, 2))
           / np.linalg.norm(direct.plan.blocks, axis=(1, 2)))
    print(f"\nM = {m ** 3}, p = {p}: {nb} stored blocks ({plan.n_table_blocks} from the table, "
          "the projected zone), "
          f"{nb * plan.blocks[0].nbytes / 2 ** 20:.0f} MB")
    print(f"  block build     direct {t_d:7.2f} s ({1e3 * t_d / nb:6.2f} ms/block)   "
          f"table {t_t:7.2f} s ({1e3 * t_t / nb:6.2f} ms/block)   ratio {t_d / t_t:5.1f}")
    print(f"  zone blocks     direct {z_d:7.2f} s ({1e3 * z_d / len(zone):6.2f} ms/block)   "
          f"table {z_t:7.2f} s ({1e3 * z_t / len(zone):6.2f} ms/block)   ratio {z_d / z_t:5.1f}"
          f"   ({len(zone)} blocks)")
    print(f"  whole set-up    direct {t_sd:7.2f} s   table {t_st:7.2f} s")
    print(f"  blocks table vs direct: median {np.median(rel):.1e}, max {rel.max():.1e}")
    every = BimSetup(c, r, pair_blocks="table-all", **kw)
    with one_blas_thread():
        _, t_a = timed(every.plan._block_values, blocked)
    print(f"  table-all       {t_a:7.2f} s ({1e3 * t_a / nb:6.2f} ms/block, "
          f"{every.plan.n_table_blocks} from the table)   ratio to direct {t_d / t_a:5.1f}")
    F = np.random.default_rng(0).standard_normal((6 * len(r), 3))
    U = {"direct": products(direct, F), "table": products(table, F),
         "table-all": products(every, F)}
    del every
    for k in ("table", "table-all"):
        d = np.linalg.norm(U[k] - U["direct"]) / np.linalg.norm(U["direct"])
        print(f"  mobility products {k} vs direct: {d:.1e}")
    if ref_p:
        ref = products(BimSetup(c, r, pair_blocks="direct", **{**kw, "p": ref_p}), F)
        for k, v in U.items():
            print(f"  {k:>9} at p = {p} vs direct at p = {ref_p}: "
                  f"{np.linalg.norm(v - ref) / np.linalg.norm(ref):.4e}")
    t_a, t_r, agree = apply_costs(table)
    print(f"  stored blocks per product: assembled {1e3 * t_a:.1f} ms, rotated prototype "
          f"{1e3 * t_r:.1f} ms (agreement on the table's pairs {agree:.0e}); memory per pair assembled "
          f"{plan.blocks[0].nbytes / 1024:.0f} KB, rotated "
          f"{8 * (int(coaxial.order_mask(p).sum()) + sum((2 * n + 1) ** 2 for n in range(p + 1))) / 1024:.0f} KB")


def table_cost(p: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["XDG_CACHE_HOME"] = tmp
        coaxial._MEMORY.clear()
        table, t = timed(coaxial.coaxial_table, p, coaxial.table_range(p))
        size = sum(f.stat().st_size for f in Path(tmp).rglob("*.npz"))
        rng = np.random.default_rng(2)
        rho = np.sort(rng.uniform(coaxial.RHO_MIN, table.rho_max, 60))
        exact = coaxial.coaxial_blocks(rho, p)
        err = (np.linalg.norm(table.blocks(rho) - exact, axis=(1, 2))
               / np.linalg.norm(exact, axis=(1, 2)))
    print(f"table p = {p}: rho in [{coaxial.RHO_MIN}, {table.rho_max:.1f}] "
          f"({table.edges.size - 1} panels x {coaxial.CHEB_NODES} nodes), built in {t:.1f} s, "
          f"{size / 2 ** 20:.1f} MB on disk; interpolation error at 60 random rho: "
          f"max {err.max():.1e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, nargs="+", default=[3, 4], help="lattice sides (M = m^3)")
    ap.add_argument("--p", type=int, default=8)
    ap.add_argument("--pack", type=int, default=40, help="RPY steps before the measurement")
    ap.add_argument("--reference-p", type=int, default=None,
                    help="also compare both with the direct build at this higher order")
    args = ap.parse_args()
    cache = os.environ.get("XDG_CACHE_HOME")
    table_cost(args.p)
    if cache is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = cache
    for m in args.m:
        one_configuration(m, args.p, args.pack, args.reference_p)
        sys.stdout.flush()


if __name__ == "__main__":
    main()
