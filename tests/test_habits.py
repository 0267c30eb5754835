"""The package habits: `python -m lcpbench`, LICENSE, CITATION.cff, CHANGELOG, py.typed, and the
Python 3.10 path of the sweep reader."""

from __future__ import annotations

import importlib.resources
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import lcpbench
from lcpbench.run.sweep import load_config

if sys.version_info >= (3, 11):
    import tomllib
else:   # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def _script() -> str:
    """The installed ``lcpbench`` console script of this interpreter's environment."""
    beside = Path(sys.executable).with_name("lcpbench")
    found = str(beside) if beside.exists() else shutil.which("lcpbench")
    assert found, "the lcpbench console script is not installed (pip install -e .)"
    return found


@pytest.mark.parametrize("args", [["--version"], ["solve", "--problem", "no-such-family"]],
                         ids=["version", "bad-problem"])
def test_python_m_lcpbench_behaves_like_the_script(args, tmp_path):
    def run(cmd):
        p = subprocess.run(cmd + args, capture_output=True, text=True, cwd=tmp_path, timeout=120)
        return p.returncode, p.stdout, p.stderr

    module = run([sys.executable, "-m", "lcpbench"])
    script = run([_script()])
    assert module == script
    if args == ["--version"]:
        assert module[0] == 0 and lcpbench.__version__ in module[1]
    else:                                   # bad input: one line naming it, exit 2
        assert module[0] == 2
        assert module[2].count("\n") == 1 and "no-such-family" in module[2]
    assert not any(tmp_path.iterdir())      # nothing written


def test_license_is_the_bsd_3_clause_text_pyproject_declares():
    assert PYPROJECT["project"]["license"] == "BSD-3-Clause"
    assert PYPROJECT["project"]["license-files"] == ["LICENSE"]
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("BSD 3-Clause License")
    for clause in ("Redistributions of source code must retain",
                   "Redistributions in binary form must reproduce",
                   "Neither the name of the copyright holder"):
        assert clause in text


def test_citation_names_this_version_and_the_method_paper():
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert cff["cff-version"] == "1.2.0" and cff["type"] == "software"
    assert str(cff["version"]) == lcpbench.__version__ == PYPROJECT["project"]["version"]
    assert cff["license"] == PYPROJECT["project"]["license"]
    assert cff["authors"] and cff["message"]
    (paper,) = [r for r in cff["references"] if "Proximal Quasi-Newton" in r["title"]]
    assert paper["title"].startswith("A Bifidelity Proximal Quasi-Newton Method")
    assert [a["family-names"] for a in paper["authors"]] == ["Rummel", "Jensen", "Becker",
                                                              "Corona"]


def test_changelog_has_a_section_for_this_version():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert f"## [{lcpbench.__version__}]" in text
    assert "## [Unreleased]" in text


def test_py_typed_marker_ships_with_the_package():
    assert importlib.resources.files("lcpbench").joinpath("py.typed").is_file()
    assert "py.typed" in PYPROJECT["tool"]["setuptools"]["package-data"]["lcpbench"]


def test_sweep_config_reads_on_python_3_10_through_tomli(monkeypatch):
    # Python 3.10 has no tomllib; the sweep reader must use the tomli package there.
    monkeypatch.setitem(sys.modules, "tomllib", None)       # `import tomllib` now fails
    monkeypatch.setitem(sys.modules, "tomli", tomllib)      # what `pip install tomli` gives
    monkeypatch.setattr(sys, "version_info", (3, 10, 14, "final", 0))
    cfg = load_config(str(ROOT / "sweeps" / "default.toml"))
    assert cfg["solvers"] and cfg["problems"]
