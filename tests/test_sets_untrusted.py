"""Untrusted stored sets: every hostile file is a StoredSetError, found
before the reader allocates, decompresses or opens anything beyond the file itself."""

from __future__ import annotations

import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest

import lcpbench.sets as st
from lcpbench.sets.common import _digest

GEN = "lcpbench generate --scene test --out SET.h5"


def _spd(seed: int, n: int):
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((n, n))
    return G @ G.T + n * np.eye(n), rng.standard_normal(n)


def _set(path: Path, n: int = 5) -> Path:
    with st.SetWriter(path, title="t", description="d", generator=GEN) as w:
        A, b = _spd(0, n)
        w.write_instance("0", A, b, low={"p4": (A + 1e-3 * np.eye(n), 0.1, {"p": 4})},
                         reference={"x": np.zeros(n), "w": b, "kkt_abs": 0.0,
                                    "solvers": ["clarabel"]})
        w.write_instance("1", *_spd(1, n))
    return path


def _replace(path: Path, rel: str, make) -> None:
    """Replace dataset ``instances/0/<rel>`` by what ``make(group, name)`` creates."""
    with h5py.File(path, "a") as f:
        parent, _, name = f"instances/0/{rel}".rpartition("/")
        del f[parent][name]
        make(f[parent], name)


def _refused(path: Path, *parts: str, instance: str = "0", **kw) -> st.StoredSetError:
    with pytest.raises(st.StoredSetError) as exc:
        st.read_instance(path, instance, **kw)
    msg = str(exc.value)
    assert str(path) in msg and f"instance '{instance}'" in msg, msg
    for part in parts:
        assert part in msg, msg
    return exc.value


# ------------------------------------------------------------------ sizes before reading
def test_a_tiny_file_declaring_a_huge_matrix_is_refused_before_allocating(tmp_path):
    """The issue's 11 KB file: A declared (60000, 60000) (26.8 GiB), no data stored."""
    path = _set(tmp_path / "huge.h5")
    n = 60_000
    with h5py.File(path, "a") as f:
        g = f["instances/0"]
        for rel in [k for k in g.attrs if k.startswith("sha256:")]:
            del g.attrs[rel]
        for rel in ("A", "b", "low", "reference"):
            del g[rel]
        g.create_dataset("A", shape=(n, n), dtype="f8")
        g["b"] = np.ones(n)
        g.attrs["n"] = n
        g.attrs["sha256:A"] = "0" * 64
        g.attrs["sha256:b"] = _digest(np.ones(n))
    assert path.stat().st_size < 1_000_000
    err = _refused(path, "dataset 'A'", "26.8 GiB", "file")
    assert err.dataset == "A"


def test_declared_data_larger_than_the_file_is_refused(tmp_path):
    path = _set(tmp_path / "short.h5")
    with h5py.File(path, "a") as f:             # 5 x 5 declared, stored nowhere
        del f["instances/0/low/p4/A"]
        f["instances/0/low/p4"].create_dataset("A", shape=(5, 5), dtype="f8")
    _refused(path, "dataset 'low/p4/A'", "not stored in the file")


def _bomb(path: Path, n: int) -> Path:
    """Instance 0's A replaced by an n x n gzip-compressed identity (checksum right)."""
    _set(path)
    A = np.eye(n)
    with h5py.File(path, "a") as f:
        g = f["instances/0"]
        for rel in ("low", "reference", "x0"):
            if rel in g:
                del g[rel]
        for key in [k for k in g.attrs if k.startswith("sha256:")]:
            del g.attrs[key]
        del g["A"], g["b"]
        g.create_dataset("A", data=A, compression="gzip", chunks=(min(n, 256), min(n, 256)))
        g["b"] = -np.ones(n)
        g.attrs["n"] = n
        g.attrs["sha256:A"] = _digest(A)
        g.attrs["sha256:b"] = _digest(-np.ones(n))
    return path


