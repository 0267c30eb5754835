"""The method paper's results page (``lcpbench paper``): numbers from the stores' rows only,
speedups as ratios of sums over the compared steps, the same page on every rerun."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd
import pytest

from lcpbench.cli.app import main
from lcpbench.report import paper_offline
from lcpbench.report.paper_page import PAGE_NAME, render_page, write_page
from lcpbench.run.store import RunStore

ROOT = Path(__file__).resolve().parents[1]
SCENE = "paper-lattice:m=3,model=bim,p=8,eps_gmres=1e-8,low=[p4],krylov_mb=0"


def _online(solver: str, step: int, total: float, coll: float, mvps: float, low: float = 0.0,
            regime: str = "paper", load: float = 1.0) -> dict:
    return {"run_id": f"online|{SCENE}|{solver}|warm=1|step={step:05d}", "kind": "online",
            "problem": SCENE, "problem_params": json.dumps({"m": 3, "model": "bim", "p": 8}),
            "family": "paper-lattice", "instance": f"step{step}", "instance_index": step,
            "repeat": 0, "solver": solver, "solver_name": solver.split(":")[0],
            "mvp_only": True, "multifidelity": solver.startswith("bi-pqn"), "step": step,
            "n": 6, "status": "converged", "solved": True, "false_convergence": False,
            "time_s": coll, "sim_total_s": total, "mvps": mvps, "lofi_mvps_total": low,
            "emvps": mvps + 0.25 * low, "app_cost": 2 * mvps, "max_overlap": 0.0,
            "started": f"2026-01-01T00:{step:02d}:00+00:00",
            "finished": f"2026-01-01T00:{step:02d}:30+00:00",
            "info": json.dumps({"regime": regime, "load_1min": load})}


# step 0: warm-up (compilation); steps 1-2: contacts but no product for anybody; 3-6 compared
TIMES = {  # solver: (totals, collision seconds, high MVPs, low MVPs) over steps 0..6
    "bb-pgd": ([90, 5, 5, 4, 6, 8, 2], [80, 1, 1, 3, 5, 7, 1], [0, 0, 0, 10, 12, 14, 8],
               [0] * 7),
    "mono-pqn": ([70, 5, 5, 2, 3, 4, 1], [60, 1, 1, 1, 2, 3, 0.5], [0, 0, 0, 7, 9, 9, 6],
                 [0] * 7),
    "bi-pqn:low=p4": ([70, 5, 5, 2, 2, 2, 2], [60, 1, 1, 1, 1, 1, 1], [0, 0, 0, 3, 3, 4, 3],
                      [0, 0, 0, 8, 8, 12, 8]),
}


def _online_store(path: Path, regime: str = "paper") -> None:
    store = RunStore(path)
    for solver, (tot, coll, hi, lo) in TIMES.items():
        for k in range(7):
            store.append(_online(solver, k, tot[k], coll[k], hi[k], lo[k], regime,
                                 load=1.0 + k))
    store.write_meta({"argv": ["lcpbench", "simulate", "--regime", regime], "git_commit":
                      "0123456789abcdef", "machine": {"cpu": "x86_64", "cpu_count": 2}})


def _offline(problem: str, solver: str, instance: int, emvps: float, mvps: float) -> dict:
    return {"run_id": f"offline|{problem}|{solver}|{instance}", "kind": "offline",
            "problem": problem, "family": "stored", "instance": f"i{instance}",
            "instance_index": instance, "repeat": 0, "solver": solver,
            "solver_name": solver.split(":")[0], "mvp_only": True,
            "multifidelity": solver.startswith("bi-pqn"), "n": 40, "status": "converged",
            "solved": True, "false_convergence": False, "time_s": 0.01, "emvps": emvps,
            "mvps": mvps, "started": "2026-01-02T00:00:00+00:00",
            "finished": "2026-01-02T00:00:01+00:00", "info": "{}"}


def _offline_store(path: Path) -> None:
    store = RunStore(path)
    for i in range(3):
        store.append(_offline("set-x", "bb-pgd", i, [16, 20, 18][i], [16, 20, 18][i]))
        store.append(_offline("set-x", "mono-pqn", i, [12, 15, 14][i], [12, 15, 14][i]))
        store.append(_offline("set-x", "bi-pqn:low=p4e6", i, [6.5, 7.0, 9.0][i], [3, 4, 5][i]))
    store.write_meta({"argv": ["lcpbench", "run"], "git_commit": "fedcba9876543210"})


def _table_row(page: str, first_cells: str) -> list[str]:
    line = next(ln for ln in page.splitlines() if re.match(rf"\|\s*{first_cells}", ln))
    return [c.strip() for c in line.strip().strip("|").split("|")]


@pytest.fixture
def folder(tmp_path, monkeypatch) -> Path:
    monkeypatch.chdir(tmp_path)
    _online_store(tmp_path / "paper" / "online-paper")
    _offline_store(tmp_path / "paper" / "offline")
    return Path("paper")


def test_speedups_are_ratios_of_sums_over_the_compared_steps(folder):
    page = render_page(folder)
    row = _table_row(page, r"3x3x3\s*\|\s*lcpbench")
    steps, bb_total, bb_coll, mono_t, mono_c, bi_t, bi_c = row[2:9]
    assert steps == "4"                                    # steps 3-6: no warm-up, no idle
    assert bb_total == "20" and bb_coll == "16"            # 4+6+8+2, 3+5+7+1
    assert mono_t == f"{20 / 10:.2f}x" and mono_c == f"{16 / 6.5:.2f}x"
    assert bi_t == f"{20 / 8:.2f}x" and bi_c == f"{16 / 4:.2f}x"
    paper_row = _table_row(page, r"3x3x3\s*\|\s*paper")
    assert paper_row[7:9] == ["1.85x", "2.07x"]           # the paper's own Bi-PQN figures


def test_medians_and_left_out_steps_come_from_the_same_rows(folder):
    page = render_page(folder)
    bi = _table_row(page, r"3x3x3\s*\|\s*`bi-pqn:low=p4`")
    # compared steps 3-6: E-MVPs 3+2, 3+2, 4+3, 3+2 -> median 5; high MVPs median 3
    assert bi[2:6] == ["4", "4/4", "5", "3"]
    warm = _table_row(page, rf"`{re.escape(SCENE)}`\s*\|\s*warm-up")
    idle = _table_row(page, rf"`{re.escape(SCENE)}`\s*\|\s*no products")
    assert warm[2:] == ["0", "1"] and idle[2:] == ["1-2", "2"]
    assert "load average over the rows: median 4.00, max 7.00" in page


def test_offline_medians_beside_the_paper(folder):
    page = render_page(folder)
    mono = _table_row(page, r"`mono-pqn`")
    bi = _table_row(page, r"`bi-pqn:low=p4e6`")
    assert mono[3:7] == ["14", "8", f"{14 / 18:.3g}", f"{8 / 11:.3g}"]
    assert bi[3:5] == ["7 (4)", "4.6 (3)"]
    assert bi[5] == f"{7 / 18:.3g}"
    assert "Offline `set-x`: Mono-PQN" in page


def test_the_page_is_the_same_on_every_rerun(folder):
    first = write_page(folder)
    assert first == folder / PAGE_NAME
    text = first.read_text()
    assert write_page(folder).read_text() == text
    assert main(["paper", str(folder)]) == 0
    assert (folder / PAGE_NAME).read_text() == text


def test_the_committed_page_is_what_its_stores_give(monkeypatch):
    committed = ROOT / "reports" / "paper" / PAGE_NAME
    if not committed.exists():
        pytest.fail("reports/paper/README.md is missing: run `lcpbench paper reports/paper`")
    monkeypatch.chdir(ROOT)
    assert render_page(Path("reports/paper")) == committed.read_text(), (
        "reports/paper/README.md differs from what its stores give: rerun "
        "`lcpbench paper reports/paper` after the stores changed")


def test_a_store_of_two_regimes_is_refused(tmp_path, capsys):
    _online_store(tmp_path / "online")
    RunStore(tmp_path / "online").append(_online("bb-pgd", 7, 1.0, 1.0, 5, regime="default"))
    assert main(["paper", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lcpbench paper: error: one store holds online rows of several")
    assert "\n" not in err


def test_a_folder_without_stores_is_refused(tmp_path, capsys):
    assert main(["paper", str(tmp_path)]) == 2
    assert "holds no run store" in capsys.readouterr().err
    assert main(["paper", str(tmp_path / "missing")]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert not (tmp_path / PAGE_NAME).exists()


def test_every_paper_row_names_a_registered_solver_spec():
    from lcpbench.core.registry import get_solver
    from lcpbench.core.specs import make_params, parse_spec

    for spec in paper_offline.PAPER_OFFLINE:
        name, values = parse_spec(spec)
        info = get_solver(name)
        make_params(name, info.params, values)


def test_the_offline_table_keeps_to_common_instances():
    rows = pd.DataFrame([_offline("s", "bb-pgd", i, 10.0 + i, 10.0 + i) for i in range(3)]
                        + [_offline("s", "mono-pqn", i, 5.0, 5.0) for i in range(2)])
    t = paper_offline.beside_paper(rows, "s")
    assert t.attrs["instances"] == 2
    assert t.set_index("solver").loc["bb-pgd", "median E-MVPs"] == pytest.approx(10.5)
