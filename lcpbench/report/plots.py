"""Figures of the report, rendered by matplotlib as inline SVG strings.

matplotlib (Agg/SVG backends, no display) was chosen because it writes
self-contained SVG that embeds in one HTML file with no network or CDN.
"""

from __future__ import annotations

import io
import re

import numpy as np
import pandas as pd

__all__ = ["boxplot_svg", "curves_svg", "profile_svg", "work_precision_svg", "prefix_ids"]


def _figure(width: float = 7.0, height: float = 3.6):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update({"svg.hashsalt": "lcpbench", "font.size": 9})
    return plt.subplots(figsize=(width, height))


def svg_of(fig) -> str:
    """A matplotlib figure as inline SVG text (closed afterwards; no date, stable ids)."""
    import matplotlib.pyplot as plt

    buf = io.StringIO()
    fig.tight_layout()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]          # drop the XML prolog: inline in HTML


def boxplot_svg(data: pd.DataFrame, group: str, value: str, by: str, title: str,
                ylabel: str, log: bool = True) -> str:
    """Box plots of ``value`` per ``group`` (x axis), one box per ``by`` within each group."""
    groups = sorted(data[group].unique(), key=lambda v: (str(type(v)), v))
    series = sorted(data[by].unique())
    fig, ax = _figure(max(7.0, 0.5 * len(groups) * len(series)), 3.8)
    width = 0.8 / max(len(series), 1)
    cmap = _colors(len(series))
    for j, s in enumerate(series):
        vals, pos = [], []
        for i, g in enumerate(groups):
            v = data[(data[group] == g) & (data[by] == s)][value].astype(float).dropna()
            if len(v):
                vals.append(v.to_numpy())
                pos.append(i + (j - (len(series) - 1) / 2) * width)
        if vals:
            bp = ax.boxplot(vals, positions=pos, widths=width * 0.9, patch_artist=True,
                            manage_ticks=False)
            for box in bp["boxes"]:
                box.set_facecolor(cmap[j])
            ax.plot([], [], color=cmap[j], lw=6, label=s)
    ax.set_xticks(range(len(groups)))
    ax.set_xticklabels([str(g) for g in groups], rotation=20, ha="right")
    ax.set_xlabel(group)
    ax.set_ylabel(ylabel)
    if log:
        ax.set_yscale("log")
    ax.set_title(title)
    ax.legend(fontsize=7, ncol=3, loc="best")
    return svg_of(fig)


def _colors(k: int):
    import matplotlib

    cmap = matplotlib.colormaps["tab20" if k > 10 else "tab10"]
    return [cmap(i % cmap.N) for i in range(k)]


def curves_svg(curves: dict, xlabel: str, title: str) -> str:
    """Median log10 residual with its 25-75 % band, one line per solver."""
    fig, ax = _figure()
    for (solver, c), color in zip(sorted(curves.items()), _colors(len(curves))):
        ax.plot(c["x"], c["median"], color=color, label=solver)
        ax.fill_between(c["x"], c["lo"], c["hi"], color=color, alpha=0.15)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("log10 ||min(x, Ax+b)|| (verified)")
    ax.set_title(title)
    ax.legend(fontsize=7, ncol=2)
    return svg_of(fig)


def profile_svg(profile: pd.DataFrame, title: str) -> str:
    """Dolan-More performance profile (log2 tau on the x axis)."""
    fig, ax = _figure()
    solvers = [c for c in profile.columns if c != "tau"]
    for s, color in zip(solvers, _colors(len(solvers))):
        ax.step(np.log2(profile["tau"]), profile[s], where="post", color=color, label=s)
    ax.set_xlabel("log2 tau (ratio to the best solver)")
    ax.set_ylabel("share of problems")
    ax.set_ylim(0, 1.02)
    ax.set_title(title)
    ax.legend(fontsize=7, ncol=2, loc="lower right")
    return svg_of(fig)


def work_precision_svg(wp: pd.DataFrame, prefix: str, xlabel: str, title: str) -> str:
    """Median cost to reach each residual level, one line per solver."""
    fig, ax = _figure()
    cols = [c for c in wp.columns if c.startswith(prefix + "@")]
    levels = [float(c.split("@")[1]) for c in cols]
    for (_, row), color in zip(wp.iterrows(), _colors(len(wp))):
        y = [row[c] for c in cols]
        pts = [(v, lv) for v, lv in zip(y, levels) if v is not None and np.isfinite(v)]
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", color=color,
                    label=row["solver"])
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("residual level reached")
    ax.set_title(title)
    ax.legend(fontsize=7, ncol=2)
    return svg_of(fig)


def prefix_ids(svg: str, key: str) -> str:
    """Prefix the SVG's ids with ``key`` so several figures can share one page."""
    return re.sub(r'(id="|url\(#|href="#)([A-Za-z])', lambda m: f"{m.group(1)}f{key}{m.group(2)}",
                  svg)
