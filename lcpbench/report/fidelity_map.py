"""Report section "Fidelity advantage": multi-fidelity MVPs against the low's relative error.

Shown when the run store holds runs on low fidelities whose names carry their
relative error (``SHAPE~ERROR``, written by the ``synthetic-low`` problem
family): per error shape (random ``E``, ``E`` shaped like the set's own low error,
the set's real lows at their measured error) and per solver, the median
high-fidelity MVPs and E-MVPs of the verified-solved runs, beside the median
E-MVPs of every single-fidelity solver on the same problem. It tells how
accurate a low fidelity must be before the multi-fidelity solver pays.
``benchmarks/fidelity_map.py`` adds the exact-subproblem oracle floor.
"""

from __future__ import annotations

import html
import json

import numpy as np
import pandas as pd

from lcpbench.core.registry import solvers
from lcpbench.report import plots, tables
from lcpbench.report.colors import solver_colors
from lcpbench.report.markup import html_table

__all__ = ["fidelity_map_table", "fidelity_map_section"]


def _low_of(solver: str, params: str) -> tuple:
    """``(shape, error)`` of the one low operator a run's ``solver_params`` JSON names;
    (None, nan) if none (the registry says which parameter names it)."""
    info = solvers().get(str(solver))
    key = info.lows.one if info is not None else ""
    try:
        low = json.loads(params).get(key, "") if key else ""
    except (TypeError, ValueError, AttributeError):
        return None, float("nan")
    shape, sep, err = str(low).rpartition("~")
    try:
        return (shape, float(err)) if sep else (None, float("nan"))
    except ValueError:
        return None, float("nan")


def fidelity_map_table(results: pd.DataFrame) -> pd.DataFrame:
    """Median MVPs per problem, solver, low shape and relative error (empty if no such runs)."""
    if results.empty or "solver_params" not in results:
        return pd.DataFrame()
    res = results[tables.solved_mask(results)]
    parsed = [_low_of(s, p) for s, p in zip(res["solver_name"], res["solver_params"])]
    res = res.assign(shape=[p[0] for p in parsed], rel_error=[p[1] for p in parsed])
    multi = res[res["shape"].notna()]
    if multi.empty:
        return pd.DataFrame()
    single = res[(res["shape"].isna()) & (res["problem"].isin(multi["problem"].unique()))]
    synthetic = multi["shape"].isin(("random", "like"))
    multi = multi.assign(shape=np.where(synthetic, multi["shape"], "real " + multi["shape"]),
                         err_key=np.where(synthetic, multi["rel_error"], np.nan))
    rows = []
    for (prob, solver, shape), g in multi.groupby(["problem", "solver_name", "shape"]):
        for _key, h in (g.groupby("err_key") if g["err_key"].notna().any() else [(None, g)]):
            e = float(h["emvps"].median())
            rows.append({"problem": prob, "solver": solver, "low": shape,
                         "rel_error": float(h["rel_error"].median()),
                         "high_mvps": float(h["mvps"].median()), "emvps": e, "runs": len(h)})
    out = pd.DataFrame(rows)
    # the best single-fidelity solver of each problem (median E-MVPs), NaN if none ran
    best = single.groupby(["problem", "solver_name"])["emvps"].median().groupby(level=0).min()
    out["best_single_fidelity"] = out["problem"].map(best).astype(float)
    return out.sort_values(["problem", "solver", "low", "rel_error"],
                           ascending=[True, True, True, False]).reset_index(drop=True)


def _figure_svg(table: pd.DataFrame, column: str, ylabel: str,
                colors: dict | None = None) -> str:
    fig, ax = plots.figure(plots.WIDTH, 3.8)
    markers = {"random": "o-", "like": "s-"}
    palette = solver_colors(table["solver"].astype(str).unique())
    palette.update(colors or {})
    for (prob, solver, low), g in table.groupby(["problem", "solver", "low"]):
        style = markers.get(low, "*")
        ax.plot(g["rel_error"], g[column], style, ms=8 if style == "*" else 4,
                color=palette.get(str(solver)), label=f"{prob} {solver} {low}")
    if column == "emvps" and table["best_single_fidelity"].notna().any():
        for _prob, g in table.groupby("problem"):
            ax.axhline(float(g["best_single_fidelity"].iloc[0]), ls=":", color="grey", lw=1)
    ax.set_xscale("log")
    ax.invert_xaxis()
    ax.set_xlabel("relative error of the low fidelity ||A_low - A|| / ||A||")
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=plots.LEGEND_PT, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              borderaxespad=0.0, frameon=False)
    return plots.svg_of(fig)


def _figure(table: pd.DataFrame, column: str, ylabel: str, key: str,
            colors: dict | None) -> str:
    svg = _figure_svg(table, column, ylabel, colors)
    return f'<div class="fig">{plots.prefix_ids(svg, key)}</div>'


def fidelity_map_section(results: pd.DataFrame, *, colors: dict | None = None
                         ) -> tuple[str, pd.DataFrame]:
    """HTML of the section and its table (``("", empty)`` when the store has no such runs).

    ``colors`` is the report's solver-to-colour map (the solvers' own colours by default).
    """
    table = fidelity_map_table(results)
    if table.empty:
        return "", table
    body = html_table(table)
    parts = ["<h2 id='fidelity-map'>Fidelity advantage</h2>"
             "<p class='note'>Median high-fidelity MVPs and E-MVPs "
             "of the multi-fidelity solvers (verified-solved runs) against the relative error "
             "of their low fidelity: synthetic A + E (random or shaped like the set's own low "
             "error) and the set's real lows (stars). Dotted: the best single-fidelity "
             "solver's median E-MVPs on the same problem. The exact-subproblem oracle floor: "
             f"{html.escape('python benchmarks/fidelity_map.py')}.</p>", body,
             _figure(table, "high_mvps", "median high-fidelity MVPs", "fm1_", colors),
             _figure(table, "emvps", "median E-MVPs", "fm2_", colors)]
    return "\n".join(parts), table
