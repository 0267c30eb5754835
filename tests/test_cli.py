"""The ``lcpbench`` command: list, solve, and usage errors (one line, exit 2)."""

import json
import subprocess
import sys

import pandas as pd
import pytest

import lcpbench
from lcpbench.cli import main


def test_list_json_has_every_solver_and_problem_with_parameters(capsys):
    assert main(["list", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    names = {e["name"] for e in data}
    # solvers registered by other test modules in this process are listed too, or hidden
    registered = {n for n in lcpbench.list_solvers() if not n.startswith("test-")}
    assert registered <= names and set(lcpbench.list_problems()) <= names
    bb = next(e for e in data if e["name"] == "bb-pgd")
    assert {p["name"] for p in bb["params"]} >= {"variant", "safeguard", "memory"}
    assert all(p["doc"] for p in bb["params"])          # every parameter documented
    defaults = [e["name"] for e in data if e["kind"] == "problem" and e["default"]]
    assert defaults


def test_list_text_and_brief(capsys):
    assert main(["list", "solvers", "--brief"]) == 0
    out = capsys.readouterr().out
    assert "mono-pqn" in out and "random-spd" not in out
    assert main(["list", "problems"]) == 0
    assert "random-spd" in capsys.readouterr().out


def test_solve_json_rows_are_verified(capsys):
    code = main(["solve", "--problem", "tiny", "--instance", "0", "--solver", "mono-pqn",
                 "--solver", "bb-pgd:variant=bb2", "--stop", "kkt", "--json"])
    assert code == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert {r["solver"] for r in rows} == {"mono-pqn", "bb-pgd:variant=bb2"}
    assert all(r["solved"] for r in rows)


def test_solve_table(capsys):
    assert main(["solve", "--problem", "tiny", "--solver", "mono-pqn"]) == 0
    out = capsys.readouterr().out
    assert "mono-pqn" in out and "emvps" in out and "verified_kkt_abs" in out


@pytest.mark.parametrize("argv, words", [
    (["solve", "--solver", "no-such"], ["unknown solver", "no-such"]),
    (["solve", "--solver", "bb-pgd:nonsense=1"], ["nonsense"]),
    (["solve", "--solver", "mono-pqn:memory=lots"], ["memory", "integer"]),
    (["solve", "--problem", "no-such"], ["unknown problem"]),
    (["solve", "--problem", "random-spd:count=0"], ["count"]),
    (["solve", "--problem", "tiny", "--instance", "999"], ["instance"]),
    (["solve", "--problem", "tiny", "--tol", "-1"], ["tol"]),
    (["run", "--config", "/nonexistent/sweep.toml"], ["sweep.toml"]),
    (["run", "--solver", "no-such", "--out", "{tmp}/r"], ["no-such"]),
    (["report", "{tmp}/missing"], ["missing"]),
])
def test_usage_errors_are_one_line_exit_2(argv, words, tmp_path, capsys):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err, err
    errors = [line for line in err.splitlines() if ": error:" in line]
    assert len(errors) == 1 and err.splitlines()[-1] == errors[0], err
    err = errors[0]
    assert err.startswith(f"lcpbench {argv[0]}: error:")
    for word in words:
        assert word in err, (word, err)


def test_bad_sweep_file_is_refused_and_nothing_is_written(tmp_path, capsys):
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[[solver]\nname = 'bb-pgd'\n")     # malformed TOML
    out = tmp_path / "r"
    assert main(["run", "--config", str(cfg), "--out", str(out), "--quiet"]) == 2
    assert "bad.toml" in capsys.readouterr().err
    assert not (out / "results.csv").exists()


def test_run_refuses_a_changed_configuration_and_keeps_rows(tmp_path, capsys):
    out = tmp_path / "r"
    base = ["run", "--problem", "tiny", "--solver", "bb-pgd", "--out", str(out), "--quiet"]
    assert main(base) == 0
    rows = pd.read_csv(out / "results.csv")
    assert main(base[:-1] + ["--tol", "1e-6", "--quiet"]) == 2
    assert "--force" in capsys.readouterr().err
    pd.testing.assert_frame_equal(pd.read_csv(out / "results.csv"), rows)


def test_console_script_and_version():
    out = subprocess.run([sys.executable, "-m", "lcpbench.cli", "--version"],
                         capture_output=True, text=True, check=True)
    assert lcpbench.__version__ in out.stdout
    bare = subprocess.run([sys.executable, "-m", "lcpbench.cli"], capture_output=True, text=True)
    assert bare.returncode == 2 and "COMMAND" in bare.stdout
