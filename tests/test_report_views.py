"""The report: no pooled view, failures counted, references apart, safe text.

Built from hand-made run-store rows, so every expected number is known in advance.
"""

from __future__ import annotations

import colorsys
import re

import numpy as np
import pandas as pd
import pytest

from lcpbench.report import plots, tables
from lcpbench.report.render import render_report
from lcpbench.run.store import RunStore


def _row(problem, instance, solver, emvps, *, solved=True, n=10, multi=False, reference=False,
         ref_solvers="clarabel,proxqp", ref_err=1e-12, message=""):
    return {"run_id": f"{problem}|{instance}|{solver}", "kind": "offline", "problem": problem,
            "family": "f", "instance": str(instance), "instance_index": 0, "repeat": 0, "n": n,
            "solver": solver, "solver_name": solver.split(":")[0], "emvps": emvps,
            "mvps": emvps, "solved": solved, "multifidelity": multi,
            "mvp_only": not reference, "reference_solver": reference,
            "status": "converged" if solved else "max_iter", "message": message,
            "false_convergence": False, "time_s": 0.001 * (emvps + 1),
            "verified_kkt_abs": 1e-10 if solved else 1e-3, "ref_err_w": ref_err,
            "ref_solvers": ref_solvers}


def _history(row, final=1e-10):
    """Residual 1, 1e-4, final at 0, half and all of the run's E-MVPs."""
    e = float(row["emvps"])
    last = final if row["solved"] else 1e-3
    return pd.DataFrame({"iteration": [0, 1, 2],
                         "emvps": [0.0, e / 2, e], "time_s": [0.0, 0.001, 0.002],
                         "kkt_abs": [1.0, 1e-4, last], "kkt_abs_verified": [1.0, 1e-4, last]})


def _store(tmp_path, rows, final=1e-10):
    store = RunStore(tmp_path)
    for row in rows:
        store.append(row, _history(row, final))
    return tmp_path


@pytest.fixture
def pooled_rows():
    """Two sets: bi-pqn was given 2 of 10 'lattice' instances only; a-pgd solved 2 of 10 'cond'."""
    rows = []
    for i in range(10):
        rows.append(_row("lattice", i, "bb-pgd", 11.0, n=45 + i % 4))
        rows.append(_row("cond", i, "bb-pgd", 100.0 + i, n=50))
        rows.append(_row("cond", i, "a-pgd", 95.0 if i < 2 else 5000.0, solved=i < 2, n=50))
        for p in ("lattice", "cond"):
            rows.append(_row(p, i, "clarabel", 0.0, reference=True, ref_err=0.0))
    for i in range(2):
        rows.append(_row("lattice", i, "bi-pqn:low=rpy", 8.5, multi=True, n=45))
    return rows


def test_no_view_pools_sets_or_instances(tmp_path, pooled_rows):
    folder = _store(tmp_path, pooled_rows)
    tdir = folder / "tables"
    tdir.mkdir()
    (tdir / "work_precision.csv").write_text("solver\nstale pooled table\n")
    render_report(folder)
    assert not (tdir / "work_precision.csv").exists()       # an earlier render's pooled table
    # the work-precision table is per set, every solver over the same runs
    per_set = sorted(tdir.glob("work_precision_set*.csv"))
    assert len(per_set) == 2
    for path in per_set:
        wp = pd.read_csv(path)
        counts = {c: set(wp[c].str.split("/").str[1]) for c in wp if c.startswith("reached@")}
        assert all(len(v) == 1 for v in counts.values()), (path.name, counts)
    lattice = pd.read_csv(tdir / "work_precision_set2.csv")         # sets sorted: cond, lattice
    assert set(lattice["solver"]) == {"bb-pgd", "bi-pqn:low=rpy"}
    assert set(lattice["reached@1e-08"]) == {"2/2"}                # bi-pqn's two instances
    html = (folder / "report.html").read_text()
    views = re.findall(r"<div class='view' data-set='([^']+)' data-instances='(\d+)'>"
                       r"<p class='caption'>([^<]+)</p>", html)
    assert views and {v[0] for v in views} == {"cond", "lattice"}
    for name, count, caption in views:
        assert f"over {count} instances" in caption and name in caption
        assert count == ("10" if name == "cond" else "2")


def test_ratio_counts_both_solved_and_failures_are_penalised(pooled_rows):
    plain = tables.paper_tables(pd.DataFrame(pooled_rows), "bb-pgd")["cond"].set_index("solver")
    # a-pgd solved 2 of 10: its ratio is over those 2, and says so
    assert plain.loc["a-pgd", "median / bb-pgd"] == f"{95.0 / 100.5:.2f} (2 of 10 both solved)"
    t = tables.paper_tables(pd.DataFrame(pooled_rows), "bb-pgd",
                            meta={"config": {"max_emvps": 5000.0}})["cond"].set_index("solver")
    assert t.loc["a-pgd", "success"] == "20 %" and t.loc["a-pgd", "solved"] == "2/10"
    # the shifted geometric mean counts the 8 failures at the budget: far worse than bb-pgd
    sgm = np.exp((2 * np.log(95 + 10) + 8 * np.log(5000 + 10)) / 10) - 10
    assert float(t.loc["a-pgd", "shifted GM"]) == pytest.approx(sgm, rel=5e-3)
    assert float(t.loc["a-pgd", "shifted GM / best"]) > 10
    assert t.loc["bb-pgd", "shifted GM / best"] == "1.00"


