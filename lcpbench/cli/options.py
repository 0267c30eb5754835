"""Options several ``lcpbench`` commands share."""

from __future__ import annotations

import argparse
import sys
from typing import Any, Optional

from lcpbench.core import guards
from lcpbench.core.registry import problem_estimate, scene_estimate
from lcpbench.core.residuals import STOP_RULES

__all__ = ["add_stop_options", "add_force_option", "add_spec_option", "guard_problem"]


def add_stop_options(p: argparse.ArgumentParser, *, tol: Optional[float] = 1e-8,
                     stop: Optional[str] = "paper", max_emvps: Optional[float] = 5000.0,
                     per: str = "solve", with_stop: bool = True) -> None:
    """Add ``--tol``, ``--stop`` and ``--max-emvps``: the stop rule and budget of each solve.

    Defaults of None leave the value to a later layer (a sweep file); the help text names
    the value that then applies.
    """
    p.add_argument("--tol", type=float, default=tol, help="stop-rule tolerance (default 1e-8)")
    if with_stop:
        p.add_argument("--stop", choices=STOP_RULES, default=stop,
                       help="stop rule (default paper)")
    p.add_argument("--max-emvps", type=float, default=max_emvps,
                   help=f"E-MVP budget per {per} (default 5000)")


def add_spec_option(p: argparse.ArgumentParser, kind: str, *, many: bool,
                    default: Any = None, help: str) -> None:
    """Add ``--KIND NAME[:k=v,...]``, a registry choice; repeatable when ``many``."""
    extra: dict[str, Any] = {"action": "append"} if many else {}
    p.add_argument(f"--{kind}", default=default, metavar="NAME[:k=v,...]", help=help, **extra)


def add_force_option(p: argparse.ArgumentParser) -> None:
    """Add ``--force``: run work past the size limits of :mod:`lcpbench.core.guards`."""
    p.add_argument("--force", action="store_true",
                   help="build and solve past the memory, time and sweep-size limits "
                        "(estimated before any work; see docs/errors.md)")


def guard_scene(spec: str, *, force: bool = False) -> None:
    """Refuse making scene ``spec`` past the memory and time limits (its registered estimate).

    Raises
    ------
    lcpbench.core.guards.TooLarge
        The estimate is over a limit and ``force`` is not set (the message names both).
    """
    try:
        est = scene_estimate(spec)
    except (KeyError, TypeError, ValueError):
        return                  # a bad spec: the simulation's own checks name the mistake
    if est is not None and not force:
        msg = guards.refusal(spec, est, what="lower m")
        if msg:
            raise guards.TooLarge(msg)


def guard_problem(command: str, label: str, name: str, params: Any, *,
                  force: bool = False) -> None:
    """Refuse building problem ``label`` past the limits; announce a long build first.

    Raises
    ------
    lcpbench.core.guards.TooLarge
        The estimate is over a limit and ``force`` is not set (the message names both).
    """
    est = problem_estimate(name, params)
    guards.check(label, est, force=force)
    if est is not None:
        secs = guards.seconds_for(est.flops)
        if secs > guards.NOTE_AFTER_S:
            print(f"lcpbench {command}: building {label} ({est.instances} instance(s) of n up "
                  f"to {est.n}) takes about {guards.format_seconds(secs)}", file=sys.stderr)
