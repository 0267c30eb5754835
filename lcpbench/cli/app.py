"""The ``lcpbench`` command: ``list``, ``solve``, ``run``, ``report``, ``simulate``,
``generate``, ``check``.

Every subcommand returns an exit code; a usage error (unknown solver or
problem, mistyped parameter, missing file, bad value) is printed as one line on
stderr and exits with 2, without a traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import textwrap
from typing import Optional, Sequence

import numpy as np

from lcpbench import __version__
from lcpbench.workflows.check import add_check_parser
from lcpbench.workflows.generate import add_generate_parser
from lcpbench.core.defaults import (DEFAULT_SOLVER, EXAMPLE_PROBLEM, EXAMPLE_SCENE,
                                     SIMULATE_SOLVER)
from lcpbench.core.registry import get_problem, problems, scenes, solvers
from lcpbench.core.specs import describe_params, make_params, parse_spec
from lcpbench.core.residuals import STOP_RULES
from lcpbench.cli.run import add_report_parser, add_run_parser
from lcpbench.run.store import StoreLocked

__all__ = ["main", "build_parser"]


def _add_list_parser(sub) -> None:
    p = sub.add_parser("list", help="registered solvers, problem families and scenes",
                       description="List every registered solver, problem family and scene, "
                                   "with their parameters, types, defaults and documentation.")
    p.add_argument("what", nargs="?", choices=("solvers", "problems", "scenes", "all"),
                   default="all")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--brief", action="store_true", help="names and summaries only")
    p.set_defaults(func=cmd_list)


def _add_solve_parser(sub) -> None:
    p = sub.add_parser("solve", help="solve the instances of one problem family with solvers",
                       description="Generate the instances of a problem family and solve "
                                   "each with every --solver; prints status, E-MVPs, "
                                   "verified residual and time per run.")
    p.add_argument("--problem", default=EXAMPLE_PROBLEM, metavar="NAME[:k=v,...]",
                   help=f"problem family spec (default {EXAMPLE_PROBLEM})")
    p.add_argument("--solver", action="append", default=None, metavar="NAME[:k=v,...]",
                   help=f"solver spec, repeatable (default {DEFAULT_SOLVER})")
    p.add_argument("--instance", type=int, default=None, metavar="I",
                   help="solve only instance I of the family (0-based)")
    p.add_argument("--tol", type=float, default=1e-8, help="stop-rule tolerance (default 1e-8)")
    p.add_argument("--stop", choices=STOP_RULES, default="paper", help="stop rule")
    p.add_argument("--max-emvps", type=float, default=5000.0, help="E-MVP budget per solve")
    p.add_argument("--json", action="store_true", help="one JSON object per solve")
    p.set_defaults(func=cmd_solve)


def _add_simulate_parser(sub) -> None:
    p = sub.add_parser("simulate", help="online run: simulate a scene once per solver",
                       description="Simulate a scene (e.g. lattice:m=3,model=rpy) once per "
                                   "--solver with forward Euler, one LCP per time step, and "
                                   "write a row per step (kind=online) to the run store DIR; "
                                   "`lcpbench report DIR` renders the online table.")
    p.add_argument("--scene", default=EXAMPLE_SCENE, metavar="NAME[:k=v,...]",
                   help=f"scene spec (default {EXAMPLE_SCENE}; low=[self] adds a "
                        "low-fidelity operator for multi-fidelity solvers)")
    p.add_argument("--solver", action="append", default=None, metavar="NAME[:k=v,...]",
                   help="solver spec, repeatable: one simulation each (default bb-pgd)")
    p.add_argument("--steps", type=int, default=50, help="time steps per simulation (default 50)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="run-store folder (default reports/simulate-<time>)")
    p.add_argument("--tol", type=float, default=1e-8, help="stop-rule tolerance (default 1e-8)")
    p.add_argument("--stop", choices=STOP_RULES, default="paper", help="stop rule")
    p.add_argument("--max-emvps", type=float, default=5000.0, help="E-MVP budget per solve")
    p.add_argument("--overlap-tol", type=float, default=None,
                   help="largest acceptable overlap after a step, as a fraction of the "
                        "smallest radius (default 0.01)")
    p.add_argument("--no-warm-start", action="store_true",
                   help="start every solve from zero instead of the previous step's forces")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_simulate)


def _extend_run_parser(sub) -> None:
    run = sub.choices["run"]
    run.add_argument("--executor", choices=("local", "process", "dask"), default=None,
                     help="where runs execute (default: process when --jobs > 1, else local)")
    run.add_argument("--scheduler", default=None, metavar="ADDRESS",
                     help="dask scheduler address (with --executor dask; default: a "
                          "LocalCluster of --jobs workers)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``lcpbench`` command."""
    parser = argparse.ArgumentParser(
        prog="lcpbench",
        description="Benchmark suite and reference solvers for symmetric LCPs "
                    "(0 <= x _|_ A x + b >= 0) where every product with A is counted.")
    parser.add_argument("--version", action="version", version=f"lcpbench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_list_parser(sub)
    _add_solve_parser(sub)
    add_run_parser(sub)
    _extend_run_parser(sub)
    add_report_parser(sub)
    _add_simulate_parser(sub)
    add_generate_parser(sub)
    add_check_parser(sub)
    return parser


# ----------------------------------------------------------------------------- list


def _entry(info, kind: str) -> dict:
    out = {"name": info.name, "kind": kind, "summary": info.summary,
           "params": [{"name": n, "type": t, "default": _jsonable(d), "doc": doc}
                      for n, t, d, doc in describe_params(info.params)]}
    if kind == "solver":
        out.update(needs_dense=info.needs_dense, reference=info.reference,
                   multifidelity=info.multifidelity)
    elif kind == "problem":
        out["default"] = info.default
    return out


def _jsonable(v):
    if isinstance(v, (tuple, list)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


def _tags(e: dict) -> str:
    tags = []
    if e["kind"] == "solver":
        if e["reference"]:
            tags.append("reference")
        if e["needs_dense"]:
            tags.append("needs dense A")
        if e["multifidelity"]:
            tags.append("multi-fidelity")
    elif e.get("default"):
        tags.append("default set")
    return f"  [{', '.join(tags)}]" if tags else ""


def cmd_list(args: argparse.Namespace) -> int:
    entries = []
    if args.what in ("solvers", "all"):
        entries += [_entry(i, "solver") for _, i in sorted(solvers().items())
                    if i.listed]
    if args.what in ("problems", "all"):
        entries += [_entry(i, "problem") for _, i in sorted(problems().items())]
    if args.what in ("scenes", "all"):
        entries += [_entry(i, "scene") for _, i in sorted(scenes().items())]
    if args.json:
        print(json.dumps(entries, indent=2, default=str))
        return 0
    kind = None
    for e in entries:
        if e["kind"] != kind:
            kind = e["kind"]
            title = {"solver": "Solvers", "problem": "Problem families",
                     "scene": "Scenes (lcpbench simulate / generate --scene)"}[kind]
            print(f"\n{title}:")
        print(f"  {e['name']:<16} {e['summary']}{_tags(e)}")
        if args.brief:
            continue
        for prm in e["params"]:
            print(f"      {prm['name']}: {prm['type']} = {prm['default']!r}")
            if prm["doc"]:
                print(textwrap.fill(prm["doc"], width=100, initial_indent=" " * 10,
                                    subsequent_indent=" " * 10, break_on_hyphens=False))
    print("\nUse as NAME:key=value,...  e.g.  bi-pqn:low=p4,inner_rtol=0.01")
    return 0


# ----------------------------------------------------------------------------- solve


def cmd_solve(args: argparse.Namespace) -> int:
    from lcpbench.core.api import requested_lows, run_solver
    from lcpbench.core.context import Budget
    from lcpbench.core.residuals import make_stop_rule

    name, raw = parse_spec(args.problem)
    info = get_problem(name)
    lcps = info.func(make_params(name, info.params, raw))
    if args.instance is not None:
        if not 0 <= args.instance < len(lcps):
            raise ValueError(f"--instance {args.instance} is out of range: {args.problem} "
                             f"has {len(lcps)} instance(s), 0..{len(lcps) - 1}")
        lcps = [lcps[args.instance]]
    specs = args.solver or [DEFAULT_SOLVER]
    for spec in specs:            # fail on a bad spec or low name before any work
        sname, sraw = parse_spec(spec)
        sinfo = solvers().get(sname)
        sparams = make_params(sname, (sinfo or _unknown_solver(sname)).params, sraw)
        for lcp in lcps:
            missing = [n for n in requested_lows(dataclasses.asdict(sparams)) if n not in lcp.low]
            if lcp.low and missing:
                raise ValueError(f"solver {spec!r}: no low fidelity {missing[0]!r} on "
                                 f"{lcp.name} (it has: {', '.join(sorted(lcp.low))})")
    make_stop_rule(args.stop, args.tol)
    budget = Budget(max_emvps=args.max_emvps)
    rows = []
    for lcp in lcps:
        for spec in specs:
            if solvers()[parse_spec(spec)[0]].multifidelity and not lcp.low:
                print(f"lcpbench solve: skipping {spec} on {lcp.name}: the instance has no "
                      "low-fidelity operators", file=sys.stderr)
                continue
            res = run_solver(lcp, spec, stop=args.stop, tol=args.tol, budget=budget)
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


# ----------------------------------------------------------------------------- simulate


def cmd_simulate(args: argparse.Namespace) -> int:
    from datetime import datetime
    from pathlib import Path

    from lcpbench.workflows.simulate import DEFAULT_OVERLAP_TOL, Interrupted, simulate

    out = Path(args.out) if args.out else \
        Path("reports") / f"simulate-{datetime.now().strftime('%Y%m%d-%H%M%S')}"
    try:
        rows = simulate(args.scene, args.solver or [SIMULATE_SOLVER], args.steps, out,
                        warm_start=not args.no_warm_start, progress=not args.quiet,
                        tol=args.tol, stop=args.stop, max_emvps=args.max_emvps,
                        overlap_tol=DEFAULT_OVERLAP_TOL if args.overlap_tol is None
                        else args.overlap_tol,
                        argv=["lcpbench"] + list(getattr(args, "argv", [])))
    except Interrupted as exc:
        print(f"lcpbench simulate: {exc}", file=sys.stderr)
        return 143
    for solver, g in rows.groupby("solver", sort=False):
        solved = int(g["solved"].astype(bool).sum())
        print(f"{solver}: {len(g)} step(s), {solved} solved, median n "
              f"{float(g['n'].median()):.0f}, median E-MVPs {float(g['emvps'].median()):.2f}, "
              f"collision {float(g['time_s'].sum()):.3g} s of {float(g['sim_total_s'].sum()):.3g}"
              f" s, max overlap {float(g['max_overlap'].max()):.3g}")
    print(f"results: {out / 'results.csv'}")
    return 0


# ----------------------------------------------------------------------------- main


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``lcpbench`` command; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    args.argv = argv
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("lcpbench: interrupted; rows already written are kept (re-run to resume)",
              file=sys.stderr)
        return 130
    except _user_errors() as exc:
        print(f"lcpbench {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2


def _user_errors() -> tuple:
    """Exceptions that mean bad input (a spec, a value, a file): one line and exit 2."""
    from lcpbench.sets import StoredSetError

    return (KeyError, ValueError, TypeError, OSError, ImportError, StoreLocked, StoredSetError)


def _one_line(exc: BaseException) -> str:
    """The exception's message on one line (a missing module gets the install hint)."""
    msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
    if isinstance(exc, ImportError) and getattr(exc, "name", None):
        msg = f"{msg}; install it (pip install -e \".[test]\" has every optional dependency)"
    elif isinstance(exc, OSError) and getattr(exc, "filename", None) and exc.strerror:
        msg = f"{exc.filename}: {exc.strerror}"
    return "; ".join(part.strip() for part in str(msg).splitlines() if part.strip())

