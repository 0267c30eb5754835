"""Untrusted simulation checkpoints: sizes checked before decompressing,
orphan temporaries of killed writers removed."""

from __future__ import annotations

import fcntl
import os
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from lcpbench.workflows.checkpoint import Checkpoint, load_checkpoint, save_checkpoint


def _save(path: Path, **state) -> Path:
    save_checkpoint(path, Checkpoint(step=3, config={"scene": "s"}, scene_state=state,
                                     row={"step": 3}))
    return path


def _rezip(path: Path, replace: dict | None = None) -> None:
    """Rewrite the .npz deflate-compressed, with raw member bytes replaced from ``replace``."""
    with zipfile.ZipFile(path) as zf:
        members = {i.filename: zf.read(i) for i in zf.infolist()}
    members.update(replace or {})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)


def test_a_small_file_inflating_beyond_the_budget_is_refused_before_decompressing(
        tmp_path, monkeypatch):
    path = _save(tmp_path / "bomb.npz", pos=np.zeros(8 << 20))    # 64 MiB of zeros
    _rezip(path)
    assert path.stat().st_size < 1 << 20
    monkeypatch.setenv("LCPBENCH_READ_BUDGET", "16M")
    with pytest.raises(ValueError) as exc:
        load_checkpoint(path)
    msg = str(exc.value)
    assert "bomb.npz" in msg and "scene/pos" in msg and "64.0 MiB" in msg
    assert "read budget" in msg and "LCPBENCH_READ_BUDGET" in msg
    monkeypatch.setenv("LCPBENCH_READ_BUDGET", "128M")
    assert load_checkpoint(path).scene_state["pos"].shape == (8 << 20,)


def _npy_header(shape, dtype="<f8") -> bytes:
    import io

    buf = io.BytesIO()
    np.lib.format.write_array_header_2_0(buf, {"descr": dtype, "fortran_order": False,
                                                "shape": shape})
    return buf.getvalue()


def test_a_header_declaring_more_than_the_member_holds_is_refused(tmp_path):
    """The issue's 4 GiB: a header declaring 2**29 float64 over 80 bytes of data."""
    path = _save(tmp_path / "liar.npz", pos=np.zeros(10))
    _rezip(path, {"scene/pos.npy": _npy_header((1 << 29,)) + bytes(80)})
    with pytest.raises(ValueError) as exc:
        load_checkpoint(path)
    msg = str(exc.value)
    assert "liar.npz" in msg and "scene/pos" in msg and "4.0 GiB" in msg
    assert "delete it" in msg


@pytest.mark.parametrize("descr", ["<c16", "|O", [("a", "<f8")]])
def test_members_of_other_kinds_are_refused(tmp_path, descr):
    path = _save(tmp_path / "kind.npz", pos=np.zeros(4))
    _rezip(path, {"scene/pos.npy": _npy_header((4,), descr) + bytes(64)})
    with pytest.raises(ValueError, match="scene/pos.*dtype"):
        load_checkpoint(path)


def test_orphan_temporaries_are_removed_and_live_ones_kept(tmp_path):
    path = _save(tmp_path / "c.npz", pos=np.arange(3.0))
    old = time.time() - 3600
    orphan = tmp_path / ".tmp-killed.npz"          # a writer killed mid-write left it
    orphan.write_bytes(b"PK\x03\x04 half a zip")
    os.utime(orphan, (old, old))
    live = tmp_path / ".tmp-writing.npz"           # a writer at work holds its lock
    live.write_bytes(b"PK")
    os.utime(live, (old, old))
    fd = os.open(live, os.O_RDWR)
    fcntl.flock(fd, fcntl.LOCK_EX)
    unrelated = tmp_path / "notes.npz"
    unrelated.write_bytes(b"x")
    try:
        ckpt = load_checkpoint(path)
        assert not orphan.exists() and live.exists() and unrelated.exists()
        np.testing.assert_array_equal(ckpt.scene_state["pos"], np.arange(3.0))
        orphan.write_bytes(b"PK")                  # saving cleans as well (first step killed)
        os.utime(orphan, (old, old))
        _save(path, pos=np.ones(2))
        assert not orphan.exists() and live.exists()
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def test_a_failed_checkpoint_write_names_the_file_and_keeps_the_old_one(tmp_path, monkeypatch):
    import errno

    path = _save(tmp_path / "c.npz", pos=np.arange(3.0))

    def full(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "savez", full)
    with pytest.raises(OSError) as exc:
        _save(path, pos=np.ones(2))
    assert exc.value.filename == str(path) and "No space left" in str(exc.value)
    assert "previous checkpoint is kept" in str(exc.value)
    monkeypatch.undo()
    np.testing.assert_array_equal(load_checkpoint(path).scene_state["pos"], np.arange(3.0))
    assert [p.name for p in tmp_path.iterdir()] == ["c.npz"]