def test_compressed_data_is_bounded_by_the_read_budget(tmp_path, monkeypatch):
    path = _bomb(tmp_path / "bomb.h5", 2048)          # 32 MiB of matrix in ~100 KB
    assert path.stat().st_size < 1_000_000
    _refused(path, "dataset 'A'", "32.0 MiB", "read budget", "LCPBENCH_READ_BUDGET",
             budget=8 << 20)
    monkeypatch.setenv("LCPBENCH_READ_BUDGET", "8M")
    _refused(path, "read budget")
    with pytest.raises(st.StoredSetError, match="read budget"):
        st.read_set(path)
    monkeypatch.setenv("LCPBENCH_READ_BUDGET", "64M")
    assert st.read_instance(path, "0").n == 2048        # a legitimate compressed set reads


def test_the_budget_covers_a_whole_read_set_call(tmp_path):
    path = _set(tmp_path / "two.h5", n=64)               # instances of 67 KB and 33 KB
    st.read_set(path, budget=110_000)
    with pytest.raises(st.StoredSetError, match="read budget"):
        st.read_set(path, budget=90_000)
    st.read_instance(path, "1", budget=50_000)
    _refused(path, "read budget", budget=50_000)


def test_a_malformed_budget_is_a_clear_error(tmp_path, monkeypatch):
    path = _set(tmp_path / "s.h5")
    monkeypatch.setenv("LCPBENCH_READ_BUDGET", "lots")
    with pytest.raises(ValueError, match="LCPBENCH_READ_BUDGET.*'lots'.*e.g. 4G"):
        st.read_set(path)


# ------------------------------------------------------------------ nothing outside the file
def test_an_external_link_is_not_followed(tmp_path):
    path = _set(tmp_path / "ext.h5")
    outside = tmp_path / "outside.h5"
    A = _spd(0, 5)[0]
    with h5py.File(outside, "w") as f:
        f["A"] = A                                   # the right data, with the right checksum
    _replace(path, "A", lambda g, name: g.__setitem__(name, h5py.ExternalLink(
        str(outside), "/A")))
    _refused(path, "dataset 'A'", "external link", "outside.h5")


def test_an_external_link_to_a_whole_instance_or_group_is_not_followed(tmp_path):
    path = _set(tmp_path / "ext.h5")
    copy = tmp_path / "copy.h5"
    copy.write_bytes(path.read_bytes())
    with h5py.File(path, "a") as f:
        del f["instances/1"]
        f["instances/1"] = h5py.ExternalLink(str(copy), "/instances/1")
        del f["instances/0/low"]
        f["instances/0/low"] = h5py.ExternalLink(str(copy), "/instances/0/low")
    _refused(path, "external link", instance="1")
    _refused(path, "dataset 'low'", "external link")


def test_a_soft_link_is_refused(tmp_path):
    path = _set(tmp_path / "soft.h5")
    _replace(path, "reference/w", lambda g, name: g.__setitem__(name, h5py.SoftLink(
        "/instances/0/b")))
    _refused(path, "dataset 'reference/w'", "soft link")


def test_external_raw_storage_is_not_read(tmp_path):
    path = _set(tmp_path / "raw.h5")
    b = _spd(0, 5)[1]
    raw = tmp_path / "b.raw"
    raw.write_bytes(b.astype("<f8").tobytes())       # the right bytes, outside the file
    _replace(path, "b", lambda g, name: g.create_dataset(
        name, shape=(5,), dtype="<f8", external=[(str(raw), 0, 40)]))
    _refused(path, "dataset 'b'", "external", "b.raw")


def test_a_virtual_dataset_is_not_read(tmp_path):
    path = _set(tmp_path / "vds.h5")
    b = _spd(0, 5)[1]
    src = tmp_path / "src.h5"
    with h5py.File(src, "w") as f:
        f["b"] = b

    def virtual(g, name):
        layout = h5py.VirtualLayout(shape=(5,), dtype="f8")
        layout[:] = h5py.VirtualSource(str(src), "b", shape=(5,))
        g.create_virtual_dataset(name, layout)

    _replace(path, "b", virtual)
    _refused(path, "dataset 'b'", "virtual")


