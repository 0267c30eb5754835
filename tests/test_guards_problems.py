"""Oversized work is refused before it starts: problem memory, build time, sweep size."""

import os

import pandas as pd
import pytest

import lcpbench
from lcpbench.cli import main
from lcpbench.core import guards
from lcpbench.core.specs import make_params


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    lines = [line for line in err if ": error:" in line]
    assert len(lines) == 1 and "Traceback" not in "\n".join(err), err
    return lines[0]


def _estimate(spec_name: str, **values):
    from lcpbench.core.registry import problem_estimate

    info = lcpbench.get_problem(spec_name)
    return problem_estimate(spec_name, make_params(spec_name, info.params,
                                                   {k: str(v) for k, v in values.items()}))


@pytest.mark.parametrize("name, values, n, count", [
    ("random-spd", {"n_min": 100, "n_max": 400, "count": 3}, 400, 3),
    ("bifidelity", {"n": 120, "count": 2}, 120, 2),
    ("planted", {"n_active": 10, "n_inactive": 5, "n_degenerate": 1, "count": 4}, 16, 4),
    ("spd-cond", {"n": 30, "count": 6}, 30, 6),
    ("all-inactive", {"n": 25, "count": 2}, 25, 2),
    ("bad-scale", {"n": 40, "count": 3}, 40, 3),
    ("infeasible", {"n": 9, "count": 2}, 9, 2),
    ("unbounded", {"n": 9, "count": 2}, 9, 2),
])
def test_estimates_cover_what_the_family_builds(name, values, n, count):
    """The estimate names the instances and largest n that the family then builds, and holds
    at least the bytes of their dense matrices."""
    est = _estimate(name, **values)
    info = lcpbench.get_problem(name)
    lcps = info.func(make_params(name, info.params, {k: str(v) for k, v in values.items()}))
    assert est.instances == len(lcps) == count
    assert est.n == n >= max(lcp.n for lcp in lcps)        # random-spd draws n up to n_max
    matrices = sum(lcp.dense().nbytes + sum(op.shape[0] ** 2 * 8 for op in lcp.low.values())
                   for lcp in lcps)
    assert est.bytes >= matrices


def test_inexact_estimate_is_linear_in_n():
    small, large = _estimate("inexact", n=1000, count=1), _estimate("inexact", n=10_000_000,
                                                                     count=1)
    assert large.bytes < 1e4 * small.bytes and large.flops == 0.0


@pytest.mark.parametrize("spec, words", [
    ("bad-scale:n=40000", ["bad-scale:n=40000: 3 instance(s) of n up to 40000",
                           "83.5 GiB of memory", "--force", "limit:"]),
    ("planted:count=1e8", ["100000000 instance(s)", "TiB of memory", "lower n or count"]),
    ("random-spd:n_min=100000,n_max=100000,count=1", ["373 GiB"]),
])
def test_solve_refuses_oversized_problems_without_allocating(spec, words, capsys):
    assert main(["solve", "--problem", spec]) == 2
    err = _error(capsys)
    for w in words:
        assert w in err, (w, err)


def test_build_time_over_the_limit_is_refused_and_long_builds_are_announced(monkeypatch,
                                                                             capsys):
    spec = "random-spd:n_min=300,n_max=300,count=2"
    monkeypatch.setattr(guards, "TIME_LIMIT_S", 1e-6)
    assert main(["solve", "--problem", spec]) == 2
    err = _error(capsys)
    assert "2 instance(s) of n up to 300 take about" in err and "to build" in err
    assert "GFLOP/s" in err
    monkeypatch.setattr(guards, "TIME_LIMIT_S", 1e9)
    monkeypatch.setattr(guards, "NOTE_AFTER_S", 0.0)
    assert main(["solve", "--problem", spec, "--json"]) == 0
    assert f"building {spec} (2 instance(s) of n up to 300) takes about" in \
        capsys.readouterr().err


def test_force_lifts_the_memory_limit(monkeypatch, capsys):
    monkeypatch.setattr(guards, "MEMORY_FRACTION", 1e-12)      # every family is "too large"
    spec = ["solve", "--problem", "planted:count=1,n_active=2,n_inactive=2,n_degenerate=0",
            "--json"]
    assert main(spec) == 2
    assert "of memory" in _error(capsys)
    assert main(spec + ["--force"]) == 0
    assert '"solved": true' in capsys.readouterr().out


