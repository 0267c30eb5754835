"""The HTML report in a real browser: headless Chromium at 1400 px, no network.

Needs the system's Chromium and ChromeDriver (Debian: ``apt-get install chromium
chromium-driver``), so it carries the ``browser`` marker: the README's test command
deselects it and ``.ci/run`` runs it after installing them.
"""

import re
import shutil
from pathlib import Path

import pytest

from lcpbench.report.render import render_report
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep
from lcpbench.workflows.simulate import simulate

pytestmark = pytest.mark.browser

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
DRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"


def _driver():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    missing = [p for p in (CHROMIUM, DRIVER) if not Path(p).exists()]
    if missing:
        pytest.fail(f"{', '.join(missing)} not found: install Debian's chromium and "
                    "chromium-driver (`apt-get install -y chromium chromium-driver`; .ci/run "
                    "does this), or deselect with -m 'not browser'")
    opts = webdriver.ChromeOptions()
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--proxy-server=127.0.0.1:9", "--window-size=1400,2000"):
        opts.add_argument(arg)                       # the proxy blackholes any network access
    opts.binary_location = CHROMIUM
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(DRIVER), options=opts)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    store = tmp_path_factory.mktemp("browser") / "store"
    sweep = Sweep(solvers=["bb-pgd", "mono-pqn", "bi-pqn", "proxqp"],
                  problems=["fathi:sizes=[4,8]", "bifidelity:count=2,n=30",
                            "set-lattice-bim-m3:instances=0-1"])
    execute(plan(sweep), RunStore(store), quiet=True)
    return render_report(store)


#: The most curves one panel may draw (lcpbench.report.panels.MAX_CURVES).
MAX_CURVES = 7

#: JavaScript: per figure, its legend entries and the CSS pixel size of each number drawn
#: in it (heatmap cells, ticks), and whether it is a heatmap of the fidelity study.
_FIGURE_TEXT = """
return Array.from(document.querySelectorAll('.fig svg')).map(svg => {
  const scale = svg.getBoundingClientRect().width / svg.viewBox.baseVal.width;
  const entries = [];
  svg.querySelectorAll('g[id*=legend]').forEach(leg => leg.querySelectorAll('text').forEach(
      t => { if (t.textContent.trim() && t.textContent !== 'solver (runs)')
               entries.push(t.textContent); }));
  const numbers = Array.from(svg.querySelectorAll('text'))
      .filter(t => /^-?[0-9.]+$/.test(t.textContent.trim()))
      .map(t => [t.textContent, parseFloat(getComputedStyle(t).fontSize) * scale]);
  return [Array.from(new Set(entries)), numbers,
          svg.textContent.includes('||A_low - A||_inf')];
});
"""


def _check_curves_and_heatmap_numbers(driver):
    """No panel draws more than seven curves; heatmap numbers are at least 11 px."""
    heatmaps = 0
    for entries, numbers, heat in driver.execute_script(_FIGURE_TEXT):
        assert len(entries) <= MAX_CURVES, entries
        if heat:
            heatmaps += 1
            small = [(t, round(px, 1)) for t, px in numbers if px < 11]
            assert small == [], f"heatmap numbers under 11 px at 1400 px: {small}"
    assert heatmaps >= 1


@pytest.fixture(scope="module")
def online_report(tmp_path_factory):
    store = tmp_path_factory.mktemp("browser-online") / "store"
    simulate("lattice:m=2,model=rpy,low=[self]", ["bb-pgd", "mono-pqn", "bi-pqn:low=self"],
             8, store, progress=False)
    return render_report(store)


def test_online_tables_fit_in_1400_px(online_report):
    driver = _driver()
    try:
        driver.get(online_report.as_uri())
        widths = driver.execute_script(
            "return Array.from(document.querySelectorAll('table')).map(t => "
            "[t.getBoundingClientRect().right, t.scrollWidth, t.clientWidth, "
            "t.innerText.slice(0, 40)]);")
        assert widths, "no table on the page"
        body = driver.execute_script("return document.body.getBoundingClientRect().right")
        wide = [w for w in widths if w[0] > body + 1 or w[1] > w[2] + 1]
        assert wide == [], wide
        assert max(w[0] for w in widths) <= 1400
        assert driver.execute_script("return document.documentElement.scrollWidth") <= 1400
        text = driver.execute_script("return document.body.innerText")
        assert re.search(r"Online, beside the method paper's online table", text)
    finally:
        driver.quit()


