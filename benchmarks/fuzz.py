"""Reliability sweep: random LCPs x every MVP solver; counts of honest and false outcomes.

Usage::

    python benchmarks/fuzz.py --cases 10000 --jobs 2     # the classic kinds, as in docs/benchmarks.md
    python benchmarks/fuzz.py --cases 40                  # what .ci/run runs
    python benchmarks/fuzz.py --start 5000 --cases 5000 --save part2.json   # one slice
    python benchmarks/fuzz.py --merge part1.json part2.json                  # the whole table
    python benchmarks/fuzz.py --family infeasible --cases 250 --jobs 2       # one adversarial family

Classic kinds (``--family classic``, the default): case ``i`` is generated from
the seed ``(seed, i)`` as one of four kinds, in turn: random SPD (condition
number 10^U(0, 6)), singular PSD (``A = J J'`` with rank ``k < n`` and a planted
solution so the LCP is solvable), degenerate (planted with indices where
``x_i = w_i = 0``), and badly scaled (SPD with ``|b_i|`` spread over
1e-12..1e6). Sizes n = 1..40.

Adversarial families (``--family NAME``, every case of that family):

* ``infeasible``: ``A = J J'`` with a null direction ``d >= 0`` and ``b'd < 0``
  (no solution), n = 2..40;
* ``unbounded``: zero rows of ``A`` with a negative ``b_i`` (the QP is unbounded
  below, no solution), n = 1..40;
* ``rank1-tiny``: ``A = u u'`` with n = 2..4 and Gaussian ``b``: some have a
  solution, some do not (those with a null direction ``d >= 0``, ``b'd < 0``);
* ``inexact``: ``A = K^{-1}`` applied by conjugate gradients at a relative
  tolerance 10^U(-10, -4), declared as the operator's accuracy, n = 5..60; its
  low fidelities are the same solves at 100x and 10^4 x looser tolerances;
* ``huge-sparse``: sparse tridiagonal SPD with a planted solution, n = 1,000..20,000;
* ``mixed-scale``: ``D S D`` with ``S`` SPD and ``D`` spread over 1e-4..1e4, a
  planted solution, n = 2..40.

Every MVP-only solver runs with its defaults at tol 1e-8 and the paper's stop
rule; the multi-fidelity ones get low-fidelity operators (perturbed copies
``A + E``, or looser solves for ``inexact``).

Each run lands in one class: ``solved`` (verified residual meets the tolerance),
``honest`` (not solved, and the status says so), ``infeasible`` (status
``infeasible`` on an instance that has no solution), ``false`` (status
``converged`` while a fresh product of the framework refutes it, or on an
instance without a solution), ``false-infeasible`` (status ``infeasible`` on an
instance with a solution) and ``crash`` (an exception escaped ``solve``). Exits 1
if any run is false or a crash, printing the case and solver to reproduce it.
"""

from __future__ import annotations

import os

# One BLAS thread per worker process: with several processes per core, multi-threaded
# BLAS spins and a length-20,000 dot product takes milliseconds instead of microseconds.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import traceback  # noqa: E402
from collections import Counter  # noqa: E402
from multiprocessing import Pool  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from common import print_outcomes, solver_names  # noqa: E402

import lcpbench  # noqa: E402
from lcpbench.problems.hard import planted_b, random_spd_matrix  # noqa: E402
from lcpbench.problems.inexact import inexact_inverse, stiffness  # noqa: E402
from lcpbench.problems.infeasible import infeasible_lcp, unbounded_lcp  # noqa: E402
from lcpbench.problems.random import with_perturbed_lows  # noqa: E402

KINDS = ("spd", "singular-psd", "degenerate", "bad-scale")
FAMILIES = ("classic", "infeasible", "unbounded", "rank1-tiny", "inexact", "huge-sparse",
            "mixed-scale")
MULTI = {"bi-pqn": "bi-pqn:low=low", "multi-pqn": "multi-pqn:lows=[low,lower]"}
#: Relative errors and declared costs of the sparse low fidelities (as PERTURBED_LOWS).
SPARSE_LOWS = (("low", 1e-3, 0.1), ("lower", 1e-2, 0.01))


