"""Symmetry, definiteness and GMRES behaviour of the boundary-integral contact operator D'MD.

Usage::

    python benchmarks/symmetry.py                              # the table of docs/mobility.md
    python benchmarks/symmetry.py --separation 0.1 --p 4 6 --upsample 1 2

A packed configuration of the lattice scene (m = 3, 27 spheres) is made cheaply with the RPY
model (``--steps`` forward Euler steps with Mono-PQN, minimum separation ``--separation``);
then, for each p and near-field treatment (``near_upsample`` 1 = traction sampled at the
nodes, 2 = projected from the order-2p grid, the default), the dense ``A = D' M D`` is formed
by n forward products (GMRES at 1e-8) and the table gives the relative asymmetry
``max|A - A'| / max|A|``, the smallest eigenvalue of ``(A + A')/2`` against the largest, the
median GMRES iterations and the largest final GMRES residual of those products.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from lcpbench.problems.suspension.bim import BimConvergenceWarning, BimMobility
from lcpbench.problems.suspension.contacts import Contacts
from lcpbench.problems.suspension.scene import LatticeScene


def packed_configuration(separation: float, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Centres and radii of the m = 3 lattice scene after ``steps`` RPY steps."""
    scene = LatticeScene(3, model="rpy", separation=separation)
    for _ in range(steps):
        scene.step("mono-pqn")
    return scene.centers, scene.radii


def row(c: np.ndarray, r: np.ndarray, D: np.ndarray, p: int, upsample: float,
        maxiter: int) -> dict:
    """Dense D'MD at order p and its symmetry, definiteness and GMRES figures."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BimConvergenceWarning)
        B = BimMobility(c, r, p=p, eps_gmres=1e-8, maxiter=maxiter, near_upsample=upsample)
        A = np.column_stack([D.T @ (B @ D[:, k]) for k in range(D.shape[1])])
    lam = np.linalg.eigvalsh(0.5 * (A + A.T))
    return {"asym": float(np.abs(A - A.T).max() / np.abs(A).max()),
            "lmin": float(lam[0]), "lmax": float(lam[-1]),
            "its": float(np.median(B.gmres_iterations)), "res": float(max(B.residuals))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--separation", type=float, nargs="+", default=[0.01, 0.1])
    ap.add_argument("--p", type=int, nargs="+", default=[3, 4, 6, 8])
    ap.add_argument("--upsample", type=float, nargs="+", default=[1.0, 2.0])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--maxiter", type=int, default=300)
    args = ap.parse_args()
    print("| separation | p | near field | asymmetry | lambda_min / lambda_max of sym. part "
          "| GMRES its (median) | worst GMRES residual |")
    print("|---|---|---|---|---|---|---|")
    for sep in args.separation:
        c, r = packed_configuration(sep, args.steps)
        D = Contacts.from_configuration(c, r, 0.3).D.toarray()
        for p in args.p:
            for up in args.upsample:
                x = row(c, r, D, p, up, args.maxiter)
                kind = "nodes" if up <= 1 else f"projected ({up:g}p grid)"
                print(f"| {sep:g} | {p} | {kind} | {x['asym']:.1e} | {x['lmin']:.2e} / "
                      f"{x['lmax']:.2e} | {x['its']:.0f} | {x['res']:.1e} |", flush=True)


if __name__ == "__main__":
    main()
