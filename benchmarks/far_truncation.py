"""The distance-split low fidelity (:mod:`bim.split`): error and block work per far-field degree.

Usage::

    python benchmarks/far_truncation.py                           # q = 4, 5, 6 at eps 1e-3
    python benchmarks/far_truncation.py --scene paper-lattice --q 4 6 --near-gap 0.5 1.5
    python benchmarks/far_truncation.py --scene paper-lattice --q 6 8 --decay 0.5 --rank-tol 1e-3

On one packed configuration the split low (p = 8 near contact, the far field truncated in
degree, GMRES at ``--eps``) is built on the high fidelity's set-up for every ``--q`` and
``--near-gap``, with the degree falling with distance (``decay``, the default of the
``p8f<q>e<j>`` fidelities) and without (every far pair at q), with its blocks dense and, for
every ``--rank-tol``, compressed to their singular values above that fraction of each
block's largest (``p8f<q>r<i>e<j>``). The script forms each low densely and prints its
relative 2-norm error against the high contact matrix, its GMRES products in one cold
product against the high's, and its block work per product relative to the high's; their
product bounds the cost ratio when the blocks are most of the work
(``benchmarks/low_fidelity.py`` measures the cost ratio itself); then, for every compressed
low, the terms kept per block by block size.
"""

from __future__ import annotations

import argparse

import numpy as np
from common import packed_lattice
from low_fidelity import build, dense_sym

from lcpbench.problems.suspension.bim import BimMobility, split_mobility


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="lattice", help="lattice (0.1a) or paper-lattice (0.3a)")
    ap.add_argument("--m", type=int, default=3)
    ap.add_argument("--pack", type=int, default=40, help="RPY steps before the measurement")
    ap.add_argument("--q", type=int, nargs="+", default=[4, 5, 6])
    ap.add_argument("--near-gap", type=float, nargs="+", default=[0.5])
    ap.add_argument("--eps", type=float, nargs="+", default=[1e-3])
    ap.add_argument("--decay", type=float, nargs="+", default=[0.0, 0.5, 1.0],
                    help="exponent of the fall of the degree with distance (0: fixed)")
    ap.add_argument("--rank-tol", type=float, nargs="*", default=[],
                    help="also compress the blocks at these relative singular-value cuts")
    args = ap.parse_args()
    cuts = [None] + list(args.rank_tol)
    scene = packed_lattice(args.m, args.pack, args.scene)
    prob = build(scene, [], 8, 1e-8)
    A = dense_sym(prob.lcp.A)
    nA = np.linalg.norm(A, 2)
    D, Dt = prob.contacts.D, prob.contacts.D.T.tocsr()
    high = BimMobility(scene.centers, scene.radii, p=8, eps_gmres=1e-8)
    v = np.linspace(1.0, 2.0, 6 * high.M)
    high @ v
    its_high = high.gmres_iterations[0]
    print(f"{args.scene} m = {args.m}: n = {prob.lcp.n}; high: {its_high} GMRES products cold")
    print("| q | degree | near gap | eps | rank cut | rel. 2-norm error | products cold | "
          "block work | bound |")
    print("|---|---|---|---|---|---|---|---|---|")
    kept = []
    for q in args.q:
        for decay in args.decay:
            for g in args.near_gap:
                for eps in args.eps:
                    for cut in cuts:
                        low = split_mobility(high, q, eps, near_gap=g, decay=decay,
                                             rank_tol=cut)
                        low @ v
                        its = low.gmres_iterations[0]
                        low = split_mobility(high, q, eps, near_gap=g, decay=decay,
                                             rank_tol=cut)      # fresh: no kept directions
                        L = np.column_stack([Dt @ (low @ (D @ e)) for e in np.eye(prob.lcp.n)])
                        err = np.linalg.norm(0.5 * (L + L.T) - A, 2) / nA
                        print(f"| {q} | {decay:g} | {g:g} | {eps:g} | "
                              f"{'-' if cut is None else f'{cut:g}'} | "
                              f"{err:.3g} | {its} | {low.block_work:.3f} | "
                              f"{its / its_high * low.block_work:.3f} |", flush=True)
                        if cut is not None:
                            kept.append((q, decay, g, cut, low))
    # terms kept per block by block size (coefficients the block acts on) of every cut
    for q, decay, g, cut, low in kept:
        print(f"\nq = {q}, decay {decay:g}, near gap {g:g}, rank cut {cut:g}: terms kept per block")
        print("| block size | blocks | terms kept (median) | range |")
        print("|---|---|---|---|")
        for size in np.unique(low.block_sizes):
            r = low.block_ranks[low.block_sizes == size]
            print(f"| {size} | {r.size} | {np.median(r):.0f} | {r.min()}-{r.max()} |")


if __name__ == "__main__":
    main()