# ------------------------------------------------------------------ types
def test_complex_data_is_refused_not_cast(tmp_path):
    path = _set(tmp_path / "cplx.h5")
    A = _spd(0, 5)[0] + 1j * np.eye(5)
    with h5py.File(path, "a") as f:
        del f["instances/0/A"]
        f["instances/0/A"] = A
        f["instances/0"].attrs["sha256:A"] = _digest(A)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                # no ComplexWarning on the way either
        _refused(path, "dataset 'A'", "complex")


@pytest.mark.parametrize("where, key, value, words", [
    ("instances/0", "n", "five", "attribute 'n'"),
    ("instances/0", "n", np.array([5, 5]), "attribute 'n'"),
    ("instances/0", "n", 5.5, "attribute 'n'"),
    ("instances/0", "n", -1, "attribute 'n'"),
    ("instances/0", "sha256:A", 17, "attribute 'sha256:A'"),
    ("instances/0/low/p4", "cost_ratio", "fast", "attribute 'cost_ratio'"),
    ("instances/0/low/p4", "cost_ratio", -0.5, "attribute 'cost_ratio'"),
    ("instances/0/low/p4", "cost_ratio", np.array([0.1, 0.2]), "attribute 'cost_ratio'"),
    ("instances/0/reference", "kkt_abs", "tiny", "attribute 'kkt_abs'"),
    ("instances/0/reference", "solvers", 5, "attribute 'solvers'"),
    ("instances/0/reference", "accepted", "no", "attribute 'accepted'"),
    ("instances/0/reference", "objective", np.array([1.0, 2.0]), "attribute 'objective'"),
])
def test_every_bad_attribute_is_a_stored_set_error(tmp_path, where, key, value, words):
    path = _set(tmp_path / "attr.h5")
    with h5py.File(path, "a") as f:
        f[where].attrs[key] = value
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _refused(path, words)
        with pytest.raises(st.StoredSetError):
            st.read_set(path)
    st.read_instance(path, "1")                       # the other instance stays readable


@pytest.mark.parametrize("key, value, words", [
    ("version", 1.5, "version"),
    ("version", "1", "version"),
    ("format", np.bytes_(b"\xff\xfe"), "format"),
    ("generator", np.array([1, 2]), "generator"),
])
def test_bad_root_attributes_are_stored_set_errors(tmp_path, key, value, words):
    path = _set(tmp_path / "root.h5")
    with h5py.File(path, "a") as f:
        f.attrs[key] = value
    for call in (st.read_set, st.set_info, st.instance_ids):
        with pytest.raises(st.StoredSetError, match=words):
            call(path)


def test_the_shipped_sets_pass_every_check():
    import lcpbench.problems.stored as stored

    for name, p in stored.shipped_sets().items():
        assert len(st.read_set(p)) == len(st.instance_ids(p)), name


@pytest.mark.parametrize("rel", ["/instances/1/b", "low/p4/b", "notes"])
def test_a_checksum_outside_the_layout_is_refused(tmp_path, rel):
    """A manifest entry may not reach another instance (an absolute path) or smuggle in a
    dataset the layout does not have."""
    path = _set(tmp_path / "layout.h5")
    with h5py.File(path, "a") as f:
        g = f["instances/0"]
        if not rel.startswith("/"):
            g[rel] = np.ones(5)
        g.attrs[f"sha256:{rel}"] = _digest(np.ones(5) if not rel.startswith("/") else
                                           f["instances/1/b"][()])
    _refused(path, f"dataset '{rel}'", "outside the stored-set layout")


def test_a_hard_link_cycle_or_deeper_nesting_is_refused(tmp_path):
    path = _set(tmp_path / "cycle.h5")
    with h5py.File(path, "a") as f:
        f["instances/0/low/loop"] = f["instances/0"]          # a hard link to its ancestor
        f["instances/1"].create_group("reference/deeper/still")
    _refused(path, "dataset 'low/loop/low'", "nested deeper")
    _refused(path, "dataset 'reference/deeper/still'", "nested deeper", instance="1")
