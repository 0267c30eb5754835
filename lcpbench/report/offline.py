"""The offline part of the report: the summary, one section per problem set, the references.

Every view of a set's section (its table, box plot, convergence curves, work-precision
table and the figure of work-precision and performance profiles) is computed from the
same runs: the set's ranked solvers on common ground
(:func:`lcpbench.report.ranking.common_ground`). Each view is wrapped in
``<div class="view" data-set=... data-instances=...>`` and its caption says how many
instances it covers, so a reader (and the browser test) can check that no view pools
unlike sets.
"""

from __future__ import annotations

import html
import json
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER
from lcpbench.report import panels, plots, ranking, ratios, tables
from lcpbench.report.markup import html_table

__all__ = ["SetView", "set_views", "summary_table", "ratio_stats", "ratio_tables", "set_section", "references_section",
           "CONVENTIONS"]

#: How each view counts failures, stated once at the top of the offline part.
CONVENTIONS = (
    "Every view below is per problem set and over the instances every compared solver "
    "was given (its caption says how many); reference QP solvers are never ranked (they "
    "have their own table). A run is a success when the framework's verified residual "
    "meets the tolerance. Tables: <i>solved</i> and <i>success</i> count every compared "
    "run; min / median / mean / max E-MVPs are over the solved runs; the ratio to the "
    "baseline is over the instances both solved, with that count; the <i>shifted GM</i> "
    "(shifted geometric mean, shift {shift_e:g} E-MVPs, as qpbenchmark) counts every run, "
    "a failure at the penalty (the sweep's E-MVP budget, else ten times the set's "
    "largest), and <i>shifted GM / best</i> divides it by the best solver's. "
    "Work-precision: medians over the runs that reached each level, with k/m. "
    "Performance profiles (Dolan-More): a failure is never within any factor tau. Box "
    "plots: the solved runs, with k/m under each solver. Convergence: median and "
    "25-75 % band over every compared run.")


@dataclass
class SetView:
    """One problem set on common ground: its runs and what the views need."""

    problem: str
    cut: pd.DataFrame               # E-MVP ranked runs (MVP-only, no reference)
    cut_time: pd.DataFrame          # seconds ranked runs (no reference)
    info: dict
    n_range: str
    history: pd.DataFrame = field(default_factory=pd.DataFrame)   # of these runs only
    reach: pd.DataFrame = field(default_factory=pd.DataFrame)


def _n_range(part: pd.DataFrame) -> str:
    n = pd.to_numeric(part.get("n"), errors="coerce").dropna()
    if n.empty:
        return "-"
    lo, hi = int(n.min()), int(n.max())
    return str(lo) if lo == hi else f"{lo}-{hi}"


def set_views(results: pd.DataFrame, history: pd.DataFrame) -> list[SetView]:
    """One :class:`SetView` per offline problem set that has ranked runs, sorted by name."""
    emvp = ranking.ranked_runs(results, "emvps")
    timed = ranking.ranked_runs(results, "time_s")
    out = []
    for problem in sorted(timed["problem"].astype(str).unique()) if not timed.empty else []:
        cut, info = ranking.common_ground(emvp[emvp["problem"].astype(str) == problem])
        cut_t, _ = ranking.common_ground(timed[timed["problem"].astype(str) == problem])
        ids = set(cut_t["run_id"]) | set(cut["run_id"])
        hist = history[history["run_id"].isin(ids)] if not history.empty else history
        view = SetView(problem, cut, cut_t, info,
                       _n_range(timed[timed["problem"].astype(str) == problem]), hist)
        view.reach = tables.reach_table(cut, hist) if not cut.empty else pd.DataFrame()
        out.append(view)
    return out


def _best_at(view: SetView, level: str) -> str:
    """``solver: cost (k/m)`` of the solver with the lowest median E-MVPs to reach ``level``,
    a run that never reached it counting as infinitely many: the statistic the cell shows."""
    r = view.reach
    if r.empty:
        return "-"
    scored = []
    for solver, g in r.groupby("solver", sort=True):
        v = g[f"emvps@{level}"]
        med = float(np.median(v.astype(float).fillna(np.inf)))
        scored.append((round(med, 9) if np.isfinite(med) else np.inf, str(solver),
                       int(v.notna().sum()), len(g)))
    scored.sort(key=lambda t: (t[0], t[1]))
    top, solver, hit, total = scored[0]
    if not np.isfinite(top):
        return f"none reached it in half its runs ({max(t[2] for t in scored)}/{total} at most)"
    ties = sum(1 for t in scored[1:] if t[0] <= top * (1 + 1e-9))
    tied = f" (tied with {ties} more)" if ties else ""
    return f"{solver}{tied}: {top:.3g} E-MVPs ({hit}/{total})"


