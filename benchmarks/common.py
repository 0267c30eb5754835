"""Helpers shared by the benchmark scripts: instance sets and per-solver medians."""

from __future__ import annotations

import sys

import numpy as np

import lcpbench
from lcpbench.core.registry import get_problem, solvers
from lcpbench.core.specs import make_params, parse_spec

HARD = ["planted", "spd-cond", "singular-psd", "fathi", "tiny", "all-inactive", "bad-scale",
        "bb-cycle"]


def instances(spec: str):
    """The LCP instances of a problem spec ``name[:k=v,...]``."""
    name, values = parse_spec(spec)
    info = get_problem(name)
    return info.func(make_params(name, info.params, values))


def run_set(solver: str, lcps, tol: float = 1e-8) -> dict:
    """Solve every instance; medians of E-MVPs and solver seconds over verified-solved runs."""
    e, t, ok = [], [], 0
    for lcp in lcps:
        r = lcpbench.solve(lcp, solver=solver, tol=tol)
        if r.solved:
            ok += 1
            e.append(r.emvps)
            t.append(r.time_s)
    return {"emvps": float(np.median(e)) if e else float("nan"),
            "time_s": float(np.median(t)) if t else float("nan"), "solved": ok, "runs": len(lcps)}


def solver_names(*, mvp_only: bool) -> list[str]:
    """Registered solvers (test doubles excluded); only MVP-only non-reference ones if asked."""
    return sorted(n for n, i in solvers().items()
                  if i.listed and (not mvp_only or (i.mvp_only and not i.reference)))


def applicable(solver: str, lcps) -> bool:
    """Multi-fidelity solvers run only where every instance has a low-fidelity operator."""
    return not solvers()[parse_spec(solver)[0]].multifidelity or all(p.low for p in lcps)


def progress(*parts) -> None:
    print("  " + " ".join(str(p) for p in parts), file=sys.stderr, flush=True)


def print_markdown_table(names, sets, cell, label=lambda s: s) -> None:
    """Print a Markdown table: one row per solver in ``names``, one column per set label.

    ``cell(solver, set_label)`` gives the text of a cell; ``label(solver)`` the row header.
    """
    print("| solver | " + " | ".join(sets) + " |")
    print("|---|" + "---|" * len(sets))
    for s in names:
        print(f"| {label(s)} | " + " | ".join(cell(s, lab) for lab in sets) + " |")


def print_outcomes(head: str, counts, names, columns: dict, *, bad: dict, problems: list) -> int:
    """Print a claims benchmark's table and verdict; 1 if any ``bad`` outcome occurred.

    ``counts[(solver, outcome)]`` are run counts; ``columns`` maps each outcome to its
    column header and ``bad`` the outcomes that are faults to their label in the totals
    line. The first 20 ``problems`` go to stderr.
    """
    print(head + "\n")
    outcome_of = {h: o for o, h in columns.items()}
    print_markdown_table(names, list(columns.values()),
                         lambda n, h: str(counts[(n, outcome_of[h])]))
    total = {o: sum(counts[(n, o)] for n in names) for o in columns}
    print(f"\nruns: {sum(total.values())}, "
          + ", ".join(f"{label}: {total[o]}" for o, label in bad.items()))
    for p in problems[:20]:
        print(p, file=sys.stderr)
    return 1 if any(total[o] for o in bad) else 0


def packed_lattice(m: int, steps: int = 40, scene: str = "lattice"):
    """The lattice scene of side ``m`` after ``steps`` cheap RPY steps: packed, with the
    closest gaps at the scene's kept separation (0.1a for ``lattice``, as the shipped sets'
    instances are; 0.3a for ``paper-lattice``)."""
    from lcpbench.core.registry import make_scene

    scene = make_scene(f"{scene}:m={m},model=rpy")
    for _ in range(steps):
        scene.step("bb-pgd")
    return scene
