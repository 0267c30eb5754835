"""Seconds of the adjoint mobility solve (``rmatvec``) against the forward solve, side by side.

Usage::

    python benchmarks/adjoint.py                 # packed 27-sphere lattice, p = 4, 6, 8
    python benchmarks/adjoint.py --m 4 --p 6 --repeat 5

Centres on an ``m x m x m`` cubic lattice with spacing ``2 + gap`` (unit spheres), eps_gmres
1e-8; for each p, one warm-up of each kind (numba compilation, adjoint set-up), then
``--repeat`` forward and adjoint products with fresh random vectors, interleaved. Prints the
median seconds, median GMRES iterations and the ratio adjoint / forward, the number that
matters: a symmetrised contact MVP costs one forward plus one adjoint solve.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lcpbench.problems.suspension.bim import BimMobility


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, default=3)
    ap.add_argument("--gap", type=float, default=0.1)
    ap.add_argument("--p", type=int, nargs="+", default=[4, 6, 8])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    g = np.arange(args.m) * (2.0 + args.gap)
    c = np.array([[x, y, z] for x in g for y in g for z in g])
    rng = np.random.default_rng(0)
    print("| M | p | s forward | s adjoint | its forward | its adjoint | adjoint / forward |")
    print("|---|---|---|---|---|---|---|")
    for p in args.p:
        A = BimMobility(c, 1.0, p=p, eps_gmres=1e-8)
        n = A.shape[0]
        A.matvec(rng.standard_normal(n))
        A.rmatvec(rng.standard_normal(n))
        tf, ta = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            A.matvec(rng.standard_normal(n))
            t1 = time.perf_counter()
            A.rmatvec(rng.standard_normal(n))
            t2 = time.perf_counter()
            tf.append(t1 - t0)
            ta.append(t2 - t1)
        itf = np.median(A.gmres_iterations[1:])
        ita = np.median(A.adjoint_iterations[1:])
        print(f"| {len(c)} | {p} | {np.median(tf):.3f} | {np.median(ta):.3f} | {itf:.0f} | "
              f"{ita:.0f} | {np.median(ta) / np.median(tf):.2f} |", flush=True)


if __name__ == "__main__":
    main()
