"""The report's tables, figures and cache, without a browser."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from lcpbench.report import tables
from lcpbench.report.render import render_report
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep, default_sweep

if sys.version_info >= (3, 11):
    import tomllib
else:   # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def _row(problem, instance, solver, emvps, mvps=None, solved=True, multi=False, mvp_only=True,
         family=None):
    return {"run_id": f"{problem}/{instance}/{solver}", "kind": "offline", "problem": problem,
            "family": family or problem, "instance": instance, "repeat": 0, "solver": solver,
            "emvps": emvps, "mvps": emvps if mvps is None else mvps, "solved": solved,
            "multifidelity": multi, "mvp_only": mvp_only, "time_s": 0.01 * emvps,
            "false_convergence": False, "ref_err_w": 1e-12}


@pytest.fixture
def results() -> pd.DataFrame:
    rows = []
    for i, e in enumerate([10, 12, 14, 20]):
        rows.append(_row("set", f"i{i}", "bb-pgd", e))
        rows.append(_row("set", f"i{i}", "mono-pqn", e / 2))
    # the multi-fidelity solver was given two of the four instances (only they have a low)
    rows.append(_row("set", "i0", "bi-pqn:low=p4", 2.5, mvps=2, multi=True))
    rows.append(_row("set", "i1", "bi-pqn:low=p4", 3.5, mvps=3, multi=True))
    rows.append(_row("set", "i2", "clarabel", 0, mvp_only=False))
    rows.append(_row("other", "j0", "bb-pgd", 7, solved=False))
    rows.append(_row("other", "j0", "mono-pqn", 4))
    return pd.DataFrame(rows)


def test_paper_table_is_on_common_ground_with_counts(results):
    per_set = tables.paper_tables(results, baseline="bb-pgd")
    assert list(per_set) == ["other", "set"]
    t = per_set["set"].set_index("solver")
    assert list(t.index) == ["bb-pgd", "mono-pqn", "bi-pqn:low=p4"]    # no reference solver
    assert list(t.columns) == ["solved", "success", "min", "median", "mean", "max",
                               "median app. cost", "median framework products",
                               "median / bb-pgd", "shifted GM",
                               "shifted GM / best"]
    # bi-pqn was given i0 and i1 only: every solver is compared over those two
    assert per_set["set"].attrs["instances"] == 2 and per_set["set"].attrs["total"] == 4
    assert t.loc["bb-pgd", ["min", "median", "mean", "max"]].tolist() == ["10", "11", "11", "12"]
    assert t.loc["mono-pqn", "median / bb-pgd"] == "0.50 (2 of 2 both solved)"
    # high-fidelity MVPs in parentheses for the multi-fidelity solver
    assert t.loc["bi-pqn:low=p4", "min"] == "2.5 (2)"
    assert t.loc["bi-pqn:low=p4", "mean"] == "3 (2.5)"
    assert t.loc["bi-pqn:low=p4", "solved"] == "2/2"
    assert t.loc["bi-pqn:low=p4", "median / bb-pgd"] == f"{3.0 / 11:.2f} (2 of 2 both solved)"
    other = per_set["other"].set_index("solver")
    assert other.loc["bb-pgd", "median"] == "-" and other.loc["bb-pgd", "success"] == "0 %"
    assert other.loc["mono-pqn", "median / bb-pgd"] == "- (0 of 1 both solved)"


def test_profile_leaves_out_runs_that_were_not_made(results):
    prof = tables.performance_profile(results, "emvps", taus=np.array([1.0, 2.0, 4.0]))
    assert prof.attrs["problems"] == 5 and prof.attrs["given"]["bi-pqn:low=p4"] == 2
    # bi-pqn is the best on both instances it ran on: 100 %, not 2 of 5
    assert prof["bi-pqn:low=p4"].tolist() == [1.0, 1.0, 1.0]
    # bb-pgd failed on "other": counted as never, over its 5 problems
    assert prof["bb-pgd"].tolist() == pytest.approx([0.0, 2 / 5, 4 / 5])
    assert prof["mono-pqn"].tolist() == pytest.approx([3 / 5, 1.0, 1.0])


def test_convergence_curves_per_family_on_a_log_grid():
    results = pd.DataFrame([_row("a", "0", "s1", 8, family="fa"),
                            _row("b", "0", "s1", 100, family="fb")])
    hist = pd.DataFrame({
        "run_id": ["a/0/s1"] * 3 + ["b/0/s1"] * 3, "emvps": [0, 2, 8, 0, 10, 100],
        "kkt_abs": [1.0, 1e-3, 1e-9, 1.0, 1e-2, 1e-9], "kkt_abs_verified": [np.nan] * 6})
    curves = tables.convergence_curves(results, hist, "emvps", points=5, by="family")
    assert set(curves) == {"fa", "fb"}
    fa = curves["fa"]["s1"]
    assert fa["x"][0] == 2 and fa["x"][-1] == 8                # clipped to the data
    assert np.allclose(np.diff(np.log(fa["x"])), np.log(4) / 4)  # logarithmic grid
    assert fa["median"][0] == pytest.approx(-3) and fa["median"][-1] == pytest.approx(-9)


def test_work_precision_display_folds_each_level_into_one_cell():
    wp = pd.DataFrame([{"solver": "s", "emvps@1e-02": 3.0, "s@1e-02": 0.01,
                        "reached@1e-02": "2/2", "emvps@1e-08": None, "s@1e-08": None,
                        "reached@1e-08": "0/2", "median_ref_err_w": "1e-10"}])
    out = tables.work_precision_display(wp)
    assert list(out.columns) == ["solver", "to 1e-02", "to 1e-08", "median error of w"]
    assert out.iloc[0]["to 1e-02"] == "3 E-MVPs, 0.01 s (2/2)"
    assert out.iloc[0]["to 1e-08"] == "never (0/2)"


@pytest.fixture(scope="module")
def small_store(tmp_path_factory):
    store = tmp_path_factory.mktemp("report") / "store"
    sweep = Sweep(solvers=["bb-pgd", "mono-pqn", "bi-pqn"],
                  problems=["fathi:sizes=[4,8]", "set-lattice-bim-m3:instances=0-1"])
    execute(plan(sweep), RunStore(store), quiet=True)
    return store


def test_report_sections_labels_and_progress(small_store):
    lines = []
    html = render_report(small_store, progress=lines.append).read_text()
    assert html.count(">fathi:sizes=[4,8]</h3>") == 1
    assert ">set-lattice-bim-m3:instances=0-1</h3>" in html
    assert "median / bb-pgd" in html
    assert "Residual against E-MVPs: fathi:sizes=[4,8] (2 instances)" in html
    assert "Residual against E-MVPs: set-lattice-bim-m3:instances=0-1 (2 instances)" in html
    assert not re.search(r"\b(lemma|eq\.|algorithm) [a-z]+[A-Z]\w*", html), "LaTeX label"
    assert any("fidelity study of lattice-bim-m3" in line for line in lines)
    # one name per set: the fidelity study names the set as the offline section does
    assert "set-lattice-bim-m3:instances=0-1 (file lattice-bim-m3.h5)" in html
    assert lines[-1].startswith("wrote ")
    for svg in re.findall(r"<svg[^>]*>", html):          # fixed-size figures, none squeezed
        width = float(re.search(r'width="([\d.]+)pt"', svg).group(1))
        assert width <= 9 * 72 + 1


@pytest.mark.slow       # three full report renders, about 30 s
def test_fidelity_study_is_cached_once_per_set_in_the_user_cache(small_store, tmp_path,
                                                                 monkeypatch):
    import shutil

    import lcpbench.workflows.fidelity as fid

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    lines = []
    render_report(small_store, progress=lines.append)
    cached = sorted((tmp_path / "xdg" / "lcpbench" / "fidelity").glob("lattice-bim-m3-*.csv"))
    assert len(cached) == 1
    assert any("c(A) of instance 2/2" in line for line in lines)      # progress per instance
    assert not (small_store / "cache").exists()                       # not per output folder
    first = (small_store / "report.html").read_text()

    def no_recompute(*args, **kwargs):
        raise AssertionError("c(A) recomputed although the study is cached")

    monkeypatch.setattr(fid, "cottle_c", no_recompute)
    other = tmp_path / "other-folder"                  # a new output folder, same stored set
    shutil.copytree(small_store, other)
    render_report(other)
    render_report(small_store)
    assert (small_store / "report.html").read_text() == first


def test_default_sweep_file_is_the_default_sweep():
    cfg = tomllib.loads((ROOT / "sweeps" / "default.toml").read_text())
    solvers, problems = default_sweep()     # test doubles are listed=False: never in it
    assert cfg["solvers"] == solvers and cfg["problems"] == problems
    assert (cfg["tol"], cfg["stop"], cfg["repeat"]) == (1e-8, "paper", 1)
    assert Sweep(solvers=solvers, problems=problems).config() == \
        Sweep(**cfg).config()
