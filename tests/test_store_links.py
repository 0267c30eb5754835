"""A run store never writes through a symbolic link planted in its folder."""

from __future__ import annotations

import os

import pytest

from lcpbench.run.store import RunLock, RunStore, atomic_write


def test_a_lock_link_is_refused_and_its_target_kept(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("keep me\n")
    store = tmp_path / "store"
    store.mkdir()
    (store / ".lock").symlink_to(outside)
    with pytest.raises(OSError, match="symbolic link"):
        with RunLock(store / ".lock"):
            pass
    assert outside.read_text() == "keep me\n"


def test_a_results_link_is_not_appended_to(tmp_path):
    outside = tmp_path / "outside.csv"
    outside.write_text("keep me\n")
    store = tmp_path / "store"
    store.mkdir()
    (store / "results.csv").symlink_to(outside)
    with pytest.raises(OSError, match="symbolic link"):
        RunStore(store).append({"run_id": "r1", "status": "converged"})
    assert outside.read_text() == "keep me\n"


def test_a_tables_link_and_a_planted_temporary_link_are_not_written(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    store = tmp_path / "store"
    store.mkdir()
    (store / "tables").symlink_to(elsewhere)
    with pytest.raises(OSError, match="symbolic link"):
        atomic_write(store / "tables" / "offline.csv", "a,b\n")
    assert list(elsewhere.iterdir()) == []
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    (store / f".report.html.tmp{os.getpid()}").symlink_to(victim)
    atomic_write(store / "report.html", "<html></html>\n")
    assert victim.read_text() == "keep me\n"
    assert (store / "report.html").read_text() == "<html></html>\n"


def test_a_corrupt_link_is_not_appended_to(tmp_path):
    outside = tmp_path / "outside.txt"
    outside.write_text("keep me\n")
    store = tmp_path / "store"
    RunStore(store).append({"run_id": "r1", "status": "converged"})
    with open(store / "results.csv", "a") as fh:
        fh.write("r2,cut short")                    # a bad line for the repair to set aside
    (store / "results.csv.corrupt").symlink_to(outside)
    with pytest.raises(OSError, match="symbolic link"):
        with RunStore(store).lock():
            pass
    assert outside.read_text() == "keep me\n"


def test_a_checkpoints_link_is_not_written_through(tmp_path, capsys):
    from lcpbench.cli import main

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "mine.npz").write_bytes(b"the user's own file")
    store = tmp_path / "sim"
    store.mkdir()
    (store / "checkpoints").symlink_to(elsewhere)
    code = main(["simulate", "--scene", "lattice:m=2,model=rpy", "--steps", "1", "--out",
                 str(store), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "checkpoints is a symbolic link" in err and len(err.splitlines()) == 1
    assert sorted(p.name for p in elsewhere.iterdir()) == ["mine.npz"]


def test_a_full_disk_during_run_is_one_line_and_the_same_command_resumes(tmp_path, capsys,
                                                                         monkeypatch):
    import errno

    import pandas as pd

    from lcpbench.cli import main

    real = RunStore._append_csv
    calls = {"n": 0}

    def full_after_two(path, columns, rows, checksum=False):
        calls["n"] += 1
        if calls["n"] > 4:                  # two runs' history and result rows, then full
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, columns, rows, checksum)

    monkeypatch.setattr(RunStore, "_append_csv", staticmethod(full_after_two))
    argv = ["run", "--problem", "tiny", "--solver", "bb-pgd", "--out", str(tmp_path / "r"),
            "--quiet", "--no-report"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("lcpbench run: error: ")
    assert err.endswith("No space left on device; free space (or choose another --out) and "
                        "rerun the same command: what was finished is kept and the run resumes")
    kept = len(pd.read_csv(tmp_path / "r" / "results.csv"))
    assert 1 <= kept < 7
    monkeypatch.setattr(RunStore, "_append_csv", staticmethod(real))
    assert main(argv) == 0
    assert len(pd.read_csv(tmp_path / "r" / "results.csv")) == 7


def test_an_out_folder_that_cannot_be_created_is_one_line(tmp_path, capsys):
    from lcpbench.cli import main

    out = "/proc/lcpbench-cannot-create"          # no folder can be made in /proc
    assert main(["run", "--problem", "tiny", "--solver", "bb-pgd", "--out", out,
                 "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"lcpbench run: error: {out}: cannot create the run store folder (No such "
                   "file or directory); choose another --out")
