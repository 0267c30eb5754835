"""The benchopt benchmark in integrations/benchopt: ``benchopt run`` on one shipped set.

Needs the extra ``benchopt`` (``pip install -e ".[benchopt]"``; ``.ci/run`` installs it).
The benchmark is copied to a temporary folder first, so benchopt's cache and outputs stay out
of the checkout.
"""

import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import lcpbench
from lcpbench.run.runner import generate
from lcpbench.run.sweep import expand

BENCHMARK = pathlib.Path(__file__).resolve().parents[1] / "integrations" / "benchopt"
SOLVERS = ["bb-pgd", "mono-pqn"]
PROBLEM = "set-paper-lattice-m3"


def _benchopt():
    path = shutil.which("benchopt", path=str(pathlib.Path(sys.executable).parent))
    assert path, 'benchopt is not installed: pip install -e ".[benchopt]"'
    return path


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One ``benchopt run``: one dataset, two solvers, two repetitions."""
    tmp = tmp_path_factory.mktemp("benchopt")
    bench = tmp / "benchmark"
    shutil.copytree(BENCHMARK, bench, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp / "run.parquet"
    cmd = [_benchopt(), "run", str(bench), "-d", f"lcpbench[problem={PROBLEM},instance=0]",
           "-r", "2", "-n", "50", "--no-plot", "--no-display", "--output", str(out)]
    for s in SOLVERS:
        cmd += ["-s", f"lcpbench[solver={s}]"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return bench, pd.read_parquet(out)


@pytest.mark.slow
def test_benchopt_runs_lcpbench_solvers_to_lcpbench_s_own_answer(run):
    _, df = run
    lcp = generate(expand(PROBLEM, "problem")[0])[0]
    assert set(df["p_solver_solver"]) == set(SOLVERS)
    for name in SOLVERS:
        rows = df[df["p_solver_solver"] == name]
        assert rows["idx_rep"].nunique() == 2
        # the E-MVPs grow along the sampled iterates and are the same in every repetition
        for _, rep in rows.groupby("idx_rep"):
            assert np.all(np.diff(rep.sort_values("stop_val")["objective_emvps"]) >= 0)
        per_rep = rows.pivot_table(index="stop_val", columns="idx_rep",
                                   values="objective_emvps")
        assert (per_rep.nunique(axis=1) == 1).all()
        # the last point is lcpbench's own solve: its E-MVPs and its verified residual
        last = rows[rows["stop_val"] == rows["stop_val"].max()].iloc[0]
        ref = lcpbench.run_solver(lcp, name, tol=1e-8)
        assert ref.solved
        assert last["objective_emvps"] == pytest.approx(ref.emvps)
        assert last["objective_mvps"] == ref.mvps
        assert last["objective_value"] == pytest.approx(ref.verified_kkt_abs, rel=1e-6,
                                                        abs=1e-14)
        assert last["objective_value"] <= 1e-8


@pytest.mark.slow
def test_the_residual_against_emvps_plot_uses_lcpbench_s_counts(run):
    bench, df = run
    from benchopt.benchmark import Benchmark

    plots = {p.name: p for p in Benchmark(bench).get_plots()}
    plot = plots["Residual against E-MVPs"]
    plot._check()
    dataset, objective = df["dataset_name"].iloc[0], df["objective_name"].iloc[0]
    traces = plot.plot(df, dataset=dataset, objective=objective)
    assert {t["label"] for t in traces} == set(df["solver_name"])
    for t in traces:
        rows = df[df["solver_name"] == t["label"]]
        assert t["x"] == sorted(t["x"])
        assert t["x"][-1] == rows["objective_emvps"].max()
        assert min(t["y"]) == pytest.approx(rows["objective_value"].min())
    assert plot.get_metadata(df, dataset=dataset, objective=objective)["xlabel"] == "E-MVPs"


def _benchmark_class(path, name):
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"lcpbench_benchopt_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return getattr(module, name)


@pytest.mark.slow
def test_the_benchmark_s_bad_input_messages_are_those_of_docs_errors():
    Dataset = _benchmark_class(BENCHMARK / "datasets" / "lcpbench_problems.py", "Dataset")
    with pytest.raises(ValueError, match=r"^instance 99 is out of range: 'tiny' has 7 "
                                         r"instance\(s\), 0\.\.6$"):
        Dataset.get_instance(problem="tiny", instance=99).get_data()
    with pytest.raises(ValueError, match=r"^problem 'planted:count=\[1,2\]' names 2 parameter "
                                         r"combinations; give one value per parameter$"):
        Dataset.get_instance(problem="planted:count=[1,2]", instance=0).get_data()
    data = Dataset.get_instance(problem=PROBLEM, instance=0).get_data()
    Solver = _benchmark_class(BENCHMARK / "solvers" / "lcpbench_solvers.py", "Solver")
    lows = ", ".join(sorted(data["lcp"].low))
    name = data["lcp"].name
    assert Solver.get_instance(solver="bi-pqn", low="").skip(data["lcp"], 1e-8) == (
        True, f"{name} has {len(data['lcp'].low)} lows; name one: "
              f"lcpbench[solver=bi-pqn,low=NAME], NAME in {lows}")
    assert Solver.get_instance(solver="bi-pqn", low="p9").skip(data["lcp"], 1e-8) == (
        True, f"{name} has no low 'p9'; it has {lows}")
    assert Solver.get_instance(solver="bb-pgd", low="p4e6").skip(data["lcp"], 1e-8) == (
        True, "bb-pgd uses no low fidelity; leave low empty")
    assert Solver.get_instance(solver="bi-pqn", low="p4e6").skip(data["lcp"], 1e-8) == (
        False, None)
    # the registry's solvers, without the reference QP solvers
    assert "bi-pqn" in Solver.parameters["solver"] and "clarabel" not in Solver.parameters["solver"]
