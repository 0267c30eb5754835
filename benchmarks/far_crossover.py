"""Far field by measured crossover: the boundary-integral product with direct sums against
fmm3dpy's Stokes FMM on packed lattices, side by side in one run.

Usage::

    python benchmarks/far_crossover.py                  # M = 8, 27, 64, 125, 216 at p = 8
    python benchmarks/far_crossover.py --m 2 3 4 --p 8 --repeat 3 --products

For every lattice side ``m`` the ``paper-lattice`` scene is stepped with RPY until it has
packed (:func:`common.packed_lattice`, cheap), and the boundary-integral mobility of that
configuration (order ``--p``, ``eps_gmres`` 1e-8) is set up with each far-field engine in
turn.  One row per ``M``: set-up seconds of each, seconds of one traction-operator product
(``apply_preconditioned``, full accuracy: the inner application every GMRES/GCR iteration
makes, where the far engine is used) and, with ``--products``, of one cold mobility product
(``M @ f`` from empty recycled spaces: every iteration of one solve), the median over
``--repeat`` of each, the engines alternating so that both see the same machine load; their
ratios ``direct / fmm`` (above 1: the FMM is faster) and the largest difference of the two
results relative to their size (the engines agree to the quadrature tolerance).

The crossover is the smallest ``M`` whose application ratio is above 1 (a cold product is
the same number of full-accuracy applications with either engine, except that the direct
sums also relax the later ones, so the application ratio is the FMM's best case); it goes
into ``problems/suspension/bim/fmm.py: FAR_CROSSOVER_M`` with this command.  When no
measured ``M`` has it, the script prints where the last ratio extrapolates to 1 if the
ratio grows like ``M`` (all-pairs direct sums ~ ``M^2``, the FMM ~ ``M``); on packed lattices
up to 125 spheres it did not (docs/benchmarks.md, "The far field's crossover").
"""

from __future__ import annotations

import argparse
import gc
import statistics
import time

import numpy as np
from common import packed_lattice


def _timed(fn, repeat: int) -> tuple[float, object]:
    """Median seconds of ``repeat`` calls of ``fn`` and its last value."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def measure(m: int, p: int, repeat: int, pack: int, products: bool) -> dict:
    """Both engines on the packed lattice of side ``m``: set-up, application and product."""
    from lcpbench.problems.suspension.bim import BimMobility

    scene = packed_lattice(m, pack, "paper-lattice")
    c, r = scene.centers, scene.radii
    rng = np.random.default_rng(0)
    f = rng.standard_normal(6 * len(c))
    row: dict = {"M": len(c)}
    ops = {}
    for far in ("direct", "fmm"):
        gc.collect()
        t0 = time.perf_counter()
        ops[far] = BimMobility(c, r, p=p, eps_gmres=1e-8, far=far)
        row[f"setup_{far}"] = time.perf_counter() - t0
    y = rng.standard_normal(ops["direct"].setup.unknowns)
    out = {}
    for k in range(repeat):                    # alternate the engines, one call each
        for far in (("direct", "fmm") if k % 2 == 0 else ("fmm", "direct")):
            A = ops[far]
            t, g = _timed(lambda A=A: A.apply_preconditioned(y), 1)
            row.setdefault(f"apply_{far}", []).append(t)
            u = None
            if products:
                with A.cold_products():
                    t, u = _timed(lambda A=A: A @ f, 1)
                row.setdefault(f"product_{far}", []).append(t)
            out[far] = (g, u)
    for key in [k for k in row if isinstance(row[k], list)]:
        row[key] = statistics.median(row[key])
    (gd, ud), (gf, uf) = out["direct"], out["fmm"]
    row["apply_ratio"] = row["apply_direct"] / row["apply_fmm"]
    row["apply_diff"] = float(np.abs(gd - gf).max() / np.abs(gd).max())
    if products:
        row["product_ratio"] = row["product_direct"] / row["product_fmm"]
        row["product_diff"] = float(np.abs(ud - uf).max() / np.abs(ud).max())
    return row


def _cell(row: dict, key: str, fmt: str) -> str:
    return format(row[key], fmt) if key in row else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, nargs="+", default=[2, 3, 4, 5, 6],
                    help="lattice sides (M = m^3 spheres)")
    ap.add_argument("--p", type=int, default=8, help="spherical-harmonic order")
    ap.add_argument("--repeat", type=int, default=3, help="calls per engine (median)")
    ap.add_argument("--pack", type=int, default=40, help="RPY steps that pack the lattice")
    ap.add_argument("--products", action="store_true",
                    help="also time one cold mobility product of each engine")
    args = ap.parse_args()
    print(f"p = {args.p}, eps_gmres = 1e-8, packed paper-lattice; seconds, median of "
          f"{args.repeat}; ratio = direct / fmm (> 1: the FMM is faster)\n")
    print("| M | set-up direct | set-up fmm | application direct | application fmm | ratio "
          "| cold product direct | cold product fmm | ratio | max rel. diff (appl., product) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    crossover, rows = None, []
    for m in args.m:
        r = measure(m, args.p, args.repeat, args.pack, args.products)
        rows.append(r)
        print(f"| {r['M']} | {r['setup_direct']:.2f} | {r['setup_fmm']:.2f} | "
              f"{r['apply_direct']:.3f} | {r['apply_fmm']:.3f} | {r['apply_ratio']:.3f} | "
              f"{_cell(r, 'product_direct', '.2f')} | {_cell(r, 'product_fmm', '.2f')} | "
              f"{_cell(r, 'product_ratio', '.3f')} | {r['apply_diff']:.1e}, "
              f"{_cell(r, 'product_diff', '.1e')} |", flush=True)
        if crossover is None and r["apply_ratio"] > 1:
            crossover = r["M"]
    if crossover is not None:
        print(f"\ncrossover (smallest M whose FMM application is faster): {crossover}")
        return
    last = rows[-1]
    guess = last["M"] / last["apply_ratio"]
    print(f"\ncrossover: none measured; if the ratio grows like M it reaches 1 near "
          f"M = {guess:.0f} (extrapolated from M = {last['M']}; check the rows' trend)")


if __name__ == "__main__":
    main()
