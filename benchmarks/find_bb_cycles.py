"""Search for small SPD LCPs on which projected BB without line search fails.

The unsafeguarded projected Barzilai-Borwein gradient method (BB-PGD: method
paper, section "Numerical Results" -> "Comparison Methods", eq.
spectralStepSize) has no convergence guarantee with bound constraints; Dai &
Fletcher (Numer. Math. 100, 2005) constructed box-constrained quadratics on
which it cycles. This script finds such instances by a seeded random search
over small (n = 3..8), ill-conditioned SPD matrices, and prints the ones it
finds as JSON lines for the ``instances`` list of ``problems/data/bb_cycle.json``
(family ``bb-cycle``; floats in round-trip precision).

The iteration, implemented here independently of ``solvers/pgd.py``::

    x_0 = 0, g_0 = b
    tau_0 = g'g / g'Ag                          (exact Cauchy step: one extra MVP)
    x_{k+1} = max(x_k - tau_k g_k, 0)
    g_{k+1} = A x_{k+1} + b                     (one MVP per iteration)
    tau_{k+1} = s's / s'y,  s = x_{k+1} - x_k, y = g_{k+1} - g_k   (BB1)

An instance is kept when ``||min(x, Ax+b)||`` stays above ``--fail-tol``
over the whole last quarter of ``--maxit`` iterations, for the plain loop and
for perturbed variants (gradient by recurrence instead of a fresh product, b
scaled by 1 +- 1e-9; with ``--robust-start`` also first steps of 0.5, 0.9,
1.1 and 2 times the Cauchy step), so that rounding and start-up differences
between implementations do not make the failure disappear. With ``--confirm`` each
kept instance is also run through ``lcpbench.solve(..., solver="bb-pgd")``
and ``lcpbench.reference``.

Usage::

    python benchmarks/find_bb_cycles.py --trials 20000 --seed 0 --keep 4 --confirm
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np


def candidate(seed: int, trial: int) -> tuple[np.ndarray, np.ndarray, float]:
    """A random small SPD instance ``(A, b, cond)`` from ``(seed, trial)``.

    n in 3..8, eigenvalues log-spaced over a condition number 10^U(1, 6) with
    random interior values, random orthogonal eigenvectors, b ~ N(0, 1) (mixed
    signs, so the solution has active and inactive indices).
    """
    rng = np.random.default_rng([seed, trial])
    n = int(rng.integers(3, 9))
    cond = 10.0 ** rng.uniform(1.0, 6.0)
    lam = np.concatenate([[1.0, cond], 10.0 ** rng.uniform(0, np.log10(cond), n - 2)])
    Q, R = np.linalg.qr(rng.standard_normal((n, n)))
    Q = Q * np.sign(np.diag(R))
    A = (Q * lam) @ Q.T
    A = (A + A.T) / 2
    b = rng.standard_normal(n) * 10.0 ** rng.uniform(-1, 1)
    return A, b, float(cond)


def projected_bb(A: np.ndarray, b: np.ndarray, maxit: int, recurrence: bool = False,
                 first_step: float = 1.0) -> np.ndarray:
    """KKT residual ``||min(x, Ax+b)||`` of every iterate of projected BB1 from x = 0.

    ``first_step`` multiplies the exact Cauchy step of the first iteration
    (1.0: the method as specified; other values test robustness).
    """
    n = len(b)
    x = np.zeros(n)
    g = b.copy()
    Ag = A @ g
    gAg = g @ Ag
    tau = first_step * (g @ g) / gAg if gAg > 0 else 1.0
    res = np.empty(maxit + 1)
    res[0] = np.linalg.norm(np.minimum(x, g))
    for k in range(maxit):
        xn = np.maximum(x - tau * g, 0.0)
        s = xn - x
        if recurrence:
            y = A @ s
            gn = g + y
        else:
            gn = A @ xn + b
            y = gn - g
        x, g = xn, gn
        res[k + 1] = np.linalg.norm(np.minimum(x, g))
        if res[k + 1] == 0.0:
            res[k + 2:] = 0.0
            break
        sy = s @ y
        if sy > 0:
            tau = (s @ s) / sy
    return res


#: First-step multipliers tried by ``--robust-start`` (implementations differ in
#: how they start: Cauchy step, a fixed step, a norm estimate).
FIRST_STEPS = (0.5, 0.9, 1.1, 2.0)


def fails(A: np.ndarray, b: np.ndarray, maxit: int, fail_tol: float,
          robust_start: bool = False) -> bool:
    """True when the plain loop and every perturbed variant fail to converge."""
    variants = [(b, False, 1.0), (b, True, 1.0), (b * (1 + 1e-9), False, 1.0),
                (b * (1 - 1e-9), False, 1.0)]
    if robust_start:
        variants += [(b, False, f) for f in FIRST_STEPS]
    for bb, rec, first in variants:
        r = projected_bb(A, bb, maxit, rec, first)
        if not np.all(np.isfinite(r)):
            continue  # divergence to inf is also a failure
        if np.min(r[-(maxit // 4):]) <= fail_tol:
            return False
    return True


def classify(A: np.ndarray, b: np.ndarray, maxit: int) -> str:
    """``"cycle"`` (bounded, not decreasing) or ``"divergence"`` (residual blows up)."""
    r = projected_bb(A, b, maxit)
    if not np.all(np.isfinite(r)) or np.max(r[-(maxit // 4):]) > 1e6 * max(r[0], 1e-300):
        return "divergence"
    return "cycle"


def confirm(A: np.ndarray, b: np.ndarray, maxit: int) -> str:
    """Run the registered bb-pgd and the consensus reference on the instance."""
    import lcpbench

    lcp = lcpbench.LCP(A, b, name="bb-cycle-candidate")
    try:
        res = lcpbench.solve(lcp, solver="bb-pgd", max_iter=maxit, max_emvps=10 * maxit)
        bb = f"bb-pgd {res.status.value} after {res.iterations} it, kkt {res.verified_kkt_abs:.2e}"
    except Exception as exc:  # pragma: no cover - the solver module may be mid-rewrite
        bb = f"bb-pgd unavailable ({type(exc).__name__}: {exc})"
    ref = lcpbench.reference(lcp)
    return f"{bb}; reference accepted={ref.accepted} kkt {ref.kkt_abs:.1e}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20000, help="random instances to try")
    ap.add_argument("--seed", type=int, default=0, help="search seed")
    ap.add_argument("--maxit", type=int, default=5000, help="iterations of projected BB")
    ap.add_argument("--fail-tol", type=float, default=1e-6,
                    help="residual the last quarter of iterates must stay above")
    ap.add_argument("--keep", type=int, default=4, help="stop after this many finds")
    ap.add_argument("--max-cond", type=float, default=np.inf,
                    help="only keep instances with condition number below this")
    ap.add_argument("--robust-start", action="store_true",
                    help="also require failure with first steps scaled by "
                         + ", ".join(map(str, FIRST_STEPS)))
    ap.add_argument("--cycles-only", action="store_true",
                    help="keep bounded cycles only, not divergence")
    ap.add_argument("--confirm", action="store_true", help="also run lcpbench bb-pgd/reference")
    args = ap.parse_args(argv)

    found = 0
    t0 = time.time()
    for trial in range(args.trials):
        A, b, cond = candidate(args.seed, trial)
        if cond > args.max_cond:
            continue
        # Cheap screen first, then the full robustness check.
        r = projected_bb(A, b, 1000)
        if np.all(np.isfinite(r)) and np.min(r[-250:]) <= args.fail_tol:
            continue
        if not fails(A, b, args.maxit, args.fail_tol, args.robust_start):
            continue
        kind = classify(A, b, args.maxit)
        if args.cycles_only and kind != "cycle":
            continue
        found += 1
        print(f"# found ({kind}): seed={args.seed} trial={trial} n={len(b)} cond={cond:.3g} "
              f"({time.time() - t0:.0f} s)")
        if args.confirm:
            print("# " + confirm(A, b, min(args.maxit, 2000)))
        print(json.dumps({"trial": trial, "cond": float(cond), "kind": kind,
                          "A": A.tolist(), "b": b.tolist()}) + ",")
        sys.stdout.flush()
        if found >= args.keep:
            break
    print(f"# {found} found in {trial + 1} trials, {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
