"""``lcpbench simulate``: online runs of a scene, one simulation per solver, resumable."""

from __future__ import annotations

import argparse
import sys

from lcpbench.cli.options import add_force_option, add_spec_option, add_stop_options, guard_scene
from lcpbench.core.defaults import EXAMPLE_SCENE, SIMULATE_SOLVER
from lcpbench.workflows.regimes import DEFAULT_REGIME, PAPER_ONLINE_LOW, REGIMES

__all__ = ["add_simulate_parser", "cmd_simulate"]


_SIMULATE_DESCRIPTION = """
Simulate a scene (e.g. lattice:m=3,model=rpy) once per --solver with forward Euler, one
LCP per time step, and write a row per step (kind=online) to the run store DIR;
`lcpbench report DIR` renders the online table.
"""


def add_simulate_parser(sub) -> None:
    """Add ``lcpbench simulate`` to the subcommands ``sub``."""
    p = sub.add_parser("simulate", help="online run: simulate a scene once per solver",
                       description=_SIMULATE_DESCRIPTION)
    add_spec_option(p, "scene", many=False, default=EXAMPLE_SCENE,
                    help=f"scene spec (default {EXAMPLE_SCENE}; low=[self] adds a "
                         "low-fidelity operator for multi-fidelity solvers)")
    add_spec_option(p, "solver", many=True,
                    help="solver spec, repeatable: one simulation each (default bb-pgd)")
    p.add_argument("--steps", type=int, default=50, help="time steps per simulation (default 50)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="run-store folder (default reports/simulate-<time>)")
    add_stop_options(p)
    p.add_argument("--overlap-tol", type=float, default=None,
                   help="largest acceptable overlap after a step, as a fraction of the "
                        "smallest radius (default 0.01)")
    p.add_argument("--no-warm-start", action="store_true",
                   help="start every solve from zero instead of the previous step's forces")
    p.add_argument("--qn-memory", action=argparse.BooleanOptionalAction, default=None,
                   help="start each PQN solve's quasi-Newton model from the previous step's "
                        "secant pairs, mapped by contact identity (default: on; "
                        "docs/benchmarks.md, \"Quasi-Newton memory across time steps\"; "
                        "off under --regime paper)")
    p.add_argument("--regime", choices=sorted(REGIMES), default=DEFAULT_REGIME,
                   help="paper: the method paper's online regime (no Krylov recycling, "
                        "no quasi-Newton memory across steps, the paper's products; its low "
                        f"fidelity is {PAPER_ONLINE_LOW}); default: lcpbench's (recycling "
                        "and memory on). Recorded in meta.json and every row")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_force_option(p)
    p.set_defaults(func=cmd_simulate)


def cmd_simulate(args: argparse.Namespace) -> int:
    from datetime import datetime
    from pathlib import Path

    from lcpbench.cli.run import check_not_foreign, out_folder
    from lcpbench.workflows.simulate import (
        DEFAULT_OVERLAP_TOL,
        Interrupted,
        simulate,
    )


    guard_scene(str(args.scene), force=args.force)  # before the scene is made
    out = out_folder(args.out,
                     Path("reports") / f"simulate-{datetime.now().strftime('%Y%m%d-%H%M%S')}")
    check_not_foreign(out)
    try:
        rows = simulate(args.scene, args.solver or [SIMULATE_SOLVER], args.steps, out,
                        warm_start=not args.no_warm_start,
                        qn_memory=args.qn_memory, regime=args.regime,
                        progress=not args.quiet,
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
    return 1 if _all_stopped_at_start(rows) else 0


def _all_stopped_at_start(rows) -> bool:
    """True (and one line on stderr) when every simulation stopped at its first step."""
    if rows.empty:
        print("lcpbench simulate: error: no step was simulated", file=sys.stderr)
        return True
    stopped = [str(g["message"].iloc[0]) for _, g in rows.groupby("solver", sort=False)
               if int(g["step"].max()) == 0
               and str(g["message"].iloc[-1]).startswith("simulation stopped")]
    if len(stopped) < rows["solver"].nunique():
        return False
    print(f"lcpbench simulate: error: every simulation stopped at step 0 ({stopped[0]}); "
          "nothing was simulated", file=sys.stderr)
    return True
