"""Two-body corrections on a cheap mobility: how close do they bring it to the p = 8 contact matrix?

Usage::

    python benchmarks/pairwise_correction.py                      # bases p4, p6 and rpy, 0.1a lattice
    python benchmarks/pairwise_correction.py --base p4 --gap 0.2 1.0 --scene paper-lattice

The lubrication-aware direction of a cheap low fidelity: start from a cheap mobility of the
whole configuration (RPY, or the boundary integral at a low order) and, for every pair of
spheres closer than ``--gap``, replace its two-body part by the p = 8 two-sphere solution,
either added to the mobility (``M + sum (M2_8 - M2_base)``, mobility form) or to its inverse
(``(M^-1 + sum (R2_8 - R2_base))^-1`` with ``R2 = M2^-1``, resistance form: how Stokesian
dynamics adds lubrication). The script forms every mobility densely (6M products for a
boundary-integral base) and prints the relative 2-norm error of ``D' M D`` against the
high-fidelity contact matrix (p = 8, eps_gmres 1e-8) of the same step.
"""

from __future__ import annotations

import argparse

import numpy as np
from common import packed_lattice
from low_fidelity import build, dense_sym

from lcpbench.problems.suspension.bim import BimMobility
from lcpbench.problems.suspension.fidelity import parse_fidelity
from lcpbench.problems.suspension.rpy import rpy_matrix


def mobility_matrix(centers, radii, name: str) -> np.ndarray:
    """The symmetrised dense mobility of fidelity ``name`` (``rpy`` or ``p<k>``)."""
    if name == "rpy":
        return rpy_matrix(centers, radii)
    f = parse_fidelity(name, 8, 1e-10)
    op = BimMobility(centers, radii, p=f.p, eps_gmres=f.eps_gmres)
    Mx = np.column_stack([op @ e for e in np.eye(6 * len(centers))])
    return 0.5 * (Mx + Mx.T)


def corrected(scene, base: np.ndarray, base_name: str, gap: float, high_p: int,
              two_body: dict) -> tuple[np.ndarray, np.ndarray]:
    """Mobility-form and resistance-form corrected mobilities (every pair below ``gap``)."""
    c, r = scene.centers, scene.radii
    M = len(c)
    d = np.linalg.norm(c[:, None] - c[None], axis=2) - r[:, None] - r[None, :]
    Mm, R = base.copy(), np.linalg.inv(base)
    for i, j in zip(*np.triu_indices(M, 1)):
        if d[i, j] >= gap:
            continue
        for name in (f"p{high_p}", base_name):
            if (i, j, name) not in two_body:
                two_body[i, j, name] = mobility_matrix(c[[i, j]], r[[i, j]], name)
        hi, lo = two_body[i, j, f"p{high_p}"], two_body[i, j, base_name]
        idx = np.r_[6 * i:6 * i + 6, 6 * j:6 * j + 6]
        Mm[np.ix_(idx, idx)] += hi - lo
        R[np.ix_(idx, idx)] += np.linalg.inv(hi) - np.linalg.inv(lo)
    Mr = np.linalg.inv(R)
    return Mm, 0.5 * (Mr + Mr.T)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="lattice", help="lattice (0.1a) or paper-lattice (0.3a)")
    ap.add_argument("--m", type=int, default=3)
    ap.add_argument("--pack", type=int, default=40, help="RPY steps before the measurement")
    ap.add_argument("--base", nargs="+", default=["p4", "p6", "rpy"])
    ap.add_argument("--gap", type=float, nargs="+", default=[0.2, 1.0])
    args = ap.parse_args()
    scene = packed_lattice(args.m, args.pack, args.scene)
    prob = build(scene, [], 8, 1e-8)
    A = dense_sym(prob.lcp.A)
    nA = np.linalg.norm(A, 2)
    D = prob.contacts.D.toarray()
    print(f"{args.scene} m = {args.m}: n = {prob.lcp.n} contacts")
    print("| base | pairs corrected (gap below) | base error | mobility form | resistance form |")
    print("|---|---|---|---|---|")
    two_body: dict = {}
    for name in args.base:
        Mb = mobility_matrix(scene.centers, scene.radii, name)
        e0 = np.linalg.norm(D.T @ Mb @ D - A, 2) / nA
        for gap in args.gap:
            Mm, Mr = corrected(scene, Mb, name, gap, 8, two_body)
            em = np.linalg.norm(D.T @ Mm @ D - A, 2) / nA
            er = np.linalg.norm(D.T @ Mr @ D - A, 2) / nA
            print(f"| {name} | {gap:g} | {e0:.3g} | {em:.3g} | {er:.3g} |", flush=True)


if __name__ == "__main__":
    main()
