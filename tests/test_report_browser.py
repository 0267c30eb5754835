"""The HTML report in a real browser: headless Chromium, no network, no console errors."""

import shutil
from pathlib import Path

import pytest

from lcpbench.report.render import render_report
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
DRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"


def _driver():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    missing = [p for p in (CHROMIUM, DRIVER) if not Path(p).exists()]
    if missing:
        pytest.fail(f"{', '.join(missing)} not found: install Debian's chromium and "
                    "chromium-driver (`apt-get install -y chromium chromium-driver`; .ci/run "
                    "does this)")
    opts = webdriver.ChromeOptions()
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--proxy-server=127.0.0.1:9", "--window-size=1280,2000"):
        opts.add_argument(arg)                       # the proxy blackholes any network access
    opts.binary_location = CHROMIUM
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(DRIVER), options=opts)


def test_report_renders_in_headless_chromium(tmp_path):
    store = tmp_path / "store"
    sweep = Sweep(solvers=["bb-pgd", "mono-pqn", "bi-pqn", "proxqp"],
                  problems=["fathi:sizes=[4,8]", "bifidelity:count=2,n=30"])
    execute(plan(sweep), RunStore(store), quiet=True)
    html = render_report(store)
    driver = _driver()
    try:
        driver.get(html.as_uri())
        assert driver.title == "lcpbench report"
        figures = driver.execute_script(
            "return Array.from(document.querySelectorAll('.fig svg')).map("
            "s => {const r = s.getBoundingClientRect(); return [r.width, r.height];});")
        assert len(figures) >= 6
        assert all(w > 50 and h > 50 for w, h in figures), figures
        broken = driver.execute_script(
            "return Array.from(document.images).filter(i => !i.complete || "
            "i.naturalWidth === 0).length;")
        assert broken == 0
        shot = tmp_path / "report.png"
        driver.save_screenshot(str(shot))
        assert shot.stat().st_size > 10_000
        errors = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
        assert errors == []
    finally:
        driver.quit()
