"""How far the boundary-integral contact matrix is from converged in the spherical-harmonic order.

Usage::

    python benchmarks/p_convergence.py                 # p = 4, 6, 8, 10, 12 on the packed 3x3x3 lattice
    python benchmarks/p_convergence.py --m 3 --p 6 8 10 --pack 40
    python benchmarks/p_convergence.py --scene paper-lattice     # the authors' 0.3a gaps

The lattice scene is stepped ``--pack`` times with RPY (cheap) until it has packed (closest
gaps at the 0.1a separation, as in the shipped sets); on that configuration the symmetrised
contact matrix ``A = D' (M + M') D / 2`` is formed column by column at every order p with
``eps_gmres`` 1e-10 (so that GMRES error is far below the discretisation error), and the
relative 2-norm difference of every pair of orders is printed, against the highest order and
against p = 8 (the high fidelity), with the extreme eigenvalues.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from common import packed_lattice

from lcpbench.problems.suspension.problem import build_contact_problem
from lcpbench.problems.suspension.scene import LatticeScene


def contact_matrix(scene: LatticeScene, p: int, eps: float) -> np.ndarray:
    """The step's symmetrised contact matrix at order ``p``, formed by its products."""
    P = scene.params
    F, T = scene.loads()
    prob = build_contact_problem(scene.centers, scene.radii, F, T, dt=P.dt, delta=P.delta,
                                 separation=P.separation, model="bim", p=p, eps_gmres=eps)
    n = prob.lcp.n
    A = np.column_stack([prob.lcp.A @ e for e in np.eye(n)])
    return 0.5 * (A + A.T)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, default=3)
    ap.add_argument("--p", type=int, nargs="+", default=[4, 6, 8, 10, 12])
    ap.add_argument("--pack", type=int, default=40, help="RPY steps before the measurement")
    ap.add_argument("--eps", type=float, default=1e-10)
    ap.add_argument("--scene", default="lattice",
                    help="lattice (0.1a separation) or paper-lattice (0.3a)")
    args = ap.parse_args()
    scene = packed_lattice(args.m, args.pack, args.scene)
    mats = {}
    for p in sorted(args.p):
        t0 = time.perf_counter()
        mats[p] = contact_matrix(scene, p, args.eps)
        ev = np.linalg.eigvalsh(mats[p])
        print(f"p = {p:>2}: n = {mats[p].shape[0]}, {time.perf_counter() - t0:6.1f} s, "
              f"eigenvalues {ev[0]:.4g} .. {ev[-1]:.4g}", flush=True)
    top = max(mats)
    for ref in sorted({top, 8} & set(mats), reverse=True):
        R = mats[ref]
        errs = ", ".join(f"p = {p}: {np.linalg.norm(A - R, 2) / np.linalg.norm(R, 2):.3g}"
                         for p, A in sorted(mats.items()) if p < ref)
        print(f"relative 2-norm difference against p = {ref}: {errs}")


if __name__ == "__main__":
    main()
