"""Figures of the report, rendered by matplotlib as inline SVG strings.

matplotlib (Agg/SVG backends, no display) was chosen because it writes
self-contained SVG that embeds in one HTML file with no network or CDN. Every
figure has a fixed size of at most :data:`WIDTH` inches, so the page never has
to shrink it: one figure per problem set, size or family rather than one wide
figure of everything.
"""

from __future__ import annotations

import io
import re
from typing import Any

import numpy as np
import pandas as pd

__all__ = ["boxplot_svg", "grouped_boxplot_svg", "curves_svg", "profile_svg",
           "work_precision_svg", "set_overview_svg", "prefix_ids", "svg_of", "figure",
           "WIDTH", "LEGEND_PT", "STYLE", "literal"]

#: Width of every figure in inches (864 CSS pixels: SVG sizes are in points).
WIDTH = 9.0
#: Legend font size in points (11.3 CSS pixels at the figure's natural size).
LEGEND_PT = 8.5
#: The report's matplotlib style. ``svg.fonttype`` ``none``: text stays text in the SVG
#: (searchable, smaller, sized by the browser).
STYLE: Any = {"svg.hashsalt": "lcpbench", "font.size": 9, "svg.fonttype": "none",
         "legend.fontsize": LEGEND_PT}


def literal(text) -> str:
    """``text`` escaped for matplotlib's mathtext: every ``$`` drawn as a dollar sign.

    A label such as the set file name ``set_$m_3_4$.h5`` would otherwise be parsed as
    mathtext (and fail on its double subscript). Already escaped dollars stay as they are.
    """
    return re.sub(r"(?<!\\)\$", r"\\$", str(text))


def _escape_texts(fig) -> None:
    """Escape every text of ``fig`` for mathtext (:func:`literal`), tick formatters' aside.

    Titles, axis labels, legend entries and fixed tick labels come from the data
    (solver, set and file names); the log axes' own tick labels are mathtext made by
    matplotlib and are left alone (they are re-made at every draw anyway).
    """
    from matplotlib.text import Text

    for text in fig.findobj(Text):
        s = text.get_text()
        if "$" in s and not s.startswith("$\\mathdefault"):
            text.set_text(literal(s))


def figure(width: float = WIDTH, height: float = 3.8, ncols: int = 1, nrows: int = 1):
    """A matplotlib figure on the Agg backend with the report's style (:data:`STYLE`)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update(STYLE)
    if nrows > 1:
        return plt.subplots(nrows, ncols, figsize=(min(width, WIDTH), height), squeeze=False)
    return plt.subplots(1, ncols, figsize=(min(width, WIDTH), height),
                        squeeze=ncols == 1)


#: Fixed margins of a one-axes figure whose legend sits on the right (no tight layout:
#: it draws the figure once more, the slowest part of rendering).
LEGEND_RIGHT_MARGINS = {"left": 0.08, "right": 0.70, "bottom": 0.13, "top": 0.91}


def svg_of(fig, *, margins: dict | None = None) -> str:
    """A matplotlib figure as inline SVG text (closed afterwards; no date, stable ids).

    ``margins`` (``subplots_adjust`` keywords) lay the figure out at once; without
    them it gets a tight layout. Every text of the figure is escaped for mathtext
    (:func:`literal`), so a ``$`` in a name is drawn as written.
    """
    import matplotlib.pyplot as plt

    _escape_texts(fig)
    buf = io.StringIO()
    with plt.rc_context(STYLE):
        if margins:
            fig.subplots_adjust(**margins)
        else:
            fig.tight_layout()
        fig.savefig(buf, format="svg", metadata={"Date": None})
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]          # drop the XML prolog: inline in HTML


def _palette(names, colors: dict | None) -> dict:
    """The report's colour of each name (:func:`lcpbench.report.colors.solver_colors`)."""
    from lcpbench.report.colors import solver_colors

    mine = dict(colors or {})
    missing = [n for n in names if n not in mine]
    if missing:
        mine.update(solver_colors(missing))
    return mine


def _colors(k: int):
    import matplotlib

    cmap = matplotlib.colormaps["tab20" if k > 10 else "tab10"]
    return [cmap(i % cmap.N) for i in range(k)]