def summary_table(views: list[SetView], baseline: str = BASELINE_SOLVER,
                  stats: dict[str, list[ratios.RatioStats]] | None = None) -> pd.DataFrame:
    """Per problem set: n, instances compared, the best solver by its median ratio to the
    baseline, and the best solver at each residual level.

    The best solver by ratio has the lowest median per-instance E-MVP ratio to
    ``baseline`` (:mod:`lcpbench.report.ratios`; an unsolved instance counts as an
    infinite ratio), shown with the quartiles and its solved count. The best solver at a
    level has the lowest median E-MVPs to first reach it, a run that never reached it
    counting as infinitely many; its cell gives that median and how many runs reached the
    level. Each cell shows the statistic its solver was chosen by. ``stats`` are the
    sets' :func:`ratio_stats` when already computed.
    """
    stats = stats if stats is not None else ratio_stats(views, baseline)
    rows = []
    for v in views:
        row = {"problem set": v.problem, "n": v.n_range,
               "instances": f"{v.info['instances']} of {v.info['total']}",
               "solvers": len(v.info["solvers"])}
        best = ratios.best_by_ratio(stats.get(v.problem, []))
        row[f"best median ratio to {baseline}"] = (
            f"{best.solver}: {ratios.format_ratio(best)}" if best is not None
            else f"- ({baseline} solved no instance at a positive cost)")
        for lv in tables.LEVELS:
            row[f"best to {lv:.0e}"] = _best_at(v, f"{lv:.0e}")
        rows.append(row)
    return pd.DataFrame(rows)


def ratio_stats(views: list[SetView], baseline: str) -> dict[str, list[ratios.RatioStats]]:
    """Per set, every solver's :class:`~lcpbench.report.ratios.RatioStats` to ``baseline``."""
    return {v.problem: ratios.ratio_stats(v.cut, baseline) for v in views}


def ratio_tables(views: list[SetView], baseline: str,
                 stats: dict[str, list[ratios.RatioStats]] | None = None) -> list[pd.DataFrame]:
    """Each solver's median ratio to ``baseline`` [quartiles] and solved count, per set
    (:func:`lcpbench.report.ratios.ratio_matrix`: solvers down, at most three sets
    across per table); ``stats`` as :func:`summary_table`'s."""
    per_set = stats if stats is not None else ratio_stats(views, baseline)
    return ratios.ratio_matrix({k: s for k, s in per_set.items() if s})


def _caption(view: SetView, what: str) -> str:
    i = view.info
    left = ""
    if i["instances"] < i["total"]:
        left = (f" ({i['total'] - i['instances']} of the set's {i['total']} left out: not "
                "every solver was given them)")
    return (f"<p class='caption'>{what}: {html.escape(view.problem)}, over "
            f"{i['instances']} instances (n {view.n_range}){left}.</p>")


def _view(view: SetView, body: str, caption: str) -> str:
    return (f"<div class='view' data-set='{html.escape(view.problem, quote=True)}' "
            f"data-instances='{view.info['instances']}'>{caption}{body}</div>")


