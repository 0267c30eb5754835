"""One solver-to-colour map for the whole report.

Every figure takes its colours from :func:`solver_colors`, so a solver has the same
colour in every figure of a report and in every report of the same installation:

* a solver family (the registered solver name, e.g. ``bi-pqn``) gets one hue, fixed by
  its place among the installed, listed solvers (sorted by name), so the hue does not
  depend on which solvers a run used;
* the variants of one family (``bi-pqn:low=rpy``, ``bi-pqn:low=p4``, ...) are shades of
  that hue, darkest first in sorted order; a family run under its bare name alone keeps
  the pure hue;
* a family that is not listed (a test double, a script's plugin) gets a hue from a
  hash of its name.
"""

from __future__ import annotations

import colorsys
import hashlib

__all__ = ["PALETTE", "family_of", "solver_colors"]

#: Distinct hues (matplotlib's tab10 and two more), one per solver family.
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939")


def family_of(label: str) -> str:
    """The family of a solver label: the registered name before ``:``."""
    return str(label).split(":", 1)[0]


def _family_hues() -> dict[str, str]:
    """Hue of every listed solver family, by its place in the sorted registry."""
    from lcpbench.core.registry import solvers

    names = sorted(name for name, info in solvers().items()
                   if info.listed and not info.reference)
    return {name: PALETTE[i % len(PALETTE)] for i, name in enumerate(names)}


def _hashed_hue(name: str) -> str:
    digest = hashlib.sha256(name.encode()).digest()
    return PALETTE[digest[0] % len(PALETTE)]


def _shade(hex_color: str, k: int, count: int) -> str:
    """The ``k``-th of ``count`` shades of ``hex_color`` (lightness 0.28 to 0.72)."""
    r, g, b = (int(hex_color[i:i + 2], 16) / 255 for i in (1, 3, 5))
    h, _, s = colorsys.rgb_to_hls(r, g, b)
    light = 0.28 + 0.44 * k / (count - 1) if count > 1 else 0.5
    rr, gg, bb = colorsys.hls_to_rgb(h, light, max(s, 0.45))
    return "#{:02x}{:02x}{:02x}".format(*(round(255 * c) for c in (rr, gg, bb)))


def solver_colors(labels) -> dict[str, str]:
    """Colour (``#rrggbb``) of each solver label.

    Parameters
    ----------
    labels : iterable of str
        Every solver label the report draws (pass them all at once: the shades of a
        family's variants are spread over the variants given).

    Returns
    -------
    dict
        ``{label: "#rrggbb"}``.
    """
    hues = _family_hues()
    fams: dict[str, list[str]] = {}
    for label in sorted({str(x) for x in labels}):
        fams.setdefault(family_of(label), []).append(label)
    out = {}
    for fam, members in fams.items():
        base = hues.get(fam) or _hashed_hue(fam)
        if members == [fam]:
            out[fam] = base
            continue
        for k, label in enumerate(members):
            out[label] = _shade(base, k, len(members))
    return out
