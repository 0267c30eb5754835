"""The report's "Beside the method paper" section: lcpbench's numbers next to the paper's.

For every paper-like set of the run store (a set with a run of Bi-PQN on one of the
paper's own low fidelities, so the paper's offline table has rows to compare), one table:
per solver of the paper's methods, the solved count, the median E-MVPs (high MVPs in
parentheses for Bi-PQN) of the solved runs, the paper's medians, and both ratios to the
baseline (lcpbench's as the median per-instance ratio with its quartiles,
:mod:`lcpbench.report.ratios`). Bi-PQN runs on lows the paper did not have (the
distance-split lows) get their own rows without paper figures. Under the table, one line
per row where lcpbench and the paper differ, saying why: the low's measured error
against the high on this set, counted set-up products, the stop rule, the set itself.

The paper's figures come from :data:`lcpbench.report.paper_offline.PAPER_OFFLINE` (the
same table ``lcpbench paper`` uses); a solver spec without a row of its own takes the
row of its solver family when the family has exactly one (``a-pgd`` beside the paper's
A-PGD, which was given its constants).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from lcpbench.report import ratios
from lcpbench.report.paper_offline import PAPER_OFFLINE, PaperRow
from lcpbench.report.ranking import truthy

__all__ = ["paper_like_sets", "paper_row_for", "SetComparison", "compare_set",
           "low_errors", "RATIO_GAP"]

#: Ratios to the baseline closer than this to the paper's count as agreeing.
RATIO_GAP = 0.05
#: The paper's own offline set, named in the lines that say why a figure differs.
PAPER_SET = "the paper's 50 LCPs of a 125-sphere simulation"


def _family(spec: str) -> str:
    return spec.split(":", 1)[0]


def paper_row_for(solver: str) -> tuple[str, PaperRow] | None:
    """The paper's row of ``solver``: its own spec's, else the one row of its family
    (``None`` when the family has none or several, as Bi-PQN has one per low)."""
    if solver in PAPER_OFFLINE:
        return solver, PAPER_OFFLINE[solver]
    same = [(k, r) for k, r in PAPER_OFFLINE.items() if _family(k) == _family(solver)]
    return same[0] if len(same) == 1 else None


def _paper_families() -> set[str]:
    return {_family(k) for k in PAPER_OFFLINE}


def paper_like_sets(cut_by_set: dict[str, pd.DataFrame]) -> list[str]:
    """The sets with a run of a multi-fidelity solver on one of the paper's lows (a spec
    of the paper's table with high MVPs), in the given order."""
    multi = {k for k, r in PAPER_OFFLINE.items() if r.high is not None}
    return [name for name, cut in cut_by_set.items()
            if not cut.empty and cut["solver"].astype(str).isin(multi).any()]


def low_errors(path: Path, instances: list[str] | None = None) -> dict[str, float]:
    """Median relative 2-norm error ``||A_low - A|| / ||A||`` of each low of a stored set
    over its instances (all of them, or ``instances``): the low's measured error."""
    from lcpbench.core.operator import dense_uncounted
    from lcpbench.sets import instance_ids, read_instance

    errs: dict[str, list[float]] = {}
    for iid in instances if instances is not None else instance_ids(path):
        lcp = read_instance(path, iid, psd_check=False)
        A = dense_uncounted(lcp.A)
        scale = float(np.linalg.norm(A, 2)) or 1.0
        for name, op in dict(lcp.low or {}).items():
            errs.setdefault(name, []).append(
                float(np.linalg.norm(dense_uncounted(op) - A, 2)) / scale)
    return {k: float(np.median(v)) for k, v in errs.items()}


@dataclass
class SetComparison:
    """One paper-like set beside the paper: the table and the lines saying why rows differ."""

    problem: str
    table: pd.DataFrame
    why: list[str]


def _median(g: pd.DataFrame, col: str) -> float:
    v = pd.to_numeric(g[col], errors="coerce").dropna()
    return float(v.median()) if len(v) else np.nan


def _fmt(v: float) -> str:
    return "-" if v is None or not np.isfinite(v) else f"{v:.3g}"


def _power_mvps(g: pd.DataFrame) -> float:
    vals = []
    for text in g["info"].dropna() if "info" in g else []:
        try:
            v = json.loads(text).get("power_mvps")
        except (ValueError, AttributeError):
            continue
        if isinstance(v, (int, float)):
            vals.append(float(v))
    return float(np.median(vals)) if vals else 0.0


