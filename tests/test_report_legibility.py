"""Legible figures without a browser: curves per panel, heatmap text, set-up products named.

The same limits are checked in a real browser by tests/test_report_browser.py; here they
are read from the generated SVG (its sizes are in points: a figure shown at its natural
width draws a font of s points at 4/3 s CSS pixels, and the page is 1200 px wide at most).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

import pytest

from lcpbench.report import panels
from lcpbench.report.render import render_report
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep

PAGE_PX = 1200          # the report's max-width at a 1400 px window
SVG = "{http://www.w3.org/2000/svg}"


def test_panels_hold_at_most_seven_and_variants_apart():
    singles = ["a-pgd", "bb-pgd", "l-bfgs-b", "minmap-newton", "mono-pqn", "multi-pqn",
               "zero-sr1"]
    variants = [f"bi-pqn:low={k}" for k in ("p3e6", "p4", "p4e6", "p6e6", "p8e3", "p8f5e3",
                                            "p8f6e3", "p8f6r3e3", "rpy")]
    groups = panels.panel_groups(singles + variants, "bb-pgd")
    assert all(len(g) <= panels.MAX_CURVES for _, g in groups)
    assert groups[0] == ("single solvers", singles)
    bi = [g for title, g in groups if title.startswith("bi-pqn variants")]
    assert len(bi) == 2 and all(g[0] == "bb-pgd" for g in bi)          # the reference
    assert sorted(s for g in bi for s in g[1:]) == sorted(variants)      # each once
    assert {len(g) for g in bi} == {5, 6}                                # split evenly
    assert panels.panel_groups(["bb-pgd", "mono-pqn"], "bb-pgd") == [("", ["bb-pgd",
                                                                           "mono-pqn"])]
    assert panels.panel_groups([], "bb-pgd") == []


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    store = tmp_path_factory.mktemp("legible") / "store"
    sweep = Sweep(solvers=["bb-pgd", "mono-pqn", "a-pgd", "bi-pqn"],
                  problems=["set-paper-lattice-m3:instances=0-1"])
    execute(plan(sweep), RunStore(store), quiet=True)
    return render_report(store).read_text()


def _svgs(text: str) -> list[ET.Element]:
    return [ET.fromstring(s) for s in re.findall(r"<svg .*?</svg>", text, re.S)]


def _scale(svg: ET.Element) -> float:
    width_pt = float(svg.get("width", "0pt").rstrip("pt"))
    view_w = float(svg.get("viewBox", "0 0 1 1").split()[2])
    return min(width_pt * 4 / 3, PAGE_PX) / view_w


def _texts(el: ET.Element) -> list[str]:
    return [t.text.strip() for t in el.iter(f"{SVG}text") if t.text and t.text.strip()]


def _legend_entries(svg: ET.Element) -> list[str]:
    out = []
    for g in svg.iter(f"{SVG}g"):
        if re.search(r"legend_\d+$", g.get("id", "")):
            out += [t for t in _texts(g) if t not in ("solver (runs)",)]
    return out


def test_no_panel_draws_more_than_seven_curves(page):
    counted = 0
    for svg in _svgs(page):
        entries = _legend_entries(svg)
        if entries:
            counted += 1
            assert len(entries) <= panels.MAX_CURVES, entries
    assert counted >= 4        # convergence and speed views, each split in two panels


def test_heatmap_numbers_are_at_least_11_px(page):
    heat = [s for s in _svgs(page) if any("||A_low - A||_inf" in t for t in _texts(s))]
    assert heat, "no heatmap on the page"
    for svg in heat:
        scale = _scale(svg)
        for t in svg.iter(f"{SVG}text"):
            size = re.search(r"font-size: ([\d.]+)px", t.get("style", ""))
            if size and t.text and re.fullmatch(r"-?[\d.]+", t.text.strip()):
                assert float(size.group(1)) * scale >= 11, (t.text, float(size.group(1)))


def test_counted_power_iterations_are_named_where_they_are_counted(page):
    section = page[page.index(">set-paper-lattice-m3:instances=0-1</h3>"):]
    assert "a-pgd: its E-MVPs include a median of 20 counted power-iteration products" in section