def _planted(rng: np.random.Generator, A, n: int, degenerate: bool = False) -> np.ndarray:
    x = np.zeros(n)
    w = np.zeros(n)
    role = rng.integers(0, 3 if degenerate else 2, n)   # 0 active, 1 inactive, 2 both 0
    x[role == 0] = rng.uniform(0.1, 2.0, int((role == 0).sum()))
    w[role == 1] = rng.uniform(0.1, 2.0, int((role == 1).sum()))
    return w - A @ x if sp.issparse(A) else planted_b(A, x, w)


def _classic(rng: np.random.Generator, i: int, seed: int) -> lcpbench.LCP:
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
        b = _planted(rng, A, n, degenerate=kind == "degenerate")
    return lcpbench.LCP((A + A.T) / 2, b, name=f"fuzz-{seed}-{i}-{kind}",
                        meta={"kind": kind, "solvable": True})


def _rank1_tiny(rng: np.random.Generator) -> lcpbench.LCP:
    n = int(rng.integers(2, 5))
    u = rng.standard_normal(n) * 10 ** rng.uniform(-2, 2)
    b = rng.standard_normal(n)
    # Solvable iff feasible; infeasible iff some d >= 0 has u'd = 0 and b'd < 0 (an LP).
    from scipy.optimize import linprog

    lp = linprog(b, A_eq=u[None, :], b_eq=[0.0], bounds=[(0, 1)] * n, method="highs")
    solvable = not (lp.status == 0 and lp.fun < -1e-9)
    return lcpbench.LCP(np.outer(u, u), b, name="rank1-tiny",
                        meta={"kind": "rank1-tiny", "solvable": solvable})


def _inexact(rng: np.random.Generator) -> lcpbench.LCP:
    n = int(rng.integers(5, 61))
    rtol = float(10 ** rng.uniform(-10, -4))
    K = stiffness(rng, n, 1e-2)
    high = lcpbench.Operator(inexact_inverse(K, rtol), rtol=rtol, cost=1.0)
    low = {"low": lcpbench.Operator(inexact_inverse(K, min(1e-2, 100 * rtol)),
                                    rtol=min(1e-2, 100 * rtol), cost=0.3),
           "lower": lcpbench.Operator(inexact_inverse(K, min(1e-1, 1e4 * rtol)),
                                      rtol=min(1e-1, 1e4 * rtol), cost=0.1)}
    return lcpbench.LCP(high, rng.standard_normal(n), low=low, name="inexact",
                        meta={"kind": "inexact", "rtol": rtol, "solvable": True})


def _huge_sparse(rng: np.random.Generator) -> lcpbench.LCP:
    n = int(10 ** rng.uniform(3, np.log10(20000)))
    off = -rng.uniform(0.1, 1.0, n - 1)
    main = np.abs(np.concatenate([off, [0.0]])) + np.abs(np.concatenate([[0.0], off])) \
        + 10 ** rng.uniform(-4, 0)
    A = sp.diags([off, main, off], [-1, 0, 1], format="csr")
    b = _planted(rng, A, n)
    low = {}
    for name, rel, cost in SPARSE_LOWS:
        low[name] = lcpbench.Operator(A + sp.diags(rel * rng.uniform(-1, 1, n) * main),
                                      cost=cost, name=name)
    return lcpbench.LCP(lcpbench.Operator(A, cost=1.0), b, low=low, name="huge-sparse",
                        meta={"kind": "huge-sparse", "solvable": True}, psd_check=False)


def _mixed_scale(rng: np.random.Generator) -> lcpbench.LCP:
    n = int(rng.integers(2, 41))
    S = random_spd_matrix(rng, n, float(10 ** rng.uniform(0, 3)))
    D = 10 ** rng.uniform(-4, 4, n)
    A = (D[:, None] * S) * D[None, :]
    A = (A + A.T) / 2
    return lcpbench.LCP(A, _planted(rng, A, n), name="mixed-scale",
                        meta={"kind": "mixed-scale", "solvable": True})


