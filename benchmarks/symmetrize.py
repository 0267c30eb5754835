"""One forward solve per contact product against the symmetrised pair, side by side.

Usage::

    python benchmarks/symmetrize.py                       # lattice m = 2 and 3, p = 4, 6, 8
    python benchmarks/symmetrize.py --scene paper-lattice --m 2 --p 4 6

Does the boundary-integral contact operator need two solves per product
(``v -> D' (M + M') D v / 2``: one forward, one adjoint), or will the plain ``D' M D``
(one forward solve) do?  For each scene size a packed configuration is made cheaply
with the RPY model (``--steps`` Mono-PQN steps, as in ``benchmarks/symmetry.py``); then, for
each p, the step's boundary-integral contact problem is built twice,
``ContactOptions(symmetrize=True)`` (the default) and ``symmetrize=False``, and each solver
runs on both from the same warm start.  Printed per row: the relative asymmetry
``||A - A'||_F / ||A||_F`` of the dense unsymmetrised ``A = D' M D`` (n forward products),
the solver's status, high MVPs, inner applications (forward + adjoint GMRES iterations),
solve seconds, the residual the framework verified (against the operator the solver saw) and
the KKT error of the returned ``x`` against the dense symmetrised matrix, the reference for
both rows.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings

import numpy as np

from lcpbench import run_solver
from lcpbench.problems.suspension.bim import BimConvergenceWarning
from lcpbench.problems.suspension.scene import LatticeScene, PaperLatticeParams

SOLVERS = ("bb-pgd", "mono-pqn", "bi-pqn:low=p4e6")


def packed_scene(kind: str, m: int, steps: int) -> LatticeScene:
    """A lattice scene packed by ``steps`` cheap RPY steps."""
    if kind == "paper-lattice":
        scene = LatticeScene(params=PaperLatticeParams(m=m, model="rpy", force=2.0))
    else:
        scene = LatticeScene(m, model="rpy", force=2.0, delta=0.5)
    for _ in range(steps):
        scene.step("mono-pqn")
    return scene


def kkt(A: np.ndarray, b: np.ndarray, x: np.ndarray) -> float:
    """``||min(x, A x + b)||``, the KKT error of ``x`` for the LCP ``(A, b)``."""
    return float(np.linalg.norm(np.minimum(x, A @ x + b)))


def dense(problem) -> np.ndarray:
    """The dense unsymmetrised ``D' M D`` of a contact problem (n forward solves)."""
    D = problem.contacts.D.toarray()
    return np.column_stack([D.T @ (problem.mobility @ D[:, k]) for k in range(D.shape[1])])


def rows(scene: LatticeScene, p: int, keep: dict) -> list[str]:
    """The table rows of one scene configuration at order ``p``; Mono-PQN's answers go
    into ``keep[(p, symmetrised)]``."""
    scene.params = dataclasses.replace(scene.params, model="bim", p=p, low=("p4e6",))
    probs = {s: scene.build(symmetrize=s) for s in (True, False)}
    A = dense(scene.build(symmetrize=False))     # its own mobility: no shared recycling
    As = 0.5 * (A + A.T)
    asym = np.linalg.norm(A - A.T) / np.linalg.norm(A)
    lmin = np.linalg.eigvalsh(As)[0]
    out = []
    for solver in SOLVERS:
        xs = {}
        for s, prob in probs.items():
            lcp = prob.lcp
            t0 = time.perf_counter()
            r = run_solver(lcp, solver, tol=1e-8)
            t = time.perf_counter() - t0
            fwd_adj = r.info.get("applications", {}).get("high", {})
            xs[s] = r.x
            if solver == "mono-pqn":
                keep[(p, s)] = r.x
            dx = np.linalg.norm(r.x - xs[True]) / np.linalg.norm(xs[True])
            out.append(
                f"| {scene.params.m} | {lcp.n} | {p} | {asym:.1e} | {lmin:.1e} | {solver} | "
                f"{'pair' if s else 'one'} | {r.status.value} | {r.mvps} | "
                f"{r.applications:.0f} | {fwd_adj.get('forward', 0):.0f}/{fwd_adj.get('adjoint', 0):.0f} | "
                f"{t:.3f} | {r.verified_kkt_abs:.1e} | {kkt(As, lcp.b, r.x):.1e} | {dx:.1e} |")
    return out


def discretisation_rows(m: int, keep: dict) -> list[str]:
    """Relative distance of each order's answers from the largest order's paired answer."""
    ref_p = max(p for p, _ in keep)
    ref = keep[(ref_p, True)]
    err = {k: np.linalg.norm(x - ref) / np.linalg.norm(ref) for k, x in keep.items()}
    return [f"| {m} | {p} | {err[(p, True)]:.1e} | {err[(p, False)]:.1e} |"
            for p in sorted({p for p, _ in keep})]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=("lattice", "paper-lattice"), default="lattice")
    ap.add_argument("--m", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--p", type=int, nargs="+", default=[4, 6, 8])
    ap.add_argument("--steps", type=int, default=20)
    args = ap.parse_args()
    print("| m | n | p | asymmetry | lambda_min sym. | solver | solves/product | status | "
          "MVPs | applications | high fwd/adj | s | verified KKT | KKT vs sym. A | ||x - x_pair|| / ||x_pair|| |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BimConvergenceWarning)
        errors = []
        for m in args.m:
            scene = packed_scene(args.scene, m, args.steps)
            keep: dict = {}
            for p in args.p:
                for line in rows(scene, p, keep):
                    print(line, flush=True)
            errors += discretisation_rows(m, keep)
    print("\nMono-PQN's forces against the symmetrised answer at the largest p (the reference):")
    print("| m | p | pair: ||x - x_ref|| / ||x_ref|| | one: ||x - x_ref|| / ||x_ref|| |")
    print("|---|---|---|---|")
    print("\n".join(errors))


if __name__ == "__main__":
    main()
