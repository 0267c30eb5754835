"""The HTML report in a real browser: headless Chromium at 1400 px, no network.

Needs the system's Chromium and ChromeDriver (Debian: ``apt-get install chromium
chromium-driver``), so it carries the ``browser`` marker: the README's test command
deselects it and ``.ci/run`` runs it after installing them.
"""

import shutil
from pathlib import Path

import pytest

from lcpbench.report.render import render_report
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep

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