_MEDIAN = {"color": "black", "linewidth": 2.0}


def _legend_right(ax, **kw) -> None:
    """Legend outside the axes on the right, so it never hides data."""
    ax.legend(fontsize=LEGEND_PT, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              borderaxespad=0.0, frameon=False, **kw)


def boxplot_svg(data: pd.DataFrame, by: str, value: str, title: str, ylabel: str,
                log: bool = True, order: list | None = None, *, colors: dict | None = None,
                counts: dict | None = None) -> str:
    """One box of ``value`` per ``by`` (the x axis), e.g. E-MVPs per solver of one set.

    ``order`` fixes the boxes; ``colors`` maps each ``by`` value to its colour (the
    report's map); ``counts`` adds a text such as ``"8/10 solved"`` under a label. An
    entry without data keeps its place with the label "(none)". On a log axis, zero
    values cannot be drawn: then the axis is symmetric-log (linear below 1), so every
    value is drawn. Medians are black lines.
    """
    series = list(order) if order is not None else sorted(data[by].unique())
    palette = _palette([str(s) for s in series], colors)
    vals, pos, cols, labels = [], [], [], []
    zeros = False
    for i, s in enumerate(series):
        v = pd.to_numeric(data[data[by] == s][value], errors="coerce").dropna()
        zeros = zeros or bool((v <= 0).any())
        extra = f" ({counts[s]})" if counts and s in counts else ""
        labels.append(f"{s}{extra}" if len(v) else f"{s} (none)")
        if len(v):
            vals.append(v.to_numpy())
            pos.append(i + 1)
            cols.append(palette[str(s)])
    height = 3.6 + 0.06 * max((len(s) for s in labels), default=0)
    fig, ax = figure(WIDTH, height)
    if vals:
        bp = ax.boxplot(vals, positions=pos, patch_artist=True, widths=0.6, manage_ticks=False,
                        medianprops=_MEDIAN)
        for box, color in zip(bp["boxes"], cols):
            box.set_facecolor(color)
        ax.set_xlim(0.4, len(series) + 0.6)
        if log and zeros:
            ax.set_yscale("symlog", linthresh=1.0)
            ylabel = ylabel.replace("(log scale)", "(log scale, linear below 1)")
        elif log:
            ax.set_yscale("log")
    else:
        ax.text(0.5, 0.5, "no solved run", ha="center", va="center", transform=ax.transAxes)
    ax.set_xticks(range(1, len(labels) + 1))
    ax.set_xticklabels([literal(x) for x in labels], rotation=35, ha="right")
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(title)
    return svg_of(fig)


