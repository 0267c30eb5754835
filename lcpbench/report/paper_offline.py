"""The method paper's offline table, and a measured offline set beside it.

The paper's offline comparison (its section "Offline Comparison": every method on the
same 50 LCPs of a 125-sphere simulation, BIM p = 8 at eps_gmres 1e-8, its stationarity
stop rule at 1e-8) gives the minimum, median, mean and maximum E-MVPs of each method, with Bi-PQN's
high-fidelity MVPs in parentheses, for three low fidelities.  :func:`beside_paper` puts
the measured medians of one stored set next to the paper's, with both ratios to BB-PGD,
so a reader compares like with like: lcpbench stops at a verified residual, and its sets
are not the paper's instances, so the ratios are the comparable figure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER, PAPER_OFFLINE_TABLE
from lcpbench.report.ranking import truthy

__all__ = ["PAPER_OFFLINE", "PaperRow", "paper_row_of", "beside_paper"]


@dataclass(frozen=True)
class PaperRow:
    """One method of the paper's offline table: E-MVPs (min, median, mean, max) and, for
    Bi-PQN, the high-fidelity MVPs of the same statistics."""

    label: str
    emvps: tuple[float, float, float, float]
    high: tuple[float, float, float, float] | None = None


PAPER_OFFLINE: dict[str, PaperRow] = {
    spec: PaperRow(label, emvps, high)
    for spec, (label, emvps, high) in PAPER_OFFLINE_TABLE.items()}
"""The paper's offline table by the lcpbench solver spec that runs the same method
(:data:`lcpbench.core.defaults.PAPER_OFFLINE_TABLE`)."""

COLUMNS = ["solver", "paper method", "solved", "median E-MVPs", "median high MVPs",
           "paper median E-MVPs", "paper median high MVPs", f"/ {BASELINE_SOLVER}",
           f"paper / {BASELINE_SOLVER}"]
"""Columns of :func:`beside_paper`."""


def paper_row_of(solver: str) -> PaperRow | None:
    """The paper's row of the method that ``solver`` (a solver spec) runs, or None."""
    return PAPER_OFFLINE.get(solver)


def _median(g: pd.DataFrame, col: str) -> float:
    v = pd.to_numeric(g[col], errors="coerce").dropna()
    return float(v.median()) if len(v) else np.nan


def beside_paper(results: pd.DataFrame, problem: str,
                 baseline: str = BASELINE_SOLVER) -> pd.DataFrame:
    """The measured offline medians of one set beside the paper's offline table.

    Parameters
    ----------
    results : DataFrame
        Offline rows of a run store.
    problem : str
        The set (``problem`` column) to compare.
    baseline : str
        The solver the ratios are taken against (the paper's BB-PGD).

    Returns
    -------
    DataFrame
        :data:`COLUMNS`, one row per solver that the paper's table has (in the paper's
        order), over the instances every one of these solvers was given: the solved
        count, the median E-MVPs and high MVPs of the verified-solved runs, the paper's
        medians, and both medians divided by their baseline's.  Empty when the set has
        no run of a solver of the paper's table.
    """
    part = results[(results["problem"] == problem)
                   & results["solver"].isin(list(PAPER_OFFLINE))]
    if part.empty:
        return pd.DataFrame(columns=COLUMNS)
    per = [set(g["instance"]) for _, g in part.groupby("solver", sort=True)]
    common = set.intersection(*per)
    part = part[part["instance"].isin(common)]
    ok = part[truthy(part["solved"])]
    base = ok[ok["solver"] == baseline]
    base_median = _median(base, "emvps") if len(base) else np.nan
    paper_base = PAPER_OFFLINE[BASELINE_SOLVER].emvps[1]
    rows = []
    for solver, paper in PAPER_OFFLINE.items():
        g = part[part["solver"] == solver]
        if g.empty:
            continue
        mine = ok[ok["solver"] == solver]
        med = _median(mine, "emvps")
        rows.append({
            "solver": solver, "paper method": paper.label,
            "solved": f"{len(mine)}/{len(g)}", "median E-MVPs": med,
            "median high MVPs": _median(mine, "mvps"),
            "paper median E-MVPs": float(paper.emvps[1]),
            "paper median high MVPs": float(paper.high[1]) if paper.high else np.nan,
            f"/ {BASELINE_SOLVER}": med / base_median if base_median > 0 else np.nan,
            f"paper / {BASELINE_SOLVER}": paper.emvps[1] / paper_base})
    out = pd.DataFrame(rows, columns=COLUMNS)
    out.attrs["instances"] = len(common)
    return out
