"""Error and cost of low-fidelity contact operators on one packed lattice configuration.

Usage::

    python benchmarks/low_fidelity.py                                  # 0.1a lattice, m = 3
    python benchmarks/low_fidelity.py --scene paper-lattice --m 3 --low p4e6 p4 p6
    python benchmarks/low_fidelity.py --low p8e3 p8e4 --repeat 3
    python benchmarks/low_fidelity.py --scene paper-lattice --low p8f6e3 p4 \
        --solve bb-pgd mono-pqn bi-pqn:low=p8f6e3 bi-pqn:low=p4

The scene is stepped ``--pack`` times with RPY (cheap) until it has packed; on that
configuration the step's contact problem is built with the high fidelity (BIM p = 8,
eps_gmres 1e-8) and every ``--low`` fidelity, exactly as a time step builds it
(:func:`build_contact_problem`), and one cold product of each operator is timed on its
fresh mobility (:func:`cold_cost`: the cost ratio of first products). Every operator is then formed densely and
symmetrised as ``lcpbench generate`` stores it, and the script prints each low's relative
2-norm error against the high matrix and its cost ratio (median over ``--repeat`` builds).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from common import packed_lattice

import lcpbench
from lcpbench.core.operator import dense_uncounted
from lcpbench.core.probes import measure_cost
from lcpbench.problems.suspension.problem import build_contact_problem

DEFAULT_LOWS = ["p3e6", "p4e6", "p6e6", "p4", "p6", "p8e3", "p8e4", "p8e5", "rpy"]


def build(scene, lows: list[str], p: int, eps: float):
    """The step's contact problem with the high fidelity and ``lows``."""
    P = scene.params
    F, T = scene.loads()
    return build_contact_problem(scene.centers, scene.radii, F, T, dt=P.dt, delta=P.delta,
                                 separation=P.separation, model="bim", p=p, eps_gmres=eps,
                                 low=lows)


def cold_cost(op) -> float:
    """Seconds of one product of ``op`` from empty recycled spaces (the step declares no
    costs since its own products price it; this script compares first products)."""
    return measure_cost(op, cold=getattr(op._impl, "cold_products", None))


def dense_sym(op) -> np.ndarray:
    A = np.asarray(dense_uncounted(op), dtype=np.float64)
    return 0.5 * (A + A.T)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="lattice", help="lattice (0.1a) or paper-lattice (0.3a)")
    ap.add_argument("--m", type=int, default=3)
    ap.add_argument("--pack", type=int, default=40, help="RPY steps before the measurement")
    ap.add_argument("--p", type=int, default=8, help="order of the high fidelity")
    ap.add_argument("--eps", type=float, default=1e-8, help="GMRES tolerance of the high")
    ap.add_argument("--low", nargs="+", default=DEFAULT_LOWS)
    ap.add_argument("--repeat", type=int, default=1, help="builds timed (median ratio)")
    ap.add_argument("--solve", nargs="*", default=[],
                    help="solvers to run on the live LCP afterwards, e.g. bb-pgd "
                         "bi-pqn:low=p8f6e3 (tol 1e-8, the paper's stop rule)")
    args = ap.parse_args()
    scene = packed_lattice(args.m, args.pack, args.scene)
    ratios: dict[str, list[float]] = {k: [] for k in args.low}
    prob = None
    for _ in range(max(1, args.repeat)):
        prob = build(scene, args.low, args.p, args.eps)
        t_high = cold_cost(prob.lcp.A)
        for k in args.low:
            ratios[k].append(cold_cost(prob.lcp.low[k]) / t_high)
    lcp = prob.lcp
    gaps = prob.contacts.gaps
    print(f"{args.scene} m = {args.m} after {args.pack} RPY steps: n = {lcp.n} contacts, "
          f"gaps {gaps.min():.3f} .. {gaps.max():.3f}; high p = {args.p}, eps {args.eps:g}, "
          f"one product {t_high:.3f} s", flush=True)
    t0 = time.perf_counter()
    A = dense_sym(lcp.A)
    nA = np.linalg.norm(A, 2)
    print(f"high formed in {time.perf_counter() - t0:.1f} s", flush=True)
    print("| low | rel. 2-norm error | cost ratio |")
    print("|---|---|---|")
    for k in args.low:
        L = dense_sym(lcp.low[k])
        err = np.linalg.norm(L - A, 2) / nA
        print(f"| {k} | {err:.3g} | {np.median(ratios[k]):.3g} |", flush=True)
    if args.solve:
        print("\n| solver | status | high MVPs | low MVPs | E-MVPs |")
        print("|---|---|---|---|---|")
    for spec in args.solve:
        prob = build(scene, args.low, args.p, args.eps)      # fresh operators per solve
        res = lcpbench.solve(prob.lcp, solver=spec, tol=1e-8)
        print(f"| {spec} | {res.status.value} | {res.mvps} | {sum(res.lofi_mvps.values())} | "
              f"{res.emvps:.2f} |", flush=True)


if __name__ == "__main__":
    main()
