"""Median MVPs and solver time of every registered solver at tol 1e-8, side by side.

Usage::

    python benchmarks/baselines.py            # the table of docs/benchmarks.md
    python benchmarks/baselines.py --quick    # 5 random instances instead of 20
    python benchmarks/baselines.py --safeguard  # BB-PGD's nonmonotone safeguards compared

Sets: (i) random SPD with condition number 10..100 and n 150..300
(``random-spd``), (ii) every hard-case family with its default parameters.
Each cell is ``median E-MVPs / median solver ms [solved/runs]`` over the runs
the framework verified as solved, and, for MVP-only solvers, the ratio of
median E-MVPs to BB-PGD's on the same set. Times are measured in the same run,
one solve after another, so their ratios are comparable; absolute times
depend on the machine. Multi-fidelity solvers are run on the same instances
given two low-fidelity operators ``A + E`` (relative errors 1e-3 and 1e-2,
declared costs 0.1 and 0.01), as in tests/test_hard_cases.py.
"""

from __future__ import annotations

import argparse

from common import HARD, instances, print_markdown_table, progress, run_set, solver_names

import lcpbench
from lcpbench.core.registry import solvers
from lcpbench.problems.random import with_perturbed_lows

MULTI_SPECS = {"bi-pqn": "bi-pqn:low=low", "multi-pqn": "multi-pqn:lows=[low,lower]"}


SAFEGUARDS = ["bb-pgd", "bb-pgd:safeguard=true", "bb-pgd:safeguard=true,reference=gll",
              "bb-pgd:safeguard=true,reference=gll,memory=10",
              "bb-pgd:safeguard=true,memory=10"]


def safeguard_study() -> None:
    """E-MVPs of BB-PGD's safeguards per instance of spd-cond and bb-cycle (budget 20000)."""
    print("| instance | cond | " + " | ".join(SAFEGUARDS) + " |")
    print("|---|---|" + "---|" * len(SAFEGUARDS))
    for family in ("spd-cond", "bb-cycle"):
        for lcp in instances(family):
            cells = []
            for spec in SAFEGUARDS:
                r = lcpbench.solve(lcp, solver=spec, max_emvps=20000, max_iter=20000)
                cells.append(f"{r.emvps:.0f}" if r.solved else f"- ({r.status.value})")
            print(f"| {lcp.name} | {lcp.meta.get('cond', float('nan')):.0e} | "
                  + " | ".join(cells) + " |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="5 random instances instead of 20")
    ap.add_argument("--safeguard", action="store_true",
                    help="only the study of BB-PGD's nonmonotone safeguards")
    args = ap.parse_args()
    if args.safeguard:
        safeguard_study()
        return
    k = 5 if args.quick else 20
    sets = {f"random-spd ({k})": f"random-spd:count={k}"}
    sets.update({h: h for h in HARD})
    names = solver_names(mvp_only=False)
    data: dict = {s: {} for s in names}
    for label, spec in sets.items():
        plain = instances(spec)
        lowed = [with_perturbed_lows(p, i) for i, p in enumerate(plain)]
        for s in names:
            multi = solvers()[s].multifidelity
            data[s][label] = run_set(MULTI_SPECS.get(s, s), lowed if multi else plain)
            progress(f"{label:18s}", f"{s:14s}", data[s][label])
    base = data["bb-pgd"]

    def cell(s: str, label: str) -> str:
        r = data[s][label]
        if not r["solved"]:
            return f"- [0/{r['runs']}]"
        ratio = ""
        if solvers()[s].mvp_only and base[label]["solved"] and base[label]["emvps"] > 0:
            ratio = f" ({r['emvps'] / base[label]['emvps']:.2f}x)"
        return f"{r['emvps']:.0f}{ratio} / {1e3 * r['time_s']:.1f} ms [{r['solved']}/{r['runs']}]"

    print_markdown_table(names, sets, cell,
                         lambda s: s + ("" if solvers()[s].mvp_only else " (dense)"))

if __name__ == "__main__":
    main()