# ------------------------------------------------------------------------------ sweeps
def test_spec_count_is_arithmetic_on_brackets():
    from lcpbench.run.sweep import expand, spec_count

    for spec, kind in [("bb-pgd", "solver"), ("bb-pgd:variant=[bb1,bb2],memory=[1,2,3]",
                                               "solver"),
                       ("planted:seed=[0,1,2,3],cond=[10,100]", "problem"),
                       ("multi-pqn:lows=[p6,p3]", "solver"),
                       ("multi-pqn:lows=[[p6,p3],[p4,p3]]", "solver")]:
        assert spec_count(spec, kind) == len(expand(spec, kind)), spec


def test_a_sweep_of_too_many_runs_is_refused_before_planning(tmp_path, monkeypatch, capsys):
    import lcpbench.run.runner as runner

    def no_planning(*a, **k):
        raise AssertionError("the sweep was planned")

    monkeypatch.setattr(runner, "plan", no_planning)
    monkeypatch.setattr("lcpbench.cli.run.plan", no_planning)
    monkeypatch.setattr(guards, "MAX_RUNS", 10)
    cfg = tmp_path / "s.toml"
    cfg.write_text('solvers = ["bb-pgd"]\nproblems = [' +
                   ",".join(f'"planted:count=1,seed={i}"' for i in range(11)) + "]\n")
    out = tmp_path / "r"
    assert main(["run", "--config", str(cfg), "--out", str(out), "--quiet"]) == 2
    assert "the sweep makes at least 11 runs (1 solver spec(s) x 11 problem spec(s)" in \
        _error(capsys)
    # instances count too: 3 specs of 4 instances and 1 solver are 12 runs
    assert main(["run", "--problem", "planted:count=4,seed=[0,1,2]", "--solver", "bb-pgd",
                 "--out", str(out), "--quiet"]) == 2
    assert "about 12 runs (12 instance(s) x 1 solver spec(s) x 1 repeat(s))" in _error(capsys)
    assert not out.exists()


def test_planning_memory_and_time_are_refused(tmp_path, monkeypatch, capsys):
    out = tmp_path / "r"
    argv = ["run", "--problem", "planted:count=2,seed=[0,1]", "--problem", "tiny",
            "--solver", "bb-pgd", "--out", str(out), "--quiet"]
    monkeypatch.setattr(guards, "TIME_LIMIT_S", 1e-6)
    assert main(argv) == 2
    err = _error(capsys)
    assert "take about" in err or "planning the sweep takes about" in err
    monkeypatch.setattr(guards, "TIME_LIMIT_S", 1e9)
    from lcpbench.run import sweep as sweep_mod
    monkeypatch.setattr(sweep_mod, "PLAN_BYTES_PER_RUN", 1e15)
    assert main(argv) == 2
    assert "planning the sweep holds about" in _error(capsys)
    assert not out.exists()


def test_run_force_lifts_the_dense_limit_inside_the_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(guards, "DENSE_LIMIT_BYTES", 8.0)        # any dense A is too large
    monkeypatch.delenv(guards.FORCE_ENV, raising=False)
    out = tmp_path / "r"
    argv = ["run", "--problem", "spd-cond:count=2,n=6", "--solver", "lemke", "--out",
            str(out), "--quiet", "--no-report"]
    assert main(argv) == 2
    assert "lemke needs A as a dense matrix: n = 6" in _error(capsys)
    assert not out.exists()
    assert main(argv + ["--force"]) == 0
    rows = pd.read_csv(out / "results.csv")
    assert len(rows) == 2 and set(rows["status"]) == {"converged"}
    assert guards.FORCE_ENV not in os.environ                  # restored after the sweep


def test_force_passes_a_huge_sweep_without_a_second_pass_over_its_specs(monkeypatch):
    from lcpbench.run import sweep as sweep_mod

    def no_expansion(self):
        raise AssertionError("the specs were expanded")

    monkeypatch.setattr(sweep_mod.Sweep, "problem_specs", no_expansion)
    big = sweep_mod.Sweep(solvers=["bb-pgd", "mono-pqn"], problems=["tiny"], repeat=10**6)
    with pytest.raises(guards.TooLarge, match="at least 2,000,000 runs"):
        sweep_mod.estimate_sweep(big)
    assert sweep_mod.estimate_sweep(big, force=True).runs == 2 * 10**6
