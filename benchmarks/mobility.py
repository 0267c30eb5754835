"""Seconds and GMRES iterations per mobility solve for clustered sphere configurations.

Usage::

    python benchmarks/mobility.py                       # M 27, 64, 125 x p 3, 4, 6, 8 x eps 1e-6, 1e-8
    python benchmarks/mobility.py --M 27 --p 4 8 --eps 1e-8 --repeat 3
    python benchmarks/mobility.py --M 125 --p 8 --profile   # where the time of one solve goes

The configurations are the clustered phase the LCPs come from: an ``m x m x m``
lattice with jitter, scaled so that the closest pairs are ``gap`` radii apart
(default 0.1), as after the particles have packed. Each cell is the median over
``--repeat`` products with random forces and torques, after one warm-up product
(numba compilation, the per-configuration near-field set-up, which is timed
separately as ``setup s``). The RPY model is timed on the same configurations
for scale. Products follow one another in one process, so the ratios between
cells are comparable; absolute seconds depend on the machine.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np

from lcpbench.problems.suspension import mobility
from lcpbench.problems.suspension.scene import lattice_configuration


def clustered(M: int, gap: float, seed: int = 0) -> np.ndarray:
    """``M = m^3`` unit spheres on a jittered lattice whose closest pair is ``gap`` apart."""
    m = round(M ** (1 / 3))
    if m ** 3 != M:
        raise SystemExit(f"--M {M}: use a cube (27, 64, 125, ...)")
    P = lattice_configuration(m, 1.0, 0.3, np.random.default_rng(seed))
    d = np.linalg.norm(P[:, None] - P[None], axis=-1)
    d[np.diag_indices(M)] = np.inf
    return P * (2.0 + gap) / d.min()


def time_products(op, M: int, repeat: int, seed: int = 1) -> tuple[float, float]:
    """Median seconds per product and median GMRES iterations (NaN if not reported)."""
    rng = np.random.default_rng(seed)
    secs, its = [], []
    for _ in range(repeat):
        f = rng.standard_normal(6 * M)
        t0 = time.perf_counter()
        op @ f
        secs.append(time.perf_counter() - t0)
        hist = getattr(op, "gmres_iterations", None)
        if hist:
            its.append(hist[-1])
    return float(np.median(secs)), float(np.median(its)) if its else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--M", type=int, nargs="+", default=[27, 64, 125])
    ap.add_argument("--p", type=int, nargs="+", default=[3, 4, 6, 8])
    ap.add_argument("--eps", type=float, nargs="+", default=[1e-6, 1e-8])
    ap.add_argument("--gap", type=float, default=0.1, help="closest gap in radii")
    ap.add_argument("--repeat", type=int, default=3, help="timed products per cell")
    ap.add_argument("--profile", action="store_true",
                    help="profile one product of each cell instead of timing")
    args = ap.parse_args()

    print("| M | model | p | eps_gmres | setup s | s per solve | GMRES its | s per solve / RPY |")
    print("|---|---|---|---|---|---|---|---|")
    for M in args.M:
        X = clustered(M, args.gap)
        rpy = mobility(X, 1.0, model="rpy")
        t_rpy, _ = time_products(rpy, M, max(args.repeat, 5))
        print(f"| {M} | rpy | - | - | - | {t_rpy:.2e} | - | 1 |", flush=True)
        for p in args.p:
            for eps in args.eps:
                t0 = time.perf_counter()
                op = mobility(X, 1.0, model="bim", p=p, eps_gmres=eps)
                op @ np.ones(6 * M)                     # warm-up: compilation and set-up
                setup = time.perf_counter() - t0
                if args.profile:
                    prof = cProfile.Profile()
                    prof.enable()
                    op @ np.random.default_rng(2).standard_normal(6 * M)
                    prof.disable()
                    print(f"\n### profile M={M} p={p} eps={eps:g}\n")
                    pstats.Stats(prof).sort_stats("cumulative").print_stats(12)
                    pstats.Stats(prof).sort_stats("tottime").print_stats(8)
                    continue
                t, it = time_products(op, M, args.repeat)
                print(f"| {M} | bim | {p} | {eps:g} | {setup:.2f} | {t:.3f} | {it:.0f} | "
                      f"{t / t_rpy:.0f} |", flush=True)


if __name__ == "__main__":
    main()
