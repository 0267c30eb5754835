"""``lcpbench report DIR``: one self-contained ``report.html`` from a run store.

No network and no CDN: figures are inline SVG, CSS is inline. The tables are
also written beside the HTML as CSV and Markdown (``DIR/tables/``), sorted and
formatted deterministically so two reports diff cleanly. The fidelity study of
stored sets is cached in ``DIR/cache/``, so re-rendering takes seconds.
"""

from __future__ import annotations

import html
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER
from lcpbench.report import fidelity_map, plots, tables
from lcpbench.report.fidelity import fidelity_section
from lcpbench.run.store import RunStore, atomic_write
from lcpbench.workflows.fidelity import stored_set_specs

__all__ = ["render_report", "stderr_progress"]

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;
max-width:1200px;color:#222;padding:0 1em}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0 1.5em;max-width:100%}
th,td{border:1px solid #ddd;padding:.25em .5em;text-align:right}
td{overflow-wrap:break-word}
table.text td{text-align:left}
th{background:#f3f3f3}td:first-child{text-align:left}
td.text{text-align:left}
.fig{margin:1em 0;overflow:hidden}.fig svg{max-width:100%;height:auto}
.note{color:#555;font-size:.9em}code{background:#f6f6f6;padding:0 .2em}
"""


def stderr_progress(prefix: str = "lcpbench report") -> Callable[[str], None]:
    """A progress callback that prints ``prefix: [seconds] text`` lines on stderr."""
    start = time.perf_counter()

    def say(text: str) -> None:
        print(f"{prefix}: [{time.perf_counter() - start:5.1f} s] {text}", file=sys.stderr,
              flush=True)

    return say


def _table_html(df: pd.DataFrame, text: bool = False) -> str:
    """An HTML table; ``text`` left-aligns every column (tables of messages)."""
    if df is None or df.empty:
        return '<p class="note">(no rows)</p>'
    return df.to_html(index=False, escape=True, na_rep="-", border=0,
                      classes="text" if text else None, float_format=lambda v: f"{v:.3g}")


def _write_table(out: Path, name: str, df: pd.DataFrame) -> None:
    out.mkdir(exist_ok=True)
    if df is None or df.empty:
        df = pd.DataFrame()
    atomic_write(out / f"{name}.csv", df.to_csv(index=False, float_format="%.6g"))
    atomic_write(out / f"{name}.md", df.to_markdown(index=False) if not df.empty else "(no rows)\n")


def render_report(path, baseline: str = BASELINE_SOLVER,
                  progress: Callable[[str], None] | None = None) -> Path:
    """Render ``DIR/report.html`` (and ``DIR/tables/*``) from the run store at ``path``.

    Parameters
    ----------
    path : str or Path
        A run store written by ``lcpbench run`` / ``lcpbench simulate``.
    baseline : str
        Solver the offline ratios and online speedups are measured against.
    progress : callable, optional
        Called with a line of text at each stage (e.g. :func:`stderr_progress`).

    Returns
    -------
    Path of the HTML file.

    Raises
    ------
    FileNotFoundError
        If ``path`` is not a run store.
    """
    folder = Path(path)
    if not (folder / "results.csv").is_file():
        raise FileNotFoundError(f"{folder} has no results.csv: not a run store (run "
                                "`lcpbench run --out DIR` first)")
    say = progress or (lambda text: None)
    say("reading the run store")
    store = RunStore(folder)
    res = store.results()
    hist = store.history()
    meta = store.read_meta() or {}
    tdir = folder / "tables"
    parts: list[str] = []
    fig_no = [0]

    def fig(svg: str) -> str:
        fig_no[0] += 1
        return f'<div class="fig">{plots.prefix_ids(svg, f"f{fig_no[0]}_")}</div>'

    parts.append("<h1>lcpbench report</h1>")
    parts.append(_meta_section(meta, res))

    say("offline tables and box plots")
    _write_table(tdir, "offline", tables.offline_table(res))
    parts.append(_offline_section(res, baseline, fig))

    say("convergence curves")
    parts.append(_convergence_section(res, hist, fig))

    say("work-precision and performance profiles")
    wp = tables.work_precision(res, hist)
    _write_table(tdir, "work_precision", wp)
    parts.append("<h2>Speed against error</h2><p class='note'>Per residual level: the median "
                 "E-MVPs and seconds to first reach it, and how many of the solver's runs "
                 "reached it (out of the runs it was given); last column: the median final "
                 "error of w against the reference.</p>")
    parts.append(_table_html(tables.work_precision_display(wp)))
    if not wp.empty:
        mvp_only = set(res.loc[res["mvp_only"].astype(str).str.lower().eq("true"), "solver"])
        parts.append(fig(plots.work_precision_svg(wp[wp["solver"].isin(mvp_only)], "emvps",
                                                  "median E-MVPs (log scale)",
                                                  "Work-precision (E-MVPs, MVP-only solvers)")))
        parts.append(fig(plots.work_precision_svg(wp, "s", "median seconds (log scale)",
                                                  "Work-precision (seconds)")))

    parts.append("<h2>Performance profiles</h2><p class='note'>Dolan-More: the share of the "
                 "problems a solver was run on that it solves within a factor tau of the best "
                 "solver; a run that did not meet the tolerance counts as never. A solver "
                 "that was not run on every problem (a multi-fidelity solver on instances "
                 "without a low fidelity) says in the legend on how many it was run; the "
                 "problems it was not run on are not counted, neither as solved nor as "
                 "failed.</p>")
    for metric, label in (("emvps", "E-MVPs (MVP-only solvers)"), ("time_s", "seconds")):
        prof = tables.performance_profile(res, metric)
        _write_table(tdir, f"profile_{metric}", prof)
        if not prof.empty:
            parts.append(fig(plots.profile_svg(prof, f"Performance profile: {label}")))

    fails = tables.failures_table(res)
    _write_table(tdir, "failures", fails)
    parts.append(f"<h2>Runs not solved ({len(fails)})</h2><p class='note'>Every run whose "
                 "verified residual missed the tolerance, with the solver's status and "
                 "message.</p>")
    parts.append(_table_html(fails, text=True))

    online = tables.online_table(res, baseline)
    if not online.empty:
        say("online table")
        paper = tables.online_paper_table(res, baseline)
        _write_table(tdir, "online_paper", paper)
        _write_table(tdir, "online", online)
        parts.append(_online_section(res, paper, online, baseline, fig))

    fmap_html, fmap = fidelity_map.fidelity_map_section(res)
    if fmap_html:
        _write_table(tdir, "fidelity_map", fmap)
        parts.append(fmap_html)

    stored_sets = stored_set_specs(res)
    if stored_sets:
        parts.append(fidelity_section(stored_sets, cache_dir=folder / "cache", progress=say))

    page = ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            "<title>lcpbench report</title><style>" + _CSS + "</style></head><body>"
            + "\n".join(p for p in parts if p) + "</body></html>\n")
    out = folder / "report.html"
    atomic_write(out, page)
    say(f"wrote {out}")
    return out


def _offline_section(res: pd.DataFrame, baseline: str, fig: Callable[[str], str]) -> str:
    """Per problem set: the paper-shaped table and a box plot of E-MVPs per solver."""
    per_set = tables.paper_tables(res, baseline)
    if not per_set:
        return ""
    off = tables.offline_runs(res)
    off = off[tables.solved_mask(off) & off["mvp_only"].astype(str).str.lower().eq("true")]
    parts = ["<h2>Offline comparison</h2><p class='note'>One table per problem set, as the "
             "method paper's: E-MVPs (effective matrix-vector products) over the runs whose "
             "verified residual met the tolerance, min / median / mean / max; for "
             "multi-fidelity solvers the high-fidelity MVPs are in parentheses. "
             f"<i>solved</i> counts the runs the solver was given; the last column is the "
             f"median E-MVPs divided by {html.escape(baseline)}'s. Reference QP solvers work "
             "on the dense matrix and are left out.</p>"]
    for problem, table in per_set.items():
        parts.append(f"<h3>{html.escape(problem)}</h3>")
        parts.append(_table_html(table))
        part = off[off["problem"] == problem]
        if len(part) and part["emvps"].astype(float).gt(0).any():
            parts.append(fig(plots.boxplot_svg(part, "solver", "emvps",
                                               f"E-MVPs of the solved runs: {problem}",
                                               "E-MVPs (log scale)",
                                               order=list(table["solver"]))))
    return "\n".join(parts)


def _online_section(res: pd.DataFrame, paper: pd.DataFrame, detail: pd.DataFrame,
                    baseline: str, fig: Callable[[str], str]) -> str:
    """The paper-shaped online table, E-MVP box plots per lattice size, then the detail."""
    b = html.escape(baseline)
    parts = ["<h2>Online simulations</h2>",
             "<p class='note'>One row per scene, as the method paper's online table. "
             "<i>total</i> is the wall time of whole time steps (contact detection, mobility "
             "set-up, the non-collisional solve, the LCP solve and the position update, "
             "plus the framework's uncounted product that verifies each answer and any "
             "per-step timing of the operators' costs); <i>collision resolution</i> is the "
             "wall time of the LCP solves alone. Times are "
             f"summed wall seconds on the machine that ran the simulations. {b} is the "
             f"baseline: its seconds are given, and every other solver's speedup is {b}'s "
             "summed seconds divided by the solver's over the same steps (- where the "
             "baseline did not run on the scene). Last columns: the median E-MVPs and "
             "high-fidelity MVPs per step. "
             + html.escape(_common_steps_note(paper)) + "</p>"]
    parts.append(_table_html(tables.online_paper_display(paper)))
    steps = tables.online_step_rows(res)
    if len(steps) and pd.to_numeric(steps["emvps"], errors="coerce").gt(0).any():
        groups = list(dict.fromkeys(steps["size"]))
        order = paper.attrs.get("solvers") or None
        parts.append(fig(plots.grouped_boxplot_svg(
            steps, "size", "solver", "emvps", "E-MVPs per time step by lattice size",
            "lattice size", "E-MVPs per step (log scale)", groups=groups, order=order)))
        parts.append("<p class='note'>Each box: one solver's E-MVPs per step over the steps "
                     "compared in the table above (steps with zero E-MVPs cannot be drawn on "
                     "the log axis).</p>")
    parts.append("<h3>Per scene and solver</h3><p class='note'>Every simulation over all the "
                 "steps it finished (the step counts of one scene may differ here): summed "
                 "total and collision-resolution seconds, median E-MVPs and MVPs per step, "
                 "the largest overlap after a step and the steps solved (verified).</p>")
    parts.append(_table_html(detail))
    return "\n".join(parts)


def _common_steps_note(paper: pd.DataFrame) -> str:
    """Which steps each scene's solvers are compared over, and where a simulation was cut."""
    stored = paper.attrs.get("stored", {})
    notes = []
    for _, row in paper.iterrows():
        counts = stored.get(row["scene"], {})
        longer = {s: n for s, n in counts.items() if n > row["steps"]}
        if longer:
            more = ", ".join(f"{s} has {n}" for s, n in sorted(longer.items()))
            notes.append(f"{row['scene']}: compared over the {row['steps']} steps every "
                         f"solver finished ({more}; the extra steps are left out)")
    head = "Solvers of one scene are compared over the steps they all finished (column steps)"
    return head + (": " + "; ".join(notes) + "." if notes else "; no simulation was cut.")


def _convergence_section(res: pd.DataFrame, hist: pd.DataFrame,
                         fig: Callable[[str], str]) -> str:
    """One figure per problem family: median residual against E-MVPs on a log axis."""
    by = "family" if "family" in res.columns and res["family"].notna().any() else "problem"
    off = tables.offline_runs(res)
    off = off[off["mvp_only"].astype(str).str.lower().eq("true")]
    curves = tables.convergence_curves(off, hist, "emvps", by=by)
    if not curves:
        return ""
    parts = ["<h2>Convergence</h2><p class='note'>Per problem family, the median over runs "
             "of log10 of the residual ||min(x, Ax+b)|| (verified by the framework; the "
             "solver's own where per-iterate verification was off) against E-MVPs on a log "
             "axis, with the 25-75 % band; the legend gives each solver's number of runs.</p>"]
    for family, c in curves.items():
        parts.append(fig(plots.curves_svg(c, "E-MVPs (log scale)",
                                          f"Residual against E-MVPs: {family}")))
    return "\n".join(parts)


def _meta_section(meta: dict, res: pd.DataFrame) -> str:
    rows = [("command", " ".join(meta.get("argv", [])) or "-"),
            ("started", meta.get("started", "-")), ("finished", meta.get("finished", "-")),
            ("git commit", meta.get("git_commit") or "-"),
            ("runs", str(len(res))),
            ("solved (verified)", str(int(tables.solved_mask(res).sum())) if len(res) else "0")]
    m = meta.get("machine", {})
    if m:
        rows += [("python", m.get("python", "-")), ("platform", m.get("platform", "-")),
                 ("cpus", str(m.get("cpu_count", "-"))),
                 ("versions", ", ".join(f"{k} {v}" for k, v in sorted(
                     (m.get("versions") or {}).items()) if v)),
                 ("threads", json.dumps(m.get("threads", {})))]
    if meta.get("config"):
        rows.append(("config", json.dumps(meta["config"], sort_keys=True)))
    if meta.get("skipped"):
        rows.append(("not run", f"{len(meta['skipped'])} multi-fidelity solver/instance pairs "
                                "without a low fidelity (listed in meta.json)"))
    body = "".join(f"<tr><th>{html.escape(k)}</th><td class='text'>{html.escape(str(v))}</td></tr>"
                   for k, v in rows)
    return f"<h2>Run</h2><table>{body}</table>"
