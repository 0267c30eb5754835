"""The held-apart choice of lcpbench's best regime: one configuration per solver family.

``sweeps/best-regime-select.sh`` simulates candidate configurations of BB-PGD, Mono-PQN and
Bi-PQN on a configuration the online campaign does not use (the paper's scene at 3x3x3 from
another random start) in lcpbench's default regime, all in one process taking their steps
in turn. Its run store is the folder :data:`SELECT_STORE` beside the campaign's stores.

The rule, per family: among the candidates that solved every compared step (verified), the
one with the smallest collision-resolution seconds summed over the compared steps (the steps
every candidate finished, the warm-up step and steps without contacts or products left out,
as in the online table). Ties are broken by the smaller summed total step seconds.
"""

from __future__ import annotations

import re

import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER, PAPER_ONLINE_FAMILIES
from lcpbench.report import tables
from lcpbench.report.markup import markdown_table as md_table

__all__ = ["SELECT_STORE", "FAMILIES", "choose", "selection_section"]

SELECT_STORE = "select"
"""The folder name of the held-apart selection's run store under ``reports/paper``."""

FAMILIES = (BASELINE_SOLVER, *PAPER_ONLINE_FAMILIES.values())
"""The solver families the best regime runs, one configuration each."""


def _family(solver: str) -> str:
    return solver.split(":", 1)[0]


def choose(res: pd.DataFrame) -> tuple[pd.DataFrame, dict[str, str]]:
    """Every candidate's sums over the compared steps, and the chosen one per family.

    Returns
    -------
    table : pandas.DataFrame
        One row per candidate: ``family``, ``solver``, ``steps`` (compared), ``solved``,
        ``collision s`` and ``total s`` (sums over the compared steps), ``median E-MVPs``,
        ``median high MVPs`` and ``chosen`` (bool), in family then collision-time order.
    chosen : dict
        ``{family: solver}`` for every family with a candidate that solved every step.
    """
    steps = tables.online_step_rows(res)
    rows = []
    for solver, g in steps.groupby("solver", sort=True):
        if _family(str(solver)) not in FAMILIES:
            continue
        rows.append({"family": _family(str(solver)), "solver": str(solver),
                     "steps": int(g["step"].nunique()),
                     "solved": int(tables.solved_mask(g).sum()),
                     "collision s": float(pd.to_numeric(g["time_s"]).sum()),
                     "total s": float(pd.to_numeric(g["sim_total_s"]).sum()),
                     "median E-MVPs": float(pd.to_numeric(g["emvps"], errors="coerce").median()),
                     "median high MVPs": float(pd.to_numeric(g["mvps"],
                                                             errors="coerce").median())})
    table = pd.DataFrame(rows, columns=["family", "solver", "steps", "solved", "collision s",
                                        "total s", "median E-MVPs", "median high MVPs"])
    table["chosen"] = False
    chosen: dict[str, str] = {}
    for fam in FAMILIES:
        part = table[(table["family"] == fam) & (table["solved"] == table["steps"])
                     & (table["steps"] > 0)]
        if part.empty:
            continue
        best = part.sort_values(["collision s", "total s"], kind="stable").index[0]
        table.loc[best, "chosen"] = True
        chosen[fam] = str(table.loc[best, "solver"])
    order = {f: i for i, f in enumerate(FAMILIES)}
    table = table.sort_values(["family", "collision s"], key=lambda c: c.map(order)
                              if c.name == "family" else c, kind="stable")
    return table.reset_index(drop=True), chosen


def selection_section(name: str, res: pd.DataFrame) -> list[str]:
    """The page's section on the held-apart choice (Markdown lines)."""
    table, chosen = choose(res)
    scenes = sorted(set(tables.online_step_rows(res)["problem"])) if len(table) else []
    lines = [f"## lcpbench's best regime: the configurations, chosen held apart (`{name}/`)",
             "", "Candidates simulated on "
             + (", ".join(f"`{s}`" for s in scenes) or "no scene yet")
             + " (not a campaign configuration), in lcpbench's default regime, taking their "
             "steps in turn. The rule, per family: among the candidates that solved every "
             "compared step, the smallest collision-resolution seconds summed over the "
             "compared steps (ties: the smaller total).", ""]
    if table.empty:
        return lines + ["No compared step yet.", ""]
    shown = pd.DataFrame({
        "family": table["family"], "candidate": "`" + table["solver"] + "`",
        "compared steps": table["steps"].astype(str),
        "solved": table["solved"].astype(str) + "/" + table["steps"].astype(str),
        "collision s": table["collision s"].map(lambda v: f"{v:.1f}"),
        "total s": table["total s"].map(lambda v: f"{v:.1f}"),
        "median E-MVPs": table["median E-MVPs"].map(lambda v: f"{v:.3g}"),
        "median high MVPs": table["median high MVPs"].map(lambda v: f"{v:.3g}"),
        "chosen": table["chosen"].map(lambda v: "yes" if v else "")})
    lines += [md_table(shown), ""]
    if chosen:
        picked = " ".join(chosen[f] for f in FAMILIES if f in chosen)
        low = re.search(r"(?:^|[:,])low=([^,]+)", chosen.get(FAMILIES[-1], ""))
        lows = f"LOW={low.group(1)} " if low else ""
        lines += ["The best regime's campaign runs them: "
                  f"`REGIME=default {lows}SOLVERS=\"{picked}\" bash sweeps/online-paper.sh "
                  "reports/paper/online-default`.", ""]
    return lines
