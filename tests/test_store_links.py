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
