"""The fidelity-advantage map: Bi-PQN's MVPs against the relative error of its low fidelity.

Usage::

    python benchmarks/fidelity_map.py     # both shipped sets: the table of docs/benchmarks.md
    python benchmarks/fidelity_map.py --sets lattice-bim-m4 --instances 0-4
    python benchmarks/fidelity_map.py --errors 0.5,1e-3 --no-oracle   # the issue's targets

For every stored set, every instance gets low fidelities ``A + E`` with
``||E||_2 / ||A||_2`` = 1e-1 ... 1e-6, ``E`` random symmetric or shaped like the
set's own p = 4 error (problem family ``synthetic-low``, declared cost 0.08),
beside the set's real lows at their measured error. Per low: the median
high-fidelity MVPs and E-MVPs of ``bi-pqn`` with its defaults (tol 1e-8, the
paper's stop rule), its ratio to BB-PGD and Mono-PQN on the same instances, and
the oracle floor: Bi-PQN with every subproblem (and the low-fidelity start)
solved exactly by Clarabel, the paper's optimal step, the free first secant pair
and BFGS corrections, i.e. the fewest high MVPs any inexact Bi-PQN can hope for
with that low. The same rows, written by ``lcpbench run`` on ``synthetic-low``,
make the report's "Fidelity advantage" section.
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
from common import progress

import lcpbench
from lcpbench.core.operator import dense_uncounted
from lcpbench.core.residuals import kkt_abs
from lcpbench.problems.synthetic_low import SyntheticLowParams, parse_low_name, synthetic_low
from lcpbench.solvers.pqn.mono import optimal_step
from lcpbench.toolkit.qp import solve_and_refine

TOL = 1e-8


def _qp(M: np.ndarray, c: np.ndarray) -> np.ndarray:
    """``argmin_{z >= 0} 1/2 z'Mz + c'z`` by Clarabel, polished on its active set."""
    z, message, _ = solve_and_refine((M + M.T) / 2, c, "clarabel", tol=1e-12)
    if z is None:
        raise RuntimeError(f"the oracle's QP failed: {message}")
    return z


def _bfgs(B: np.ndarray, s: np.ndarray, y: np.ndarray) -> np.ndarray:
    Bs = B @ s
    sy, sBs = float(s @ y), float(s @ Bs)
    if sy <= 1e-12 * np.linalg.norm(s) * np.linalg.norm(y) or sBs <= 0:
        return B
    return B + np.outer(y, y) / sy - np.outer(Bs, Bs) / sBs


def oracle_high_mvps(A: np.ndarray, L: np.ndarray, b: np.ndarray, tol: float = TOL,
                     max_iter: int = 60) -> int:
    """High MVPs of Bi-PQN with exact subproblems (Clarabel), optimal steps, BFGS corrections."""
    z = _qp(L, b)                                              # the low LCP: no high MVP
    g = A @ z + b                                              # the first high MVP
    hi = 1
    B = _bfgs(L.copy(), z, g - b) if np.any(z) else L.copy()   # the free pair (z - 0, A z - A 0)
    while kkt_abs(z, g) > tol and hi < max_iter:
        p = _qp(B, g - B @ z) - z
        Ap = A @ p
        hi += 1
        z_new, g_new, eta = optimal_step(z, g, p, Ap)       # the paper's step (algorithm stepSize)
        if z_new is None or eta <= 0:
            break
        z, g = z_new, g_new
        B = _bfgs(B, eta * p, eta * Ap)
    return hi


def _median(v) -> float:
    return float(np.median(v)) if len(v) else float("nan")


def set_rows(path: str, instances: str, oracle: bool, errors: tuple = ()) -> list[dict]:
    params = SyntheticLowParams(path=path, instances=instances)
    if errors:
        params = SyntheticLowParams(path=path, instances=instances, errors=errors)
    lcps = synthetic_low(params)
    base = {s: _median([lcpbench.solve(lcp, solver=s, tol=TOL).emvps for lcp in lcps])
            for s in ("bb-pgd", "mono-pqn")}
    groups: dict = defaultdict(lambda: defaultdict(list))
    for lcp in lcps:
        A, b = dense_uncounted(lcp.A), lcp.b
        for name in lcp.low:
            shape, err = parse_low_name(name)
            key = (shape if shape in ("random", "like") else f"real {shape}",
                   err if shape in ("random", "like") else None)
            r = lcpbench.solve(lcp, solver=f"bi-pqn:low={name}", tol=TOL)
            g = groups[key]
            g["err"].append(err)
            g["hi"].append(r.mvps if r.solved else np.nan)
            g["emvps"].append(r.emvps if r.solved else np.nan)
            g["solved"].append(r.solved)
            if oracle:
                g["oracle"].append(oracle_high_mvps(A, dense_uncounted(lcp.low[name]), b))
        progress(path, lcp.name)
    rows = []
    order = sorted(groups.items(), key=lambda kv: (kv[0][0], -np.median(kv[1]["err"])))
    for (shape, _), g in order:
        e = _median(g["emvps"])
        rows.append({"set": path, "low": shape, "rel_error": _median(g["err"]),
                     "bi_high": _median(g["hi"]), "bi_emvps": e,
                     "vs_bb": e / base["bb-pgd"], "vs_mono": e / base["mono-pqn"],
                     "oracle_high": _median(g["oracle"]) if oracle else float("nan"),
                     "solved": f"{sum(g['solved'])}/{len(g['solved'])}"})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="lattice-bim-m3,lattice-bim-m4",
                    help="comma-separated stored sets (shipped names or .h5 files)")
    ap.add_argument("--instances", default="", help="positions per set, e.g. 0-9 (default all)")
    ap.add_argument("--errors", default="", help="relative errors of the synthetic lows, "
                    "e.g. 0.5,1e-3 (default 1e-1 ... 1e-6)")
    ap.add_argument("--no-oracle", action="store_true", help="skip the exact-subproblem oracle")
    args = ap.parse_args()
    print("| set | low | rel. error | Bi-PQN high MVPs | oracle high MVPs | Bi-PQN E-MVPs | "
          "vs BB-PGD | vs Mono-PQN | solved |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in args.sets.split(","):
        errors = tuple(float(e) for e in args.errors.split(",") if e.strip())
        for r in set_rows(path, args.instances, not args.no_oracle, errors):
            print(f"| {r['set']} | {r['low']} | {r['rel_error']:.2g} | {r['bi_high']:.1f} | "
                  f"{r['oracle_high']:.1f} | {r['bi_emvps']:.2f} | {r['vs_bb']:.2f}x | "
                  f"{r['vs_mono']:.2f}x | {r['solved']} |", flush=True)


if __name__ == "__main__":
    main()
