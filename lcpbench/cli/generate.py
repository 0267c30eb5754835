"""``lcpbench generate``: a dense stored set from a live scene (see lcpbench.workflows.generate)."""

from __future__ import annotations

import sys
from pathlib import Path

from lcpbench.cli.options import add_spec_option, add_stop_options
from lcpbench.core.defaults import DEFAULT_SOLVER, EXAMPLE_SCENE
from lcpbench.sets import StoredSetError
from lcpbench.workflows.generate import default_cache_dir, generate, parse_lows

__all__ = ["add_generate_parser", "cmd_generate"]


_GENERATE_DESCRIPTION = """
Simulate a scene with one solver and write, for each chosen step, the dense
high-fidelity A (n MVPs), b, the dense low-fidelity matrices with their measured cost ratios,
the QP consensus reference and provenance to an HDF5 set. Re-running into the same file
resumes: instances already in it are verified and kept, and the simulation continues
from the checkpoint FILE-stem.checkpoint.npz written beside the set after every step. A
failed write (disk full) leaves the set as it was before that instance; the same command
then resumes.
"""


def add_generate_parser(sub) -> None:
    """Add ``lcpbench generate`` to the subcommands ``sub``."""
    p = sub.add_parser(
        "generate", help="write a dense stored set from a live scene",
        description=_GENERATE_DESCRIPTION)
    add_spec_option(p, "scene", many=False, default=EXAMPLE_SCENE,
                    help=f"scene spec (default {EXAMPLE_SCENE})")
    add_spec_option(p, "solver", many=False, default=DEFAULT_SOLVER,
                    help=f"solver that advances the simulation (default {DEFAULT_SOLVER})")
    p.add_argument("--steps", required=True, metavar="RANGE",
                   help="0-based steps to store, e.g. 31-50 or 0,3,5-7 (earlier steps are "
                        "simulated, not stored)")
    p.add_argument("--low", action="append", default=[], metavar="FIDELITY",
                   help="low fidelity to store, repeatable: p=3,4 (orders, at each --eps), "
                        "rpy, self, p4e6, the distance-split p8f6e3 (order 8 near contact, "
                        "far field degree 6, GMRES 1e-3) or p8f6r3e3 (its blocks compressed "
                        "at 1e-3)")
    p.add_argument("--eps", default="", metavar="E1,E2",
                   help="GMRES tolerances of the p= fidelities, e.g. 1e-6,1e-8 (names p4e6, "
                        "p4e8; default the scene's eps_gmres, names p4)")
    p.add_argument("--out", default=None, metavar="FILE.h5",
                   help="the set file (default <cache>/sets/NAME.h5, cache $LCPBENCH_CACHE "
                        "or ~/.cache/lcpbench)")
    p.add_argument("--name", default=None, help="set name (default: the file stem)")
    p.add_argument("--title", default=None, help="one-line title (root attr)")
    p.add_argument("--description", default=None, help="description (root attr)")
    add_stop_options(p)
    p.add_argument("--compression", choices=("gzip", "lzf"), default=None,
                   help="compress the matrices")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_generate)


def _parse_eps(text: str) -> list[float]:
    out = []
    for t in (s.strip() for s in str(text).split(",")):
        if not t:
            continue
        try:
            out.append(float(t))
        except ValueError:
            raise ValueError(f"--eps: {t!r} is not a number; use e.g. --eps 1e-6,1e-8") \
                from None
    return out


def cmd_generate(args) -> int:
    """``lcpbench generate``: exit 0, or 2 with one line for a usage or file error."""

    try:
        lows = parse_lows(args.low, _parse_eps(args.eps))
        if args.out is None and not args.name:
            raise ValueError("give --out FILE.h5 or --name NAME (written to the cache folder)")
        out = Path(args.out) if args.out else default_cache_dir() / f"{args.name}.h5"
        if out.is_dir():
            raise ValueError(f"--out {out} is a folder; give the set's file, e.g. "
                             f"{out / 'my-set.h5'}")
        summary = generate(args.scene, args.steps, out, solver=args.solver, lows=lows,
                           name=args.name, title=args.title, description=args.description,
                           tol=args.tol, stop=args.stop, max_emvps=args.max_emvps,
                           progress=not args.quiet,
                           argv=["lcpbench"] + list(getattr(args, "argv", ["generate"])),
                           compression=args.compression)
    except StoredSetError as exc:
        print(f"lcpbench generate: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(f"{summary.path}: wrote {len(summary.written)} instance(s), kept "
          f"{len(summary.kept)}, simulated {summary.simulated} step(s) in "
          f"{summary.seconds:.1f} s")
    if summary.references_rejected:
        print(f"note: the QP backends disagreed on {', '.join(summary.references_rejected)} "
              "(reference stored with accepted = False)")
    return 0
