"""Near-field block build from the coaxial pair table against the direct build, in one run.

Usage::

    python benchmarks/pair_table.py                 # packed paper-lattice, 27 and 64 spheres, p = 8
    python benchmarks/pair_table.py --m 3 --p 8 --reference-p 12

For every lattice side ``m`` the ``paper-lattice`` scene is stepped ``--pack`` times with
the RPY mobility (cheap) until it has packed (closest gaps 0.3a), as
benchmarks/live_operator.py does.  On that configuration, at order ``--p`` and the
quadrature tolerance of ``eps_gmres`` 1e-8:

* side by side for every size, the direct build (assembled blocks) and the default
  rotated table (``"table-all"``: equal-radius pairs kept as Wigner matrices and coaxial
  entries): the whole set-up (:class:`BimSetup`) and its block part
  (:meth:`PairPlan._block_values`), the memory of the stored near field, milliseconds per
  forward / transposed / fused near-field product (:class:`StoredBlocks`, BLAS on one
  thread) and seconds per mobility product (``eps_gmres`` 1e-10, three right-hand sides);
* the agreement of those mobility products, and with ``--reference-p`` of each against
  the direct build at that higher order (the discretisation error both approximate);
* with ``--converged-upsample U``, of each against the direct build whose projection grid
  has order ``ceil(U p)`` (``near_upsample``, default 2): the direct build converged in its
  projection (the table is the exact projection; the default direct build's depends on the
  pair's orientation, docs/mobility.md "Coaxial pair table"); and of the rotated table
  against the same converged direct build with every expansion pair projected (the
  projected zone widened to every distance: the discretisation the table computes, so
  the two differ by the table's interpolation and rounding only);
* the table's build time (from an empty cache), its range and its size on disk.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import packed_lattice

from lcpbench.problems.suspension.bim import coaxial, pairs
from lcpbench.problems.suspension.bim.blocks import StoredBlocks
from lcpbench.problems.suspension.bim.operator import BimMobility
from lcpbench.problems.suspension.bim.recycle import KrylovBudget
from lcpbench.problems.suspension.bim.setup import BimSetup
from lcpbench.problems.suspension.bim.sphere_vsh import default_quad_tol
from lcpbench.toolkit.blas import one_blas_thread


def mobility(setup: BimSetup, eps: float) -> BimMobility:
    """A mobility operator on a given set-up (the constructor builds its own)."""
    op = object.__new__(BimMobility)
    op._assemble(setup, StoredBlocks(setup.plan), eps_gmres=eps, on_failure="warn",
                 maxiter=500, recycle=0, krylov=KrylovBudget(0))
    return op


def products(setup: BimSetup, F: np.ndarray) -> np.ndarray:
    op = mobility(setup, 1e-10)
    return np.column_stack([op @ F[:, k] for k in range(F.shape[1])])


@contextlib.contextmanager
def every_pair_projected():
    """Builds inside have every expansion pair in the projected zone (the exact projection
    the table computes) instead of node sampling beyond ``PROJECT_RHO``."""
    old = pairs.PROJECT_RHO
    pairs.PROJECT_RHO = np.inf
    try:
        yield
    finally:
        pairs.PROJECT_RHO = old


def timed(fn, *args, **kwargs):
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t


def near_costs(setup: BimSetup, repeat: int = 5) -> dict:
    """Milliseconds per call of the stored near field's forward, transposed and fused
    products (the compiled kernels the operator calls, BLAS on one thread as in the
    solves), and its memory in MB."""
    plan = setup.plan
    near = StoredBlocks(plan)
    rng = np.random.default_rng(1)
    coef = rng.standard_normal((plan.M, plan.near.block_synth.shape[0]))
    ob = rng.standard_normal((plan.M, 3 * plan.N))
    bar, out = np.zeros_like(coef), np.zeros_like(ob)
    calls = {"apply": lambda: near.apply(coef),
             "transpose": lambda: near.add_transpose(ob, bar),
             "both": lambda: near.apply_both(coef, ob, bar, out)}
    res = {"MB": near.nbytes / 2 ** 20}
    with one_blas_thread():
        for name, fn in calls.items():
            fn()                                               # compiled and warm
            t = time.perf_counter()
            for _ in range(repeat):
                fn()
            res[name] = 1e3 * (time.perf_counter() - t) / repeat
    return res


def one_configuration(m: int, p: int, pack: int, ref_p: int | None,
                      upsample: float | None = None) -> dict:
    """Set-up and product costs, direct against the rotated table (``"table-all"``), and
    their agreement, on the packed lattice of side m; returns the numbers."""
    scene = packed_lattice(m, pack, scene="paper-lattice")
    c, r = scene.centers, scene.radii
    kw = dict(p=p, mu=1.0, quad_tol=default_quad_tol(1e-8))
    coaxial.coaxial_table(p, coaxial.table_range(p))           # built or read before timing
    for mode in ("direct", "table-all"):                       # compiled code and caches warm
        StoredBlocks(BimSetup(c[:2], r[:2], pair_blocks=mode, **kw).plan).apply(
            np.zeros((2, 3 * (p + 1) ** 2 - 2)))
    out: dict = {"M": m ** 3}
    setups = {}
    for mode in ("direct", "table-all"):
        setups[mode], t = timed(BimSetup, c, r, pair_blocks=mode, **kw)
        plan = setups[mode].plan
        blocked = list(zip(plan.near.block_tgt.tolist(), plan.near.block_src.tolist()))
        with one_blas_thread():
            _, t_b = timed(plan._block_values, blocked)
        out[mode] = {"setup": t, "blocks": t_b, "pairs": len(blocked),
                     **near_costs(setups[mode])}
        out["table pairs"] = plan.near.n_table_blocks
    F = np.random.default_rng(0).standard_normal((6 * len(r), 3))
    U = {}
    for mode, setup in setups.items():
        U[mode], t = timed(products, setup, F)
        out[mode]["mobility"] = t / F.shape[1]
    out["agree"] = float(np.linalg.norm(U["table-all"] - U["direct"])
                         / np.linalg.norm(U["direct"]))
    if upsample:
        # "table": the projected zone's pairs from the table, the others node-sampled as
        # the direct build samples them; the converged direct build differs from it only
        # in the zone's projection
        U["table"] = products(BimSetup(c, r, pair_blocks="table", **kw), F)
        conv = products(BimSetup(c, r, pair_blocks="direct", near_upsample=upsample, **kw), F)
        out["converged"] = {k: float(np.linalg.norm(v - conv) / np.linalg.norm(conv))
                            for k, v in U.items()}
        with every_pair_projected():
            conv = products(BimSetup(c, r, pair_blocks="direct", near_upsample=upsample,
                                     **kw), F)
        out["converged all"] = float(np.linalg.norm(U["table-all"] - conv)
                                     / np.linalg.norm(conv))
    if ref_p:
        ref = products(BimSetup(c, r, pair_blocks="direct", **{**kw, "p": ref_p}), F)
        out["ref"] = {k: float(np.linalg.norm(v - ref) / np.linalg.norm(ref))
                      for k, v in U.items()}
    return out


def report(rows: list[dict], p: int) -> None:
    """Prints the configurations side by side."""
    head = "".join(f"{'M = ' + str(r['M']) + ' direct':>16}{'rotated table':>15}" for r in rows)
    print(f"\npacked paper-lattice, p = {p}{'':8}{head}")
    lines = [("stored pairs", "pairs", "{:.0f}"), ("set-up s", "setup", "{:.2f}"),
             ("  blocks s", "blocks", "{:.2f}"), ("near field MB", "MB", "{:.0f}"),
             ("apply ms", "apply", "{:.1f}"), ("transpose ms", "transpose", "{:.1f}"),
             ("both ms", "both", "{:.1f}"), ("mobility product s", "mobility", "{:.2f}")]
    for label, key, fmt in lines:
        cells = "".join(f"{fmt.format(r['direct'][key]):>16}{fmt.format(r['table-all'][key]):>15}"
                        for r in rows)
        print(f"{label:<35}{cells}")
    for r in rows:
        print(f"M = {r['M']}: {r['table pairs']} of {r['table-all']['pairs']} pairs from the "
              f"table; mobility products rotated table vs direct {r['agree']:.1e}"
              + ("".join(f"; {k} vs p = {p} ref {v:.2e}" for k, v in r["ref"].items())
                 if "ref" in r else "")
              + ("".join(f"; {k} vs the direct build converged in its projection {v:.1e}"
                         for k, v in r["converged"].items()) if "converged" in r else "")
              + (f"; table-all vs it with every pair projected {r['converged all']:.1e}"
                 if "converged all" in r else ""))


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
    ap.add_argument("--converged-upsample", type=float, default=None, metavar="U",
                    help="also compare both with the direct build whose projection grid "
                         "has order ceil(U p) (near_upsample; the default is 2; e.g. 14)")
    args = ap.parse_args()
    cache = os.environ.get("XDG_CACHE_HOME")
    table_cost(args.p)
    if cache is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = cache
    rows = []
    for m in args.m:
        rows.append(one_configuration(m, args.p, args.pack, args.reference_p,
                                      args.converged_upsample))
        sys.stdout.flush()
    report(rows, args.p)


if __name__ == "__main__":
    main()
