"""HTML of the report's "Beside the method paper" section.

Offline: one table per paper-like set (:func:`lcpbench.report.paper_section.compare_set`)
with the lines saying why rows differ; online, when the store has online rows: the
measured online table beside the paper's (:mod:`lcpbench.report.paper_online`).
"""

from __future__ import annotations

import html
from collections.abc import Callable
from pathlib import Path

import pandas as pd

from lcpbench.report import paper_online, paper_section, tables
from lcpbench.report.markup import html_table

__all__ = ["paper_html", "online_beside_paper_html"]


def online_beside_paper_html(paper: pd.DataFrame, baseline: str) -> str:
    """The measured online table (:func:`lcpbench.report.tables.online_paper_table`) beside
    the method paper's."""
    both = paper_online.beside_paper(paper, baseline)
    both["collision share"] = [f"{v:.0%}" if pd.notna(v) else "-"
                               for v in both["collision share"]]
    return ("<h3>Online, beside the method paper's online table</h3><p class='note'>Per "
            "lattice size, the measured row(s) and the paper's (200 time steps, 24 cores, a "
            "Stokes FMM far field): the baseline's summed seconds, the share of its step that "
            "collision resolution takes (the paper's premise is that it dominates a step), and "
            "the speedups of Mono-PQN and Bi-PQN over the compared steps (warm-up steps and "
            "steps without products set apart, see <a href='#online'>Online simulations</a>). "
            "Seconds of different machines do not compare; shares and speedups do.</p>"
            + html_table(tables.online_paper_display(both)))


def _set_paths(res: pd.DataFrame, problem: str) -> tuple[Path | None, list[str] | None]:
    from lcpbench.workflows.fidelity import stored_set_specs

    specs = stored_set_specs(res[res["problem"].astype(str) == problem].head(1))
    return specs[0] if specs else (None, None)


def _offline_part(views: list, res: pd.DataFrame, baseline: str,
                  write: Callable[[str, pd.DataFrame], None]) -> list[str]:
    cuts = {v.problem: v.cut for v in views}
    parts, frames = [], []
    for problem in paper_section.paper_like_sets(cuts):
        path, ids = _set_paths(res, problem)
        errors = paper_section.low_errors(path, ids) if path is not None else {}
        comp = paper_section.compare_set(problem, cuts[problem], baseline, errors)
        frames.append(comp.table.assign(problem=problem))
        view = next(v for v in views if v.problem == problem)
        parts.append(f"<p class='caption'>{html.escape(problem)}: {view.info['instances']} "
                     f"instances (n {html.escape(view.n_range)}) beside the paper's offline "
                     "table</p>")
        parts.append(html_table(comp.table, text=True))
        if comp.why:
            parts.append("<p class='note'>Where lcpbench and the paper differ, and why:</p>"
                         "<ul class='note'>" + "".join(f"<li>{html.escape(w)}</li>"
                                                        for w in comp.why) + "</ul>")
        else:
            parts.append("<p class='note'>Every ratio is within "
                         f"{paper_section.RATIO_GAP:g} of the paper's.</p>")
    write("beside_paper", pd.concat(frames, ignore_index=True) if frames else pd.DataFrame())
    return parts


def paper_html(views: list, res: pd.DataFrame, baseline: str,
               write: Callable[[str, pd.DataFrame], None]) -> str:
    """The section's HTML ("" when the store has neither a paper-like set nor online rows)."""
    b = html.escape(baseline)
    parts = _offline_part(views, res, baseline, write)
    online = tables.online_runs(res) if len(res) else res
    paper = tables.online_paper_table(res, baseline) if len(online) else pd.DataFrame()
    if not parts and paper.empty:
        return ""
    head = ("<h2 id='paper'>Beside the method paper</h2><p class='note'>The method paper's "
            "offline table (every method on 50 LCPs of a 125-sphere simulation, BIM p = 8 "
            "at eps_gmres 1e-8) beside each set here with a Bi-PQN run on one of the "
            "paper's lows: the median E-MVPs of the solved runs (high-fidelity MVPs in "
            f"parentheses for Bi-PQN), and the ratio to {b}, lcpbench's as the median "
            f"per-instance ratio [25-75 %] with the solved count. The sets are not the "
            "paper's instances, so the ratios are the comparable figures. Bi-PQN on lows the "
            "paper did not have (the distance-split lows) has no paper figure.</p>")
    if paper.empty and parts:
        return head + "\n".join(parts)
    return head + "\n".join(parts) + online_beside_paper_html(paper, baseline)
