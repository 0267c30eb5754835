"""lcpbench run: sweep expansion, store, resume, timeouts, failure rows, report."""

import dataclasses
import json
import re

import misbehave_plugin  # noqa: F401  (registers test-misbehave)
import pandas as pd
import pytest

from lcpbench.run import executors
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import HISTORY_STORE_COLUMNS, RESULT_COLUMNS, RunStore
from lcpbench.run.sweep import Sweep, expand

SMALL = "fathi:sizes=[4,6]"


def test_expand_sweeps_lists_and_products():
    assert [s.label for s in expand("bi-pqn:low=[p3,p4]", "solver")] == \
        ["bi-pqn:low=p3", "bi-pqn:low=p4"]
    assert len(expand("bi-pqn:low=[p3,p4],memory=[0,5]", "solver")) == 4
    one = expand("multi-pqn:lows=[p6,p3]", "solver")
    assert len(one) == 1 and one[0].params["lows"] == ["p6", "p3"]
    assert len(expand("multi-pqn:lows=[[p6,p3],[p4]]", "solver")) == 2
    with pytest.raises(Exception, match="memry"):
        expand("mono-pqn:memry=3", "solver")
    with pytest.raises(KeyError, match="no-such"):
        expand("no-such-solver", "solver")


def test_run_store_schema_and_resume_without_duplicates(tmp_path):
    sweep = Sweep(solvers=["bb-pgd", "mono-pqn"], problems=[SMALL], repeat=2)
    p = plan(sweep)
    store = RunStore(tmp_path)
    counts = execute(p, store, quiet=True)
    assert counts["ran"] == len(p.runs) == 8
    res = pd.read_csv(tmp_path / "results.csv")
    hist = pd.read_csv(tmp_path / "history.csv")
    assert list(res.columns) == RESULT_COLUMNS and list(hist.columns) == HISTORY_STORE_COLUMNS
    assert res["solved"].all()
    # simulate an interruption: keep two rows and half of a third
    lines = (tmp_path / "results.csv").read_text().splitlines(keepends=True)
    (tmp_path / "results.csv").write_text("".join(lines[:3]) + lines[3][:20])
    again = execute(plan(sweep), RunStore(tmp_path), quiet=True)
    assert again["kept"] == 2 and again["ran"] == 6
    res = pd.read_csv(tmp_path / "results.csv")
    assert len(res) == 8 and res["run_id"].is_unique
    assert set(RunStore(tmp_path).history()["run_id"]) == set(res["run_id"])


def test_failure_rows_never_stop_the_sweep(tmp_path, monkeypatch):
    monkeypatch.setattr(executors, "GRACE_S", 0.5)
    solvers = ["test-misbehave:mode=[sleep,raise,nan,die]", "bb-pgd"]
    sweep = Sweep(solvers=solvers, problems=["fathi:sizes=[4]"], timeout=1.0)
    counts = execute(plan(sweep), RunStore(tmp_path), jobs=2, timeout=1.0, quiet=True)
    res = pd.read_csv(tmp_path / "results.csv").set_index("solver")
    assert counts["ran"] == 5
    assert res.loc["test-misbehave:mode=sleep", "status"] == "timeout"
    assert res.loc["test-misbehave:mode=raise", "status"] == "failed"
    assert "boom on purpose" in res.loc["test-misbehave:mode=raise", "message"]
    assert res.loc["test-misbehave:mode=nan", "status"] == "diverged"
    assert res.loc["test-misbehave:mode=die", "status"] == "failed"
    assert "exit code 3" in res.loc["test-misbehave:mode=die", "message"]
    assert bool(res.loc["bb-pgd", "solved"])


def test_in_process_failures_are_rows_too(tmp_path):
    sweep = Sweep(solvers=["test-misbehave:mode=[raise,nan]"], problems=["fathi:sizes=[4]"])
    execute(plan(sweep), RunStore(tmp_path), quiet=True)
    res = pd.read_csv(tmp_path / "results.csv")
    assert sorted(res["status"]) == ["diverged", "failed"]


def test_reference_errors_are_recorded(tmp_path):
    sweep = Sweep(solvers=["mono-pqn"], problems=["planted:count=2"])
    execute(plan(sweep), RunStore(tmp_path), quiet=True)
    res = pd.read_csv(tmp_path / "results.csv")
    assert (res["ref_err_w"] < 1e-6).all()


def test_multifidelity_solvers_skip_instances_without_low():
    p = plan(Sweep(solvers=["bi-pqn"], problems=[SMALL]))
    assert not p.runs and len(p.skipped) == 2 and "no low-fidelity" in p.skipped[0]