def _stop_note(cut: pd.DataFrame) -> str:
    tol = pd.to_numeric(cut.get("tol"), errors="coerce").dropna()
    stop = cut["stop"].dropna().astype(str) if "stop" in cut else pd.Series(dtype=str)
    t = f"{tol.iloc[0]:.0e}" if len(tol) else "its tolerance"
    s = stop.iloc[0] if len(stop) else "its"
    return (f"lcpbench stops at a verified residual of {t} ({s} stop rule, checked by the "
            "framework's own product); the paper stops at its stationarity rule at 1e-8")


def _why(solver: str, paper: PaperRow | None, row: dict, g: pd.DataFrame,
         errors: dict[str, float], cut: pd.DataFrame, baseline: str) -> str | None:
    """Why the row differs from the paper's, or None when it agrees (or has no paper row)."""
    if paper is None:
        return None
    mine, theirs = row["_ratio"], row["_paper_ratio"]
    if solver == baseline:
        med = row["_median"]
        if np.isfinite(med) and abs(med - paper.emvps[1]) <= 0.1 * paper.emvps[1]:
            return None
        return (f"{solver}: a median {_fmt(med)} E-MVPs against the paper's "
                f"{paper.emvps[1]:g}: {_stop_note(cut)}; the set is not {PAPER_SET}")
    if np.isfinite(mine) and abs(mine - theirs) <= RATIO_GAP:
        return None
    bits = [f"{solver}: ratio {mine:.2f} against the paper's {theirs:.2f}"]
    low = dict(json.loads(g["solver_params"].iloc[0])).get("low") \
        if "solver_params" in g and len(g) else None
    if isinstance(low, str) and low in errors:
        bits.append(f"the low {low} is {errors[low]:.2g} from the high on this set (median "
                    "relative 2-norm error), which decides how many high products Bi-PQN "
                    f"needs (median {_fmt(row['_high'])} here, the paper's "
                    f"{paper.high[1] if paper.high else '-'})")
    power = _power_mvps(g)
    if power > 0:
        bits.append(f"its E-MVPs include a median {power:g} counted power-iteration products "
                    "that estimate L (the paper's A-PGD was given L and mu: "
                    "a-pgd:constants=oracle)")
    bits.append(_stop_note(cut))
    return "; ".join(bits)


def compare_set(problem: str, cut: pd.DataFrame, baseline: str,
                errors: dict[str, float] | None = None) -> SetComparison:
    """The table of one paper-like set (runs on common ground, ``cut``) beside the paper's.

    Columns: solver, paper method, solved, median E-MVPs (high), the paper's, median ratio
    to the baseline [quartiles] and the paper's ratio. Rows: the solvers of the paper's
    families, the baseline first, then the paper's order, Bi-PQN on other lows last.
    """
    errors = errors or {}
    stats = {s.solver: s for s in ratios.ratio_stats(cut, baseline)}
    paper_base = PAPER_OFFLINE[baseline].emvps[1] if baseline in PAPER_OFFLINE else np.nan
    order = list(PAPER_OFFLINE)
    solvers = [s for s in sorted(cut["solver"].astype(str).unique())
               if _family(s) in _paper_families()]

    def rank(s: str) -> tuple:
        match = paper_row_for(s)
        return (s != baseline, order.index(match[0]) if match else len(order), s)

    solvers.sort(key=rank)
    multi_families = {_family(k) for k, r in PAPER_OFFLINE.items() if r.high is not None}
    rows, why = [], []
    for solver in solvers:
        g = cut[cut["solver"].astype(str) == solver]
        ok = g[truthy(g["solved"])]
        match = paper_row_for(solver)
        paper = match[1] if match else None
        multi = _family(solver) in multi_families
        st = stats.get(solver)
        med, high = _median(ok, "emvps"), _median(ok, "mvps")
        row = {"solver": solver, "paper method": paper.label if paper else "-",
               "solved": f"{len(ok)}/{len(g)}",
               "median E-MVPs (high)": f"{_fmt(med)} ({_fmt(high)})" if multi else _fmt(med),
               "paper (high)": ("-" if paper is None else
                                f"{paper.emvps[1]:g} ({paper.high[1]:g})" if paper.high
                                else f"{paper.emvps[1]:g}"),
               f"ratio to {baseline} [25-75 %]": ratios.format_ratio(st) if st else "-",
               "paper ratio": (f"{paper.emvps[1] / paper_base:.2f}"
                               if paper is not None and np.isfinite(paper_base) else "-"),
               "_ratio": st.median if st else np.nan, "_median": med, "_high": high,
               "_paper_ratio": (paper.emvps[1] / paper_base if paper is not None
                                else np.nan)}
        line = _why(solver, paper, row, g, errors, cut, baseline)
        if line:
            why.append(line)
        rows.append(row)
    table = pd.DataFrame(rows)
    if not table.empty:
        table = table.drop(columns=[c for c in table.columns if c.startswith("_")])
    return SetComparison(problem, table, why)
