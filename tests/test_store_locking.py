"""The run store under a live writer: readers take no liberties with its files.

A reader (``lcpbench report``, a second ``run`` that is refused) must leave a runner's
half-written line alone; repairs happen only under the exclusive lock; a last line without
its newline but with a valid checksum is kept; whatever is removed is set aside.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from lcpbench.cli import main
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import HISTORY_STORE_COLUMNS, RunLock, RunStore, StoreLocked
from lcpbench.run.sweep import Sweep

SWEEP = ["--solver", "bb-pgd", "--problem", "fathi:sizes=[4,6]"]


def _store(folder: Path) -> Path:
    execute(plan(Sweep(solvers=["bb-pgd"], problems=["fathi:sizes=[4,6]"])), RunStore(folder),
            quiet=True)
    return folder


def _late_row(folder: Path, scratch: Path) -> tuple[bytes, bytes]:
    """The bytes one more run appends to results.csv and history.csv (a run id of its own)."""
    shutil.copytree(folder, scratch)
    store = RunStore(scratch)
    row = store.results().iloc[0].drop("row_crc").to_dict()
    hist = store.history()
    hist = hist[hist["run_id"] == row["run_id"]].drop(columns="run_id")
    before = [(scratch / f).read_bytes() for f in ("results.csv", "history.csv")]
    store.append({**row, "run_id": "late-run"}, hist)
    after = [(scratch / f).read_bytes() for f in ("results.csv", "history.csv")]
    return after[0][len(before[0]):], after[1][len(before[1]):]


WRITER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from lcpbench.run.store import RunStore
    out, parts = Path(sys.argv[1]), Path(sys.argv[2])
    row, hist = (parts / "row").read_bytes(), (parts / "hist").read_bytes()

    def append(name, data):
        with open(out / name, "ab") as fh:
            fh.write(data)

    def hold(flag):
        (parts / flag).touch()
        while not (parts / flag.replace("ready", "release")).exists():
            time.sleep(0.02)

    with RunStore(out).lock():
        # the runner is inside its append: half of the history line, then wait
        append("history.csv", hist[: len(hist) // 2])
        hold("ready")
        append("history.csv", hist[len(hist) // 2:])
        append("results.csv", row[: len(row) // 2])
        hold("ready2")
        append("results.csv", row[len(row) // 2:])
""")


def _wait(path: Path, proc: subprocess.Popen) -> None:
    t0 = time.monotonic()
    while not path.exists():
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() - t0 < 60, "the writer did not get there"
        time.sleep(0.02)


def _files(out: Path) -> dict[str, bytes]:
    return {f: (out / f).read_bytes() for f in ("results.csv", "history.csv")}


REFUSED_RUN = ["run", *SWEEP, "--no-report"]
REFUSED_SIMULATE = ["simulate", "--scene", "lattice:m=2,model=rpy", "--solver", "bb-pgd",
                    "--steps", "1"]


def _readers_leave_the_files_alone(out: Path, rows: int, hist_rows: int, capsys,
                                   commands: list[list[str]]) -> None:
    """Open the store as readers do while the writer is mid-line (the store's reader, then
    ``commands``: the report, or a second run or simulate, which are refused); nothing
    changes."""
    snapshot = _files(out)
    store = RunStore(out)
    assert len(store.results()) == rows and len(store.history()) == hist_rows
    assert store.corrupt == []
    for args in commands:
        if args[0] == "report":
            assert main(["report", str(out), "--quiet"]) == 0
            continue
        assert main([*args, "--out", str(out), "--quiet"]) == 2
        assert "being written by another lcpbench run" in capsys.readouterr().err
    assert _files(out) == snapshot                          # the half line survives, byte for byte
    assert not list(out.glob("*.corrupt"))


def test_readers_never_cut_the_line_a_live_runner_is_writing(tmp_path, capsys):
    out = _store(tmp_path / "store")
    parts = tmp_path / "parts"
    parts.mkdir()
    row, hist = _late_row(out, tmp_path / "scratch")
    (parts / "row").write_bytes(row)
    (parts / "hist").write_bytes(hist)
    rows, hist_rows = len(RunStore(out).results()), len(RunStore(out).history())
    writer = subprocess.Popen([sys.executable, "-c", WRITER, str(out), str(parts)],
                              stderr=subprocess.PIPE)
    try:
        _wait(parts / "ready", writer)                       # half a history line on disk
        _readers_leave_the_files_alone(out, rows, hist_rows, capsys,
                                       [["report"], REFUSED_SIMULATE])
        (parts / "release").touch()
        _wait(parts / "ready2", writer)                      # half a result line on disk
        _readers_leave_the_files_alone(out, rows, hist_rows, capsys, [["report"], REFUSED_RUN])
        (parts / "release2").touch()
        assert writer.wait(timeout=60) == 0
    finally:
        if writer.poll() is None:
            writer.kill()
    store = RunStore(out)                                    # the writer is gone: all whole
    assert store.corrupt == []
    res = store.results()
    assert len(res) == rows + 1 and "late-run" in set(res["run_id"])
    assert (store.history()["run_id"] == "late-run").sum() == hist.count(b"\n")


