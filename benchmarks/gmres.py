"""scipy's GMRES against the compiled one in the boundary-integral mobility (``model="bim"``).

Usage::

    python benchmarks/gmres.py                          # 27 and 64 packed spheres x p 4, 6, 8
    python benchmarks/gmres.py --M 27 --p 4 --repeat 5 --eps 1e-10

Configurations: packed unit spheres with centres on an ``m x m x m`` grid, spacing 2.1
for M = 27 (gaps 0.1a) and 2.3 for M = 64 (gaps 0.3a).  For every (M, p) one operator
per ``krylov`` setting ("compiled", "scipy") is built, each makes one warm-up product
(numba compilation, per-configuration set-up), then both make the same ``--repeat``
products with random forces and torques, interleaved (compiled, scipy, compiled, ...) so
that load from other jobs hits both alike.  Reported: median seconds per forward product
and median GMRES iterations of each, the ratio of the seconds scipy / compiled, and the
largest relative difference between the two results (both solve to ``eps``).  Prints a
Markdown table.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from lcpbench.problems.suspension.bim import KRYLOV_METHODS, BimMobility

SPACING = {27: 2.1, 64: 2.3}
"""Default centre spacing (radius 1) of the packed lattices."""


def lattice(M: int, spacing: float) -> np.ndarray:
    """Centres of ``M = m^3`` spheres on a cubic grid of the given spacing."""
    m = round(M ** (1 / 3))
    if m ** 3 != M:
        raise SystemExit(f"--M {M}: use a cube (27, 64, 125, ...)")
    g = np.arange(m) * spacing
    return np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T.copy()


def compare(M: int, spacing: float, p: int, eps: float, repeat: int, seed: int = 1) -> dict:
    """Median seconds and iterations per forward product for both ``krylov`` settings."""
    c = lattice(M, spacing)
    ops = {k: BimMobility(c, 1.0, p=p, eps_gmres=eps, krylov=k) for k in KRYLOV_METHODS}
    rng = np.random.default_rng(seed)
    f0 = rng.standard_normal(6 * M)
    for op in ops.values():                                  # warm-up
        op @ f0
    secs: dict = {k: [] for k in ops}
    diff = 0.0
    for _ in range(repeat):
        f = rng.standard_normal(6 * M)
        u = {}
        for k, op in ops.items():
            t0 = time.perf_counter()
            u[k] = op @ f
            secs[k].append(time.perf_counter() - t0)
        diff = max(diff, float(np.linalg.norm(u["scipy"] - u["compiled"])
                               / np.linalg.norm(u["compiled"])))
    out = {"M": M, "p": p, "diff": diff}
    for k, op in ops.items():
        out[f"s_{k}"] = float(np.median(secs[k]))
        out[f"its_{k}"] = float(np.median(op.gmres_iterations[1:]))
        out[f"res_{k}"] = float(max(op.residuals[1:]))
    out["ratio"] = out["s_scipy"] / out["s_compiled"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--M", type=int, nargs="+", default=[27, 64])
    ap.add_argument("--p", type=int, nargs="+", default=[4, 6, 8])
    ap.add_argument("--eps", type=float, default=1e-8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--spacing", type=float, default=None,
                    help="centre spacing (radius 1); default 2.1 for M = 27, else 2.3")
    args = ap.parse_args()
    print(f"eps_gmres = {args.eps:g}, median of {args.repeat} forward products after one "
          "warm-up, products interleaved\n")
    print("| M | spacing | p | its compiled | its scipy | s compiled | s scipy | "
          "scipy / compiled | max rel diff | max residual |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for M in args.M:
        spacing = args.spacing if args.spacing is not None else SPACING.get(M, 2.3)
        for p in args.p:
            r = compare(M, spacing, p, args.eps, args.repeat)
            print(f"| {M} | {spacing:g} | {p} | {r['its_compiled']:g} | {r['its_scipy']:g} | "
                  f"{r['s_compiled']:.3f} | {r['s_scipy']:.3f} | {r['ratio']:.2f} | "
                  f"{r['diff']:.1e} | {max(r['res_compiled'], r['res_scipy']):.1e} |",
                  flush=True)


if __name__ == "__main__":
    main()