def test_references_only_in_their_own_table(tmp_path, pooled_rows):
    res = pd.DataFrame(pooled_rows)
    for metric in ("emvps", "time_s"):
        assert "clarabel" not in tables.performance_profile(res, metric).columns
    assert all("clarabel" not in set(t["solver"]) for t in tables.paper_tables(res).values())
    folder = _store(tmp_path, pooled_rows)
    html = render_report(folder).read_text()
    refs = html.index("<h2 id='references'>")
    before, after = html[:refs], html[refs:html.index("<h2", refs + 5)]
    assert "clarabel" not in before.split("<h2 id='offline'>")[1]
    assert "clarabel" in after
    table = pd.read_csv(folder / "tables" / "references.csv").set_index("problem")
    # clarabel is in every consensus: its error against itself is not reported as accuracy
    assert table.loc["cond", "in consensus"] == "10/10"
    assert table.loc["cond", "error of w vs the others"] == "-"


def test_convergence_floor_starts_at_the_data():
    rows = [_row("tiny", i, "mono-pqn", 1.0) for i in range(3)]
    res = pd.DataFrame(rows)
    hist = pd.concat([_history(r, final=0.0).assign(run_id=r["run_id"]) for r in rows])
    hist.loc[hist["kkt_abs"] == 1e-4, ["kkt_abs", "kkt_abs_verified"]] = 1e-3
    curves = tables.convergence_curves(res, hist, "emvps", points=5)
    c = curves["mono-pqn"]
    # exact zeros sit a decade below the smallest positive residual (1e-3), not at 1e-20
    assert c["floor"] == pytest.approx(1e-4)
    assert np.nanmin(c["lo"]) == pytest.approx(-4.0)


def _hue(hex_color):
    r, g, b = (int(hex_color[i:i + 2], 16) / 255 for i in (1, 3, 5))
    return colorsys.rgb_to_hls(r, g, b)


def test_one_colour_map_families_as_shades():
    from lcpbench.report.colors import solver_colors

    labels = ["bb-pgd", "mono-pqn", "bi-pqn:low=rpy", "bi-pqn:low=p4e6", "bi-pqn:low=p3e6"]
    colors = solver_colors(labels)
    assert solver_colors(["bb-pgd"])["bb-pgd"] == colors["bb-pgd"]     # stable across runs
    hues = [_hue(colors[s])[0] for s in labels[2:]]
    assert max(hues) - min(hues) < 0.02                               # one hue ...
    assert len({_hue(colors[s])[1] for s in labels[2:]}) == 3         # ... three shades
    assert abs(_hue(colors["bb-pgd"])[0] - hues[0]) > 0.05
    # every figure draws a solver in its colour from the map
    data = pd.DataFrame({"solver": labels, "emvps": [1.0, 2.0, 3.0, 4.0, 5.0]})
    svg = plots.boxplot_svg(data, "solver", "emvps", "t", "E-MVPs", order=labels,
                            colors=colors)
    for s in labels:
        assert f"fill: {colors[s]}" in svg


def test_a_dollar_in_a_name_is_drawn_not_parsed(tmp_path):
    name = "stored:path=set_$m_3_4$.h5"
    rows = [_row(name, i, s, 10.0 + i) for i in range(3) for s in ("bb-pgd", "mono-pqn")]
    html = render_report(_store(tmp_path, rows)).read_text()
    assert "set_$m_3_4$.h5" in html.split("<svg")[1]                  # drawn as written


def test_markdown_tables_carry_no_raw_html(tmp_path):
    evil = "<script>alert(1)</script> a|b"
    rows = [_row("p", 0, "bb-pgd", 10.0), _row("p", 0, "mono-pqn", 9.0, solved=False,
                                                message=evil)]
    folder = _store(tmp_path, rows)
    render_report(folder)
    md = (folder / "tables" / "failures.md").read_text()
    assert "<script>" not in md and "&lt;script&gt;" in md
    assert "a\\|b" in md                      # a pipe cannot split the cell
    assert len(md.strip().splitlines()) == 3  # header, rule, one row


