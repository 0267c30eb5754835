"""Median E-MVPs of every MVP-only solver, with ratios to BB-PGD, and the PQN tuning runs.

Usage::

    python benchmarks/pqn.py              # the table of docs/benchmarks.md
    python benchmarks/pqn.py --quick      # fewer instances
    python benchmarks/pqn.py --tune       # Mono-PQN scaling and Bi-PQN inner accuracy grid

Problem sets (tol 1e-8, the paper's stop rule): random SPD with condition
number 10..100 and n 150..300 (``random-spd``), every hard-case family, and
bi-fidelity pairs ``A_low = A + E`` with cost ratios 0.1 and 0.01. E-MVPs
are counted by the operators; a solver's median is over the runs the
framework verified as solved (the solved count is printed beside it).
"""

from __future__ import annotations

import argparse
import itertools
import sys

import numpy as np
from common import (
    HARD,
    applicable,
    instances,
    print_markdown_table,
    progress,
    run_set,
    solver_names,
)


def medians(solver: str, lcps, tol: float = 1e-8) -> tuple[float, int, int]:
    """Median E-MVPs over verified-solved runs, solved count, run count."""
    r = run_set(solver, lcps, tol)
    return r["emvps"], r["solved"], r["runs"]


def table(quick: bool) -> None:
    k = 5 if quick else 20
    sets = {f"random-spd (n 150-300, cond 10-100, {k})": f"random-spd:count={k}"}
    sets.update({h: h for h in HARD})
    sets["bifidelity ratio 0.1"] = f"bifidelity:count={k // 2},cost_ratio=0.1"
    sets["bifidelity ratio 0.01"] = f"bifidelity:count={k // 2},cost_ratio=0.01"
    names = solver_names(mvp_only=True)
    data = {s: {} for s in names}
    for label, spec in sets.items():
        lcps = instances(spec)
        for s in names:
            if not applicable(s, lcps):
                data[s][label] = None
                continue
            data[s][label] = medians(s, lcps)
            progress(f"{label:40s}", f"{s:16s}", data[s][label])
    base = data.get("bb-pgd", {})

    def cell(s: str, label: str) -> str:
        v = data[s][label]
        if v is None:
            return "n/a"
        med, ok, n = v
        ratio = ""
        if base.get(label) and np.isfinite(base[label][0]) and base[label][0] > 0 \
                and np.isfinite(med):
            ratio = f" ({med / base[label][0]:.2f}x)"
        return f"{med:.1f}{ratio} [{ok}/{n}]"

    print_markdown_table(names, sets, cell)

def tune(quick: bool) -> None:
    k = 3 if quick else 6
    pairs = []
    for rel in (1e-4, 1e-2, 1e-1):
        for ratio in (0.1, 0.01):
            pairs.append((rel, ratio, instances(
                f"bifidelity:count={k},rel_error={rel},cost_ratio={ratio},n=200")))
    rand = instances(f"random-spd:count={3 * k}")
    print("| mono-pqn scaling | random-spd median E-MVPs | bifidelity median MVPs |")
    print("|---|---|---|")
    for sc in ("bb", "identity"):
        m1 = medians(f"mono-pqn:scaling={sc}", rand)[0]
        m2 = medians(f"mono-pqn:scaling={sc}", [p for _, _, ps in pairs[::2] for p in ps])[0]
        print(f"| {sc} | {m1:.1f} | {m2:.1f} |")
    print()
    print("| inner_rtol | inner_max_iter | warm_rtol | median E-MVPs, ratio 0.1 | ratio 0.01 |")
    print("|---|---|---|---|---|")
    for ir, im, wr in itertools.product((0.1, 1e-2, 1e-3), (10, 20, 50), (0.1, 1e-3)):
        spec = f"bi-pqn:inner_rtol={ir},inner_max_iter={im},warm_rtol={wr}"
        e = {ratio: [] for ratio in (0.1, 0.01)}
        for _rel, ratio, ps in pairs:
            e[ratio].append(medians(spec, ps)[0])
        print(f"| {ir:g} | {im} | {wr:g} | {np.median(e[0.1]):.2f} | {np.median(e[0.01]):.2f} |")
        sys.stdout.flush()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer instances")
    ap.add_argument("--tune", action="store_true", help="the PQN parameter study")
    args = ap.parse_args()
    (tune if args.tune else table)(args.quick)


if __name__ == "__main__":
    main()
