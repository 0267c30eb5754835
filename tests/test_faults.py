"""Sweeps that survive faults, on every executor (issue: Dask and fault tolerance).

kill -9 of the runner then resume; dying workers (exit, SIGKILL, segfault); per-run
timeouts on local, process and Dask executors; a second runner on the same folder;
atomic writes; the same rows from every executor.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import misbehave_plugin
import pandas as pd
import pytest

from lcpbench.cli import main
from lcpbench.run import executors
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore, atomic_write
from lcpbench.run.sweep import Sweep

PLUGIN = str(Path(misbehave_plugin.__file__).resolve())
TIMING = ["time_s", "mvp_time_s", "started", "finished", "info", "message", "row_crc"]


def _rows(path: Path) -> pd.DataFrame:
    return pd.read_csv(path / "results.csv").sort_values("run_id").reset_index(drop=True)


def test_second_runner_is_refused_and_nothing_is_written(tmp_path, capsys):
    out = tmp_path / "store"
    args = ["run", "--solver", "bb-pgd", "--problem", "fathi:sizes=[4]", "--out", str(out),
            "--quiet", "--no-report"]
    with RunStore(out).lock():
        assert main(args) == 2
        err = capsys.readouterr().err
        assert "being written by another lcpbench run" in err and str(os.getpid()) in err
        assert not (out / "results.csv").exists()
    assert main(args) == 0                      # the lock is gone with its holder
    assert len(_rows(out)) == 1


def _wait_for(predicate, seconds=120.0):
    t0 = time.monotonic()
    while not predicate():
        assert time.monotonic() - t0 < seconds, "the runner did not get there"
        time.sleep(0.02)


def test_second_runner_process_is_refused_while_first_runs(tmp_path):
    out = tmp_path / "store"
    release = tmp_path / "release"
    env = {**os.environ, "LCPBENCH_PLUGINS": PLUGIN, "LCPBENCH_TEST_RELEASE": str(release)}
    cmd = [sys.executable, "-m", "lcpbench.cli", "run", "--solver", "test-misbehave:mode=wait",
           "--problem", "fathi:sizes=[4,6,8,10]", "--out", str(out), "--quiet", "--no-report"]
    first = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE)
    try:
        _wait_for(lambda: (out / "meta.json").exists())   # holds the lock, runs blocked
        second = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)
        assert second.returncode == 2
        assert "being written by another lcpbench run" in second.stderr
    finally:
        release.touch()
        first.wait(timeout=120)
    assert first.returncode == 0
    rows = _rows(out)
    assert len(rows) == 4 and rows["run_id"].is_unique


def test_kill_9_mid_sweep_then_resume_gives_every_row_exactly_once(tmp_path):
    out = tmp_path / "store"
    release = tmp_path / "release"
    env = {**os.environ, "LCPBENCH_PLUGINS": PLUGIN, "LCPBENCH_TEST_RELEASE": str(release)}
    # bb-pgd's 12 runs come first and finish; the waiting runs after them cannot finish
    # before the kill, so the kill always lands mid-sweep
    cmd = [sys.executable, "-m", "lcpbench.cli", "run", "--solver", "bb-pgd", "--solver",
           "test-misbehave:mode=[wait,slow],seconds=0.05",
           "--problem", "planted:count=4", "--repeat", "3", "--jobs", "2",
           "--out", str(out), "--quiet", "--no-report"]
    planned = 4 * 3 + 2 * 4 * 3
    proc = subprocess.Popen(cmd, env=env, start_new_session=True)
    results = out / "results.csv"
    _wait_for(lambda: results.exists() and results.read_text().count("\n") > 6)
    os.killpg(proc.pid, signal.SIGKILL)          # the runner and its forked children
    proc.wait()
    partial = results.read_text().count("\n") - 1
    assert 0 < partial < planned
    release.touch()
    subprocess.run(cmd, env=env, check=True, timeout=300)
    rows = _rows(out)
    assert len(rows) == planned and rows["run_id"].is_unique
    assert rows["status"].notna().all()
    hist = RunStore(out).history()
    assert set(hist["run_id"]) <= set(rows["run_id"])


def test_dying_workers_become_failed_rows(tmp_path, monkeypatch):
    monkeypatch.setattr(executors, "GRACE_S", 0.5)
    sweep = Sweep(solvers=["test-misbehave:mode=[die,kill,segv]", "bb-pgd"],
                  problems=["fathi:sizes=[4]"], timeout=20.0)
    execute(plan(sweep), RunStore(tmp_path), executor="process", jobs=2, timeout=20.0,
            quiet=True)
    res = pd.read_csv(tmp_path / "results.csv").set_index("solver")
    assert res.loc["test-misbehave:mode=die", "status"] == "failed"
    assert "exit code 3" in res.loc["test-misbehave:mode=die", "message"]
    assert "signal 9" in res.loc["test-misbehave:mode=kill", "message"]
    assert "signal 11" in res.loc["test-misbehave:mode=segv", "message"]
    assert res.loc["test-misbehave:mode=kill", "status"] == "failed"
    assert bool(res.loc["bb-pgd", "solved"])


@pytest.mark.parametrize("executor", ["local", "process"])
def test_timeouts_hold_on_local_and_process(tmp_path, monkeypatch, executor):
    monkeypatch.setattr(executors, "GRACE_S", 0.5)
    sweep = Sweep(solvers=["test-misbehave:mode=sleep", "bb-pgd"],
                  problems=["fathi:sizes=[4]"], timeout=1.0)
    t0 = time.monotonic()
    execute(plan(sweep), RunStore(tmp_path), executor=executor, timeout=1.0, quiet=True)
    assert time.monotonic() - t0 < 30                       # the 60 s sleep was killed
    res = pd.read_csv(tmp_path / "results.csv").set_index("solver")
    assert res.loc["test-misbehave:mode=sleep", "status"] == "timeout"
    assert bool(res.loc["bb-pgd", "solved"])


@pytest.mark.slow       # starts a local dask cluster, about 18 s
def test_dask_local_cluster_faults_timeouts_and_same_rows(tmp_path, monkeypatch):
    monkeypatch.setenv("LCPBENCH_PLUGINS", PLUGIN)
    faulty = Sweep(solvers=["test-misbehave:mode=[sleep,raise,die,kill,segv]", "bb-pgd"],
                   problems=["fathi:sizes=[4]"], timeout=1.0)
    execute(plan(faulty), RunStore(tmp_path / "faults"), executor="dask", jobs=2, timeout=1.0,
            quiet=True)
    res = pd.read_csv(tmp_path / "faults" / "results.csv").set_index("solver")
    assert res.loc["test-misbehave:mode=sleep", "status"] == "timeout"
    for mode in ("raise", "die", "kill", "segv"):
        assert res.loc[f"test-misbehave:mode={mode}", "status"] == "failed", mode
    assert bool(res.loc["bb-pgd", "solved"])

    same = Sweep(solvers=["bb-pgd", "mono-pqn", "zero-sr1"], problems=["planted:count=2"])
    frames = {}
    for kind, jobs in (("local", 1), ("process", 2), ("dask", 2)):
        execute(plan(same), RunStore(tmp_path / kind), executor=kind, jobs=jobs, quiet=True)
        frames[kind] = _rows(tmp_path / kind).drop(columns=TIMING)
    pd.testing.assert_frame_equal(frames["local"], frames["process"])
    pd.testing.assert_frame_equal(frames["local"], frames["dask"])


def test_atomic_write_keeps_the_old_file_when_interrupted(tmp_path, monkeypatch):
    target = tmp_path / "meta.json"
    atomic_write(target, '{"old": true}')

    def boom(*a, **k):
        raise OSError("disk went away")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError):
        atomic_write(target, '{"new": true}')
    assert target.read_text() == '{"old": true}'
