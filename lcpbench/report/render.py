"""``lcpbench report DIR``: one self-contained ``report.html`` from a run store.

No network and no CDN: figures are inline SVG, CSS is inline. The tables are
also written beside the HTML as CSV and Markdown (``DIR/tables/``), sorted and
formatted deterministically so two reports diff cleanly.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import pandas as pd

from lcpbench.workflows import fidelity

from lcpbench.core.defaults import BASELINE_SOLVER
from lcpbench.report import fidelity_map, plots

from lcpbench.report import tables
from lcpbench.run.store import RunStore, atomic_write

__all__ = ["render_report"]

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;
max-width:1200px;color:#222;padding:0 1em}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0 1.5em}
th,td{border:1px solid #ddd;padding:.25em .5em;text-align:right}
th{background:#f3f3f3}td:first-child,td:nth-child(2){text-align:left}
.fig{margin:1em 0}.fig svg{max-width:100%;height:auto}
.note{color:#555;font-size:.9em}code{background:#f6f6f6;padding:0 .2em}
"""


def _table_html(df: pd.DataFrame) -> str:
    if df is None or df.empty:
        return '<p class="note">(no rows)</p>'
    return df.to_html(index=False, escape=True, na_rep="-", border=0)


def _write_table(out: Path, name: str, df: pd.DataFrame) -> None:
    out.mkdir(exist_ok=True)
    if df is None or df.empty:
        df = pd.DataFrame()
    atomic_write(out / f"{name}.csv", df.to_csv(index=False, float_format="%.6g"))
    atomic_write(out / f"{name}.md", df.to_markdown(index=False) if not df.empty else "(no rows)\n")


def render_report(path, baseline: str = BASELINE_SOLVER) -> Path:
    """Render ``DIR/report.html`` (and ``DIR/tables/*``) from the run store at ``path``.

    Parameters
    ----------
    path : str or Path
        A run store written by ``lcpbench run`` / ``lcpbench simulate``.
    baseline : str
        Solver the online speedups are measured against.

    Returns
    -------
    Path of the HTML file.
    """
    folder = Path(path)
    if not (folder / "results.csv").exists():
        raise FileNotFoundError(f"{folder} has no results.csv: not a run store (run "
                                "`lcpbench run --out DIR` first)")
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

    offline = tables.offline_table(res)
    _write_table(tdir, "offline", offline)
    parts.append("<h2>Offline comparison</h2><p class='note'>E-MVPs over verified-solved runs: "
                 "min / median / mean / max; for multi-fidelity solvers the high-fidelity MVPs "
                 "are in parentheses (the paper's table, section \"Offline Comparison\"). "
                 "Success = the framework's own residual met the tolerance.</p>")
    parts.append(_table_html(offline))

    off = res[(res["kind"].fillna("offline") == "offline") & tables.solved_mask(res)]
    off = off[off["mvp_only"].astype(str).str.lower() == "true"]
    if not off.empty:
        parts.append("<h2>E-MVPs per problem size</h2>")
        parts.append(fig(plots.boxplot_svg(off, "n", "emvps", "solver",
                                           "E-MVPs per problem size (solved runs)", "E-MVPs")))
        parts.append("<h2>E-MVPs per instance family</h2>")
        parts.append(fig(plots.boxplot_svg(off, "family", "emvps", "solver",
                                           "E-MVPs per family (solved runs)", "E-MVPs")))

    parts.append("<h2>Convergence</h2><p class='note'>Median of log10 of the verified KKT "
                 "residual (the solver's own where verification per iterate was off), with the "
                 "25-75 % band.</p>")
    for x, label in (("emvps", "E-MVPs"), ("time_s", "seconds")):
        curves = tables.convergence_curves(res, hist, x)
        if curves:
            parts.append(fig(plots.curves_svg(curves, label, f"Residual against {label}")))

    wp = tables.work_precision(res, hist)
    _write_table(tdir, "work_precision", wp)
    parts.append("<h2>Speed against error</h2><p class='note'>Median E-MVPs and seconds to "
                 "first reach each residual level, the share of runs that reached it, and the "
                 "median final error of w against the reference.</p>")
    parts.append(_table_html(wp))
    if not wp.empty:
        parts.append(fig(plots.work_precision_svg(wp, "emvps", "median E-MVPs",
                                                  "Work-precision (E-MVPs)")))
        parts.append(fig(plots.work_precision_svg(wp, "s", "median seconds",
                                                  "Work-precision (seconds)")))

    parts.append("<h2>Performance profiles</h2><p class='note'>Dolan-More: the share of "
                 "problems a solver solves within a factor tau of the best solver; unsolved "
                 "counts as never.</p>")
    for metric, label in (("emvps", "E-MVPs (MVP-only solvers)"), ("time_s", "seconds")):
        prof = tables.performance_profile(res, metric)
        _write_table(tdir, f"profile_{metric}", prof)
        if not prof.empty:
            parts.append(fig(plots.profile_svg(prof, f"Performance profile: {label}")))

    fails = tables.failures_table(res)
    _write_table(tdir, "failures", fails)
    parts.append(f"<h2>Failures ({len(fails)})</h2>")
    parts.append(_table_html(fails))

    online = tables.online_table(res, baseline)
    if not online.empty:
        _write_table(tdir, "online", online)
        parts.append(f"<h2>Online simulations</h2><p class='note'>Totals over all steps; "
                     f"speedups against {html.escape(baseline)}.</p>")
        parts.append(_table_html(online))
        on = res[res["kind"] == "online"]
        parts.append(fig(plots.boxplot_svg(on, "problem", "emvps", "solver",
                                           "E-MVPs per step, per scene", "E-MVPs")))

    fmap_html, fmap = fidelity_map.fidelity_map_section(res)
    if fmap_html:
        _write_table(tdir, "fidelity_map", fmap)
        parts.append(fmap_html)

    stored_sets = fidelity.stored_set_specs(res)
    if stored_sets:
        parts.append(fidelity.fidelity_section(stored_sets))

    page = ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            "<title>lcpbench report</title><style>" + _CSS + "</style></head><body>"
            + "\n".join(parts) + "</body></html>\n")
    out = folder / "report.html"
    atomic_write(out, page)
    return out


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
        rows.append(("skipped", f"{len(meta['skipped'])} solver/instance pairs (see meta.json)"))
    body = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(str(v))}</td></tr>"
                   for k, v in rows)
    return f"<h2>Run</h2><table>{body}</table>"


