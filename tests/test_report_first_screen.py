"""The report's first screen: ratios to the baseline with their spread, and the paper beside."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from lcpbench.report import offline, paper_section, ratios, render
from lcpbench.report.render import render_report
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep


def _row(instance, solver, emvps, solved=True, mvps=None, multi=False, info=None,
         problem="set"):
    params = {"low": solver.split("low=")[1]} if "low=" in solver else {}
    return {"run_id": f"{problem}/{instance}/{solver}", "kind": "offline", "problem": problem,
            "family": problem, "instance": instance, "repeat": 0, "solver": solver,
            "solver_params": json.dumps(params), "emvps": emvps,
            "mvps": emvps if mvps is None else mvps, "solved": solved, "multifidelity": multi,
            "mvp_only": True, "time_s": 0.01 * emvps, "false_convergence": False,
            "ref_err_w": 1e-12, "tol": 1e-8, "stop": "paper", "n": 10,
            "info": json.dumps(info or {})}


def _cut(rows) -> pd.DataFrame:
    return pd.DataFrame(rows)


def test_ratios_are_per_instance_with_quartiles_and_failures_infinite():
    base = [10, 20, 40, 80]
    rows = [_row(f"i{k}", "bb-pgd", e) for k, e in enumerate(base)]
    rows += [_row(f"i{k}", "half", e / 2) for k, e in enumerate(base)]
    # cheap where it solves, but solves one instance of four
    rows += [_row("i0", "lucky", 1.0)] + [_row(f"i{k}", "lucky", 1.0, solved=False)
                                          for k in (1, 2, 3)]
    rows += [_row(f"i{k}", "spread", e * f) for k, (e, f) in
             enumerate(zip(base, (0.2, 0.4, 0.6, 0.8)))]
    stats = {s.solver: s for s in ratios.ratio_stats(_cut(rows), "bb-pgd")}
    assert stats["half"].median == pytest.approx(0.5)
    assert stats["half"].q25 == pytest.approx(0.5) and stats["half"].q75 == pytest.approx(0.5)
    assert stats["spread"].median == pytest.approx(0.5)
    assert stats["spread"].q25 == pytest.approx(0.35) and stats["spread"].q75 == pytest.approx(0.65)
    assert np.isinf(stats["lucky"].median) and stats["lucky"].q25 == np.inf
    assert (stats["lucky"].solved, stats["lucky"].runs) == (1, 4)
    best = ratios.best_by_ratio(list(stats.values()))
    assert best is not None and best.solver == "half"     # 'spread' ties on the median: name
    assert ratios.format_ratio(stats["spread"]) == "0.50 [0.35-0.65], 4/4 solved"
    assert ratios.format_ratio(stats["lucky"]) == "unsolved [unsolved-unsolved], 1/4 solved"


def test_summary_names_the_best_by_the_statistic_it_shows():
    rows = []
    for k, e in enumerate([10, 12, 14, 20]):
        rows += [_row(f"i{k}", "bb-pgd", e), _row(f"i{k}", "mono-pqn", e * 0.6)]
        rows += [_row(f"i{k}", "fragile", 1.0, solved=(k == 0))]
    res = _cut(rows)
    hist = pd.DataFrame({"run_id": res["run_id"], "k": 0, "emvps": res["emvps"],
                         "time_s": res["time_s"], "kkt_abs_verified": np.nan,
                         "kkt_abs": np.where(res["solved"], 1e-9, 1.0)})
    views = offline.set_views(res, hist)
    summary = offline.summary_table(views, "bb-pgd")
    cell = summary["best median ratio to bb-pgd"].iloc[0]
    assert cell == "mono-pqn: 0.60 [0.60-0.60], 4/4 solved"
    # at a residual level the best is the lowest median to reach it, and its cell is that
    # median: 'fragile' reached it once, cheaply, and is not named
    assert summary["best to 1e-08"].iloc[0] == "mono-pqn: 7.8 E-MVPs (4/4)"
    grid = offline.ratio_tables(views, "bb-pgd")[0].set_index("solver")
    assert grid.loc["best (lowest median ratio)", "set"] == "mono-pqn"
    assert grid.loc["fragile", "set"].startswith("unsolved")


def test_ratio_tables_split_sets_three_to_a_table():
    per_set = {f"s{k}": [ratios.RatioStats("bb-pgd", 1, 1, 1, 2, 2, 2)] for k in range(7)}
    grids = ratios.ratio_matrix(per_set)
    assert [list(g.columns[1:]) for g in grids] == [["s0", "s1", "s2"], ["s3", "s4", "s5"],
                                                     ["s6"]]


def test_paper_rows_say_why_they_differ():
    rows = []
    for k in range(4):
        rows += [_row(f"i{k}", "bb-pgd", 11.0), _row(f"i{k}", "mono-pqn", 8.0)]
        rows += [_row(f"i{k}", "bi-pqn:low=p4e6", 8.58, mvps=7, multi=True)]     # 0.78x
        rows += [_row(f"i{k}", "bi-pqn:low=p6e6", 5.06, mvps=2, multi=True)]     # 0.46x
        rows += [_row(f"i{k}", "bi-pqn:low=p8f6e3", 3.4, mvps=3, multi=True)]    # no paper row
        rows += [_row(f"i{k}", "a-pgd", 66.0, info={"power_mvps": 20})]
    comp = paper_section.compare_set("set", _cut(rows), "bb-pgd",
                                     errors={"p4e6": 0.27, "p6e6": 0.007})
    t = comp.table.set_index("solver")
    assert list(t.index) == ["bb-pgd", "a-pgd", "mono-pqn", "bi-pqn:low=p4e6",
                             "bi-pqn:low=p6e6", "bi-pqn:low=p8f6e3"]
    assert t.loc["bi-pqn:low=p4e6", "paper (high)"] == "4.6 (3)"
    assert t.loc["bi-pqn:low=p4e6", "median E-MVPs (high)"] == "8.58 (7)"
    assert t.loc["bi-pqn:low=p4e6", "paper ratio"] == "0.42"
    assert t.loc["bi-pqn:low=p4e6", "ratio to bb-pgd [25-75 %]"] == "0.78 [0.78-0.78], 4/4 solved"
    assert t.loc["a-pgd", "paper method"] == "A-PGD"
    assert t.loc["bi-pqn:low=p8f6e3", "paper (high)"] == "-"
    why = {line.split(":")[0] + (":" + line.split(":")[1] if "low=" in line else ""): line
           for line in comp.why}
    # agreeing rows (BB-PGD at the paper's 11, Mono-PQN 0.73 against 0.73, p6e6 0.46
    # against 0.46) have no line; the others say why
    assert sorted(why) == ["a-pgd", "bi-pqn:low=p4e6"]
    assert "0.27 from the high" in why["bi-pqn:low=p4e6"]
    assert "median 7 here, the paper's 3" in why["bi-pqn:low=p4e6"]
    assert "20 counted power-iteration products" in why["a-pgd"]


def test_sets_without_a_paper_low_are_not_paper_like():
    with_low = _cut([_row("i0", "bb-pgd", 1), _row("i0", "bi-pqn:low=p4e6", 1, multi=True)])
    other = _cut([_row("i0", "bb-pgd", 1), _row("i0", "bi-pqn:low=rpy", 1, multi=True)])
    assert paper_section.paper_like_sets({"a": with_low, "b": other}) == ["a"]


@pytest.fixture(scope="module")
def paper_store(tmp_path_factory):
    store = tmp_path_factory.mktemp("paper") / "store"
    sweep = Sweep(solvers=["bb-pgd", "mono-pqn", "bi-pqn:low=p4e6", "bi-pqn:low=p8f6e3"],
                  problems=["fathi:sizes=[4]", "set-paper-lattice-m3:instances=0-1"])
    execute(plan(sweep), RunStore(store), quiet=True)
    return store


def test_the_report_opens_with_the_paper_after_the_summary(paper_store, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    # the fidelity study (tests/test_report.py) is left out: it takes a minute on this set
    monkeypatch.setattr(render, "fidelity_section", lambda *a, **k: "")
    text = render_report(paper_store).read_text()
    h2 = re.findall(r"<h2 id='([\w-]+)'>", text)
    assert h2[:3] == ["summary", "paper", "run"], h2
    section = text[text.index("<h2 id='paper'>"):text.index("<h2 id='run'>")]
    assert "set-paper-lattice-m3:instances=0-1: 2 instances" in section
    assert "Bi-PQN, low p = 4, eps 1e-6" in section and "bi-pqn:low=p8f6e3" in section
    assert "fathi" not in section                      # no paper low: not paper-like
    table = pd.read_csv(paper_store / "tables" / "beside_paper.csv")
    row = table[table["solver"] == "bi-pqn:low=p4e6"].iloc[0]
    assert str(row["paper ratio"]) == "0.42"
    summary = text[text.index("<h2 id='summary'>"):text.index("<h2 id='paper'>")]
    assert "[25 %-75 %]" in summary and "solved" in summary


def test_a_set_the_baseline_never_solved_says_so():
    rows = [_row(f"i{k}", "bb-pgd", 5.0, solved=False) for k in range(2)]
    rows += [_row(f"i{k}", "mono-pqn", 3.0) for k in range(2)]
    res = _cut(rows)
    hist = pd.DataFrame({"run_id": res["run_id"], "k": 0, "emvps": res["emvps"],
                         "time_s": res["time_s"], "kkt_abs_verified": np.nan,
                         "kkt_abs": np.where(res["solved"], 1e-9, 1.0)})
    summary = offline.summary_table(offline.set_views(res, hist), "bb-pgd")
    assert summary["best median ratio to bb-pgd"].iloc[0] == \
        "- (bb-pgd solved no instance at a positive cost)"
