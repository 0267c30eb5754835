"""No file of the repository names an internal work item: code, tests and docs say what the
code does, not which ticket asked for it.

Every tracked text file is scanned (``git ls-files``; without git, every file under the
checkout but the virtual environment and caches). The patterns are built from pieces so that
this file does not match itself.
"""

import os
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

_WORDS = "|".join(["issues?", "items?", "tickets?", "tasks?", "briefs?", "sessions?"])
REFERENCE = re.compile(
    r"(?i)\b(?:" + _WORDS + r")[ ]?#?\d+(?:\.\d+)?\b"       # a numbered work item
    + r"|\b(?:work|issue|item|task)-\d+\b"                    # a work-item label
    + r"|(?-i:\bbrief [A-Z]\b)"                               # a lettered brief
    + r"|(?:^|[\s(\[,;])" + "#" + r"\d{1,4}\b"                # a tracker number
)
SKIP_DIRS = {".git", ".venv", "venv", "__pycache__", ".pytest_cache", ".hypothesis",
             "build", "dist", "_build", "__cache__", "outputs"}


def _tracked_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                             check=True).stdout.decode()
        return [ROOT / f for f in out.split("\0") if f]
    except (OSError, subprocess.CalledProcessError):
        files = []
        for top, dirs, names in os.walk(ROOT):
            dirs[:] = [d for d in dirs if d not in SKIP_DIRS and not d.endswith(".egg-info")]
            files += [Path(top) / n for n in names]
        return files


def _text(path: Path):
    try:
        data = path.read_bytes()
    except OSError:             # listed by git but removed in the work tree
        return None
    if b"\0" in data[:8192]:    # binary: stored sets, images
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def references(text: str) -> list[str]:
    """The work-item references in ``text``."""
    return [m.group(0).strip() for m in REFERENCE.finditer(text)]


@pytest.mark.parametrize("text", [
    "see is" + "sue 40", "(It" + "em 3)", "Is" + "sues 27 and 28", "wo" + "rk-41",
    "fixed in " + "#" + "38", "(" + "#" + "12)", "bri" + "ef H items", "is" + "sue 31.10",
    "ta" + "sk 7", "tic" + "ket " + "#" + "9",
])
def test_the_pattern_finds_work_item_references(text):
    assert references(text), text


@pytest.mark.parametrize("text", [
    "color:#222;padding", "block work 0.191 -> 0.093", "step 3 of 200", "a brief listing",
    "items are kept", "issue a warning", "# 1. the first step", "x[#]", "p8f6r3e3",
])
def test_the_pattern_leaves_ordinary_text_alone(text):
    assert references(text) == [], text


def test_no_file_names_an_internal_work_item():
    found = []
    files = _tracked_files()
    assert len(files) > 100     # the scan saw the repository, not an empty folder
    for path in files:
        text = _text(path)
        if text is None:
            continue
        for i, line in enumerate(text.splitlines(), 1):
            found += [f"{path.relative_to(ROOT)}:{i}: {ref}" for ref in references(line)]
    assert not found, "work-item references (say what the code does instead):\n" + \
        "\n".join(found[:50])
