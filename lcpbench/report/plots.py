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

import numpy as np
import pandas as pd

__all__ = ["boxplot_svg", "grouped_boxplot_svg", "curves_svg", "profile_svg", "work_precision_svg", "prefix_ids",
           "svg_of", "figure", "WIDTH"]

#: Width of every figure in inches (about 860 CSS pixels).
WIDTH = 9.0


def figure(width: float = WIDTH, height: float = 3.8, ncols: int = 1):
    """A matplotlib figure on the Agg backend with the report's style."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update({"svg.hashsalt": "lcpbench", "font.size": 9})
    return plt.subplots(1, ncols, figsize=(min(width, WIDTH), height),
                        squeeze=ncols == 1)


def svg_of(fig) -> str:
    """A matplotlib figure as inline SVG text (closed afterwards; no date, stable ids)."""
    import matplotlib.pyplot as plt

    buf = io.StringIO()
    fig.tight_layout()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]          # drop the XML prolog: inline in HTML


def _colors(k: int):
    import matplotlib

    cmap = matplotlib.colormaps["tab20" if k > 10 else "tab10"]
    return [cmap(i % cmap.N) for i in range(k)]


def _legend_right(ax, **kw) -> None:
    """Legend outside the axes on the right, so it never hides data."""
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0,
              frameon=False, **kw)


def boxplot_svg(data: pd.DataFrame, by: str, value: str, title: str, ylabel: str,
                log: bool = True, order: list | None = None) -> str:
    """One box of ``value`` per ``by`` (the x axis), e.g. E-MVPs per solver of one set.

    ``order`` fixes the boxes and their colours; an entry without data keeps its
    place with the label "(none)". On a log axis, zero values cannot be drawn and
    are left out.
    """
    series = list(order) if order is not None else sorted(data[by].unique())
    colors = _colors(len(series))
    vals, pos, cols, labels = [], [], [], []
    for i, s in enumerate(series):
        v = pd.to_numeric(data[data[by] == s][value], errors="coerce").dropna()
        if log:
            v = v[v > 0]
        labels.append(str(s) if len(v) else f"{s} (none)")
        if len(v):
            vals.append(v.to_numpy())
            pos.append(i + 1)
            cols.append(colors[i])
    height = 3.6 + 0.06 * max((len(s) for s in labels), default=0)
    fig, ax = figure(WIDTH, height)
    if vals:
        bp = ax.boxplot(vals, positions=pos, patch_artist=True, widths=0.6, manage_ticks=False)
        for box, color in zip(bp["boxes"], cols):
            box.set_facecolor(color)
        ax.set_xlim(0.4, len(series) + 0.6)
        if log:
            ax.set_yscale("log")
    else:
        ax.text(0.5, 0.5, "no solved run", ha="center", va="center", transform=ax.transAxes)
    ax.set_xticks(range(1, len(labels) + 1))
    ax.set_xticklabels(labels, rotation=35, ha="right")
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(title)
    return svg_of(fig)


def _svg_id(text: str) -> str:
    """``text`` as an SVG id: letters, digits, ``_``, ``-`` and ``.`` kept, the rest ``_``."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", text)