def test_online_warm_up_and_contact_free_steps_are_apart():
    def step(solver, k, total, coll, emvps, n=5):
        return {"run_id": f"on|{solver}|{k}", "kind": "online", "problem": "lattice:m=3",
                "problem_params": '{"m": 3}', "solver": solver, "solver_name": solver,
                "step": k, "n": n, "time_s": coll, "sim_total_s": total, "emvps": emvps,
                "mvps": emvps, "solved": True, "multifidelity": False, "max_overlap": 0.0}
    rows = [step("bb-pgd", 0, 66.0, 60.0, 0.0, n=0), step("mono-pqn", 0, 13.0, 8.0, 0.0, n=0),
            step("bb-pgd", 1, 4.0, 2.0, 10.0), step("mono-pqn", 1, 2.0, 1.0, 5.0),
            step("bb-pgd", 2, 1.0, 0.1, 0.0, n=0), step("mono-pqn", 2, 1.0, 0.1, 0.0),
            step("bb-pgd", 3, 6.0, 3.0, 20.0), step("mono-pqn", 3, 4.0, 2.0, 8.0)]
    res = pd.DataFrame(rows)
    t = tables.online_paper_table(res, "bb-pgd").iloc[0]
    assert t["steps"] == 2                                           # steps 1 and 3
    assert t["mono-pqn total speedup"] == pytest.approx(10.0 / 6.0)  # not (66+..)/(13+..)
    assert t["mono-pqn median E-MVPs"] == pytest.approx(6.5)
    apart = tables.online_left_out(res).set_index(["solver", "reason"])
    assert apart.loc[("bb-pgd", "warm-up"), "total s"] == 66.0
    assert apart.loc[("mono-pqn", "no contacts"), "steps"] == "2"
    # the box plot is drawn from the same rows as the table
    steps = tables.online_step_rows(res)
    assert sorted(steps["step"].unique()) == [1, 3]
    assert steps.groupby("solver")["emvps"].median()["mono-pqn"] == t["mono-pqn median E-MVPs"]


def test_online_without_a_step_to_compare_gives_no_speedup(tmp_path):
    rows = [{"run_id": f"on|{s}|0", "kind": "online", "problem": "lattice:m=2",
             "problem_params": '{"m": 2}', "solver": s, "solver_name": s, "step": 0, "n": 0,
             "time_s": t, "sim_total_s": t, "emvps": 0.0, "mvps": 0.0, "solved": True,
             "multifidelity": False, "max_overlap": 0.0}
            for s, t in (("bb-pgd", 66.0), ("mono-pqn", 13.0))]
    store = RunStore(tmp_path)
    for r in rows:
        store.append(r)
    html = render_report(tmp_path).read_text()
    section = html.split("Online simulations</h2>")[1]
    assert "No step is left to compare" in section
    assert not re.search(r"\d\.\d\dx", section)              # no speedup such as 5.08x
    assert "Performance profiles</h2>" not in html            # no empty section either


def test_a_set_solved_for_free_gets_a_note_not_an_empty_box_plot(tmp_path):
    rows = [_row("free", i, s, 0.0) for i in range(3) for s in ("bb-pgd", "mono-pqn")]
    rows += [_row("paid", i, s, 10.0 + i) for i in range(3) for s in ("bb-pgd", "mono-pqn")]
    html = render_report(_store(tmp_path, rows)).read_text()
    free = html.split(">free</h3>")[1].split(">paid</h3>")[0]      # the 'free' set's section
    assert html.count("spent 0 E-MVPs") == 1 and "spent 0 E-MVPs" in free
    assert "E-MVPs of the solved runs: paid" in html
    assert "E-MVPs of the solved runs: free" not in html


def test_online_steps_that_no_solver_needed_a_product_for_are_apart():
    def step(solver, k, total, mvps):
        return {"run_id": f"on|{solver}|{k}", "kind": "online", "problem": "lattice:m=2",
                "problem_params": '{"m": 2}', "solver": solver, "solver_name": solver,
                "step": k, "n": 4, "time_s": total / 2, "sim_total_s": total,
                "emvps": mvps, "mvps": mvps, "lofi_mvps_total": 0.0, "solved": True,
                "multifidelity": False, "max_overlap": 0.0}
    # step 0 warm-up; steps 1-3 contacts far apart (x = 0 read off b); step 4 only mono-pqn
    # needed no product (a real difference: kept); steps 4-5 compared
    rows = [step(s, 0, 50.0, 0.0) for s in ("bb-pgd", "mono-pqn")]
    rows += [step(s, k, 1.0, 0.0) for k in (1, 2, 3) for s in ("bb-pgd", "mono-pqn")]
    rows += [step("bb-pgd", 4, 4.0, 6.0), step("mono-pqn", 4, 1.0, 0.0),
             step("bb-pgd", 5, 6.0, 10.0), step("mono-pqn", 5, 4.0, 8.0)]
    res = pd.DataFrame(rows)
    t = tables.online_paper_table(res, "bb-pgd").iloc[0]
    assert t["steps"] == 2
    assert t["mono-pqn total speedup"] == pytest.approx(10.0 / 5.0)
    assert t["bb-pgd median E-MVPs"] == pytest.approx(8.0)           # not 0
    apart = tables.online_left_out(res).set_index(["solver", "reason"])
    assert apart.loc[("bb-pgd", "no products"), "steps"] == "1,2,3"
    assert apart.loc[("mono-pqn", "no products"), "total s"] == 3.0