def make_case(i: int, seed: int = 0, family: str = "classic") -> lcpbench.LCP:
    """Case ``i`` of ``family`` (deterministic in ``(seed, i)``; classic as before)."""
    if family == "classic":
        rng = np.random.default_rng([seed, i])
        lcp = _classic(rng, i, seed)
        return with_perturbed_lows(lcp, seed=i)
    rng = np.random.default_rng([seed, i, FAMILIES.index(family)])
    if family == "infeasible":
        lcp = infeasible_lcp(rng, int(rng.integers(2, 41)))
        lcp.meta.update(kind="infeasible", solvable=False)
    elif family == "unbounded":
        lcp = unbounded_lcp(rng, int(rng.integers(1, 41)))
        lcp.meta.update(kind="unbounded", solvable=False)
    elif family == "rank1-tiny":
        lcp = _rank1_tiny(rng)
    elif family == "inexact":
        return _inexact(rng)
    elif family == "huge-sparse":
        return _huge_sparse(rng)
    elif family == "mixed-scale":
        lcp = _mixed_scale(rng)
    else:
        raise ValueError(f"unknown family {family!r}; use one of {', '.join(FAMILIES)}")
    return with_perturbed_lows(lcp, seed=i)


def mvp_solvers() -> list[str]:
    return solver_names(mvp_only=True)


def classify(res: lcpbench.SolveResult, solvable: bool) -> str:
    """The outcome class of one run (see the module docstring)."""
    if res.status.value == "converged":
        refuted = not (res.verified_kkt_abs <= res.threshold)
        return "false" if refuted or not solvable else "solved"
    if res.status.value == "infeasible":
        return "infeasible" if not solvable else "false-infeasible"
    return "solved" if res.solved and solvable else "honest"


def run_case(args: tuple) -> list[tuple[str, str, str, str]]:
    """``(kind, solver, outcome, detail)`` for every solver (or the named ones) on case ``i``."""
    i, seed, max_emvps, max_seconds, only, family = args
    out = []
    try:
        lcp = make_case(i, seed, family)
    except Exception:
        return [("?", "(generator)", "crash", traceback.format_exc(limit=3))]
    kind = lcp.meta["kind"]
    for name in mvp_solvers():
        if only and name not in only:
            continue
        spec = MULTI.get(name, name)
        try:
            res = lcpbench.solve(lcp, solver=spec, tol=1e-8, max_emvps=max_emvps,
                                 max_seconds=max_seconds)
        except Exception:
            out.append((kind, name, "crash", f"case {i}: {traceback.format_exc(limit=3)}"))
            continue
        outcome = classify(res, bool(lcp.meta["solvable"]))
        detail = f"case {i}: {res.summary()}" if outcome in ("false", "false-infeasible") \
            else res.status.value
        out.append((kind, name, outcome, detail))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=1000, help="number of random LCPs")
    ap.add_argument("--family", default="classic", choices=FAMILIES,
                    help="classic (the four kinds in turn, default) or one adversarial family")
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
    ap.add_argument("--max-seconds", type=float, default=10.0,
                    help="wall-time budget per solve (default 10; status timeout when it runs out)")
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
    work = [(i, args.seed, args.max_emvps, args.max_seconds, only, args.family)
            for i in range(args.start, args.start + args.cases)]
    with Pool(args.jobs) as pool:
        for rows in tqdm(pool.imap_unordered(run_case, work, chunksize=4), total=len(work),
                         unit="case", file=sys.stderr):
            for kind, name, outcome, detail in rows:
                counts[(name, outcome)] += 1
                if outcome in ("false", "false-infeasible", "crash"):
                    problems.append(f"{name} on {kind} {detail}")
    head = (f"family {args.family}, cases {args.start}..{args.start + args.cases - 1} "
            f"(seed {args.seed}), tol 1e-8, paper's stop rule, budget {args.max_emvps:g} "
            f"E-MVPs and {args.max_seconds:g} s per solve"
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


OUTCOMES = ("solved", "honest", "infeasible", "false", "false-infeasible", "crash")


def report(head: str, counts: Counter, problems: list[str]) -> int:
    """Print the table; 1 if any run was a false claim or a crash."""
    columns = dict(zip(OUTCOMES, ("solved", "honest failure", "infeasible (found)",
                                  "false converged", "false infeasible", "crash")))
    return print_outcomes(head, counts, sorted({n for n, _ in counts}), columns,
                          problems=problems, bad={"false": "false converged",
                                                  "false-infeasible": "false infeasible",
                                                  "crash": "crashes"})


if __name__ == "__main__":
    sys.exit(main())
