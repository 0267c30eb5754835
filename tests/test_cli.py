"""The ``lcpbench`` command: list, solve, and usage errors (one line, exit 2)."""

import json
import re
import shlex
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import lcpbench
from lcpbench.cli import main
from lcpbench.core.specs import describe_params


def test_list_json_has_every_solver_and_problem_with_parameters(capsys):
    assert main(["list", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    names = {e["name"] for e in data}
    # test doubles registered by other test modules in this process are listed=False
    registered = {n for n, i in lcpbench.list_solvers().items() if i.listed}
    assert registered <= names and set(lcpbench.list_problems()) <= names
    bb = next(e for e in data if e["name"] == "bb-pgd")
    assert {p["name"] for p in bb["params"]} >= {"variant", "safeguard", "memory"}
    assert all(p["doc"] for p in bb["params"])          # every parameter documented
    defaults = [e["name"] for e in data if e["kind"] == "problem" and e["default"]]
    assert defaults


def test_list_is_brief_by_default_and_full_on_request(capsys):
    assert main(["list", "solvers"]) == 0
    out = capsys.readouterr().out
    assert "mono-pqn" in out and "random-spd" not in out
    assert "memory: int" not in out                     # no parameter lines
    assert main(["list", "problems"]) == 0
    assert "random-spd" in capsys.readouterr().out
    assert main(["list"]) == 0
    brief = capsys.readouterr().out.splitlines()
    assert len(brief) < 80
    assert "Every parameter: lcpbench list --full [solvers|problems|scenes]" in brief
    assert main(["list", "--full"]) == 0
    full = capsys.readouterr().out
    assert len(full.splitlines()) > 2 * len(brief)
    # every parameter of every listed solver, with its type and default
    for name, info in lcpbench.list_solvers().items():
        if info.listed:
            for prm, typ, _, _ in describe_params(info.params):
                assert f"      {prm}: {typ} = " in full, (name, prm)
    assert main(["list", "--brief"]) == 0              # still accepted: the default
    assert capsys.readouterr().out.splitlines() == brief


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


# ------------------------------------------------------------------ docs/errors.md, CLI table
DOC = Path(__file__).resolve().parents[1] / "docs" / "errors.md"


def _doc_rows(prefix: str) -> list[tuple[str, str, str]]:
    """``(input, outcome, message)`` of the docs/errors.md table rows whose input starts so."""
    rows = []
    for line in DOC.read_text().splitlines():
        if not line.startswith("| `" + prefix):
            continue
        cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        rows.append((cells[0].strip("`"), cells[1].strip("`"), cells[2]))
    return rows


def _matches(documented: str, actual: str) -> bool:
    if documented.endswith("..."):
        return actual.startswith(documented[:-3])
    return actual == documented


@pytest.fixture(scope="module")
def error_folder(tmp_path_factory):
    """The folder the documented commands run in: a file, bad files, a run store."""
    from lcpbench.problems.stored import shipped_sets

    root = tmp_path_factory.mktemp("errors")
    (root / "afile").write_text("not a folder\n")
    (root / "bad.toml").write_text("[[solver]\nname = 'bb-pgd'\n")
    data = shipped_sets()["lattice-bim-m3"].read_bytes()
    (root / "trunc.h5").write_bytes(data[:len(data) // 3])
    flipped = bytearray(data)                   # one bit of the root's format attribute
    flipped[data.index(b"lcpbench.set", 512)] ^= 1
    (root / "flipped.h5").write_bytes(bytes(flipped))
    (root / "mine").mkdir()
    (root / "mine" / "notes.txt").write_text("the user's own file\n")
    specs = ",".join(f'"planted:count=1,seed={i}"' for i in range(150_000))
    (root / "many.toml").write_text(f'solvers = ["bb-pgd", "mono-pqn"]\nproblems = [{specs}]\n')
    (root / "empty.toml").write_text("")
    (root / "table.csv").write_text("a,b\n1,2\n")
    (root / "foreign").mkdir()
    (root / "foreign" / "results.csv").write_text("a,b\n1,2\n")
    code = main(["run", "--problem", "tiny", "--solver", "bb-pgd", "--out", str(root / "store"),
                 "--quiet", "--no-report"])
    assert code == 0
    shutil.copytree(root / "store", root / "swapped")
    head, rest = (root / "swapped" / "results.csv").read_text().split("\n", 1)
    columns = head.split(",")
    i, j = columns.index("status"), columns.index("message")
    columns[i], columns[j] = columns[j], columns[i]
    (root / "swapped" / "results.csv").write_text(",".join(columns) + "\n" + rest)
    return root


def test_errors_doc_lists_at_least_25_bad_inputs():
    assert len(_doc_rows("lcpbench ")) + len(_doc_rows("lcpbench.")) + \
        len(_doc_rows("LCP(")) + len(_doc_rows("Operator(")) >= 25


@pytest.mark.parametrize("command, code, message", _doc_rows("lcpbench "))
def test_documented_cli_error(command, code, message, error_folder, monkeypatch, capsys):
    monkeypatch.chdir(error_folder)
    argv = shlex.split(command)[1:]
    outs = [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--out"]
    fresh = [o for o in outs if not Path(o).exists()]
    assert main(argv) == int(code)
    err = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in err if ": error:" in line]
    assert len(errors) == 1 and "Traceback" not in "\n".join(err), err
    assert _matches(message, errors[0]), (message, errors[0])
    for o in fresh:                               # nothing left behind in --out
        assert not Path(o).exists(), o
    if "mine" in argv:                            # nothing written beside the user's files
        assert sorted(p.name for p in (error_folder / "mine").iterdir()) == ["notes.txt"]


def test_dask_executor_without_dask_is_refused_up_front(tmp_path, monkeypatch, capsys):
    import importlib.util

    import lcpbench.cli.run as run_mod

    real = importlib.util.find_spec
    monkeypatch.setattr(run_mod.importlib.util, "find_spec",
                        lambda name, *a: None if name == "distributed" else real(name, *a))
    out = tmp_path / "r"
    assert main(["run", "--problem", "tiny", "--executor", "dask", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ('lcpbench run: error: --executor dask needs dask.distributed, which is not '
                   'installed: pip install -e ".[dask]" (or use --executor process)')
    assert not out.exists()


def test_list_shows_whole_parameter_docs_in_plain_words(capsys):
    assert main(["list", "--full"]) == 0
    out = capsys.readouterr().out
    # the second and later lines of a parameter's docstring are shown, not only the first
    assert "Dai & Fletcher" in " ".join(out.split())
    # no LaTeX labels of the paper such as "eq. pqnSubproblem" or "Proposition prop-nnProx"
    assert not re.search(r"\b(eq\.|lemma|[Aa]lgorithm|Proposition) [a-z]+[A-Z-]", out), \
        re.search(r".{40}\b(eq\.|lemma|[Aa]lgorithm|Proposition) [a-z]+[A-Z-].{20}", out)


# ------------------------------------------------------------------ README
README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_commands_and_pointers():
    text = README.read_text()
    assert 'python -m pytest -q -n auto -m "not browser and not slow"' in text
    assert "../shared" not in text.split("## Layout")[0]
    assert not re.search(r"(/work/|/home/|/root/)", text)


def test_readme_snippet_gives_the_same_emvps_on_every_run():
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    rng = np.random.default_rng(3)
    M = rng.standard_normal((40, 40))
    A = M @ M.T / 40 + np.eye(40)
    E = 1e-3 * rng.standard_normal((40, 40))
    env0 = {"A": A, "A_low": A + (E + E.T) / 2, "b": rng.standard_normal(40),
            "x_prev": None, "state": None}
    emvps = []
    for _ in range(3):
        env = dict(env0)
        with warnings.catch_warnings():
            warnings.simplefilter("error")          # declared costs: no wall-clock warning
            exec(code, env)
        res = env["res"]
        assert res.emvps == pytest.approx(res.mvps + 0.1 * res.lofi_mvps["coarse"])
        emvps.append(res.emvps)
    assert emvps[0] == emvps[1] == emvps[2]


def test_solve_warns_when_emvps_are_priced_by_the_clock():
    A = np.array([[2.0, 1.0], [1.0, 2.0]])
    b = np.array([-1.0, 1.0])
    with pytest.warns(UserWarning, match="wall time"):
        lcpbench.solve(A, b, solver="bi-pqn", low={"c": 1.01 * A})
    res = lcpbench.solve(lambda v: A @ v, b)                  # shape taken from b
    assert res.solved and res.mvps > 0
    res = lcpbench.solve(lambda v: A @ v, b, shape=(2, 2), solver="bi-pqn",
                         low={"c": lambda v: 1.01 * A @ v}, low_cost=0.25)
    assert res.emvps == pytest.approx(res.mvps + 0.25 * res.lofi_mvps["c"])


def test_readme_links_every_documentation_page():
    text = README.read_text()
    docs = README.parent / "docs"
    pages = sorted(p.relative_to(README.parent).as_posix()
                   for p in [*docs.glob("*.md"), *docs.glob("guide/*.md"),
                             *docs.glob("archive/*.md")] if p.name != "index.md")
    assert "docs/report.md" in pages and "docs/errors.md" in pages
    missing = [p for p in pages if f"]({p})" not in text]
    assert not missing, f"README does not link {missing}"
