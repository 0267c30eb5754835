"""``lcpbench check``: regression checks on the shipped sets (see lcpbench.workflows.check)."""

from __future__ import annotations

import sys

from lcpbench.cli.options import add_spec_option, add_stop_options
from lcpbench.workflows.check import EMVP_SLACK, W_RTOL, check, default_baseline, format_table

__all__ = ["add_check_parser", "cmd_check"]


_CHECK_DESCRIPTION = f"""
Run every MVP-only solver with its defaults on every shipped set; exit 1 with a table of
what regressed when a verified residual exceeds --tol, w differs from the stored reference
by more than {W_RTOL:g} relative, or a median E-MVP count exceeds its baseline by more
than {EMVP_SLACK:.0%}.
"""


def add_check_parser(sub) -> None:
    """Add ``lcpbench check`` to the subcommands ``sub``."""
    p = sub.add_parser(
        "check", help="regression checks of the MVP-only solvers on the shipped sets",
        description=_CHECK_DESCRIPTION)
    p.add_argument("--set", action="append", default=None, metavar="NAME",
                   help="shipped set name or .h5 path, repeatable (default: every shipped set)")
    add_spec_option(p, "solver", many=True,
                    help="solver spec, repeatable (default: every MVP-only solver); "
                         "bi-pqn without low= runs once per low of the set")
    add_stop_options(p, per="run", with_stop=False)
    p.add_argument("--baseline", default=None, metavar="FILE",
                   help="baseline file (default problems/data/baselines.json)")
    p.add_argument("--update-baseline", action="store_true",
                   help="rewrite the baselines of the checked sets with this run's medians")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_check)


def cmd_check(args) -> int:
    """``lcpbench check``: exit 0 (no regression), 1 (regression) or 2 (usage/file error)."""
    from lcpbench.sets import StoredSetError

    try:
        rows = check(args.set, tol=args.tol, baseline=args.baseline,
                     update_baseline=args.update_baseline, solver_specs=args.solver,
                     max_emvps=args.max_emvps, progress=not args.quiet)
    except StoredSetError as exc:
        print(f"lcpbench check: error: {exc}", file=sys.stderr)
        return 2
    if not rows:
        print("lcpbench check: no shipped set to check (problems/data/*.h5); generate one with "
              "lcpbench generate or pass --set FILE.h5")
        return 0
    print(format_table(rows))
    bad = [r for r in rows if r.regressed]
    new = [r for r in rows if r.baseline is None and not r.regressed]
    base = args.baseline or default_baseline()
    if args.update_baseline:
        print(f"\nbaselines of {len({r.set for r in rows})} set(s) written to {base}")
    elif new:
        print(f"\n{len(new)} solver/set pair(s) have no baseline; record them with "
              "lcpbench check --update-baseline")
    if bad:
        print(f"\n{len(bad)} of {len(rows)} solver/set pair(s) regressed", file=sys.stderr)
        return 1
    return 0
