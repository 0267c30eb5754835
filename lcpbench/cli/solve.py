"""``lcpbench solve``: every instance of one problem family with one or more solvers."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from lcpbench.cli.options import add_force_option, add_stop_options, guard_problem
from lcpbench.core.defaults import DEFAULT_SOLVER, EXAMPLE_PROBLEM
from lcpbench.core.guards import dense_refusal
from lcpbench.core.registry import get_problem, solvers
from lcpbench.core.specs import make_params, parse_spec

__all__ = ["add_solve_parser", "cmd_solve"]


_SOLVE_DESCRIPTION = """
Generate the instances of a problem family and solve each with every --solver; prints
status, E-MVPs, verified residual and time per run.
"""


def add_solve_parser(sub) -> None:
    """Add ``lcpbench solve`` to the subcommands ``sub``."""
    p = sub.add_parser("solve", help="solve the instances of one problem family with solvers",
                       description=_SOLVE_DESCRIPTION)
    p.add_argument("--problem", default=EXAMPLE_PROBLEM, metavar="NAME[:k=v,...]",
                   help=f"problem family spec (default {EXAMPLE_PROBLEM})")
    p.add_argument("--solver", action="append", default=None, metavar="NAME[:k=v,...]",
                   help=f"solver spec, repeatable (default {DEFAULT_SOLVER})")
    p.add_argument("--instance", type=int, default=None, metavar="I",
                   help="solve only instance I of the family (0-based)")
    add_stop_options(p)
    p.add_argument("--json", action="store_true", help="one JSON object per solve")
    add_force_option(p)
    p.set_defaults(func=cmd_solve)


def cmd_solve(args: argparse.Namespace) -> int:
    from lcpbench.core.api import requested_lows, run_solver
    from lcpbench.core.context import Budget
    from lcpbench.core.residuals import make_stop_rule

    name, raw = parse_spec(args.problem)
    info = get_problem(name)
    params = make_params(name, info.params, raw)
    specs = args.solver or [DEFAULT_SOLVER]
    for spec in specs:            # a bad solver spec is reported before the problem is built
        sname, sraw = parse_spec(spec)
        make_params(sname, (solvers().get(sname) or _unknown_solver(sname)).params, sraw)
    guard_problem("solve", args.problem, name, params, force=args.force)
    lcps = info.func(params)
    if args.instance is not None:
        if not 0 <= args.instance < len(lcps):
            raise ValueError(f"--instance {args.instance} is out of range: {args.problem} "
                             f"has {len(lcps)} instance(s), 0..{len(lcps) - 1}")
        lcps = [lcps[args.instance]]
    for spec in specs:            # fail on a low name or a dense A too large before any solve
        sname, sraw = parse_spec(spec)
        sinfo = solvers()[sname]
        sparams = make_params(sname, sinfo.params, sraw)
        for lcp in lcps:
            missing = [n for n in requested_lows(dataclasses.asdict(sparams), sname)
                       if n not in lcp.low]
            if lcp.low and missing:
                raise ValueError(f"solver {spec!r}: no low fidelity {missing[0]!r} on "
                                 f"{lcp.name} (it has: {', '.join(sorted(lcp.low))})")
            refused = sinfo.needs_dense and dense_refusal(
                sname, lcp.n, matrix_free=not lcp.A.explicit, force=args.force)
            if refused:
                raise ValueError(f"{lcp.name}: {refused}")
    make_stop_rule(args.stop, args.tol)
    budget = Budget(max_emvps=args.max_emvps)
    rows = []
    for lcp in lcps:
        for spec in specs:
            if solvers()[parse_spec(spec)[0]].multifidelity and not lcp.low:
                print(f"lcpbench solve: skipping {spec} on {lcp.name}: the instance has no "
                      "low-fidelity operators", file=sys.stderr)
                continue
            res = run_solver(lcp, spec, stop=args.stop, tol=args.tol, budget=budget,
                             force=args.force)
            row = {"instance": lcp.name, "n": lcp.n, "solver": spec, "status": res.status.value,
                   "solved": bool(res.solved), "emvps": round(float(res.emvps), 3),
                   "mvps": int(res.mvps), "iterations": int(res.iterations),
                   "verified_kkt_abs": float(res.verified_kkt_abs),
                   "time_s": round(float(res.time_s), 4), "message": res.message}
            rows.append(row)
            if args.json:
                print(json.dumps(row))
    if not rows:
        raise ValueError(f"nothing was solved: {', '.join(specs)} need(s) low-fidelity operators "
                         f"and {args.problem} has none; try --problem bifidelity")
    if not args.json:
        _print_table(rows)
    return 0


def _unknown_solver(name: str):
    from lcpbench.core.registry import get_solver
    return get_solver(name)        # raises the registry's KeyError with suggestions


def _print_table(rows: list[dict]) -> None:
    from tabulate import tabulate

    cols = ["instance", "n", "solver", "status", "emvps", "iterations", "verified_kkt_abs",
            "time_s"]
    print(tabulate([[r[c] for c in cols] for r in rows], headers=cols, floatfmt=".3g"))
    failed = [r for r in rows if not r["solved"]]
    if failed:
        print(f"\n{len(failed)} of {len(rows)} solve(s) did not meet the stop rule "
              "(status says why; see --json for messages)")