def _svg_id(text: str) -> str:
    """``text`` as an SVG id: letters, digits, ``_``, ``-`` and ``.`` kept, the rest ``_``."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", text)


def grouped_boxplot_svg(data: pd.DataFrame, group: str, by: str, value: str, title: str,
                        xlabel: str, ylabel: str, *, groups: list | None = None,
                        order: list | None = None, log: bool = True,
                        colors: dict | None = None) -> str:
    """Boxes of ``value`` grouped along x by ``group``, one box per ``by`` in each group.

    E.g. E-MVPs per step with one group per lattice size and one box per solver:
    each ``by`` value keeps its colour in every group and appears once in the
    legend. ``groups`` and ``order`` fix the order of the groups and of the boxes
    within a group (default: as first seen, sorted). Every value is drawn: with a zero
    among them the log axis becomes symmetric-log (linear below 1), so the boxes show
    the same rows as the table beside them. Each box carries the SVG id
    ``box_<group>_<by>`` (characters outside ``[A-Za-z0-9_.-]`` become ``_``).
    """
    groups = list(groups) if groups is not None else sorted(data[group].unique())
    series = list(order) if order is not None else sorted(data[by].unique())
    colors = _palette([str(s) for s in series], colors)
    width = 0.8 / max(len(series), 1)
    fig, ax = figure(WIDTH, 3.8)
    drawn = set()
    zeros = bool((pd.to_numeric(data[value], errors="coerce") <= 0).any())
    for i, gval in enumerate(groups):
        for j, s in enumerate(series):
            v = pd.to_numeric(data[(data[group] == gval) & (data[by] == s)][value],
                              errors="coerce").dropna()
            if v.empty:
                continue
            x = i + 1 - 0.4 + width * (j + 0.5)
            bp = ax.boxplot([v.to_numpy()], positions=[x], widths=width * 0.85,
                            patch_artist=True, manage_ticks=False, medianprops=_MEDIAN)
            box = bp["boxes"][0]
            box.set_facecolor(colors[str(s)])
            box.set_gid(_svg_id(f"box_{gval}_{s}"))
            if s not in drawn:
                box.set_label(str(s))
                drawn.add(s)
    if drawn:
        if log and zeros:
            ax.set_yscale("symlog", linthresh=1.0)
            ylabel = ylabel.replace("(log scale)", "(log scale, linear below 1)")
        elif log:
            ax.set_yscale("log")
        _legend_right(ax)
    else:
        ax.text(0.5, 0.5, "no value to draw", ha="center", va="center",
                transform=ax.transAxes)
    ax.set_xlim(0.4, len(groups) + 0.6)
    ax.set_xticks(range(1, len(groups) + 1))
    ax.set_xticklabels([literal(g) for g in groups])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(title)
    return svg_of(fig, margins=LEGEND_RIGHT_MARGINS)


def curves_svg(curves: dict, xlabel: str, title: str, log_x: bool = True, *,
               colors: dict | None = None) -> str:
    """Median log10 residual with its 25-75 % band, one line per solver.

    The x axis is logarithmic by default and clipped to where the runs are; the y
    axis starts at the lowest value drawn (an exact zero residual sits at the curves'
    ``floor``, a decade below the smallest positive one, see
    :func:`lcpbench.report.tables.convergence_curves`).
    """
    fig, ax = figure(WIDTH, 3.8)
    palette = _palette(list(curves), colors)
    lo_x, hi_x = np.inf, -np.inf
    for solver, c in sorted(curves.items()):
        color = palette[solver]
        ax.plot(c["x"], c["median"], color=color, lw=1.6,
                label=f"{solver} ({c.get('runs', '?')})")
        ax.fill_between(c["x"], c["lo"], c["hi"], color=color, alpha=0.15)
        lo_x, hi_x = min(lo_x, float(c["x"][0])), max(hi_x, float(c["x"][-1]))
    if log_x:
        ax.set_xscale("log")
    if np.isfinite(lo_x) and hi_x > lo_x:
        ax.set_xlim(lo_x, hi_x)
    lows = [np.nanmin(c["lo"]) for c in curves.values() if np.isfinite(c["lo"]).any()]
    highs = [np.nanmax(c["hi"]) for c in curves.values() if np.isfinite(c["hi"]).any()]
    if lows and highs and max(highs) > min(lows):
        pad = 0.03 * (max(highs) - min(lows))
        ax.set_ylim(min(lows) - pad, max(highs) + pad)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("log10 residual ||min(x, Ax+b)||")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    _legend_right(ax, title="solver (runs)", title_fontsize=LEGEND_PT)
    return svg_of(fig, margins=LEGEND_RIGHT_MARGINS)


def _profile_panel(ax, profile: pd.DataFrame, palette: dict, title: str) -> None:
    """Draw a Dolan-More profile (log2 tau on x) on ``ax``."""
    solvers = [c for c in profile.columns if c != "tau"]
    for s in solvers:
        ax.step(np.log2(profile["tau"]), profile[s], where="post", color=palette[s],
                lw=1.6, label=s)
    ax.set_xlim(0.0, float(np.log2(profile["tau"].max())))
    ax.set_xlabel("log2 tau (ratio to the best solver)")
    ax.set_ylabel("share of instances solved")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.set_title(title)


def _wp_panel(ax, wp: pd.DataFrame, prefix: str, palette: dict, xlabel: str,
              title: str) -> None:
    """Draw median cost to reach each residual level (log-log) on ``ax``."""
    cols = [c for c in wp.columns if c.startswith(prefix + "@")]
    levels = [float(c.split("@")[1]) for c in cols]
    for _, row in wp.iterrows():
        pts = [(row[c], lv) for c, lv in zip(cols, levels)
               if row[c] is not None and np.isfinite(row[c]) and row[c] > 0]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", color=palette[row["solver"]],
                    lw=1.6, ms=4, label=row["solver"])
    from matplotlib.ticker import NullFormatter

    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.xaxis.set_minor_formatter(NullFormatter())     # minor labels would overlap
    ax.set_xlabel(xlabel)
    ax.set_ylabel("residual level reached")
    ax.grid(alpha=0.3)
    ax.set_title(title)


def profile_svg(profile: pd.DataFrame, title: str, *, colors: dict | None = None) -> str:
    """Dolan-More performance profile (log2 tau on the x axis, from 1 to the data's end).

    A failure never reaches 1; a solver that was not run on every problem says on how
    many it was, in the legend (the report passes common ground, where all were).
    """
    fig, ax = figure(WIDTH, 3.8)
    solvers = [c for c in profile.columns if c != "tau"]
    palette = _palette(solvers, colors)
    _profile_panel(ax, profile, palette, title)
    given = profile.attrs.get("given", {})
    total = profile.attrs.get("problems")
    if total:
        for line in ax.get_lines():
            s = line.get_label()
            if given.get(s, total) < total:
                line.set_label(f"{s} (run on {given[s]} of {total})")
    _legend_right(ax)
    return svg_of(fig, margins=LEGEND_RIGHT_MARGINS)


def work_precision_svg(wp: pd.DataFrame, prefix: str, xlabel: str, title: str, *,
                       colors: dict | None = None) -> str:
    """Median cost to reach each residual level, one line per solver (log-log)."""
    fig, ax = figure(WIDTH, 3.8)
    _wp_panel(ax, wp, prefix, _palette(list(wp.get("solver", [])), colors), xlabel, title)
    if ax.get_legend_handles_labels()[0]:
        _legend_right(ax)
    return svg_of(fig, margins=LEGEND_RIGHT_MARGINS)


def set_overview_svg(wp: pd.DataFrame, profiles: dict, title: str, *,
                     colors: dict | None = None) -> str:
    """One problem set's speed views in one figure, with one legend for all panels.

    Top: work-precision in E-MVPs and in seconds (median cost to reach each residual
    level); bottom: the Dolan-More profiles ``profiles["emvps"]`` and
    ``profiles["time_s"]`` (either may be empty). Every panel has the same solvers
    and colours.
    """
    names = list(wp["solver"]) if not wp.empty else []
    for prof in profiles.values():
        names += [c for c in prof.columns if c != "tau" and c not in names]
    palette = _palette(names, colors)
    fig, axes = figure(WIDTH, 6.6, ncols=2, nrows=2)
    panels = [("emvps", "median E-MVPs (log scale)", "Work-precision: E-MVPs"),
              ("s", "median seconds (log scale)", "Work-precision: seconds")]
    for ax, (prefix, xlabel, name) in zip(axes[0], panels):
        if wp.empty:
            ax.set_axis_off()
        else:
            _wp_panel(ax, wp, prefix, palette, xlabel, name)
    for ax, (metric, name) in zip(axes[1], (("emvps", "Profile: E-MVPs"),
                                            ("time_s", "Profile: seconds"))):
        prof = profiles.get(metric)
        if prof is None or prof.empty:
            ax.set_axis_off()
        else:
            _profile_panel(ax, prof, palette, name)
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=palette[n], lw=2.5, label=n) for n in names]
    fig.suptitle(title)
    fig.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.755, 0.93),
               frameon=False, fontsize=LEGEND_PT)
    return svg_of(fig, margins={"left": 0.075, "right": 0.745, "bottom": 0.08, "top": 0.9,
                                "wspace": 0.32, "hspace": 0.42})


def prefix_ids(svg: str, key: str) -> str:
    """Prefix the SVG's ids with ``key`` so several figures can share one page."""
    return re.sub(r'(id="|url\(#|href="#)([A-Za-z])', lambda m: f"{m.group(1)}f{key}{m.group(2)}",
                  svg)
