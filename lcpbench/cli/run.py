"""The ``lcpbench run`` and ``lcpbench report`` subcommands."""

from __future__ import annotations

import argparse
import sys
from datetime import datetime
from pathlib import Path

from lcpbench.core.defaults import BASELINE_SOLVER
from lcpbench.core.residuals import STOP_RULES
from lcpbench.report.render import render_report
from lcpbench.run.runner import describe_counts, execute, git_commit, machine_info, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep, default_sweep, load_config
from lcpbench.core.clock import utc_now

__all__ = ["add_run_parser", "add_report_parser", "cmd_run", "cmd_report", "build_sweep"]


def add_run_parser(sub) -> None:
    p = sub.add_parser(
        "run", help="sweep solvers x problems into a run store, then write the HTML report",
        description="Run every solver on every problem instance, verify each answer, append "
                    "rows to DIR/results.csv and render DIR/report.html. Without --solver and "
                    "--problem: every MVP-only and reference solver on the default problem "
                    "set. Re-running into the same DIR resumes.")
    p.add_argument("--solver", action="append", default=None, metavar="NAME[:k=v,...]",
                   help="solver spec, repeatable; a value in brackets sweeps: bi-pqn:low=[p3,p4]")
    p.add_argument("--problem", action="append", default=None, metavar="NAME[:k=v,...]",
                   help="problem spec, repeatable (values in brackets sweep)")
    p.add_argument("--config", metavar="SWEEP.toml", help="sweep file (see sweeps/)")
    p.add_argument("--tol", type=float, default=None, help="stop-rule tolerance (default 1e-8)")
    p.add_argument("--stop", choices=STOP_RULES, default=None,
                   help="stop rule (default paper)")
    p.add_argument("--repeat", type=int, default=None, help="runs per (instance, solver)")
    p.add_argument("--seed", type=int, default=None,
                   help="seed for problem families that take one (default 0)")
    p.add_argument("--max-emvps", type=float, default=None, help="E-MVP budget per run")
    p.add_argument("--out", metavar="DIR", help="run store folder (default: a new folder "
                                                 "under reports/)")
    p.add_argument("--jobs", type=int, default=1, help="parallel worker processes")
    p.add_argument("--timeout", type=float, default=None, metavar="SECONDS",
                   help="per-run wall-time limit; a run over it is recorded as timeout")
    p.add_argument("--force", action="store_true",
                   help="run into a DIR whose stored configuration differs")
    p.add_argument("--no-report", action="store_true", help="do not render report.html")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_run)


def add_report_parser(sub) -> None:
    p = sub.add_parser("report", help="render DIR/report.html from a run store")
    p.add_argument("dir", metavar="DIR")
    p.add_argument("--baseline", default=BASELINE_SOLVER,
                   help="solver the online speedups are measured against")
    p.set_defaults(func=cmd_report)


def build_sweep(args: argparse.Namespace) -> Sweep:
    """The sweep from ``--config`` and the command line (the command line wins)."""
    cfg = load_config(args.config) if args.config else {}
    if args.solver:
        cfg["solvers"] = args.solver
    if args.problem:
        cfg["problems"] = args.problem
    for key in ("tol", "stop", "repeat", "seed", "timeout"):
        if getattr(args, key) is not None:
            cfg[key] = getattr(args, key)
    if args.max_emvps is not None:
        cfg["max_emvps"] = args.max_emvps
    if not cfg.get("solvers") or not cfg.get("problems"):
        sv, pb = default_sweep()
        cfg.setdefault("solvers", sv)
        cfg.setdefault("problems", pb)
    return Sweep(**cfg)


def cmd_run(args: argparse.Namespace) -> int:
    sweep = build_sweep(args)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(args.out) if args.out else Path("reports") / f"run-{stamp}"
    store = RunStore(out)
    with store.lock():
        return _run_locked(args, sweep, store, out)


def _run_locked(args: argparse.Namespace, sweep: Sweep, store: RunStore, out: Path) -> int:
    old = store.read_meta()
    config = sweep.config()
    if old is not None and old.get("config") != config and not args.force:
        raise ValueError(
            f"{out} holds a sweep with a different configuration:\n  stored:  "
            f"{old.get('config')}\n  now:     {config}\nchoose another --out, or pass --force "
            "to add this sweep's rows to it (rows are keyed by run, nothing is overwritten)")
    quiet = args.quiet
    if not quiet:
        print(f"lcpbench run: planning {len(sweep.solvers)} solver spec(s) x "
              f"{len(sweep.problems)} problem spec(s) into {out}", file=sys.stderr)
    p = plan(sweep)
    meta = {"argv": ["lcpbench"] + list(args.argv), "config": config,
            "timeout": sweep.timeout, "jobs": args.jobs,
            "executor": getattr(args, "executor", None) or ("process" if args.jobs > 1 else "local"),
            "started": utc_now(),
            "finished": None, "machine": machine_info(), "git_commit": git_commit(),
            "skipped": p.skipped, "previous": (old or {}).get("started")}
    store.write_meta(meta)
    counts = execute(p, store, executor=getattr(args, "executor", None), jobs=args.jobs,
                     timeout=sweep.timeout, scheduler=getattr(args, "scheduler", None),
                     quiet=quiet)
    meta["finished"] = utc_now()
    meta["counts"] = counts
    store.write_meta(meta)
    print(f"lcpbench run: {describe_counts(counts)}", file=sys.stderr)
    if p.skipped and not quiet:
        print(f"lcpbench run: skipped {len(p.skipped)} multi-fidelity run(s) on instances "
              "without low-fidelity operators (listed in meta.json)", file=sys.stderr)
    if not args.no_report:
        html = render_report(out)
        print(f"report: {html}")
    else:
        print(f"results: {out / 'results.csv'}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    html = render_report(args.dir, baseline=args.baseline)
    print(f"report: {html}")
    return 0
