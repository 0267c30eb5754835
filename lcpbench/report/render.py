"""``lcpbench report DIR``: one self-contained ``report.html`` from a run store.

No network and no CDN: figures are inline SVG, CSS is inline. The tables are
also written beside the HTML as CSV and Markdown (``DIR/tables/``), sorted and
formatted deterministically so two reports diff cleanly; their Markdown is
escaped (no raw HTML). The page opens with a table of contents and a summary per
problem set; every ranking is per problem set on common ground (see
:mod:`lcpbench.report.offline`). The fidelity study of stored sets is cached in the
user cache directory (:func:`lcpbench.workflows.fidelity.user_cache_dir`), keyed by
the set's content, so it is computed once per set, not once per output folder.
"""

from __future__ import annotations

import html
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER
from lcpbench.report import fidelity_map, offline, paper_online, plots, tables
from lcpbench.report.colors import solver_colors
from lcpbench.report.fidelity import fidelity_section
from lcpbench.report.markup import html_table, markdown_table
from lcpbench.report.paper_html import paper_html
from lcpbench.run.store import RunStore, atomic_write
from lcpbench.workflows.fidelity import stored_set_specs, user_cache_dir

__all__ = ["render_report", "stderr_progress", "markdown_table", "Section", "SECTIONS"]

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;
max-width:1200px;color:#222;padding:0 1em}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0 1.5em;max-width:100%}
th,td{border:1px solid #ddd;padding:.25em .5em;text-align:right;overflow-wrap:anywhere}
table.text td{text-align:left}
th{background:#f3f3f3}td:first-child{text-align:left}
td.text{text-align:left}
.fig{margin:1em 0;overflow:hidden}.fig svg{max-width:100%;height:auto}
.note{color:#555;font-size:.9em}code{background:#f6f6f6;padding:0 .2em}
.caption{font-weight:600;margin:1.2em 0 .2em}
nav#contents ul{columns:2;list-style:none;padding-left:0}nav#contents li.sub{padding-left:1.5em}
"""


def stderr_progress(prefix: str = "lcpbench report") -> Callable[[str], None]:
    """A progress callback that prints ``prefix: [seconds] text`` lines on stderr."""
    start = time.perf_counter()

    def say(text: str) -> None:
        print(f"{prefix}: [{time.perf_counter() - start:5.1f} s] {text}", file=sys.stderr,
              flush=True)

    return say


def _write_table(out: Path, name: str, df: pd.DataFrame) -> None:
    out.mkdir(exist_ok=True)
    if df is None or df.empty:
        df = pd.DataFrame()
    atomic_write(out / f"{name}.csv", df.to_csv(index=False, float_format="%.6g"))
    atomic_write(out / f"{name}.md", markdown_table(df))


#: Tables written per problem set (or, by earlier versions, pooled over every set): the
#: ones of a previous render are removed first, so no stale or pooled table stays behind.
_PER_SET_TABLES = ("work_precision*.csv", "work_precision*.md", "profile_*.csv", "profile_*.md")


def _drop_stale_tables(tdir: Path) -> None:
    for pattern in _PER_SET_TABLES:
        for old in tdir.glob(pattern):
            old.unlink()


def _anchor(k: int) -> str:
    return f"set{k + 1}"


@dataclass(frozen=True)
class Section:
    """One part of the page: its anchor, its entry in the contents (level 2, or 3 for a
    problem set) and its HTML."""

    anchor: str
    title: str
    html: str
    level: int = 2


@dataclass
class _Page:
    """What every section builder reads: the run store's data and the page's services."""

    res: pd.DataFrame
    hist: pd.DataFrame
    meta: dict
    baseline: str
    colors: dict
    fig: Callable[[str], str]                         # an SVG as a numbered figure
    write: Callable[[str, pd.DataFrame], None]        # a table to DIR/tables/
    say: Callable[[str], None]
    views: list = field(default_factory=list)         # offline sets on common ground


def render_report(path, baseline: str = BASELINE_SOLVER,
                  progress: Callable[[str], None] | None = None) -> Path:
    """Render ``DIR/report.html`` (and ``DIR/tables/*``) from the run store at ``path``.

    The page is the sections of :data:`SECTIONS` in order, each builder returning
    its :class:`Section` list (empty when the store has nothing for it).

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
    for file, line, reason in store.corrupt:   # never set aside without a word
        print(f"lcpbench report: {file}, line {line}: {reason}; the line was moved to "
              f"{Path(file).name}.corrupt and its run is not in the report (rerun the same "
              "lcpbench run command to redo it)", file=sys.stderr)
    res = store.results()
    tdir = folder / "tables"
    fig_no = [0]

    def fig(svg: str) -> str:
        fig_no[0] += 1
        return f'<div class="fig">{plots.prefix_ids(svg, f"f{fig_no[0]}_")}</div>'

    _drop_stale_tables(tdir)
    page = _Page(res, store.history(), store.read_meta() or {}, baseline,
                 solver_colors(res["solver"].astype(str).unique()) if len(res) else {}, fig,
                 lambda name, df: _write_table(tdir, name, df), say)
    say("offline tables and figures, per problem set")
    page.write("offline", tables.offline_table(res))
    page.views = offline.set_views(res, page.hist)
    sections = [section for build in SECTIONS for section in build(page)]
    text = ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            "<title>lcpbench report</title><style>" + _CSS + "</style></head><body>"
            "<h1>lcpbench report</h1>" + _toc_html(sections)
            + "\n".join(s.html for s in sections if s.html) + "</body></html>\n")
    out = folder / "report.html"
    atomic_write(out, text)
    say(f"wrote {out}")
    return out


def _summary_sections(page: _Page) -> list[Section]:
    """The summary: per set the best solver and each solver's ratio to the baseline."""
    views = page.views
    out = []
    if views:
        stats = offline.ratio_stats(views, page.baseline)
        summary = offline.summary_table(views, page.baseline, stats)
        page.write("summary", summary)
        b = html.escape(page.baseline)
        grids = offline.ratio_tables(views, page.baseline, stats)
        page.write("ratios", pd.concat(grids, ignore_index=True) if grids else pd.DataFrame())
        out.append(Section("summary", "Summary", (
            "<h2 id='summary'>Summary</h2><p class='note'>Per problem set: its "
            "problem size n, the instances compared (those every compared solver "
            "was given, of the set's), the solvers compared, the solver with the lowest "
            f"median ratio of its E-MVPs to {b}'s (per instance; an instance it did not "
            "solve counts as an infinite ratio) with the 25-75 % quartiles of the ratios "
            "and its solved count, and at each residual level the solver with the lowest "
            "median E-MVPs to first reach it (a run that never reached it counting as "
            "infinitely many), that median and how many runs reached the level. Every cell "
            "shows the statistic its solver was chosen by.</p>"
            + html_table(summary, text=True)
            + f"<p class='caption'>Each solver's median ratio to {b} [25 %-75 %], solved "
            "count, per set</p><p class='note'>Ratios per instance of the set's compared "
            f"instances that {b} solved; below 1 is cheaper than {b}.</p>"
            + "".join(html_table(g, text=True) for g in grids))))
    return out


def _paper_sections(page: _Page) -> list[Section]:
    """Beside the method paper: its offline table next to each paper-like set, and its
    online table next to the online rows (:mod:`lcpbench.report.paper_section`)."""
    html_text = paper_html(page.views, page.res, page.baseline, page.write)
    return [Section("paper", "Beside the method paper", html_text)] if html_text else []


def _offline_sections(page: _Page) -> list[Section]:
    """The run's metadata and one section per problem set."""
    views = page.views
    out = [Section("run", "Run", _meta_section(page.meta, page.res))]
    if not views:
        return out
    shift = offline.ranking.SHIFT["emvps"]
    out.append(Section("offline", "Offline comparison, per problem set", (
        "<h2 id='offline'>Offline comparison, per problem set</h2><p class='note'>"
        + offline.CONVENTIONS.format(shift_e=shift)
        + f" The baseline of the ratios is {html.escape(page.baseline)}.</p>")))
    for k, view in enumerate(views):
        page.say(f"problem set {k + 1}/{len(views)}: {view.problem}")
        out.append(Section(_anchor(k), view.problem, offline.set_section(
            view, baseline=page.baseline, meta=page.meta, colors=page.colors,
            anchor=_anchor(k), fig=page.fig, write=page.write), level=3))
    return out


def _references_sections(page: _Page) -> list[Section]:
    refs = offline.references_section(page.res, page.write)
    return [Section("references", "Reference QP solvers", refs)] if refs else []


def _failures_sections(page: _Page) -> list[Section]:
    fails = tables.failures_table(page.res)
    page.write("failures", fails)
    title = f"Runs not solved ({len(fails)})"
    return [Section("failures", title, (
        f"<h2 id='failures'>{title}</h2><p class='note'>Every "
        "run whose verified residual missed the tolerance, with the solver's status "
        "and message.</p>" + html_table(fails, text=True)))]


def _online_sections(page: _Page) -> list[Section]:
    if not len(tables.online_runs(page.res)):
        return []
    page.say("online table")
    paper = tables.online_paper_table(page.res, page.baseline)
    page.write("online_paper", paper)
    if not paper.empty:
        page.write("online_beside_paper", paper_online.beside_paper(paper, page.baseline))
    page.write("online", tables.online_table(page.res, page.baseline))
    page.write("online_left_out", tables.online_left_out(page.res))
    return [Section("online", "Online simulations", _online_html(
        page.res, paper, page.baseline, page.fig, page.colors))]


def _fidelity_map_sections(page: _Page) -> list[Section]:
    fmap_html, fmap = fidelity_map.fidelity_map_section(page.res, colors=page.colors)
    if not fmap_html:
        return []
    page.write("fidelity_map", fmap)
    return [Section("fidelity-map", "Fidelity advantage", fmap_html)]


def _fidelity_study_sections(page: _Page) -> list[Section]:
    stored_sets = stored_set_specs(page.res)
    if not stored_sets:
        return []
    fid = fidelity_section(stored_sets, cache_dir=user_cache_dir(), progress=page.say,
                           names=_set_names(page.res))
    return [Section("fidelity", "Fidelity study of the stored sets", fid)] if fid else []


#: The page's sections, in order.
SECTIONS: tuple[Callable[[_Page], list[Section]], ...] = (
    _summary_sections, _paper_sections, _offline_sections, _references_sections, _failures_sections, _online_sections,
    _fidelity_map_sections, _fidelity_study_sections)


def _toc_html(sections: list[Section]) -> str:
    items = []
    for s in sections:
        cls = " class='sub'" if s.level > 2 else ""
        items.append(f"<li{cls}><a href='#{s.anchor}'>{html.escape(s.title)}</a></li>")
    return f"<nav id='contents'><h2>Contents</h2><ul>{''.join(items)}</ul></nav>"


def _set_names(res: pd.DataFrame) -> dict[str, str]:
    """The problem-set label of each stored-set file the runs used (resolved path -> label)."""
    names: dict[str, str] = {}
    if res.empty or "problem" not in res:
        return names
    for problem, part in res.groupby("problem", sort=True):
        for path, _ in stored_set_specs(part.head(1)):
            names.setdefault(str(Path(path).resolve()), str(problem))
    return names


def _online_html(res: pd.DataFrame, paper: pd.DataFrame, baseline: str,
                 fig: Callable[[str], str], colors: dict) -> str:
    """The paper-shaped online table and its E-MVP box plot (same rows), then what was left out."""
    b = html.escape(baseline)
    parts = ["<h2 id='online'>Online simulations</h2>",
             "<p class='note'>One row per scene, as the method paper's online table. "
             "<i>total</i> is the wall time of whole time steps (contact detection, mobility "
             "set-up, the non-collisional solve, the LCP solve and the position update, "
             "plus the framework's uncounted product that verifies each answer and any "
             "per-step timing of the operators' costs); <i>collision resolution</i> is the "
             "wall time of the LCP solves alone. Times are "
             f"summed wall seconds on the machine that ran the simulations. {b} is the "
             f"baseline: its seconds are given, and every other solver's speedup is {b}'s "
             "summed seconds divided by the solver's over the same compared steps (- where "
             "the baseline did not run on the scene or no step is left to compare). The "
             "compared steps are those every solver of the scene finished, less the warm-up "
             "steps (each simulation's first step, which pays the one-off compilation of the "
             "numerical kernels) and the steps without contacts (nothing to solve); those "
             "are listed apart below. Last columns: the median E-MVPs and high-fidelity MVPs "
             "per compared step. " + html.escape(_common_steps_note(res)) + "</p>"]
    if paper.empty:
        parts.append("<p class='note'>No step is left to compare once the warm-up steps and "
                     "the steps without contacts are set apart: no speedup is given.</p>")
    else:
        parts.append(html_table(tables.online_paper_display(paper)))
        parts.append("<p class='note'>The same rows beside the method paper's online table: "
                     "<a href='#paper'>Beside the method paper</a>.</p>")
    steps = tables.online_step_rows(res)
    if len(steps) and pd.to_numeric(steps["emvps"], errors="coerce").notna().any():
        groups = list(dict.fromkeys(steps["size"]))
        order = paper.attrs.get("solvers") or None
        parts.append(fig(plots.grouped_boxplot_svg(
            steps, "size", "solver", "emvps", "E-MVPs per compared time step by lattice size",
            "lattice size", "E-MVPs per step (log scale)", groups=groups, order=order,
            colors=colors)))
        parts.append("<p class='note'>Each box: one solver's E-MVPs per step over the same "
                     "compared steps as the table above (its medians are the black lines); "
                     "with a zero among them the axis is linear below 1.</p>")
    apart = tables.online_left_out(res)
    if not apart.empty:
        parts.append("<h3>Steps left out of the speedups</h3><p class='note'>Per scene and "
                     "solver: the warm-up steps and the steps without contacts, with their "
                     "summed seconds and E-MVPs.</p>")
        parts.append(html_table(apart, text=True))
    parts.append("<h3>Per scene and solver</h3><p class='note'>Every simulation over all the "
                 "steps it finished, warm-up and contact-free steps included (the step counts "
                 "of one scene may differ here): summed total and collision-resolution "
                 "seconds, median E-MVPs and MVPs per step, the largest overlap after a step "
                 "and the steps solved (verified).</p>")
    parts.append(html_table(tables.online_table(res, baseline)))
    return "\n".join(parts)


def _common_steps_note(res: pd.DataFrame) -> str:
    """Which steps each scene's solvers are compared over, and where a simulation was cut."""
    notes = []
    for scene, info in tables.online_common_steps(res).items():
        common = len(info["steps"])
        longer = {s: n for s, n in info["stored"].items() if n > common}
        if longer:
            more = ", ".join(f"{s} has {n}" for s, n in sorted(longer.items()))
            notes.append(f"{scene}: {common} steps every solver finished ({more}; the extra "
                         "steps are left out)")
    head = "Solvers of one scene are compared over the steps they all finished"
    return head + (": " + "; ".join(notes) + "." if notes else "; no simulation was cut.")


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
    return f"<h2 id='run'>Run</h2><table>{body}</table>"
