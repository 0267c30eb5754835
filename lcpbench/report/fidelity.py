"""Figures and report section of the fidelity study of stored sets.

Per stored set a run used: the table of :func:`lcpbench.workflows.fidelity.fidelity_table`
(taken from the run store's cache when present), two heatmaps over the fidelity knobs
``(p, eps_gmres)`` (log10 of the largest ``||A_low - A||_inf`` and how many low MVPs cost
one high MVP, as the paper's figure) and the share of instances within ``c(A)`` of ``A``
(as the paper's appendix figure).
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from lcpbench.core.scene import FidelityAxes
from lcpbench.report import plots
from lcpbench.report.markup import html_table
from lcpbench.workflows.fidelity import cache_entry, cached_fidelity_table

__all__ = ["cottle_heatmap_svg", "fidelity_section", "heatmap_svg", "heatmaps"]

#: Font size of the numbers in heatmap cells, in points (12 CSS pixels at the figures'
#: natural size; the report's browser test holds them to at least 11 px at 1400 px).
CELL_PT = 9.0

def _axes(table: Optional[pd.DataFrame]) -> Optional[FidelityAxes]:
    """The knobs the table's scene declared (``table.attrs["axes"]``), or None."""
    return None if table is None else table.attrs.get("axes")


def _on_grid(table: pd.DataFrame) -> pd.Series:
    """Rows that get a heatmap cell: both knobs, a knob-driven model, first of its cell.

    The scene's axes say which knobs span the grid and which models they set
    (``grid_models``); ``lcpbench generate`` records the high fidelity's knobs on other
    models too (an analytic one), whose fidelity they do not set, so such rows are listed
    beside the heatmaps instead. Without axes no row is on a grid.
    """
    axes = _axes(table)
    if axes is None:
        return pd.Series(False, index=table.index)
    rows, cols = table[axes.rows], table[axes.columns]
    models = table[axes.model_knob].fillna("").astype(str).str.lower()
    mask = rows.notna() & cols.notna() & models.isin(axes.grid_models)
    dup = rows.astype(str) + "/" + cols.astype(str)
    return mask & ~(dup.where(mask).duplicated() & mask)


def _grid(table: Optional[pd.DataFrame]) -> pd.DataFrame:
    """Rows placed on the heatmaps over the scene's two knobs (:func:`_on_grid`)."""
    if table is None or table.empty or _axes(table) is None:
        return pd.DataFrame()
    return table[_on_grid(table)]


def _fmt_knob(v: float) -> str:
    """A knob value as a tick label: an integer, a power of ten (``1e-6``), else 2 digits."""
    v = float(v)
    if v.is_integer():
        return str(int(v))
    exp = math.log10(abs(v)) if v else 0.0
    return f"1e{round(exp)}" if v > 0 and abs(exp - round(exp)) < 1e-9 else f"{v:.2g}"


def _heat(ax, grid: pd.DataFrame, column: str, title: str, cbar: str, fmt: str,
          cmap: str, fig) -> None:
    axes = _axes(grid)
    assert axes is not None                      # _grid is empty without axes
    ps = sorted(grid[axes.rows].unique())
    eps = sorted(grid[axes.columns].unique(), reverse=True)
    M = np.full((len(ps), len(eps)), np.nan)
    for _, r in grid.iterrows():
        M[ps.index(r[axes.rows]), eps.index(r[axes.columns])] = r[column]
    shown = np.ma.masked_invalid(np.where(np.isfinite(M), M, np.nan))
    im = ax.imshow(shown, origin="lower", aspect="auto", cmap=cmap)
    fig.colorbar(im, ax=ax, label=cbar)
    ax.set_xticks(range(len(eps)))
    ax.set_xticklabels([_fmt_knob(e) for e in eps])
    ax.set_yticks(range(len(ps)))
    ax.set_yticklabels([_fmt_knob(p) for p in ps])
    ax.set_xlabel(axes.columns)
    ax.set_ylabel(axes.rows)
    ax.set_title(title)
    finite = M[np.isfinite(M)]
    mid = float(np.mean([finite.min(), finite.max()])) if finite.size else 0.0
    for a in range(len(ps)):
        for b in range(len(eps)):
            if np.isfinite(M[a, b]):
                ax.text(b, a, format(M[a, b], fmt), ha="center", va="center", fontsize=CELL_PT,
                        color="white" if M[a, b] < mid else "black")



def heatmap_svg(table: pd.DataFrame) -> str:
    """The paper's two heatmaps over the scene's two knobs (``(p, eps_gmres)``) as one SVG.

    Left: log10 of the max ``||A_low - A||_inf``; right: median low MVPs per high MVP.
    Cells: fidelities with both knobs whose model is one the knobs set (the scene's
    ``FidelityAxes.grid_models``). Returns
    ``""`` when there is none.
    """
    grid = _grid(table)
    if grid.empty:
        return ""
    ncol = grid[_axes(grid).columns].nunique()  # type: ignore[union-attr]
    fig, axes = plots.figure(max(8.0, 2 * (2.5 + 0.7 * ncol)), 3.6, ncols=2)
    _heat(axes[0, 0], grid, "log10_max_err", "log10 max ||A_low - A||_inf",
          "log10 error", ".2f", "viridis", fig)
    _heat(axes[0, 1], grid, "median_low_per_high", "low MVPs per high MVP (median)",
          "t_high / t_low", ".3g", "magma", fig)
    return plots.svg_of(fig)


