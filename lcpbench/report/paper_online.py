"""The method paper's online table, and the measured online table set beside it.

The paper (its table "online": BB-PGD, Mono-PQN and Bi-PQN simulating 3x3x3 to 6x6x6
lattices for 200 time steps, BIM p = 8 at eps_gmres 1e-8, a Stokes FMM far field, 24 cores)
gives BB-PGD's total and collision-resolution wall time and the two PQN solvers' speedups.
:func:`beside_paper` puts the measured rows of :func:`lcpbench.report.tables.online_paper_table`
next to those numbers, size by size, so a reader compares like with like: the speedups, and
the share of a step that collision resolution takes (the paper's premise is that it
dominates a step).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER, PAPER_ONLINE_FAMILIES

__all__ = ["PAPER_ONLINE", "beside_paper"]

_H, _D = 3600.0, 86400.0

PAPER_ONLINE: dict[int, dict[str, float]] = {
    3: {"steps": 200, "total_s": 15 * _H + 21 * 60, "collision_s": 13 * _H + 31 * 60,
        "mono_total": 1.59, "mono_collision": 1.70, "bi_total": 1.85, "bi_collision": 2.07},
    4: {"steps": 200, "total_s": _D + 3 * _H + 54 * 60, "collision_s": 23 * _H + 26 * 60,
        "mono_total": 1.37, "mono_collision": 1.49, "bi_total": 1.75, "bi_collision": 2.10},
    5: {"steps": 200, "total_s": 2 * _D + 18 * _H + 36 * 60,
        "collision_s": 2 * _D + 43 * 60,
        "mono_total": 1.32, "mono_collision": 1.43, "bi_total": 1.60, "bi_collision": 2.10},
    6: {"steps": 200, "total_s": 7 * _D + 18 * _H, "collision_s": 5 * _D + 25 * 60,
        "mono_total": 1.16, "mono_collision": 1.32, "bi_total": 1.57, "bi_collision": 2.47},
}
"""The paper's online table by lattice side: BB-PGD's summed seconds (total, collision
resolution; the paper prints them as days, hours and minutes) and the speedups of Mono-PQN
and Bi-PQN (BB-PGD's time divided by theirs), over 200 time steps."""

COLUMNS = ["lattice size", "source", "steps", "BB-PGD total s", "BB-PGD collision s",
           "collision share", "Mono-PQN total speedup", "Mono-PQN collision speedup",
           "Bi-PQN total speedup", "Bi-PQN collision speedup"]
"""Columns of :func:`beside_paper`."""


def _first(solvers: list[str], family: str) -> str | None:
    """The first solver of the measured table whose name is ``family`` or ``family:...``."""
    return next((s for s in solvers if s == family or s.startswith(family + ":")), None)


def _measured_row(row: pd.Series, baseline: str, mono: str | None, bi: str | None) -> dict:
    """One measured scene of the paper-shaped table in :data:`COLUMNS` form."""
    total, coll = row.get(f"{baseline} total s", np.nan), row.get(f"{baseline} collision s",
                                                                  np.nan)
    out = {"lattice size": row["lattice size"], "source": f"lcpbench ({row['scene']})",
           "steps": row["steps"], "BB-PGD total s": total, "BB-PGD collision s": coll,
           "collision share": coll / total if total and np.isfinite(total) else np.nan}
    for name, solver in (("Mono-PQN", mono), ("Bi-PQN", bi)):
        for what in ("total", "collision"):
            out[f"{name} {what} speedup"] = (row.get(f"{solver} {what} speedup", np.nan)
                                            if solver else np.nan)
    return out


def beside_paper(measured: pd.DataFrame, baseline: str = BASELINE_SOLVER) -> pd.DataFrame:
    """The measured online table beside the paper's, one pair of rows per lattice size.

    Parameters
    ----------
    measured : DataFrame
        :func:`lcpbench.report.tables.online_paper_table` (its ``attrs["solvers"]`` names
        the solvers in column order).
    baseline : str
        The measured baseline, compared with the paper's BB-PGD.

    Returns
    -------
    DataFrame
        :data:`COLUMNS`: per lattice size measured, the measured row(s) (Mono-PQN and Bi-PQN
        are the first measured solvers of those names, e.g. ``bi-pqn:low=p8f6e3``) and the
        paper's row; then the paper's rows for sizes not measured.  ``collision share`` is
        the baseline's collision-resolution seconds over its total.  Empty when nothing was
        measured.
    """
    if measured is None or measured.empty:
        return pd.DataFrame(columns=COLUMNS)
    solvers = list(measured.attrs.get("solvers") or [])
    mono, bi = (_first(solvers, PAPER_ONLINE_FAMILIES[k]) for k in ("Mono-PQN", "Bi-PQN"))
    rows, seen = [], set()
    for _, row in measured.iterrows():
        m = int(row["M"] ** (1 / 3) + 0.5) if np.isfinite(row.get("M", np.nan)) else None
        rows.append(_measured_row(row, baseline, mono, bi))
        if m in PAPER_ONLINE and m not in seen:
            rows.append(_paper_row(m))
            seen.add(m)
    rows += [_paper_row(m) for m in sorted(PAPER_ONLINE) if m not in seen]
    return pd.DataFrame(rows, columns=COLUMNS)


def _paper_row(m: int) -> dict:
    """The paper's row for lattice side ``m`` in :data:`COLUMNS` form."""
    p = PAPER_ONLINE[m]
    return {"lattice size": f"{m}x{m}x{m}", "source": "paper", "steps": p["steps"],
            "BB-PGD total s": p["total_s"], "BB-PGD collision s": p["collision_s"],
            "collision share": p["collision_s"] / p["total_s"],
            "Mono-PQN total speedup": p["mono_total"],
            "Mono-PQN collision speedup": p["mono_collision"],
            "Bi-PQN total speedup": p["bi_total"], "Bi-PQN collision speedup": p["bi_collision"]}