def grouped_boxplot_svg(data: pd.DataFrame, group: str, by: str, value: str, title: str,
                        xlabel: str, ylabel: str, groups: list | None = None,
                        order: list | None = None, log: bool = True) -> str:
    """Boxes of ``value`` grouped along x by ``group``, one box per ``by`` in each group.

    E.g. E-MVPs per step with one group per lattice size and one box per solver:
    each ``by`` value keeps its colour in every group and appears once in the
    legend. ``groups`` and ``order`` fix the order of the groups and of the boxes
    within a group (default: as first seen, sorted). On a log axis zero values
    cannot be drawn and are left out. Each box carries the SVG id
    ``box_<group>_<by>`` (characters outside ``[A-Za-z0-9_.-]`` become ``_``).
    """
    groups = list(groups) if groups is not None else sorted(data[group].unique())
    series = list(order) if order is not None else sorted(data[by].unique())
    colors = dict(zip(series, _colors(len(series))))
    width = 0.8 / max(len(series), 1)
    fig, ax = figure(WIDTH, 3.8)
    drawn = set()
    for i, gval in enumerate(groups):
        for j, s in enumerate(series):
            v = pd.to_numeric(data[(data[group] == gval) & (data[by] == s)][value],
                              errors="coerce").dropna()
            if log:
                v = v[v > 0]
            if v.empty:
                continue
            x = i + 1 - 0.4 + width * (j + 0.5)
            bp = ax.boxplot([v.to_numpy()], positions=[x], widths=width * 0.85,
                            patch_artist=True, manage_ticks=False,
                            medianprops={"color": "black"})
            box = bp["boxes"][0]
            box.set_facecolor(colors[s])
            box.set_gid(_svg_id(f"box_{gval}_{s}"))
            if s not in drawn:
                box.set_label(str(s))
                drawn.add(s)
    if drawn:
        if log:
            ax.set_yscale("log")
        _legend_right(ax)
    else:
        ax.text(0.5, 0.5, "no positive value to draw", ha="center", va="center",
                transform=ax.transAxes)
    ax.set_xlim(0.4, len(groups) + 0.6)
    ax.set_xticks(range(1, len(groups) + 1))
    ax.set_xticklabels([str(g) for g in groups])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.set_title(title)
    return svg_of(fig)


def curves_svg(curves: dict, xlabel: str, title: str, log_x: bool = True) -> str:
    """Median log10 residual with its 25-75 % band, one line per solver.

    The x axis is logarithmic by default and clipped to where the runs are.
    """
    fig, ax = figure(WIDTH, 3.8)
    lo_x, hi_x = np.inf, -np.inf
    for (solver, c), color in zip(sorted(curves.items()), _colors(len(curves))):
        ax.plot(c["x"], c["median"], color=color, label=f"{solver} ({c.get('runs', '?')})")
        ax.fill_between(c["x"], c["lo"], c["hi"], color=color, alpha=0.15)
        lo_x, hi_x = min(lo_x, float(c["x"][0])), max(hi_x, float(c["x"][-1]))
    if log_x:
        ax.set_xscale("log")
    if np.isfinite(lo_x) and hi_x > lo_x:
        ax.set_xlim(lo_x, hi_x)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("log10 residual ||min(x, Ax+b)||")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    _legend_right(ax, title="solver (runs)", title_fontsize=7)
    return svg_of(fig)


def profile_svg(profile: pd.DataFrame, title: str) -> str:
    """Dolan-More performance profile (log2 tau on the x axis).

    A solver that was not run on every problem says on how many it was, in the
    legend; its share is over those problems only.
    """
    fig, ax = figure(WIDTH, 3.8)
    solvers = [c for c in profile.columns if c != "tau"]
    given = profile.attrs.get("given", {})
    total = profile.attrs.get("problems")
    for s, color in zip(solvers, _colors(len(solvers))):
        label = s
        if total and given.get(s, total) < total:
            label = f"{s} (run on {given[s]} of {total})"
        ax.step(np.log2(profile["tau"]), profile[s], where="post", color=color, label=label)
    ax.set_xlabel("log2 tau (ratio to the best solver)")
    ax.set_ylabel("share of problems solved")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.set_title(title)
    _legend_right(ax)
    return svg_of(fig)


def work_precision_svg(wp: pd.DataFrame, prefix: str, xlabel: str, title: str) -> str:
    """Median cost to reach each residual level, one line per solver (log-log)."""
    fig, ax = figure(WIDTH, 3.8)
    cols = [c for c in wp.columns if c.startswith(prefix + "@")]
    levels = [float(c.split("@")[1]) for c in cols]
    for (_, row), color in zip(wp.iterrows(), _colors(len(wp))):
        y = [row[c] for c in cols]
        pts = [(v, lv) for v, lv in zip(y, levels)
               if v is not None and np.isfinite(v) and v > 0]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", color=color,
                    label=row["solver"])
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("residual level reached")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    if ax.get_legend_handles_labels()[0]:
        _legend_right(ax)
    return svg_of(fig)


def prefix_ids(svg: str, key: str) -> str:
    """Prefix the SVG's ids with ``key`` so several figures can share one page."""
    return re.sub(r'(id="|url\(#|href="#)([A-Za-z])', lambda m: f"{m.group(1)}f{key}{m.group(2)}",
                  svg)
