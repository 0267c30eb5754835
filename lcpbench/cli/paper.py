"""``lcpbench paper``: the method paper's experiment as a Markdown page from run stores
(see lcpbench.report.paper_page)."""

from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["add_paper_parser", "cmd_paper"]

_DESCRIPTION = """
Read every run store directly under DIR (the online stores of sweeps/online-paper.sh, one
per regime, and the offline store of sweeps/paper-offline.toml) and write DIR/README.md: the
online table per regime and lattice and the offline table per set, each beside the method
paper's, and what differs. The page is computed from the stores alone: rerunning the
command on the same stores gives the same page.
"""


def add_paper_parser(sub) -> None:
    """Add ``lcpbench paper`` to the subcommands ``sub``."""
    p = sub.add_parser("paper", help="the method paper's experiment as a Markdown page",
                       description=_DESCRIPTION)
    p.add_argument("folder", nargs="?", default="reports/paper", metavar="DIR",
                   help="folder of run stores (default reports/paper)")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="page to write (default DIR/README.md)")
    p.add_argument("--baseline", default=None, metavar="SOLVER",
                   help="solver the speedups are measured against (default bb-pgd)")
    p.set_defaults(func=cmd_paper)


def cmd_paper(args) -> int:
    """``lcpbench paper``: exit 0 (page written) or 2 (no stores, unreadable store)."""
    from lcpbench.core.defaults import BASELINE_SOLVER
    from lcpbench.report.paper_page import write_page

    baseline = args.baseline or BASELINE_SOLVER
    try:
        path = write_page(Path(args.folder), Path(args.out) if args.out else None, baseline)
    except (FileNotFoundError, FileExistsError, ValueError, OSError) as exc:
        print(f"lcpbench paper: error: {exc}", file=sys.stderr)
        return 2
    print(f"page: {path}")
    return 0
