"""Stored HDF5 sets: round trips, resuming, corruption detection, recovery, the plugin."""

from __future__ import annotations

import contextlib
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import h5py
import numpy as np
import pytest

import lcpbench
import lcpbench.problems.stored as stored_plugin
import lcpbench.sets as st
import lcpbench.sets.write
from lcpbench.core.registry import get_problem
from lcpbench.core.specs import make_params
from lcpbench.sets.seal import seal_image

GEN = "lcpbench generate --scene test --out SET.h5"


def spd(seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((n, n))
    A = G @ G.T / n + np.eye(n)
    return (A + A.T) / 2, rng.standard_normal(n)


def perturbed(A: np.ndarray, seed: int, rel: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    E = rng.standard_normal(A.shape)
    E = (E + E.T) / 2
    return A + rel * np.linalg.norm(A, 2) / np.linalg.norm(E, 2) * E


def write_set(path: Path, ids=("0", "1", "2")) -> dict:
    """A small set: instance 0 with two low operators, a warm start and a reference."""
    data = {}
    with st.SetWriter(path, title="test set", description="three SPD LCPs",
                      generator=GEN) as w:
        for k, iid in enumerate(ids):
            A, b = spd(k, 8 + k)
            low, x0, ref = None, None, None
            if k == 0:
                low = {"p4": (perturbed(A, 1, 1e-3), 0.1, {"p": 4, "eps_gmres": 1e-4}),
                       "p2": (perturbed(A, 2, 1e-2), 0.02, {"p": 2})}
                x0 = np.abs(b)
                ref = lcpbench.reference(lcpbench.LCP(A, b))
            w.write_instance(iid, A, b, low=low, x0=x0, reference=ref,
                             attrs={"step": k, "M": 5 + k, "t_mvp_high": 0.9,
                                    "scene": {"phi": 0.3}, "tags": ["a", "b"]})
            data[iid] = (A, b, low, x0, ref)
    return data


@contextlib.contextmanager
def _edit(path: Path) -> Iterator[h5py.File]:
    """The set opened for editing with h5py, its file checksum made to match afterwards,
    so that the checks behind the checksum are the ones exercised."""
    with h5py.File(path, "a") as f:
        yield f
    path.write_bytes(seal_image(path.read_bytes()))


def test_round_trip_preserves_everything(tmp_path):
    path = tmp_path / "set.h5"
    data = write_set(path)
    lcps = st.read_set(path)
    assert [lcp.meta["instance"] for lcp in lcps] == ["0", "1", "2"]
    for lcp, (iid, (A, b, low, x0, ref)) in zip(lcps, data.items()):
        np.testing.assert_array_equal(lcp.dense(), A)
        np.testing.assert_array_equal(lcp.b, b)
        assert lcp.name == f"set/{iid}"
        assert lcp.A.declared_cost == 1.0
        assert lcp.meta["step"] == int(iid) and lcp.meta["M"] == 5 + int(iid)
        assert lcp.meta["t_mvp_high"] == 0.9 and lcp.meta["n"] == b.size
        assert lcp.meta["tags"] == ["a", "b"] and lcp.meta["scene"] == '{"phi": 0.3}'
        if low is None:
            assert lcp.low == {} and lcp.x0 is None and lcp.reference is None
            continue
        np.testing.assert_array_equal(lcp.x0, x0)
        assert set(lcp.low) == {"p4", "p2"}
        for name, (A_low, ratio, knobs) in low.items():
            op = lcp.low[name]
            np.testing.assert_array_equal(op._impl, A_low)
            assert op.declared_cost == ratio and op.name == name
            assert lcp.meta["low"][name] == {**knobs, "cost_ratio": ratio}
        r = lcp.reference
        np.testing.assert_array_equal(r["x"], ref.x)
        np.testing.assert_array_equal(r["w"], ref.w)
        assert r["solvers"] == list(ref.solvers) and r["kkt_abs"] == ref.kkt_abs
        assert r["disagreement"] == ref.disagreement and r["objective"] == ref.objective
        assert r["accepted"] is True


def test_info_and_single_instance(tmp_path):
    path = tmp_path / "set.h5"
    write_set(path)
    info = st.set_info(path)
    assert info["format"] == st.FORMAT and info["version"] == st.VERSION
    assert info["generator"] == GEN and info["title"] == "test set"
    assert info["ids"] == ["0", "1", "2"] and info["incomplete"] == []
    assert info["cost_convention"] == st.COST_CONVENTION
    lcp = st.read_instance(path, "1")
    np.testing.assert_array_equal(lcp.dense(), spd(1, 9)[0])
    with pytest.raises(st.StoredSetError, match="no instance '7'"):
        st.read_instance(path, "7")


def test_emvps_use_the_stored_cost_ratio(tmp_path):
    path = tmp_path / "set.h5"
    write_set(path)
    lcp = st.read_instance(path, "0")
    res = lcpbench.solve(lcp, solver="bi-pqn:low=p4")
    assert res.verified["kkt_abs"] <= 1e-6
    assert res.lofi_mvps["p4"] > 0
    assert res.emvps == pytest.approx(res.mvps + 0.1 * res.lofi_mvps["p4"], rel=1e-12)
    # the solve ran on copies: the instance's own counters start at zero, and products on
    # them are priced at the stored ratios (p4 0.1, p2 0.02 of a high-fidelity MVP)
    assert lcp.A.count == 0 and lcp.low["p4"].count == 0
    lcp.A @ np.ones(lcp.n)
    lcp.low["p4"] @ np.ones((lcp.n, 10))
    lcp.low["p2"] @ np.ones((lcp.n, 5))
    assert lcp.emvps() == pytest.approx(1 + 10 * 0.1 + 5 * 0.02, rel=1e-12)


def test_resume_keeps_instances_and_appends(tmp_path):
    path = tmp_path / "set.h5"
    write_set(path, ids=("0",))
    created = st.set_info(path)["created"]
    with st.SetWriter(path, title="ignored", description="ignored", generator="x") as w:
        assert w.has("0") and not w.has("1")
        with pytest.raises(ValueError, match="exists already"):
            w.write_instance("0", *spd(0, 8))
        w.write_instance("1", *spd(5, 6))
        assert w.ids() == ["0", "1"]
    info = st.set_info(path)
    assert info["ids"] == ["0", "1"] and info["created"] == created
    assert info["generator"] == GEN            # the original command is kept
    lcps = st.read_set(path)
    np.testing.assert_array_equal(lcps[0].dense(), spd(0, 8)[0])
    np.testing.assert_array_equal(lcps[1].b, spd(5, 6)[1])


def _flip_byte(path: Path, dataset: str, index: int = 3) -> None:
    with h5py.File(path, "r") as f:
        offset = f[dataset].id.get_offset()
    assert offset is not None
    with open(path, "r+b") as fh:
        fh.seek(offset + index)
        byte = fh.read(1)
        fh.seek(offset + index)
        fh.write(bytes([byte[0] ^ 0x5A]))


@pytest.mark.parametrize("dataset", ["b", "A", "low/p4/A", "reference/w", "x0"])
def test_flipped_byte_is_a_checksum_error(tmp_path, dataset):
    path = tmp_path / "set.h5"
    write_set(path)
    _flip_byte(path, f"instances/0/{dataset}")
    with pytest.raises(st.StoredSetError, match="file checksum mismatch"):
        st.read_set(path)                      # the whole-file checksum finds it first
    path.write_bytes(seal_image(path.read_bytes()))
    with pytest.raises(st.StoredSetError) as err:
        st.read_set(path)
    msg = str(err.value)
    assert "checksum mismatch" in msg and str(path) in msg
    assert "instance '0'" in msg and f"dataset '{dataset}'" in msg and GEN in msg
    assert err.value.instance == "0" and err.value.dataset == dataset
    st.read_instance(path, "1")                # the other instances stay readable


def test_truncated_file_is_a_clear_error(tmp_path):
    path = tmp_path / "set.h5"
    write_set(path)
    size = path.stat().st_size
    with open(path, "r+b") as fh:
        fh.truncate(size // 2)
    with pytest.raises(st.StoredSetError, match="truncated or corrupted") as err:
        st.read_set(path)
    assert str(path) in str(err.value) and "Regenerate" in str(err.value)


@pytest.mark.parametrize("dataset", ["low/p4/A", "b", "reference/x"])
def test_deleted_dataset_is_a_clear_error(tmp_path, dataset):
    path = tmp_path / "set.h5"
    write_set(path)
    with _edit(path) as f:
        del f[f"instances/0/{dataset}"]
    with pytest.raises(st.StoredSetError, match="dataset is missing") as err:
        st.read_set(path)
    assert err.value.instance == "0" and err.value.dataset == dataset
    assert f"dataset '{dataset}'" in str(err.value)


def test_shape_and_manifest_checks(tmp_path):
    path = tmp_path / "set.h5"
    write_set(path)
    with _edit(path) as f:
        b = f["instances/1/b"][()]
        del f["instances/1/b"]
        f["instances/1/b"] = b[:-1]
        f["instances/2/extra"] = np.zeros(3)
    with pytest.raises(st.StoredSetError, match=r"shape \(8,\), expected \(9,\)"):
        st.read_instance(path, "1")
    with pytest.raises(st.StoredSetError, match="without a checksum: extra"):
        st.read_instance(path, "2")


def test_not_a_set_and_newer_version(tmp_path):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(2)
    with pytest.raises(st.StoredSetError, match="not an lcpbench stored set"):
        st.read_set(other)
    with pytest.raises(st.StoredSetError, match="not an lcpbench set"):
        st.SetWriter(other, title="t", description="d", generator="g").open()
    path = tmp_path / "set.h5"
    write_set(path, ids=("0",))
    with _edit(path) as f:
        f.attrs["version"] = st.VERSION + 1
    with pytest.raises(st.StoredSetError, match="upgrade lcpbench"):
        st.read_set(path)
    with pytest.raises(st.StoredSetError, match="no such stored set"):
        st.read_set(tmp_path / "missing.h5")


def test_half_written_group_is_deleted_and_reported(tmp_path):
    path = tmp_path / "set.h5"
    write_set(path, ids=("0",))
    with _edit(path) as f:        # what an interrupted write_instance leaves
        g = f.create_group("_incomplete/1")
        g["A"] = np.zeros((4, 4))
    assert st.set_info(path)["incomplete"] == ["1"]
    assert [lcp.meta["instance"] for lcp in st.read_set(path)] == ["0"]
    with pytest.warns(RuntimeWarning, match="half-written instance.*: 1"):
        w = st.SetWriter(path, title="t", description="d", generator="g").open()
    try:
        assert w.recovered == ["1"] and not w.has("1")
        w.write_instance("1", *spd(1, 9))
    finally:
        w.close()
    info = st.set_info(path)
    assert info["ids"] == ["0", "1"] and info["incomplete"] == []


def test_killed_writer_leaves_a_recoverable_file(tmp_path):
    path = tmp_path / "set.h5"
    write_set(path, ids=("0",))
    before = path.read_bytes()
    script = textwrap.dedent(f"""
        import os, numpy as np
        import lcpbench.sets as st
        import lcpbench.sets.write as sw
        def die(fh, data):
            fh.write(memoryview(data)[: len(data) // 2])
            os._exit(3)                     # killed half-way through writing the new file
        sw._write_all = die
        with st.SetWriter({str(path)!r}, title="t", description="d", generator="g") as w:
            w.write_instance("1", np.eye(3), np.ones(3))
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60, check=False)
    assert proc.returncode == 3, proc.stderr
    assert path.read_bytes() == before and st.instance_ids(path) == ["0"]
    assert len(list(tmp_path.glob(".set.h5.tmp-*"))) == 1     # the half-written new file
    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        assert w.recovered == [] and w.ids() == ["0"]
        w.write_instance("1", np.eye(3), np.ones(3))
    assert st.instance_ids(path) == ["0", "1"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["set.h5"]


def test_failed_write_leaves_no_trace(tmp_path, monkeypatch):
    path = tmp_path / "set.h5"
    write_set(path, ids=("0",))

    def boom(arr):
        raise OSError("disk full")

    with st.SetWriter(path, title="t", description="d", generator="g") as w:
        monkeypatch.setattr(lcpbench.sets.write, "_digest", boom)
        with pytest.raises(OSError, match="disk full"):
            w.write_instance("1", np.eye(3), np.ones(3))
        monkeypatch.undo()
        assert not w.has("1")
    assert st.set_info(path)["incomplete"] == []


@pytest.mark.parametrize("kwargs, match", [
    ({"A": np.eye(3), "b": np.ones(4)}, r"shape \(3, 3\) does not match"),
    ({"A": np.eye(3), "b": np.ones(3), "x0": np.ones(2)}, "x0: length 2"),
    ({"A": np.eye(3), "b": np.ones(3), "low": {"p4": (np.eye(3), 0.0)}}, "cost_ratio"),
    ({"A": np.eye(3), "b": np.ones(3), "low": {"p4": np.eye(3)}}, r"\(A_low, cost_ratio\)"),
    ({"A": np.eye(3), "b": np.ones(3), "attrs": {"n": 3}}, "may not set 'n'"),
    ({"A": np.eye(3), "b": np.ones(3), "attrs": {"k": None}}, "cannot be None"),
    ({"A": np.eye(3), "b": np.ones(3), "reference": {"x": np.ones(3)}}, "missing w"),
    ({"A": np.eye(3), "b": np.array([1.0, np.nan, 0])}, "non-finite"),
])
def test_writer_rejects_bad_input(tmp_path, kwargs, match):
    with st.SetWriter(tmp_path / "s.h5", title="t", description="d", generator="g") as w:
        A, b = kwargs.pop("A"), kwargs.pop("b")
        with pytest.raises((ValueError, TypeError), match=match):
            w.write_instance("0", A, b, **kwargs)
        with pytest.raises(ValueError, match="letters, digits"):
            w.write_instance("a/b", A, b)
        assert w.ids() == []


def test_parse_instances():
    assert st.parse_instances("", 3) == [0, 1, 2]
    assert st.parse_instances("0-2,5", 6) == [0, 1, 2, 5]
    assert st.parse_instances("4, 1-2", 6) == [4, 1, 2]
    for bad, match in [("3-1", "reversed"), ("0-9", "out of range"), ("a", "cannot parse")]:
        with pytest.raises(ValueError, match=match):
            st.parse_instances(bad, 6)


def test_plugin_and_shipped_sets(tmp_path, monkeypatch):
    path = tmp_path / "mine.h5"
    write_set(path)
    info = get_problem("stored")
    lcps = info.func(make_params("stored", info.params, {"path": str(path),
                                                         "instances": "1-2"}))
    assert [lcp.meta["instance"] for lcp in lcps] == ["1", "2"]
    with pytest.raises(ValueError, match="path is required"):
        make_params("stored", info.params, {})
    for name, p in stored_plugin.shipped_sets().items():
        assert p.suffix == ".h5" and p.stem == name and p.exists()
    monkeypatch.setattr(stored_plugin, "DATA_DIR", tmp_path)
    assert stored_plugin.shipped_sets() == {"mine": path}
    lcps = info.func(make_params("stored", info.params, {"path": "mine"}))
    assert len(lcps) == 3 and lcps[0].meta["set"] == "mine"
