"""What confirming ``converged`` costs on the shipped sets: runs that paid a fresh product.

Usage::

    python benchmarks/confirmations.py            # every shipped set, lcpbench check's solvers

Runs ``lcpbench check`` (default tolerance and budget) with a recorder around
each solve and prints, per solver, how many converged runs were accepted on
the solver's certified drift bound, on the operator's own last product at the
returned ``x`` (both free), or after a fresh counted product, how many claims
that product refuted, and the extra E-MVPs per run.
"""

from __future__ import annotations

import sys
from collections import defaultdict

import lcpbench.core.api as api
from lcpbench.workflows.check import check


def main() -> int:
    real = api.run_solver
    tally: dict = defaultdict(lambda: defaultdict(int))

    def recording(lcp, solver, **kw):
        res = real(lcp, solver, **kw)
        t = tally[solver.split(":")[0]]
        t["runs"] += 1
        extra = int(res.info.get("confirmation_mvps", 0))
        t["extra_mvps"] += extra
        if res.info.get("refuted_convergence"):
            t["refuted"] += 1
        elif res.status.value == "converged":
            t["bound" if res.info.get("confirmed_by") == "drift bound"
              else "fresh" if extra else "last product"] += 1
        return res

    api.run_solver = recording
    try:
        check(progress=False)
    finally:
        api.run_solver = real
    print("| solver | runs | converged: drift bound | converged: last product | "
          "converged: fresh product | refuted | extra MVPs per run |")
    print("|---|---|---|---|---|---|---|")
    for name in sorted(tally):
        t = tally[name]
        print(f"| {name} | {t['runs']} | {t['bound']} | {t['last product']} | {t['fresh']} | "
              f"{t['refuted']} | {t['extra_mvps'] / t['runs']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
