"""The ``lcpbench`` command: ``list``, ``solve``, ``run``, ``report``, ``simulate``,
``generate``, ``check``, ``paper``.

Every subcommand returns an exit code; a usage error (unknown solver or
problem, mistyped parameter, missing file, bad value) is printed as one line on
stderr and exits with 2, without a traceback.
"""

from __future__ import annotations

import argparse
import errno
import os
import sys
from collections.abc import Sequence
from typing import Optional

from lcpbench import __version__
from lcpbench.cli.check import add_check_parser
from lcpbench.cli.generate import add_generate_parser
from lcpbench.cli.listing import add_list_parser
from lcpbench.cli.paper import add_paper_parser
from lcpbench.cli.run import add_report_parser, add_run_parser
from lcpbench.cli.simulate import add_simulate_parser
from lcpbench.cli.solve import add_solve_parser
from lcpbench.run.store import StoreLocked

__all__ = ["main", "build_parser"]


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
    add_list_parser(sub)
    add_solve_parser(sub)
    add_run_parser(sub)
    _extend_run_parser(sub)
    add_report_parser(sub)
    add_simulate_parser(sub)
    add_generate_parser(sub)
    add_check_parser(sub)
    add_paper_parser(sub)
    return parser


# ----------------------------------------------------------------------------- main


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``lcpbench`` command; returns the exit code.

    Output cut short by its reader (``lcpbench list | head``) ends quietly with exit 0.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except _user_errors() as exc:                # a plugin that fails to load, say
        print(f"lcpbench: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    args.argv = argv
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:
        _silence_stdout()
        return 0
    except KeyboardInterrupt:
        print("lcpbench: interrupted; rows already written are kept (re-run to resume)",
              file=sys.stderr)
        return 130
    except _user_errors() as exc:
        print(f"lcpbench {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        return 2


def _user_errors() -> tuple:
    """Exceptions that mean bad input (a spec, a value, a file, a plugin): one line and exit 2."""
    from lcpbench.core.registry import PluginError
    from lcpbench.sets import StoredSetError

    return (KeyError, ValueError, TypeError, OSError, ImportError, StoreLocked, StoredSetError,
            PluginError)


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's last flush does not fail again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):   # no real stdout (a test's capture)
        pass


#: What to do after an OS error of a file the command writes, by errno.
_OS_HINTS = {
    errno.ENOSPC: "; free space (or choose another --out) and rerun the same command: what "
                  "was finished is kept and the run resumes",
    errno.EDQUOT: "; free space within your quota and rerun the same command to resume",
    errno.EACCES: "; choose a folder you can write to (--out)",
    errno.EPERM: "; choose a folder you can write to (--out)",
    errno.EROFS: "; the file system is read-only: choose a folder on a writable one (--out)",
}


def _one_line(exc: BaseException) -> str:
    """The exception's message on one line (a missing module gets the install hint)."""
    msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
    if isinstance(exc, ImportError) and getattr(exc, "name", None):
        msg = f"{msg}; install it (pip install -e \".[test]\" has every optional dependency)"
    elif isinstance(exc, OSError) and getattr(exc, "filename", None) and exc.strerror:
        plain = exc.errno is not None and exc.strerror == os.strerror(exc.errno)
        msg = f"{exc.filename}: {exc.strerror}" + (_OS_HINTS.get(exc.errno or 0, "") if plain
                                                   else "")   # a message of its own says it
    return "; ".join(part.strip() for part in str(msg).splitlines() if part.strip())