def test_report_is_readable_at_1400_px(report, tmp_path):
    driver = _driver()
    try:
        driver.get(report.as_uri())
        assert driver.title == "lcpbench report"
        assert driver.execute_script("return window.innerWidth") >= 1300
        figures = driver.execute_script(
            "return Array.from(document.querySelectorAll('.fig svg')).map("
            "s => {const r = s.getBoundingClientRect(); return [r.width, r.height];});")
        # per set (3): box plot, convergence, work-precision and profiles; fidelity (2)
        assert len(figures) >= 11, figures
        small = [(w, h) for w, h in figures if h < 250 or w < 400]
        assert small == [], f"figures rendered too small (width, height px): {small}"
        overflowing = driver.execute_script(
            "const body = document.body.getBoundingClientRect();"
            "return Array.from(document.querySelectorAll('table')).filter(t => {"
            "  const r = t.getBoundingClientRect();"
            "  return r.right > body.right + 1 || t.scrollWidth > t.clientWidth + 1;"
            "}).map(t => t.innerText.slice(0, 60));")
        assert overflowing == [], overflowing
        page_width = driver.execute_script("return document.documentElement.scrollWidth")
        assert page_width <= driver.execute_script("return window.innerWidth")
        labels = driver.execute_script("return document.body.innerText")
        for latex in ("cottleLemma", "pqnSubproblem", "stepSize", "eq. "):
            assert latex not in labels, latex
        _check_views_colours_and_legends(driver)
        _check_curves_and_heatmap_numbers(driver)
        h2 = driver.execute_script(
            "return Array.from(document.querySelectorAll('h2')).map(h => h.id);")
        assert h2[1:4] == ["summary", "paper", "run"], h2     # the paper after the summary
        shot = tmp_path / "report.png"
        driver.save_screenshot(str(shot))
        assert shot.stat().st_size > 10_000
        errors = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
        assert errors == []
    finally:
        driver.quit()


#: JavaScript: per figure, each legend label with the colour drawn just before it.
_LEGENDS = """
return Array.from(document.querySelectorAll('.fig svg')).map(svg => {
  const scale = svg.getBoundingClientRect().width / svg.viewBox.baseVal.width;
  const out = [];
  svg.querySelectorAll('g[id*=legend]').forEach(leg => {
    let colour = null;
    leg.querySelectorAll('path, text').forEach(el => {
      if (el.tagName === 'path') {
        const st = getComputedStyle(el);
        const c = st.stroke && st.stroke !== 'none' ? st.stroke : st.fill;
        if (c && c !== 'none' && c !== 'rgb(255, 255, 255)') colour = c;
      } else {
        out.push([el.textContent, colour, parseFloat(getComputedStyle(el).fontSize) * scale]);
      }
    });
  });
  return out;
});
"""


def _check_views_colours_and_legends(driver):
    """Every view states its instance count; one colour per solver; legends >= 10 px;
    the reference QP solver (proxqp) only in its own table."""
    views = driver.execute_script(
        "return Array.from(document.querySelectorAll('.view')).map(v => [v.dataset.set, "
        "v.dataset.instances, v.querySelector('.caption').innerText, "
        "v.querySelectorAll('svg').length, v.innerText]);")
    assert len(views) >= 9, views
    per_set = {}
    for name, count, caption, _, text in views:
        assert f"over {count} instances" in caption and name in caption, caption
        per_set.setdefault(name, set()).add(count)
        assert "proxqp" not in text, (name, caption)
    assert all(len(c) == 1 for c in per_set.values()), per_set       # no view mixes sets
    colours = {}
    sizes = []
    for legend in driver.execute_script(_LEGENDS):
        for label, colour, px in legend:
            sizes.append((label, px))
            solver = label.split(" (")[0]
            assert solver != "proxqp", "a reference solver in a figure legend"
            if colour is not None and not solver.startswith("solver"):
                colours.setdefault(solver, set()).add(colour)
    assert sizes, "no legend text found"
    small = [(label, round(px, 1)) for label, px in sizes if px < 10]
    assert small == [], f"legend text under 10 px at 1400 px: {small}"
    mixed = {s: c for s, c in colours.items() if len(c) > 1}
    assert mixed == {}, f"a solver drawn in several colours: {mixed}"
    refs = driver.execute_script(
        "const r = document.getElementById('references');"
        "return r ? r.nextElementSibling.nextElementSibling.innerText : '';")
    assert "proxqp" in refs
