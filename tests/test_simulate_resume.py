"""`lcpbench simulate` resumes: killed or stopped, rerun, and every step is there exactly once."""

import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from lcpbench.cli import main

SCENE = "lattice:m=2,model=rpy"
SOLVERS = ["--solver", "bb-pgd", "--solver", "mono-pqn"]
STEPS = 120
KEYS = ["solver", "step"]
SAME = ["n", "emvps", "mvps", "max_overlap", "status"]


def _argv(out, steps=STEPS):
    return ["simulate", "--scene", SCENE, *SOLVERS, "--steps", str(steps), "--out", str(out),
            "--stop", "kkt", "--quiet"]


def _rows(out):
    return pd.read_csv(out / "results.csv")


def _start(out):
    return subprocess.Popen([sys.executable, "-m", "lcpbench.cli", *_argv(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_rows(out, proc, count, timeout=300):
    path = out / "results.csv"
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if path.exists() and sum(1 for _ in open(path)) - 1 >= count:
            return
        if proc.poll() is not None:
            pytest.fail(f"simulation ended before {count} rows: {proc.stderr.read()}")
        time.sleep(0.02)
    pytest.fail("no rows appeared")


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    out = tmp_path_factory.mktemp("straight")
    assert main(_argv(out)) == 0
    rows = _rows(out)
    assert len(rows) == 2 * STEPS
    return rows.set_index(KEYS).sort_index()


def _same_as_straight(rows, straight):
    got = rows.set_index(KEYS).sort_index()
    assert not got.index.duplicated().any(), "a step was written twice"
    assert list(got.index) == list(straight.index), "a step is missing"
    pd.testing.assert_frame_equal(got[SAME], straight[SAME], check_dtype=False)


def test_kill_9_mid_run_then_rerun_gives_every_step_once(tmp_path, straight):
    out = tmp_path / "sim"
    proc = _start(out)
    _wait_for_rows(out, proc, 5)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    before = len(_rows(out))
    assert before < 2 * STEPS                          # killed mid-run
    assert main(_argv(out)) == 0                       # the same command resumes
    _same_as_straight(_rows(out), straight)            # same trajectory, each step once


def test_row_lost_after_its_checkpoint_is_restored(tmp_path, straight):
    out = tmp_path / "sim"
    assert main(_argv(out, 4)) == 0
    lines = (out / "results.csv").read_text().splitlines(keepends=True)
    (out / "results.csv").write_text("".join(lines[:-1]))   # killed between checkpoint and row
    assert main(_argv(out, STEPS)) == 0                       # resumes and extends to STEPS
    _same_as_straight(_rows(out), straight)


def test_sigterm_stops_with_a_message_and_resumes(tmp_path, straight):
    out = tmp_path / "sim"
    proc = _start(out)
    _wait_for_rows(out, proc, 3)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "stopped by SIGTERM" in err and "run the same command again to resume" in err
    assert main(_argv(out)) == 0
    _same_as_straight(_rows(out), straight)


def test_other_settings_are_refused_before_any_step(tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(_argv(out, 3)) == 0
    size = os.path.getsize(out / "results.csv")
    assert main(["simulate", "--scene", SCENE, "--solver", "bb-pgd", "--steps", "5",
                 "--out", str(out), "--tol", "1e-6", "--quiet"]) == 2
    assert "under other settings" in capsys.readouterr().err
    assert os.path.getsize(out / "results.csv") == size
