"""Options several ``lcpbench`` commands share."""

from __future__ import annotations

import argparse
from typing import Optional

from lcpbench.core.residuals import STOP_RULES

__all__ = ["add_stop_options"]


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