def test_a_last_row_without_newline_but_valid_checksum_is_kept(tmp_path):
    out = _store(tmp_path)
    results = out / "results.csv"
    text = results.read_text()
    results.write_text(text.rstrip("\n"))                   # saved without the final newline
    store = RunStore(out)
    assert store.corrupt == []
    assert len(store.results()) == text.count("\n") - 1
    assert results.read_text() == text                      # repaired: the newline is back
    assert not (out / "results.csv.corrupt").exists()


def test_a_cut_last_row_is_set_aside_with_its_file_and_line(tmp_path):
    out = _store(tmp_path)
    results = out / "results.csv"
    lines = results.read_text().split("\n")[:-1]
    cut = lines[-1][:-12]                                    # cut inside the checksum
    results.write_text("\n".join(lines[:-1] + [cut]))
    store = RunStore(out)
    assert [(path, line) for path, line, _ in store.corrupt] == [(str(results), len(lines))]
    assert "no newline" in store.corrupt[0][2]
    assert (out / "results.csv.corrupt").read_text() == cut + "\n"
    assert len(store.results()) == len(lines) - 2


def test_the_last_history_line_without_newline(tmp_path):
    out = _store(tmp_path)
    history = out / "history.csv"
    text = history.read_text()
    history.write_text(text.rstrip("\n"))                   # its run has a result row: kept
    store = RunStore(out)
    assert store.corrupt == [] and history.read_text() == text
    orphan = text.split("\n")[-2].split(",", 1)[1]
    history.write_text(text + "never-finished," + orphan[: len(orphan) // 2])
    store = RunStore(out)                                    # a run without result row: aside
    assert [(path, line) for path, line, _ in store.corrupt] == \
        [(str(history), text.count("\n") + 1)]
    assert (out / "history.csv.corrupt").read_text().startswith("never-finished,")
    assert history.read_text() == text


def test_an_append_after_a_cut_line_never_merges_with_it(tmp_path):
    out = _store(tmp_path)
    store = RunStore(out)
    row = store.results().iloc[0].drop("row_crc").to_dict()
    results = out / "results.csv"
    whole = results.read_text()
    with open(results, "a") as fh:
        fh.write(whole.split("\n")[1][:30])                  # a cut line the store has not seen
    store.append({**row, "run_id": "after-the-cut"})
    reopened = RunStore(out)
    assert [line for _, line, _ in reopened.corrupt] == [whole.count("\n") + 1]
    assert "after-the-cut" in set(reopened.results()["run_id"])


def test_a_runner_waits_for_a_readers_repair_but_not_for_a_runner(tmp_path):
    lock = tmp_path / ".lock"
    got: list = []

    def runner() -> None:
        with RunLock(lock):
            got.append(time.monotonic())

    with RunLock(lock, repair=True):
        t = threading.Thread(target=runner)
        t.start()
        time.sleep(0.3)
        assert got == []                                     # still waiting, not refused
        released = time.monotonic()
    t.join(timeout=10)
    assert got and got[0] >= released
    with RunLock(lock):
        with pytest.raises(StoreLocked, match=r"another lcpbench run \(pid \d+\)"):
            RunLock(lock).__enter__()
        with pytest.raises(StoreLocked):
            RunLock(lock, repair=True).__enter__()


def test_compact_history_refuses_while_a_runner_holds_the_lock(tmp_path):
    out = _store(tmp_path)
    history = (out / "history.csv").read_bytes()
    with RunStore(out).lock():
        with pytest.raises(StoreLocked):
            RunStore(out).compact_history()
    assert (out / "history.csv").read_bytes() == history
    assert isinstance(RunStore(out).history(), pd.DataFrame)


def test_history_lines_are_checked_by_their_fields_quotes_included(tmp_path):
    out = _store(tmp_path)
    history = out / "history.csv"
    lines = history.read_text().split("\n")[:-1]
    run_id, rest = lines[1].split(",", 1)
    quoted = f'"{run_id}",{rest}'                             # same fields, through the parser
    short = lines[2].rsplit(",", 2)[0]                        # two fields missing
    history.write_text("\n".join([lines[0], quoted, short] + lines[3:]) + "\n")
    store = RunStore(out)
    assert [(path, line) for path, line, _ in store.corrupt] == [(str(history), 3)]
    assert f"not {len(HISTORY_STORE_COLUMNS)} fields" in store.corrupt[0][2]
    assert (out / "history.csv.corrupt").read_text() == short + "\n"
    assert history.read_text().split("\n")[1] == quoted