def cottle_heatmap_svg(table: pd.DataFrame) -> str:
    """The appendix figure: share of instances with ``||A_low - A||_inf < c(A)``, in %."""
    grid = _grid(table).copy()
    if grid.empty:
        return ""
    grid["pct"] = 100.0 * grid["share_err_below_c"]
    ncol = grid[_axes(grid).columns].nunique()  # type: ignore[union-attr]
    fig, ax = plots.figure(max(4.5, 2.5 + 0.7 * ncol), 3.6)
    _heat(ax, grid, "pct", "% instances with ||A_low - A||_inf < c(A)", "%",
          ".0f", "cividis", fig)
    return plots.svg_of(fig)


def heatmaps(table: pd.DataFrame, id_prefix: str = "fidhm_") -> str:
    """HTML: the two heatmaps (inline SVG) and a small table of the other fidelities.

    Fidelities off the grid of the scene's two knobs (another model, or a knob missing)
    have no cell in the heatmaps and are listed in the
    table instead. The SVG's ids get ``id_prefix`` so
    several figures can share one page.
    """
    parts = []
    svg = heatmap_svg(table)
    if svg:
        svg = plots.prefix_ids(svg, id_prefix)
        parts.append(f'<div class="fig">{svg}</div>')
    if table is not None and not table.empty:
        others = table[~_on_grid(table)]
        if not others.empty:
            axes = _axes(table)
            grid = f"({axes.rows}, {axes.columns}) grid" if axes is not None else "grid"
            parts.append(f"<p class='note'>Fidelities not on the {html.escape(grid)} "
                         "(other models, or a knob missing):</p>")
            parts.append(html_table(others, digits=4))
    return "\n".join(parts)


def fidelity_section(paths: Iterable, cache_dir=None,
                     progress: Callable[[str], None] | None = None,
                     names: dict[str, str] | None = None) -> str:
    """HTML section of the report: per stored set, the table, heatmaps and Cottle figure.

    Parameters
    ----------
    paths : iterable
        Stored-set paths, or ``(path, instance ids or None)`` pairs as returned by
        :func:`lcpbench.workflows.fidelity.stored_set_specs`.
    cache_dir : str or Path, optional
        Where the tables are cached; default the user cache directory
        (:func:`lcpbench.workflows.fidelity.user_cache_dir`).
    progress : callable, optional
        Called with a line of text before each set and after each instance's ``c(A)``
        while a table is computed (nothing more when it is cached).
    names : dict, optional
        The problem-set label of each file (resolved path -> label), so the section
        names a set as the rest of the report does, with its file name beside it.

    Returns
    -------
    str
        ``""`` when no set has a low fidelity.
    """
    from lcpbench.sets import StoredSetError

    parts = []
    for k, item in enumerate(paths):
        path, ids = (item if isinstance(item, tuple) else (item, None))
        path = Path(path)
        label = (names or {}).get(str(path.resolve()), path.name)
        title = label if label == path.name else f"{label} (file {path.name})"
        try:
            cached = cache_entry(path, ids, cache_dir).exists()
            if progress is not None:
                progress(f"fidelity study of {path.name}: " + (
                    "cached" if cached else "c(A) of each instance, computed once and "
                    f"cached in {cache_entry(path, ids, cache_dir).parent}"))
            say = (lambda text, _n=path.name: progress(f"fidelity study of {_n}: {text}")) \
                if progress is not None else None
            table = cached_fidelity_table(path, ids, cache_dir, progress=say)
        except (StoredSetError, OSError, ValueError) as exc:
            parts.append(f"<h3>{html.escape(title)}</h3><p class='note'>fidelity study "
                         f"skipped: {html.escape(str(exc))}</p>")
            continue
        if table.empty:
            continue
        used = f"{len(ids)} selected instance(s)" if ids is not None else "all instances"
        parts.append(f"<h3>{html.escape(title)}: {used}</h3>")
        parts.append(html_table(table, digits=4))
        parts.append(heatmaps(table, id_prefix=f"fid{k}a_"))
        cottle = cottle_heatmap_svg(table)
        if cottle:
            parts.append(f'<div class="fig">{plots.prefix_ids(cottle, f"fid{k}b_")}</div>')
    if not parts:
        return ""
    intro = ("<h2 id='fidelity'>Fidelity study of the stored sets</h2>"
             "<p class='note'>Per low fidelity: "
             "log10 of the largest ||A_low - A||_inf over the instances (induced infinity "
             "norm), the median number of low-fidelity MVPs per high-fidelity MVP "
             "(1 / cost_ratio, as measured when the set was generated), and the share of "
             "instances with ||A_low - A||_inf &lt; c(A), the condition of Cottle's "
             "lemma for a locally Lipschitz solution map. c(A) is estimated by "
             "multi-start local optimisation (the paper's appendix on computing c(A)); the "
             "estimate is an upper bound of c(A), so share_err_below_lower also gives the share "
             "certainly inside, with the lower bound lambda_min(A)/n of c(A).</p>")
    return intro + "\n".join(parts)
