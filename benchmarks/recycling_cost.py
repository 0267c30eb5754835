"""PQN's products of the iterate against the paper's products of the direction, with Krylov
recycling, beside BB-PGD: E-MVPs, inner applications, app_cost and time, side by side.

Usage::

    python benchmarks/recycling_cost.py                  # paper-lattice m = 3 and 4, p = 8
    python benchmarks/recycling_cost.py --m 3 --p 6      # quicker

For each lattice side ``m`` the paper-lattice scene (``m^3`` spheres, the authors'
parameters) is packed by ``--pack`` cheap RPY steps; then, from that one state, each solver
gets the step's contact LCP with the boundary-integral mobility at order ``--p`` and
``eps_gmres`` 1e-8 (the paper's high fidelity), Krylov recycling on (the default), built
afresh for every solver so that each starts from the same empty recycled spaces (the
build, timed apart, is not in the solve time). Bi-PQN gets the low fidelity ``--low``.
Every solve is verified by the framework (``solved`` is the verified residual).

Printed per solver: status, high and low MVPs, E-MVPs, inner applications (high; low),
``app_cost`` (high products at their cold number of applications), the solve's CPU
seconds (``time.process_time`` of the whole call, every thread of the process: on a
machine shared with other jobs the wall clock mostly measures waiting for a core) and
wall seconds, the products applied to points (``products=iterate``: high and low; in
brackets the high products of points made before the switch to directions), and
BB-PGD's E-MVPs, app_cost and CPU seconds over the solver's (above 1: the solver is
faster). The last column says whether the app_cost ratio predicts the CPU time ratio
within 20 %. ``--repeat`` solves each solver that many times, each on a fresh build, and
keeps the solve of median CPU time. ``products=iterate`` is PQN's product of the new
point (docs/benchmarks.md, "Products of the iterate"), ``relax`` its loose products
("Loose products"). ``--per-product`` prints each solver's applications per product.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings

from common import packed_lattice

from lcpbench.core.api import run_solver
from lcpbench.core.specs import parse_spec

SOLVERS = ("bb-pgd", "mono-pqn", "mono-pqn:products=iterate", "bi-pqn:low={low}",
           "bi-pqn:low={low},products=iterate")


def solve_best(scene, p: int, low: str, solver: str, tol: float, repeat: int) -> dict:
    """:func:`solve_one` ``repeat`` times; the solve with the median CPU time (the counts are
    the same every time: each build starts from empty recycled spaces)."""
    runs = sorted((solve_one(scene, p, low, solver, tol) for _ in range(repeat)),
                  key=lambda r: r["time"])
    return runs[len(runs) // 2]


def solve_one(scene, p: int, low: str, solver: str, tol: float) -> dict:
    """Build the step's problem (fresh recycled spaces) and solve it; the row's numbers."""
    multi = parse_spec(solver)[0].startswith("bi-")
    scene.params = dataclasses.replace(scene.params, model="bim", p=p,
                                       low=(low,) if multi else ())
    t0 = time.perf_counter()
    prob = scene.build(lows=[low] if multi else [])
    build = time.perf_counter() - t0
    c0 = time.process_time()
    res = run_solver(prob.lcp, solver, stop="paper", tol=tol)
    cpu = time.process_time() - c0
    return {"solver": solver, "n": prob.lcp.n, "status": res.status.value,
            "solved": bool(res.solved), "mvps": res.mvps,
            "lofi": sum(res.lofi_mvps.values()), "emvps": res.emvps,
            "apps": res.applications, "lofi_apps": sum(res.lofi_applications.values()),
            "app_cost": res.app_cost, "wall": res.time_s, "time": cpu, "build": build,
            "switched": res.info.get("iterate_switched"), "kkt": res.verified_kkt_abs,
            "points": res.info.get("iterate_products", 0) + res.info.get("low_iterate_products",
                                                                           0),
            # the high mobility's GMRES/GCR applications per solve, the step's non-collisional
            # solve first (made while building), then one entry per product of the solve
            "sequence": list(getattr(prob.mobility, "gmres_iterations", []))}


def ratio_cells(base: dict, r: dict, clock: str = "time") -> str:
    """BB-PGD's E-MVPs, app_cost and time (``clock``: "time" CPU, "wall") over the
    solver's; does app_cost predict time?"""
    e = base["emvps"] / r["emvps"] if r["emvps"] else float("nan")
    a = base["app_cost"] / r["app_cost"] if r["app_cost"] else float("nan")
    t = base[clock] / r[clock] if r[clock] else float("nan")
    within = abs(a / t - 1.0) <= 0.2
    return f"{e:.2f} | {a:.2f} | {t:.2f} | {'yes' if within else 'no'} ({a / t:.2f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, nargs="+", default=[3, 4], help="lattice sides (M = m^3)")
    ap.add_argument("--p", type=int, default=8)
    ap.add_argument("--low", default="p4e6", help="Bi-PQN's low fidelity")
    ap.add_argument("--pack", type=int, default=40, help="RPY steps before the measurement")
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--solvers", nargs="+", default=list(SOLVERS))
    ap.add_argument("--repeat", type=int, default=1,
                    help="solves per solver (each on a fresh build); the median time is kept")
    ap.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                    help="the time the ratios compare: cpu (default; on a shared machine the "
                         "wall clock mostly measures waiting for a core) or wall (an idle "
                         "machine: the compiled kernels' threads make a parallel product's "
                         "CPU seconds exceed its wall seconds, a serial one's not)")
    ap.add_argument("--per-product", action="store_true",
                    help="after the table, each solver's high applications per product (forward "
                         "solves; the first entry is the step's non-collisional solve)")
    args = ap.parse_args()
    clock = "time" if args.clock == "cpu" else "wall"
    print("| M | n | solver | status | solved | high | low | E-MVPs | applications (high; low) "
          "| app_cost | solve CPU s | solve wall s | build s | products of points "
          "(switched after) | E-MVPs ratio | app_cost ratio "
          f"| {args.clock} time ratio | app_cost predicts time (20%) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    sequences = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for m in args.m:
            scene = packed_lattice(m, args.pack, scene="paper-lattice")
            base = None
            for spec in args.solvers:
                r = solve_best(scene, args.p, args.low, spec.format(low=args.low), args.tol,
                               args.repeat)
                base = base or r
                sw = f"{r['points']}" + ("" if r["switched"] is None else f" ({r['switched']})")
                print(f"| {m ** 3} | {r['n']} | {r['solver']} | {r['status']} | "
                      f"{'yes' if r['solved'] else 'NO'} | {r['mvps']} | {r['lofi']} | "
                      f"{r['emvps']:.2f} | {r['apps']:.0f}; {r['lofi_apps']:.0f} | "
                      f"{r['app_cost']:.2f} | {r['time']:.2f} | {r['wall']:.2f} | "
                      f"{r['build']:.1f} | {sw} | "
                      f"{ratio_cells(base, r, clock)} |", flush=True)
                sequences.append((m ** 3, r["solver"], r["sequence"]))
    if args.per_product:
        print("\n| M | solver | high applications per forward solve (non-collisional first) |")
        print("|---|---|---|")
        for M, solver, seq in sequences:
            print(f"| {M} | {solver} | {' '.join(str(k) for k in seq)} |")


if __name__ == "__main__":
    main()
