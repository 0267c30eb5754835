"""Reliability sweep: random LCPs x every MVP solver; counts of honest and false outcomes.

Usage::

    python benchmarks/fuzz.py --cases 10000 --jobs 2     # the number in docs/benchmarks.md
    python benchmarks/fuzz.py --cases 40                  # what .ci/run runs
    python benchmarks/fuzz.py --start 5000 --cases 5000 --save part2.json   # one slice
    python benchmarks/fuzz.py --merge part1.json part2.json                  # the whole table

Case ``i`` is generated from the seed ``(seed, i)`` as one of four kinds, in turn:
random SPD (condition number 10^U(0, 6)), singular PSD (``A = J J'`` with rank
``k < n`` and a planted solution so the LCP is solvable), degenerate (planted with
indices where ``x_i = w_i = 0``), and badly scaled (SPD with ``|b_i|`` spread over
1e-12..1e6). Sizes n = 1..40. Every MVP-only solver runs with its defaults at tol
1e-8 and the paper's stop rule; the multi-fidelity ones get the low-fidelity
operators of :func:`lcpbench.problems.random.with_perturbed_lows`.

Each run lands in one class: ``solved`` (verified residual meets the tolerance),
``honest`` (not solved, and the status says so), ``false`` (status ``converged``
but the verified residual exceeds 10 x tol: the defect this sweep hunts) and
``crash`` (an exception escaped the framework). Exits 1 if any run is false or a
crash, printing the case and solver to reproduce it.
"""

from __future__ import annotations

import argparse
import json
import sys
import traceback
from collections import Counter
from multiprocessing import Pool

import numpy as np

import lcpbench
from lcpbench.problems.hard import planted_b, random_spd_matrix
from lcpbench.problems.random import with_perturbed_lows
from lcpbench.core.registry import solvers

KINDS = ("spd", "singular-psd", "degenerate", "bad-scale")
MULTI = {"bi-pqn": "bi-pqn:low=low", "multi-pqn": "multi-pqn:lows=[low,lower]"}


