"""Stored sets on a failing disk: a write that fails leaves the set as it was.

The full disk is real for the process: ``RLIMIT_FSIZE`` caps the size of every file it writes
(the kernel then fails the write with EFBIG, as a full disk fails it with ENOSPC), so the HDF5
library and numpy meet the error exactly where they would meet a full disk.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import lcpbench.sets as st
import lcpbench.sets.write as set_write
from lcpbench.workflows.generate import generate, instance_id

SCENE = "lattice:m=3,model=rpy"
STEPS = "20-25"            # six instances of ~48 KB each (about 290 KB in all)

CAPPED = textwrap.dedent("""
    import resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)     # a failed write, not a killed process
    resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]), resource.RLIM_INFINITY))
    from lcpbench.cli import main
    sys.exit(main(sys.argv[2:]))
""")


def _generate(out: Path, cap: int) -> subprocess.CompletedProcess:
    args = ["generate", "--scene", SCENE, "--steps", STEPS, "--low", "self",
            "--out", str(out), "--quiet"]
    return subprocess.run([sys.executable, "-c", CAPPED, str(cap), *args],
                          capture_output=True, text=True, timeout=300, check=False)


@pytest.fixture(scope="module")
def one_shot(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("disk") / "one-shot.h5"
    generate(SCENE, STEPS, path, lows=["self"], progress=False)
    return path


# a second disk size (the set cut at another instance) repeats the check: slow
@pytest.mark.parametrize("cap", [60_000, pytest.param(170_000, marks=pytest.mark.slow)])
def test_full_disk_during_generate_keeps_the_set_and_the_same_command_resumes(
        tmp_path, one_shot, cap):
    out = tmp_path / "full.h5"
    failed = _generate(out, cap)
    assert failed.returncode == 2, failed.stderr[-2000:]
    err = failed.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "full.h5" in err and "rerun" in err
    # every instance the file lists is whole and verified; nothing half-written is visible
    kept = st.instance_ids(out)
    assert 0 < len(kept) < 6
    st.read_set(out)
    assert st.set_info(out)["incomplete"] == []
    assert not [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name]
    # space again: the same command resumes and finishes
    again = _generate(out, 1 << 40)
    assert again.returncode == 0, again.stderr[-2000:]
    assert f"kept {len(kept)}" in again.stdout
    ids = [instance_id(k) for k in range(20, 26)]
    assert st.instance_ids(out) == ids
    for a, b in zip(st.read_set(out), st.read_set(one_shot)):
        np.testing.assert_array_equal(a.dense(), b.dense())
        np.testing.assert_array_equal(a.b, b.b)
    # on the full disk again, a rerun with nothing left to store writes nothing and succeeds
    done = _generate(out, cap)
    assert done.returncode == 0 and "kept 6" in done.stdout, done.stderr[-2000:]


def _small(seed: int, n: int = 6):
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((n, n))
    return G @ G.T + n * np.eye(n), rng.standard_normal(n)


def test_a_failed_commit_leaves_the_file_and_the_writer_as_before(tmp_path, monkeypatch):
    path = tmp_path / "set.h5"
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        w.write_instance("0", *_small(0))
    before = path.read_bytes()
    real = set_write._write_all

    def full(fh, data):
        real(fh, memoryview(data)[: len(data) // 2])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        monkeypatch.setattr(set_write, "_write_all", full)
        with pytest.raises(st.StoredSetError, match="No space left on device") as exc:
            w.write_instance("1", *_small(1))
        msg = str(exc.value)
        assert "instance '1'" in msg and "1 finished instance" in msg and "rerun" in msg
        assert path.read_bytes() == before and not w.has("1") and w.ids() == ["0"]
        monkeypatch.undo()                      # space again: the same writer goes on
        w.write_instance("1", *_small(1))
    assert st.instance_ids(path) == ["0", "1"]
    np.testing.assert_array_equal(st.read_instance(path, "1").b, _small(1)[1])
    assert not [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name]


def test_every_committed_state_is_a_readable_set(tmp_path):
    """After each write_instance the file on disk is a whole set (a kill -9 at any later
    moment loses nothing already written), and readers can read it while the writer is open."""
    path = tmp_path / "set.h5"
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        assert st.instance_ids(path) == []
        for k in range(3):
            w.write_instance(str(k), *_small(k))
            assert [lcp.meta["instance"] for lcp in st.read_set(path)] == \
                [str(i) for i in range(k + 1)]


def test_a_second_writer_is_refused(tmp_path):
    path = tmp_path / "set.h5"
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        w.write_instance("0", *_small(0))
        with pytest.raises(st.StoredSetError, match="being written by another"):
            st.SetWriter(path, title="t", description="d", generator="g").open()
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        assert w.ids() == ["0"]


def test_orphan_temporaries_of_a_killed_writer_are_removed(tmp_path):
    path = tmp_path / "set.h5"
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        w.write_instance("0", *_small(0))
    orphan = tmp_path / ".set.h5.tmp-k1ll3d"        # what a writer killed mid-commit leaves
    orphan.write_bytes(b"\x89HDF half an image")
    other = tmp_path / ".other.h5.tmp-k1ll3d"       # another set's: not ours to remove
    other.write_bytes(b"x")
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        assert w.ids() == ["0"]
    assert not orphan.exists() and other.exists()


def test_a_writer_that_adds_nothing_does_not_rewrite_the_file(tmp_path):
    """A resume that only keeps instances needs no free space: the file is not replaced."""
    path = tmp_path / "set.h5"
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        w.write_instance("0", *_small(0))
    inode = path.stat().st_ino
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        assert w.has("0")
    assert path.stat().st_ino == inode
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        w.file.attrs["steps"] = "0-3"               # a change of the root attributes is saved
    assert path.stat().st_ino != inode and st.set_info(path)["steps"] == "0-3"
