"""Print the fidelity table of a stored set as Markdown (for docs).

Usage::

    python benchmarks/fidelity.py PATH.h5 [--instances 0-9]

One row per low fidelity: its knobs (model, p, eps_gmres), how many instances have it,
log10 of the largest ||A_low - A||_inf over the instances (induced infinity norm), the
median number of low-fidelity MVPs per high-fidelity MVP (1 / cost_ratio) and the share
of instances with ||A_low - A||_inf < c(A) (lemma cottleLemma of the paper; c(A) is an
upper-bound estimate by multi-start local optimisation, appendix "Computing c(A)").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lcpbench.core.registry import stored_sets
from lcpbench.sets import StoredSetError, instance_ids, parse_instances
from lcpbench.workflows.fidelity import fidelity_table


def main(argv: list[str] | None = None) -> int:
    """Parse the arguments, compute the table and print it; return the exit code."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path", help="stored set (.h5) or the name of a shipped set")
    ap.add_argument("--instances", default="",
                    help="positions to use, e.g. '0-9' or '0,3,5-7' (default all)")
    args = ap.parse_args(argv)
    path = Path(args.path)
    if not path.exists() and args.path in stored_sets():
        path = Path(stored_sets()[args.path].path)
    try:
        all_ids = instance_ids(path)
        ids = [all_ids[i] for i in parse_instances(args.instances, len(all_ids))]
        table = fidelity_table(path, instances=ids)
    except (StoredSetError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if table.empty:
        print(f"{path}: no low fidelities stored; nothing to tabulate", file=sys.stderr)
        return 1
    print(f"Fidelity study of `{path.name}` ({len(ids)} instances)\n")
    print(table.to_markdown(index=False, floatfmt=".4g"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
