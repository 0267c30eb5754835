"""The report's online section: the paper-shaped table over common steps and the E-MVP figure."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from lcpbench.report import plots, tables
from lcpbench.report.render import render_report
from lcpbench.run.store import RunStore
from lcpbench.workflows.simulate import simulate

BASE = "bb-pgd"


def _scene(m: int) -> str:
    return f"lattice:m={m},model=rpy"


def _row(m: int, solver: str, step: int, time_s: float | None, total_s: float | None,
         emvps: float = 10.0, mvps: float | None = None, multi: bool = False) -> dict:
    """One online step as ``lcpbench simulate`` stores it (the columns the report reads)."""
    scene = _scene(m)
    return {"run_id": f"online|{scene}|{solver}|warm=1|step={step:05d}", "kind": "online",
            "problem": scene, "problem_params": json.dumps({"m": m, "model": "rpy", "p": 8}),
            "family": "lattice", "instance": f"step{step}", "instance_index": step,
            "repeat": 0, "solver": solver, "solver_name": solver.split(":")[0],
            "mvp_only": True, "multifidelity": multi, "step": step, "n": 5,
            "status": "converged" if time_s is not None else "failed",
            "solved": time_s is not None, "false_convergence": False,
            "time_s": time_s, "sim_total_s": total_s, "emvps": emvps,
            "mvps": emvps if mvps is None else mvps, "max_overlap": 0.0}


def _sim(m: int, solver: str, times: list[float], totals: list[float], emvps: list[float],
         mvps: list[float] | None = None, multi: bool = False) -> list[dict]:
    """A simulation: a warm-up step 0 (compilation: 40 s) and then the given steps 1, 2, ..."""
    mvps = emvps if mvps is None else mvps
    warm = [_row(m, solver, 0, 40.0, 60.0, emvps[0], mvps[0], multi)]
    return warm + [_row(m, solver, k + 1, t, tot, e, v, multi)
                   for k, (t, tot, e, v) in enumerate(zip(times, totals, emvps, mvps))]


@pytest.fixture
def online() -> pd.DataFrame:
    """Lattice 4 (listed first) with all steps; lattice 3 where bi-pqn stopped after 3 of 5."""
    rows = []
    rows += _sim(4, BASE, [2.0, 3.0], [5.0, 6.0], [40, 50])
    rows += _sim(4, "mono-pqn", [1.0, 1.0], [4.0, 4.0], [20, 30])
    rows += _sim(4, "bi-pqn:low=p4", [0.5, 0.5], [3.0, 3.0], [4, 5], [2, 3], multi=True)
    rows += _sim(3, BASE, [1.0, 2.0, 3.0, 50.0, 60.0], [2.0, 4.0, 6.0, 90.0, 95.0],
                 [10, 20, 30, 900, 900])
    rows += _sim(3, "mono-pqn", [0.5, 1.0, 1.0, 1.0, 1.0], [1.0, 2.0, 3.0, 1.0, 1.0],
                 [5, 6, 7, 900, 900])
    rows += _sim(3, "bi-pqn:low=p4", [0.25, 0.25, 0.5], [1.5, 1.5, 2.0], [3, 3, 4], [2, 2, 3],
                 multi=True)
    return pd.DataFrame(rows)


def test_speedups_are_ratios_of_summed_times_over_the_common_steps(online):
    t = tables.online_paper_table(online, BASE)
    assert list(t["scene"]) == [_scene(3), _scene(4)]            # by lattice size, not as stored
    assert list(t["lattice size"]) == ["3x3x3", "4x4x4"] and list(t["M"]) == [27, 64]
    r3, r4 = t.iloc[0], t.iloc[1]
    # lattice 3: bi-pqn finished 3 steps after its warm-up, so every solver is compared
    # over steps 1-3 (step 0, the warm-up, is left out)
    assert r3["steps"] == 3 and r4["steps"] == 2
    assert r3[f"{BASE} total s"] == pytest.approx(12.0)           # 2 + 4 + 6, not the 5 steps
    assert r3[f"{BASE} collision s"] == pytest.approx(6.0)
    assert r3["mono-pqn total speedup"] == pytest.approx(12.0 / 6.0)
    assert r3["mono-pqn collision speedup"] == pytest.approx(6.0 / 2.5)
    assert r3["bi-pqn:low=p4 total speedup"] == pytest.approx(12.0 / 5.0)
    assert r3["bi-pqn:low=p4 collision speedup"] == pytest.approx(6.0 / 1.0)
    assert r4["mono-pqn collision speedup"] == pytest.approx(5.0 / 2.0)
    assert r4["bi-pqn:low=p4 total speedup"] == pytest.approx(11.0 / 6.0)
    # medians per step over the common steps only (steps 3 and 4 had 900 E-MVPs)
    assert r3[f"{BASE} median E-MVPs"] == 20 and r3["mono-pqn median E-MVPs"] == 6
    assert r3["bi-pqn:low=p4 median E-MVPs"] == 3 and r3["bi-pqn:low=p4 median MVPs"] == 2
    # the baseline's columns come first and it has no speedup of its own
    cols = list(t.columns)
    assert cols[4:6] == [f"{BASE} total s", f"{BASE} collision s"]
    assert f"{BASE} total speedup" not in cols
    assert t.attrs["stored"][_scene(3)] == {BASE: 6, "mono-pqn": 6, "bi-pqn:low=p4": 4}


def test_a_stopped_simulation_cuts_its_scene_to_the_steps_it_finished():
    rows = _sim(3, BASE, [1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [10, 10, 10])
    rows += _sim(3, "mono-pqn", [0.5, 0.25], [1.0, 1.0], [5, 5])
    rows.append(_row(3, "mono-pqn", 3, None, None))               # the step that stopped it
    t = tables.online_paper_table(pd.DataFrame(rows), BASE).iloc[0]
    assert t["steps"] == 2
    assert t["mono-pqn collision speedup"] == pytest.approx(2.0 / 0.75)
    detail = tables.online_table(pd.DataFrame(rows), BASE).set_index("solver")
    assert detail.loc["mono-pqn", "steps"] == 3 and detail.loc[BASE, "steps"] == 4


def test_scene_without_the_baseline_has_no_speedups():
    rows = _sim(3, "mono-pqn", [1.0, 1.0], [2.0, 2.0], [5, 5])
    t = tables.online_paper_table(pd.DataFrame(rows), BASE)
    assert np.isnan(t.loc[0, "mono-pqn total speedup"])
    assert np.isnan(t.loc[0, f"{BASE} total s"])
    shown = tables.online_paper_display(t).iloc[0]
    assert shown["mono-pqn total speedup"] == "-" and shown[f"{BASE} total s"] == "-"


def test_display_formats_speedups_and_seconds(online):
    shown = tables.online_paper_display(tables.online_paper_table(online, BASE)).iloc[0]
    assert shown["mono-pqn collision speedup"] == "2.40x"
    assert shown[f"{BASE} total s"] == "12" and shown["M"] == "27"


def test_figure_has_one_group_per_lattice_size_and_one_box_per_solver(online):
    steps = tables.online_step_rows(online)
    assert set(steps.groupby("size")["step"].max()) == {2, 3}     # lattice 3 cut to steps 1-3
    assert set(steps["step"]) == {1, 2, 3}                          # no warm-up step
    solvers = [BASE, "mono-pqn", "bi-pqn:low=p4"]
    svg = plots.grouped_boxplot_svg(steps, "size", "solver", "emvps", "t", "lattice size",
                                    "E-MVPs", order=solvers)
    boxes = re.findall(r'id="box_(\dx\dx\d)_([^"]+)"', svg)
    assert sorted(boxes) == sorted((s, re.sub(r"[^A-Za-z0-9_.-]", "_", v))
                                   for s in ("3x3x3", "4x4x4") for v in solvers)
    for solver in solvers:                                         # one legend entry each
        assert svg.count(f">{solver}</text>") == 1
    # groups sit apart along x: every box of the 3x3x3 group left of every 4x4x4 box
    xs = {}
    for size, name in boxes:
        block = svg[svg.index(f'id="box_{size}_{name}"'):]
        xs.setdefault(size, []).append(float(re.search(r"M\s*([-\d.]+)", block).group(1)))
    assert max(xs["3x3x3"]) < min(xs["4x4x4"])


def test_report_renders_the_online_section_from_a_store(tmp_path, online):
    store = RunStore(tmp_path)
    for row in online.to_dict("records"):
        store.append(row)
    html = render_report(tmp_path).read_text()
    section = html[html.index("Online simulations</h2>"):]
    assert "collision resolution</i> is the wall time of the LCP solves" in section
    assert f"{BASE} is the baseline" in section and "wall seconds" in section
    assert f"{_scene(3)}: 4 steps every solver finished" in section
    assert "bb-pgd has 6" in section and "mono-pqn has 6" in section
    assert "<h3>Steps left out of the speedups</h3>" in section
    assert len(set(re.findall(r'box_(\dx\dx\d)_', section))) == 2
    assert "<h3>Per scene and solver</h3>" in section
    # the online table beside the paper's is in the section after the summary
    beside = html[html.index("<h2 id='paper'>"):html.index("<h2 id='run'>")]
    assert "1.85x" in beside and "2.47x" in beside and "88%" in beside   # the paper's rows
    paper = pd.read_csv(tmp_path / "tables" / "online_paper.csv")
    assert list(paper["steps"]) == [3, 2]
    beside = pd.read_csv(tmp_path / "tables" / "online_beside_paper.csv")
    assert list(beside["source"]).count("paper") == 4
    detail = pd.read_csv(tmp_path / "tables" / "online.csv")
    assert len(detail) == 6 and detail["steps"].tolist()[:3] == [6, 6, 4]


def test_simulated_store_gives_ratios_over_the_common_steps(tmp_path):
    """Real ``lcpbench simulate`` rows: two lattice sizes, one simulation extended further."""
    for m in (2, 3):
        simulate(_scene(m), [BASE, "mono-pqn"], 3, tmp_path, progress=False)
    simulate(_scene(3), "mono-pqn", 5, tmp_path, progress=False)
    res = pd.read_csv(tmp_path / "results.csv")
    render_report(tmp_path)
    paper = pd.read_csv(tmp_path / "tables" / "online_paper.csv")
    # a lattice whose steps 1-2 needed no product for any solver has no compared step
    sizes = []
    for m in (2, 3):
        scene = res[res["problem"].str.startswith(f"lattice:m={m},")]
        work = scene[scene["step"].isin([1, 2])].groupby("step")["mvps"].sum()
        if (work > 0).any():
            sizes.append(f"{m}x{m}x{m}")
    assert list(paper["lattice size"]) == sizes and "3x3x3" in sizes
    for _, row in paper.iterrows():
        # steps 0-2 every solver finished, less the warm-up step 0, contact-free steps and
        # steps no solver needed a product for
        scene = res[res["problem"] == row["scene"]]
        empty = set(scene.loc[scene["n"] == 0, "step"])
        idle = set(scene.groupby("step")["mvps"].sum().loc[lambda v: v == 0].index)
        keep = [k for k in (1, 2) if k not in empty | idle]
        assert row["steps"] == len(keep)
        if not keep:
            continue
        part = scene[scene["step"].isin(keep)]
        base = part[part["solver"] == BASE]
        mono = part[part["solver"] == "mono-pqn"]
        assert row["mono-pqn total speedup"] == pytest.approx(
            base["sim_total_s"].sum() / mono["sim_total_s"].sum(), rel=1e-5)
        assert row["mono-pqn collision speedup"] == pytest.approx(
            base["time_s"].sum() / mono["time_s"].sum(), rel=1e-5)
    html = (tmp_path / "report.html").read_text()
    assert "3 steps every solver finished (mono-pqn has 5" in html


def test_measured_rows_sit_beside_the_papers_with_its_numbers(online):
    from lcpbench.report.paper_online import beside_paper
    both = beside_paper(tables.online_paper_table(online, BASE), BASE)
    sizes = list(both["lattice size"])
    # each measured size is followed by the paper's row; the unmeasured 5 and 6 come after
    assert sizes == ["3x3x3", "3x3x3", "4x4x4", "4x4x4", "5x5x5", "6x6x6"]
    assert list(both["source"])[1::2][:2] == ["paper", "paper"]
    m3, p3 = both.iloc[0], both.iloc[1]
    assert m3["Mono-PQN collision speedup"] == pytest.approx(6.0 / 2.5)
    assert m3["Bi-PQN total speedup"] == pytest.approx(12.0 / 5.0)   # bi-pqn:low=p4 found
    assert m3["collision share"] == pytest.approx(6.0 / 12.0)
    # the paper's 3x3x3: 15h 21m total, 13h 31m collision, Bi-PQN 1.85x / 2.07x
    assert p3["BB-PGD total s"] == 55260 and p3["BB-PGD collision s"] == 48660
    assert (p3["Bi-PQN total speedup"], p3["Bi-PQN collision speedup"]) == (1.85, 2.07)
    p6 = both.iloc[5]
    assert p6["BB-PGD total s"] == 7 * 86400 + 18 * 3600 and p6["Mono-PQN total speedup"] == 1.16
    assert p3["collision share"] == pytest.approx(0.8806, abs=1e-3)  # the paper's 88 %


def test_online_table_carries_the_application_weighted_cost(online):
    on = online.copy()
    on["app_cost"] = np.where(on["solver"] == BASE, 4.0, 9.0)
    t = tables.online_paper_table(on, BASE).iloc[0]
    assert t[f"{BASE} median app cost"] == 4.0 and t["mono-pqn median app cost"] == 9.0
    old = tables.online_paper_table(online, BASE).iloc[0]           # stores written before it
    assert np.isnan(old["mono-pqn median app cost"])