def set_section(view: SetView, *, baseline: str, meta: dict, colors: dict, anchor: str,
                fig: Callable[[str], str], write: Callable[[str, pd.DataFrame], None]) -> str:
    """HTML of one problem set: table, box plot, convergence, work-precision and profiles."""
    parts = [f"<h3 id='{anchor}'>{html.escape(view.problem)}</h3>"]
    n_inst = view.info["instances"]
    if not view.cut.empty:
        table = ranking.ranking_table(view.cut, baseline, meta)
        parts.append(_view(view, html_table(table), _caption(
            view, f"E-MVPs per solver (failures count at {table.attrs['penalty']:.3g} in the "
                  "shifted GM)")))
        solved = view.cut[ranking.truthy(view.cut["solved"])]
        counts = {s: f"{int(ranking.truthy(g['solved']).sum())}/{len(g)}"
                  for s, g in view.cut.groupby("solver")}
        free = len(solved) and bool((pd.to_numeric(solved["emvps"], errors="coerce")
                                     == 0).all())
        if free:        # nothing to draw on a log axis: say so instead of an empty figure
            parts.append(_view(view, "<p class='note'>Every solved run spent 0 E-MVPs (the "
                               "warm start already solves or no product was needed): no "
                               "E-MVP box plot.</p>", _caption(view, "Box plot of solved runs")))
        elif len(solved):
            parts.append(_view(view, fig(plots.boxplot_svg(
                solved, "solver", "emvps", f"E-MVPs of the solved runs: {view.problem} "
                f"({n_inst} instances)", "E-MVPs (log scale)", order=list(table["solver"]),
                colors=colors, counts=counts)), _caption(view, "Box plot of solved runs")))
        setup = _setup_note(view.cut)
        if setup:
            parts.append(setup)
        curves = tables.convergence_curves(view.cut, view.history, "emvps")
        for title, group in panels.panel_groups(curves, baseline):
            parts.append(_view(view, fig(plots.curves_svg(
                {s: curves[s] for s in group}, "E-MVPs (log scale)",
                f"Residual against E-MVPs: {view.problem} ({n_inst} instances)"
                + (f", {title}" if title else ""), colors=colors)), _caption(
                view, "Convergence (exact zeros drawn a decade below the smallest residual)"
                + (f", {title}" if title else ""))))
    wp = tables.work_precision(view.cut_time, view.history)
    write(f"work_precision_{anchor}", wp)
    if not wp.empty:
        parts.append(_view(view, html_table(tables.work_precision_display(wp)),
                           _caption(view, "Speed against error (E-MVPs, seconds, k/m)")))
        profiles = {m: tables.performance_profile(view.cut if m == "emvps" else view.cut_time,
                                                  m) for m in ("emvps", "time_s")}
        for m, prof in profiles.items():
            write(f"profile_{m}_{anchor}", prof)
        mvp_only = wp["solver"].isin(set(view.cut["solver"]))    # E-MVPs mean nothing else
        wp_e = wp.copy()
        for c in wp.columns:
            if c.startswith("emvps@"):
                wp_e[c] = wp[c].where(mvp_only, None)
        for title, group in panels.panel_groups(wp["solver"].astype(str), baseline):
            keep = {m: p[["tau"] + [c for c in p.columns if c in group]] if not p.empty else p
                    for m, p in profiles.items()}
            parts.append(_view(view, fig(plots.set_overview_svg(
                wp_e[wp_e["solver"].isin(group)], keep,
                f"Speed views: {view.problem} ({n_inst} instances)"
                + (f", {title}" if title else ""), colors=colors)),
                _caption(view, "Work-precision and performance profiles"
                         + (f", {title}" if title else ""))))
    return "\n".join(parts)


def _setup_note(cut: pd.DataFrame) -> str:
    """A note naming the counted set-up products inside some solvers' E-MVPs (A-PGD's
    power iterations that estimate L), or ""."""
    notes = []
    for solver, g in cut.groupby("solver", sort=True):
        power = []
        for text in g["info"].dropna() if "info" in g else []:
            try:
                v = json.loads(text).get("power_mvps")
            except (ValueError, AttributeError):
                continue
            if isinstance(v, (int, float)) and v > 0:
                power.append(float(v))
        if power:
            notes.append(f"{html.escape(str(solver))}: its E-MVPs include a median of "
                         f"{np.median(power):g} counted power-iteration products (set-up "
                         "products that estimate L before the first step; with "
                         "constants=oracle it is given L and mu and counts none, as in the "
                         "method paper)")
    return ("<p class='note'>Set-up products counted in the E-MVPs: " + "; ".join(notes)
            + ".</p>") if notes else ""


def references_section(results: pd.DataFrame,
                       write: Callable[[str, pd.DataFrame], None]) -> str:
    """The reference QP solvers in their own table (never in a ranking)."""
    refs = ranking.references_table(results)
    write("references", refs)
    if refs.empty:
        return ""
    return ("<h2 id='references'>Reference QP solvers</h2><p class='note'>The reference QP "
            "solvers (through qpsolvers, on the dense matrix) define the ground truth: a "
            "consensus of those that agree. They count no MVPs, so they are in no E-MVP "
            "ranking and in no figure. Per set: the runs solved (verified), the median wall "
            "seconds, the median verified residual ||min(x, Ax+b)|| (needs no reference), what "
            "the set's reference is made of (most often), on how many instances the solver was part of the consensus, and the median error "
            "of w against a reference that did not include it (the count in parentheses; - "
            "where it was in every consensus).</p>" + html_table(refs))
