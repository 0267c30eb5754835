"""The command line's bad inputs: one line, exit 2, nothing written."""

import os
import subprocess
import sys

import pytest

from lcpbench.cli import main


def _lcpbench(*args, env=None, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lcpbench.cli", *args], capture_output=True,
                          text=True, env={**os.environ, **(env or {})}, cwd=cwd, timeout=300)


def test_list_into_a_closed_pipe_ends_quietly_with_exit_0():
    cmd = f"{sys.executable} -m lcpbench.cli list | head -n 1"
    out = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, (out.returncode, out.stderr)
    assert "Broken pipe" not in out.stderr and "Traceback" not in out.stderr
    assert out.stderr.strip() == ""


def test_missing_plugin_file_is_one_line_exit_2(tmp_path):
    out = _lcpbench("list", env={"LCPBENCH_PLUGINS": "nosuch.py"}, cwd=tmp_path)
    assert out.returncode == 2
    assert out.stderr.strip() == ("lcpbench list: error: $LCPBENCH_PLUGINS names 'nosuch.py', "
                                  "which is not a file; fix the path or remove it from "
                                  "$LCPBENCH_PLUGINS")


def test_plugin_that_raises_is_one_line_exit_2(tmp_path):
    (tmp_path / "broken_plugin.py").write_text("raise ValueError('half written')\n")
    out = _lcpbench("solve", "--problem", "tiny", env={"LCPBENCH_PLUGINS": "broken_plugin.py"},
                    cwd=tmp_path)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.strip() == ("lcpbench solve: error: plugin 'broken_plugin.py' named in "
                                  "$LCPBENCH_PLUGINS failed to load: ValueError: half written")


@pytest.mark.parametrize("command", ["run", "simulate"])
def test_out_at_a_folder_of_the_users_files_writes_nothing(command, tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("mine\n")
    argv = (["run", "--problem", "tiny", "--solver", "bb-pgd"] if command == "run"
            else ["simulate", "--steps", "1"]) + ["--out", str(mine), "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"lcpbench {command}: error: --out {mine} is a folder of other files (e.g. "
                   f"thesis.tex), not a run store; give a new or empty folder, e.g. "
                   f"{mine / 'lcpbench-run'}")
    assert [p.name for p in mine.iterdir()] == ["thesis.tex"]


def test_out_at_an_empty_folder_or_a_run_store_is_used(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    argv = ["run", "--problem", "tiny", "--solver", "bb-pgd", "--quiet", "--no-report", "--out",
            str(empty)]
    assert main(argv) == 0
    assert main(argv) == 0                                   # the same store resumes
    assert (empty / "results.csv").exists()


def test_check_refuses_a_reference_solver_and_leaves_the_baselines_alone(tmp_path, capsys):
    base = tmp_path / "baselines.json"
    assert main(["check", "--solver", "clarabel", "--baseline", str(base), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lcpbench check: error: --solver clarabel: clarabel is a reference QP "
                          "solver that needs the dense A")
    assert not base.exists()


def test_a_folder_given_as_a_stored_set_says_so(tmp_path, capsys):
    folder = tmp_path / "sets.h5"
    folder.mkdir()
    for argv in (["solve", "--problem", f"stored:path={folder}"],
                 ["solve", "--problem", f"synthetic-low:path={folder}"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err == (f"lcpbench solve: error: {folder} is a folder, not a stored set; give "
                       f"the set's .h5 file, e.g. {folder / 'NAME.h5'}")
    assert main(["check", "--set", str(folder)]) == 2
    assert "a folder, not a stored set" in capsys.readouterr().err


def test_plugin_that_exits_at_import_is_one_line_exit_2(tmp_path):
    (tmp_path / "exiting_plugin.py").write_text("import sys\nsys.exit(0)\n")
    out = _lcpbench("run", "--problem", "tiny", "--solver", "bb-pgd", "--out", "r",
                    env={"LCPBENCH_PLUGINS": "exiting_plugin.py"}, cwd=tmp_path)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.strip() == ("lcpbench run: error: plugin 'exiting_plugin.py' named in "
                                  "$LCPBENCH_PLUGINS called sys.exit(0) while it was imported; "
                                  "a plugin module must only register its solvers, problems "
                                  "and scenes")
    assert not (tmp_path / "r" / "results.csv").exists()


def test_a_solver_that_exits_is_a_failed_row_and_the_sweep_goes_on(tmp_path):
    """sys.exit(0) inside a solve, in the runner's own process (no --timeout)."""
    import pandas as pd

    plugin = os.path.join(os.path.dirname(__file__), "misbehave_plugin.py")
    out = _lcpbench("run", "--problem", "tiny", "--solver", "test-misbehave:mode=exit",
                    "--solver", "bb-pgd", "--out", "r", "--quiet",
                    env={"LCPBENCH_PLUGINS": plugin}, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    rows = pd.read_csv(tmp_path / "r" / "results.csv")
    exits = rows[rows["solver"] == "test-misbehave:mode=exit"]
    assert len(exits) == 7 and len(rows) == 14
    called = exits[exits["n"] > 0]              # n = 0 is solved without calling the solver
    assert len(called) >= 5 and set(called["status"]) == {"failed"}
    assert called["message"].str.contains("called sys.exit\\(0\\)").all()
    assert (rows[rows["solver"] == "bb-pgd"]["status"] == "converged").all()
    assert (tmp_path / "r" / "report.html").exists()


def test_simulate_exits_1_when_every_simulation_stopped_at_step_0(tmp_path):
    plugin = os.path.join(os.path.dirname(__file__), "misbehave_plugin.py")
    args = ("simulate", "--scene", "lattice:m=2,model=rpy", "--steps", "3", "--quiet")
    out = _lcpbench(*args, "--solver", "test-misbehave:mode=nan", "--out", "s1",
                    env={"LCPBENCH_PLUGINS": plugin}, cwd=tmp_path)
    assert out.returncode == 1 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1] == (
        "lcpbench simulate: error: every simulation stopped at step 0 (simulation stopped: "
        "step 0: the contact forces are not finite; the simulation cannot continue from a "
        "diverged solve); nothing was simulated")
    both = _lcpbench(*args, "--solver", "test-misbehave:mode=nan", "--solver", "bb-pgd",
                     "--out", "s2", env={"LCPBENCH_PLUGINS": plugin}, cwd=tmp_path)
    assert both.returncode == 0, both.stderr         # one simulation went on: not a failure