def test_bi_pqn_without_a_named_low_runs_once_per_low_operator(tmp_path):
    from lcp_cases import planted

    from lcpbench import LCP, register_problem
    from lcpbench.problems.random import with_perturbed_lows

    @dataclasses.dataclass(frozen=True)
    class TwoLowParams:
        """Parameters.

        Parameters
        ----------
        n : int
            Size.
        """

        n: int = 12

    @register_problem("test-two-lows", TwoLowParams)
    def two_lows(p):
        """One planted LCP with two low operators."""
        return [with_perturbed_lows(LCP(*planted(p.n), name="two-lows"), seed=0)]

    p = plan(Sweep(solvers=["bi-pqn", "bi-pqn:low=low", "multi-pqn"], problems=["test-two-lows"]))
    labels = sorted(r.solver.label for r in p.runs)
    assert labels == ["bi-pqn:low=low", "bi-pqn:low=low", "bi-pqn:low=lower", "multi-pqn"]
    assert len({r.run_id for r in p.runs}) == 3       # the explicit and expanded p4 are one run
    store = RunStore(tmp_path / "s")
    execute(p, store, quiet=True)
    res = store.results()
    assert res["solved"].all() and set(res["solver"]) == {"bi-pqn:low=low", "bi-pqn:low=lower",
                                                         "multi-pqn"}


def test_cli_run_resume_refusal_and_report(tmp_path, capsys):
    from lcpbench.cli import main

    out = tmp_path / "store"
    args = ["run", "--solver", "bb-pgd", "--solver", "mono-pqn", "--problem", SMALL,
            "--out", str(out), "--quiet"]
    assert main(args) == 0
    html = (out / "report.html").read_text()
    for section in ("Offline comparison", "E-MVPs of the solved runs", "Residual against E-MVPs",
                    "Speed against error", "Performance profiles", "Runs not solved"):
        assert section in html, section
    # self-contained: nothing loaded from the network (SVG namespace URIs are not loads)
    assert re.search(r"""(src|href)\s*=\s*["']https?://""", html) is None
    assert "@import" not in html
    assert (out / "tables" / "offline.csv").exists() and (out / "tables" / "offline.md").exists()
    meta = json.loads((out / "meta.json").read_text())
    assert meta["counts"]["ran"] == 4 and meta["machine"]["versions"]["numpy"]
    assert main(args) == 0                                   # resume: nothing to do
    assert len(pd.read_csv(out / "results.csv")) == 4
    rc = main(args[:-1] + ["--tol", "1e-6", "--quiet"])      # changed config: refused
    assert rc == 2
    assert "different configuration" in capsys.readouterr().err


def test_config_file(tmp_path):
    from lcpbench.cli import main

    cfg = tmp_path / "s.toml"
    cfg.write_text('solvers = ["bb-pgd"]\nproblems = ["fathi:sizes=[4]"]\ntol = 1e-9\n')
    assert main(["run", "--config", str(cfg), "--out", str(tmp_path / "o"), "--quiet",
                 "--no-report"]) == 0
    res = pd.read_csv(tmp_path / "o" / "results.csv")
    assert res["tol"].tolist() == [1e-9]
    bad = tmp_path / "bad.toml"
    bad.write_text('solver = ["bb-pgd"]\n')
    assert main(["run", "--config", str(bad), "--out", str(tmp_path / "p"), "--quiet"]) == 2


def test_reference_backends_are_scored_against_the_others(tmp_path):
    """A reference QP solver is scored against the other backends' answers (leave one out),
    never against a consensus that contains its own answer."""
    import numpy as np

    from lcpbench.core.reference import reference_without
    from lcpbench.report.ranking import references_table

    x = np.ones(2)
    ref = {"solvers": ["a", "b"], "answers": {"a": (x, np.array([1.0, 0.0]), 1e-12),
                                              "b": (x, np.array([2.0, 0.0]), 1e-11),
                                              "c": (x, np.array([3.0, 0.0]), 1e-14)}}
    assert reference_without(ref, "a")[1][0] == 2.0      # the group's other member
    assert reference_without(ref, "b")[1][0] == 1.0
    assert reference_without(ref, "c")[1][0] == 1.0      # best of the group, not c itself
    assert reference_without({"solvers": ["a"], "answers": {"a": ref["answers"]["a"]}},
                             "a") is None

    sweep = Sweep(solvers=["clarabel", "osqp"], problems=["random-spd:count=2,n_min=8,n_max=8"])
    execute(plan(sweep), RunStore(tmp_path), quiet=True)
    res = pd.read_csv(tmp_path / "results.csv")
    assert res["ref_err_w_others"].notna().all() and (res["ref_err_w_others"] < 1e-6).all()
    table = references_table(res).set_index("solver")
    for name in ("clarabel", "osqp"):
        assert table.loc[name, "in consensus"] == "2/2"
        assert table.loc[name, "error of w vs the others"].endswith("(2)")