def make_case(i: int, seed: int = 0) -> lcpbench.LCP:
    """Case ``i`` of the sweep (deterministic in ``(seed, i)``)."""
    rng = np.random.default_rng([seed, i])
    kind = KINDS[i % len(KINDS)]
    n = int(rng.integers(1, 41))
    if kind == "singular-psd":
        k = max(1, n - int(rng.integers(1, max(2, n // 2 + 1))))
        J = rng.standard_normal((n, k))
        A = J @ J.T
    else:
        A = random_spd_matrix(rng, n, float(10 ** rng.uniform(0, 6)))
    if kind == "bad-scale":
        b = rng.choice([-1.0, 1.0], n) * 10 ** rng.uniform(-12, 6, n)
    else:
        x = np.zeros(n)
        w = np.zeros(n)
        role = rng.integers(0, 3 if kind == "degenerate" else 2, n)   # 0 active, 1 inactive, 2 both 0
        x[role == 0] = rng.uniform(0.1, 2.0, int((role == 0).sum()))
        w[role == 1] = rng.uniform(0.1, 2.0, int((role == 1).sum()))
        b = planted_b(A, x, w)
    lcp = lcpbench.LCP((A + A.T) / 2, b, name=f"fuzz-{seed}-{i}-{kind}",
                       meta={"kind": kind, "case": i, "seed": seed})
    return with_perturbed_lows(lcp, seed=i)


def mvp_solvers() -> list[str]:
    return sorted(n for n, s in solvers().items() if s.mvp_only and not s.reference
                  and not n.startswith("test-"))


def run_case(args: tuple) -> list[tuple[str, str, str, str]]:
    """``(kind, solver, outcome, detail)`` for every solver (or the named ones) on case ``i``."""
    i, seed, max_emvps, only = args
    out = []
    try:
        lcp = make_case(i, seed)
    except Exception:
        return [("?", "(generator)", "crash", traceback.format_exc(limit=3))]
    kind = lcp.meta["kind"]
    for name in mvp_solvers():
        if only and name not in only:
            continue
        spec = MULTI.get(name, name)
        try:
            res = lcpbench.solve(lcp, solver=spec, tol=1e-8, max_emvps=max_emvps)
        except Exception:
            out.append((kind, name, "crash", f"case {i}: {traceback.format_exc(limit=3)}"))
            continue
        if res.status.value == "converged" and res.verified_kkt_abs > 10 * res.threshold:
            out.append((kind, name, "false", f"case {i}: {res.summary()}"))
        elif res.solved:
            out.append((kind, name, "solved", ""))
        else:
            out.append((kind, name, "honest", res.status.value))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=1000, help="number of random LCPs")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--start", type=int, default=0,
                    help="first case index (to split a sweep into slices)")
    ap.add_argument("--save", metavar="FILE.json", help="also write the counts to this file")
    ap.add_argument("--solvers", nargs="+", metavar="NAME",
                    help="only these solvers (default every MVP-only solver)")
    ap.add_argument("--merge", nargs="+", metavar="FILE.json",
                    help="print the table of saved slices instead of running")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    ap.add_argument("--max-emvps", type=float, default=1000.0,
                    help="budget per solve (default 1000: a false 'converged' does not need "
                         "a long run to show, and runs that exhaust it are honest failures)")
    args = ap.parse_args()
    if args.merge:
        return merge(args.merge)
    if args.cases < 1 or args.jobs < 1 or args.start < 0:
        ap.error("--cases and --jobs must be >= 1, --start >= 0")
    from tqdm import tqdm

    counts: Counter = Counter()
    problems: list[str] = []
    only = tuple(args.solvers or ())
    unknown = set(only) - set(mvp_solvers())
    if unknown:
        ap.error(f"--solvers: {sorted(unknown)} are not MVP-only solvers: {mvp_solvers()}")
    work = [(i, args.seed, args.max_emvps, only)
            for i in range(args.start, args.start + args.cases)]
    with Pool(args.jobs) as pool:
        for rows in tqdm(pool.imap_unordered(run_case, work, chunksize=4), total=len(work),
                         unit="case", file=sys.stderr):
            for kind, name, outcome, detail in rows:
                counts[(name, outcome)] += 1
                if outcome in ("false", "crash"):
                    problems.append(f"{name} on {kind} {detail}")
    head = (f"cases {args.start}..{args.start + args.cases - 1} (seed {args.seed}), tol 1e-8, "
            f"paper's stop rule, budget {args.max_emvps:g} E-MVPs per solve"
            + (f", solvers {', '.join(only)}" if only else ""))
    if args.save:
        with open(args.save, "w") as fh:
            json.dump({"head": head, "cases": args.cases, "problems": problems,
                       "counts": [[n, o, v] for (n, o), v in counts.items()]}, fh)
    return report(head, counts, problems)


def merge(paths: list[str]) -> int:
    """Print the table of slices saved with ``--save``."""
    counts: Counter = Counter()
    problems: list[str] = []
    heads = []
    for path in paths:
        with open(path) as fh:
            part = json.load(fh)
        heads.append(part["head"])
        problems += part["problems"]
        for n, o, v in part["counts"]:
            counts[(n, o)] += v
    return report("; ".join(heads), counts, problems)


def report(head: str, counts: Counter, problems: list[str]) -> int:
    """Print the table; 1 if any run was a false convergence or a crash."""
    names = sorted({n for n, _ in counts})
    print(head + "\n")
    print("| solver | solved | honest failure | false converged | crash |")
    print("|---|---|---|---|---|")
    for n in names:
        print(f"| {n} | {counts[(n, 'solved')]} | {counts[(n, 'honest')]} | "
              f"{counts[(n, 'false')]} | {counts[(n, 'crash')]} |")
    total_false = sum(v for (n, o), v in counts.items() if o == "false")
    total_crash = sum(v for (n, o), v in counts.items() if o == "crash")
    print(f"\nfalse converged: {total_false}, crashes: {total_crash}")
    for p in problems[:20]:
        print(p, file=sys.stderr)
    return 1 if total_false or total_crash else 0


if __name__ == "__main__":
    sys.exit(main())
