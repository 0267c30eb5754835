"""The ``lcpbench run`` and ``lcpbench report`` subcommands.

Everything a user can get wrong is checked before the run store is created:
the sweep's values and budgets, every solver and problem spec, the instances
(a missing or damaged stored set), the low-fidelity names a multi-fidelity
solver asks for, the executor and the ``--out`` folder. A bad input therefore
leaves nothing behind in ``--out``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import math
import os
import sys
from datetime import datetime
from pathlib import Path
from typing import Optional

from lcpbench.cli.options import add_spec_option, add_stop_options
from lcpbench.core import guards
from lcpbench.core.api import requested_lows
from lcpbench.core.clock import utc_now
from lcpbench.core.context import Budget
from lcpbench.core.defaults import BASELINE_SOLVER
from lcpbench.core.registry import get_solver
from lcpbench.report.render import render_report, stderr_progress
from lcpbench.run.runner import Plan, describe_counts, execute, git_commit, machine_info, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep, default_sweep, estimate_sweep, load_config

__all__ = ["add_run_parser", "add_report_parser", "cmd_run", "cmd_report", "build_sweep",
           "check_plan", "check_out_dir", "check_not_foreign", "out_folder"]

#: Files that mark a folder as a run store (``lcpbench run`` or ``simulate`` wrote it).
STORE_MARKERS = ("results.csv", "meta.json", "history.csv", ".lock", "checkpoints")


_RUN_DESCRIPTION = """
Run every solver on every problem instance, verify each answer, append rows to
DIR/results.csv and render DIR/report.html. Without --solver and --problem: every
MVP-only and reference solver on the default problem set. Re-running into the same DIR
resumes.
"""


def add_run_parser(sub) -> None:
    p = sub.add_parser(
        "run", help="sweep solvers x problems into a run store, then write the HTML report",
        description=_RUN_DESCRIPTION)
    add_spec_option(p, "solver", many=True,
                    help="solver spec, repeatable; a value in brackets sweeps: bi-pqn:low=[p3,p4]")
    add_spec_option(p, "problem", many=True,
                    help="problem spec, repeatable (values in brackets sweep)")
    p.add_argument("--config", metavar="SWEEP.toml", help="sweep file (see sweeps/)")
    add_stop_options(p, tol=None, stop=None, max_emvps=None, per="run")
    p.add_argument("--repeat", type=int, default=None, help="runs per (instance, solver)")
    p.add_argument("--seed", type=int, default=None,
                   help="seed for problem families that take one (default 0)")
    p.add_argument("--out", metavar="DIR", help="run store folder (default: a new folder "
                                                 "under reports/)")
    p.add_argument("--jobs", type=int, default=1, help="parallel worker processes (>= 1)")
    p.add_argument("--timeout", type=float, default=None, metavar="SECONDS",
                   help="per-run wall-time limit; a run over it is recorded as timeout. "
                        "Each QP backend of an instance's reference gets it too (without "
                        "it: 10 s + 20 s x (n/1000)^3), in a child killed at the limit")
    p.add_argument("--force", action="store_true",
                   help="run into a DIR whose stored configuration differs, and past the "
                        "memory, time and sweep-size limits (estimated before any work)")
    p.add_argument("--no-report", action="store_true", help="do not render report.html")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_run)


_REPORT_DESCRIPTION = """
Render DIR/report.html and DIR/tables/ from a run store. The fidelity study of stored
sets is computed once per set and cached in $XDG_CACHE_HOME/lcpbench (default
~/.cache/lcpbench), so re-rendering takes seconds.
"""


def add_report_parser(sub) -> None:
    p = sub.add_parser("report", help="render DIR/report.html from a run store",
                       description=_REPORT_DESCRIPTION)
    p.add_argument("dir", metavar="DIR")
    p.add_argument("--baseline", default=BASELINE_SOLVER,
                   help="solver the offline ratios and online speedups are measured against")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
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
    sweep = Sweep(**cfg)
    if not math.isfinite(float(sweep.tol)):
        raise ValueError(f"tol must be a finite number > 0, got {sweep.tol}")
    Budget(max_emvps=sweep.max_emvps)          # the budget's own check, before any run
    return sweep


def out_folder(given: Optional[str], default: Path, flag: str = "--out") -> Path:
    """The ``--out`` folder: the given one (an empty name refused), else ``default``.

    Raises
    ------
    ValueError
        For ``--out ''`` (which would otherwise fall back to the default folder).
    """
    if given is None:
        return default
    if not given.strip():
        raise ValueError(f"{flag} {given!r}: an empty folder name; give a folder, e.g. "
                         f"{flag} {default.parent / 'my-run'}")
    return Path(given)


def check_out_dir(out: Path, flag: str = "--out") -> None:
    """Refuse an ``--out`` that is a file or cannot be created or written.

    Raises
    ------
    ValueError
        With one line naming the folder and what to do.
    """
    if out.exists() and not out.is_dir():
        raise ValueError(f"{flag} {out} exists and is not a folder; choose another {flag}")
    parent = out if out.exists() else next((p for p in out.parents if p.exists()), Path("."))
    if not parent.is_dir():
        raise ValueError(f"{flag} {out}: {parent} is not a folder; choose another {flag}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{flag} {out}: {parent} is not writable; choose another {flag}")
    check_not_foreign(out, flag)


def check_not_foreign(out: Path, flag: str = "--out") -> None:
    """Refuse an ``--out`` folder that holds files but is not a run store.

    A run store is written beside nothing else: an existing folder of the user's own
    (no ``results.csv``, ``meta.json``, ``history.csv``, lock or ``checkpoints``) is not
    written into.

    Raises
    ------
    ValueError
        Naming the folder, one of its files and what to do.
    """
    if not out.is_dir() or any((out / m).exists() for m in STORE_MARKERS):
        return
    own = sorted(p.name for p in out.iterdir())
    if own:
        raise ValueError(f"{flag} {out} is a folder of other files (e.g. {own[0]}), not a run "
                         f"store; give a new or empty folder, e.g. {out / 'lcpbench-run'}")


def check_plan(p: Plan, *, force: bool = False) -> None:
    """Low-fidelity names a solver asks for must exist on the instances it runs on, and
    a solver that needs the dense A must get one within the limit (unless ``force``).

    Raises
    ------
    ValueError
        Naming the solver, the missing name, the problem and its low fidelities; or the
        instance and the size of its dense A.
    """
    for run in p.runs:
        if get_solver(run.solver.name).needs_dense:
            lcp = p.lcp(run)
            refused = guards.dense_refusal(run.solver.name, lcp.n,
                                           matrix_free=not lcp.A.explicit, force=force)
            if refused:
                raise ValueError(f"{run.problem.label}/{lcp.name}: {refused}")
        names = requested_lows(run.solver.params, run.solver.name)
        if not names:
            continue
        lcp = p.lcp(run)
        missing = [n for n in names if n not in lcp.low]
        if missing:
            raise ValueError(f"solver {run.solver.label!r}: no low fidelity {missing[0]!r} on "
                             f"{run.problem.label} (it has: {', '.join(sorted(lcp.low))}); "
                             "see `lcpbench list problems`")


def _check_executor(args: argparse.Namespace) -> None:
    if args.jobs < 1:
        raise ValueError(f"--jobs {args.jobs}: the number of worker processes must be >= 1")
    if getattr(args, "executor", None) == "dask" and \
            importlib.util.find_spec("distributed") is None:
        raise ValueError("--executor dask needs dask.distributed, which is not installed: "
                         "pip install -e \".[dask]\" (or use --executor process)")


def cmd_run(args: argparse.Namespace) -> int:
    sweep = build_sweep(args)
    _check_executor(args)
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    out = out_folder(args.out, Path("reports") / f"run-{stamp}")
    check_out_dir(out)
    est = estimate_sweep(sweep, force=args.force, progress=not args.quiet)
    if not args.quiet:
        print(f"lcpbench run: planning {len(sweep.solvers)} solver spec(s) x "
              f"{len(sweep.problems)} problem spec(s) into {out}", file=sys.stderr)
        if est.seconds > guards.NOTE_AFTER_S:
            print(f"lcpbench run: about {est.runs:,} runs on {est.instances:,} instance(s); "
                  f"planning takes about {guards.format_seconds(est.seconds)}", file=sys.stderr)
    p = plan(sweep, progress=not args.quiet)
    check_plan(p, force=args.force)
    store = RunStore(out)
    with store.lock(), _forced(args.force):
        return _run_locked(args, sweep, p, store, out)


@contextlib.contextmanager
def _forced(force: bool):
    """Set :data:`lcpbench.core.guards.FORCE_ENV` while the runs of a ``--force`` sweep execute,
    so that solves in this process and in the workers it starts lift the dense limit too."""
    if not force:
        yield
        return
    old = os.environ.get(guards.FORCE_ENV)
    os.environ[guards.FORCE_ENV] = "1"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(guards.FORCE_ENV, None)
        else:
            os.environ[guards.FORCE_ENV] = old


def _run_locked(args: argparse.Namespace, sweep: Sweep, p: Plan, store: RunStore,
                out: Path) -> int:
    old = store.read_meta()
    config = sweep.config()
    if old is not None and old.get("config") != config and not args.force:
        raise ValueError(
            f"{out} holds a sweep with a different configuration (stored: "
            f"{old.get('config')}; now: {config}); choose another --out, or pass --force "
            "to add this sweep's rows to it (rows are keyed by run, nothing is overwritten)")
    quiet = args.quiet
    meta = {"argv": ["lcpbench"] + list(args.argv), "config": config,
            "timeout": sweep.timeout, "jobs": args.jobs,
            "executor": getattr(args, "executor", None)
            or ("process" if args.jobs > 1 else "local"),
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
        html = render_report(out, progress=None if quiet else stderr_progress())
        print(f"report: {html}")
    else:
        print(f"results: {out / 'results.csv'}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    folder = Path(args.dir)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder} is a file, not a run store folder; give the DIR that "
                         "`lcpbench run --out DIR` wrote")
    _check_baseline(args.baseline)
    html = render_report(folder, baseline=args.baseline,
                         progress=None if args.quiet else stderr_progress())
    print(f"report: {html}")
    return 0


def _check_baseline(baseline: str) -> None:
    """Refuse a ``--baseline`` that names no registered solver, before the report is written.

    Raises
    ------
    ValueError
        Naming the value and the closest solver names.
    """
    import difflib

    from lcpbench.core.registry import solvers
    from lcpbench.core.specs import parse_spec

    name = parse_spec(baseline)[0]
    known = sorted(solvers())
    if name not in known:
        close = difflib.get_close_matches(name, known, n=2)
        hint = f"did you mean {' or '.join(close)}? " if close else ""
        raise ValueError(f"--baseline {baseline!r} is no solver; {hint}the report was not "
                         f"written (solvers: {', '.join(known)})")
