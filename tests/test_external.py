"""Importers of Siconos numerics ``.dat`` LCPs and FCLIB local problems."""

from __future__ import annotations

import warnings
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.sparse as sp

import lcpbench
import lcpbench.problems.external as ex
import lcpbench.problems.siconos as siconos_format
from lcpbench.core.registry import get_problem
from lcpbench.core.specs import make_params


def spd(seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    G = rng.standard_normal((n, n))
    A = G @ G.T / n + 0.5 * np.eye(n)
    A = (A + A.T) / 2
    A[np.abs(A) < 0.3] = 0.0               # some structural zeros for the sparse storages
    A += n * np.eye(n)                     # keep it SPD after the thinning
    return A, rng.standard_normal(n)


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# ---------------------------------------------------------------------- siconos
@pytest.mark.parametrize("storage", ex.SICONOS_STORAGES)
def test_siconos_round_trip_is_exact(tmp_path, storage):
    A, b = spd(0, 7)
    path = ex.write_siconos_lcp(tmp_path / "p.dat", A, b, storage=storage)
    lcp = ex.read_siconos_lcp(path)
    np.testing.assert_array_equal(lcp.dense(), A)
    np.testing.assert_array_equal(lcp.b, b)
    assert lcp.meta["storage"] == ("dense" if storage == "dense" else "sparse")
    assert lcp.meta["family"] == "siconos" and lcp.name == "siconos/p"


def test_siconos_dense_layout_matches_numerics(tmp_path):
    A = np.array([[2.0, 1.0], [1.0, 3.0]])
    path = ex.write_siconos_lcp(tmp_path / "p.dat", A, [-1.0, 0.5])
    lines = path.read_text().split("\n")
    assert lines[:5] == ["2", "0", "2", "2", "2\t2"]
    assert [float(t) for t in lines[5].split()] == [2.0, 1.0]
    assert [float(t) for t in lines[7].split()] == [-1.0, 0.5]
    assert lines[5].startswith(f"{2.0:32.24e} ")


def test_siconos_dense_is_column_major():
    c = siconos_format._Cursor("2\t2\n1 3\n2 4\n", Path("mem.dat"))
    np.testing.assert_array_equal(siconos_format._read_dense(c, 2, 2), [[1.0, 2.0], [3.0, 4.0]])


def test_siconos_handwritten_dense_with_trailing_remarks(tmp_path):
    path = write(tmp_path / "h.dat", "3\n0\n3\n3\n3\t3\n4 1 0\n1 5 2\n0 2 6\n-1 2 -3\n\n"
                                     "Remark: a comment after q is ignored\n")
    lcp = ex.read_siconos_lcp(path)
    np.testing.assert_array_equal(lcp.dense(), [[4, 1, 0], [1, 5, 2], [0, 2, 6]])
    np.testing.assert_array_equal(lcp.b, [-1, 2, -3])


# The CSparse dump as siconos writes it (%g values, a version line, an empty column).
CSC_TEXT = """3
2
3
3
2
CSparse Version 3.1.4, Oct 10, 2014.  Copyright (c) Timothy A. Davis, 2006-2014
3-by-3, nzmax: 4 nnz: 4, 1-norm: 4
    col 0 : locations 0 to 1
      0 : 4
      2 : 0.5
    col 1 : locations 2 to 1
    col 2 : locations 2 to 3
      0 : 0.5
      2 : 3
 -1.0 1.0 -2.0
"""


def test_siconos_handwritten_sparse_storages(tmp_path):
    expected = np.array([[4.0, 0.0, 0.5], [0.0, 0.0, 0.0], [0.5, 0.0, 3.0]])
    lcp = ex.read_siconos_lcp(write(tmp_path / "csc.dat", CSC_TEXT))
    np.testing.assert_array_equal(lcp.dense(), expected)
    np.testing.assert_array_equal(lcp.b, [-1.0, 1.0, -2.0])
    csr = CSC_TEXT.replace("\n2\nCSparse", "\n3\nCSparse").replace("3-by-3,", "csr: 3-by-3,")
    csr = csr.replace("    col", "    row")
    lcp = ex.read_siconos_lcp(write(tmp_path / "csr.dat", csr))
    np.testing.assert_array_equal(lcp.dense(), expected)
    triplet = ("3\n2\n3\n3\n1\nCSparse Version 3.1.4\ntriplet: 3-by-3, nzmax: 5 nnz: 5\n"
               "    0 0 : 3\n    2 0 : 0.5\n    0 2 : 0.5\n    2 2 : 3\n    0 0 : 1\n"
               "-1 1 -2\n")
    lcp = ex.read_siconos_lcp(write(tmp_path / "tri.dat", triplet))
    np.testing.assert_array_equal(lcp.dense(), expected)  # duplicates add up, as in CSparse


def test_siconos_sparse_block_storage(tmp_path):
    # Blocks 2+1 rows/cols: block (0,0) 2x2, (0,1) 2x1, (1,0) 1x2, (1,1) 1x1, column-major.
    text = ("3\n1\n3\n3\n"
            "4\n2\n2\n2\t3\t\n2\t3\t\n3\n4\n0\t2\t4\t\n0\t1\t0\t1\t\n"
            "0\n5.0\n1.0\n1.0\n6.0\n"
            "1\n0.5\n-0.5\n"
            "2\n0.5\n-0.5\n"
            "3\n7.0\n"
            " 1.0 -1.0 2.0\n")
    lcp = ex.read_siconos_lcp(write(tmp_path / "sbm.dat", text))
    np.testing.assert_array_equal(lcp.dense(), [[5, 1, 0.5], [1, 6, -0.5], [0.5, -0.5, 7]])
    np.testing.assert_array_equal(lcp.b, [1, -1, 2])
    empty = ex.read_siconos_lcp(write(tmp_path / "zero.dat", "2\n1\n2\n2\n0\n1 1\n"),
                                psd_check=True)
    np.testing.assert_array_equal(empty.dense(), np.zeros((2, 2)))


@pytest.mark.parametrize("text, match", [
    ("3\n0\n3\n3\n3\t3\n1 0 0\n0 1 0\n", "ends where dense entry 6"),
    ("2\n5\n2\n2\n", "unknown storage type 5"),
    ("3\n0\n2\n2\n2\t2\n1 0 0 1\n1 1\n", "problem size is 3"),
    ("2\n0\n2\n2\n2\t2\n1 x 0 1\n1 1\n", "expected a number for dense entry 1, found 'x'"),
    ("2\n2\n2\n2\n4\nCSparse\ntriplet: 2-by-2, nzmax: 1 nnz: 1\n    0 0 : 1\n1 1\n",
     "half triplet"),
    ("30000\n1\n30000\n30000\n0\n" + "0\n" * 30000,
     "the 30000x30000 matrix takes 6.7 GiB as a dense matrix, over the read budget"),
    ("100000\n0\n100000\n100000\n100000 100000\n1\n",
     "matrix takes 74.5 GiB as a dense matrix, over the read budget of 2.0 GiB"),
    (("2\n2\n2\n2\n2\nCSparse\n2-by-2, nzmax: 1 nnz: 1\n    col 0 : locations 0 to 0\n"
      "      0 : 1\n    col 5 : locations 1 to 0\n1 1\n"), "expected 'col 1 : locations"),
])
def test_siconos_malformed_files(tmp_path, text, match):
    with pytest.raises(ex.SiconosFormatError, match=match) as err:
        ex.read_siconos_lcp(write(tmp_path / "bad.dat", text))
    assert "bad.dat, line" in str(err.value)


def test_siconos_symmetry_policy(tmp_path):
    M = np.array([[2.0, 1.0], [0.0, 2.0]])
    path = ex.write_siconos_lcp(tmp_path / "ns.dat", M, [1.0, -1.0])
    with pytest.raises(ValueError, match=r"not symmetric .*0\.5 relative.*symmetrize_rtol"):
        ex.read_siconos_lcp(path)
    with pytest.warns(RuntimeWarning, match=r"symmetrised .*0\.5 relative"):
        lcp = ex.read_siconos_lcp(path, symmetrize_rtol=1.0)
    np.testing.assert_array_equal(lcp.dense(), [[2.0, 0.5], [0.5, 2.0]])
    with pytest.raises(ValueError, match="neg.dat: Siconos LCP is not a valid lcpbench LCP.*positive semidefinite"):
        ex.read_siconos_lcp(ex.write_siconos_lcp(tmp_path / "neg.dat", -np.eye(2), [1, 1]))


def test_siconos_writer_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="storage 'coo'"):
        ex.write_siconos_lcp(tmp_path / "x.dat", np.eye(2), [1, 1], storage="coo")
    with pytest.raises(ValueError, match=r"shape \(2, 2\) and b of length 3"):
        ex.write_siconos_lcp(tmp_path / "x.dat", np.eye(2), [1, 1, 1])


# ---------------------------------------------------------------------- fclib
def delassus(seed: int, nc: int, d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A Delassus W = H' M^-1 H (symmetric PSD), q and mu for ``nc`` contacts."""
    rng = np.random.default_rng(seed)
    H = rng.standard_normal((2 * nc * d, nc * d))
    W = H.T @ H / H.shape[0]
    W = (W + W.T) / 2
    return W, rng.standard_normal(nc * d), rng.uniform(0.1, 0.9, nc)


@pytest.mark.parametrize("storage", ["csc", "csr", "triplet"])
@pytest.mark.parametrize("d", [2, 3])
def test_fclib_round_trip_normal_block(tmp_path, storage, d):
    W, q, mu = delassus(d, 5, d)
    path = ex.write_fclib_local(tmp_path / "p.hdf5", W, q, mu, d, title="Boxes",
                                description="test problem", storage=storage)
    lcp = ex.read_fclib_local(path)
    N = np.arange(5) * d
    np.testing.assert_array_equal(lcp.dense(), W[np.ix_(N, N)])
    np.testing.assert_array_equal(lcp.b, q[N])
    assert lcp.meta["spacedim"] == d and lcp.meta["contacts"] == 5
    assert lcp.meta["title"] == "Boxes" and lcp.meta["description"] == "test problem"
    assert lcp.meta["mu_min"] == mu.min() and lcp.meta["mu_max"] == mu.max()
    res = lcpbench.solve(lcp)
    assert res.verified["kkt_abs"] <= 1e-6


def test_fclib_layout_follows_fclib_write_local(tmp_path):
    W, q, mu = delassus(0, 4, 3)
    W[np.abs(W) < 0.05] = 0.0
    path = ex.write_fclib_local(tmp_path / "p.hdf5", W, q, mu, 3, title="T")
    with h5py.File(path, "r") as f:
        g = f["fclib_local"]
        assert g["spacedim"].dtype == np.int32 and g["spacedim"][()].tolist() == [3]
        Wg = g["W"]
        for key in ("nzmax", "m", "n", "nz"):
            assert Wg[key].shape == (1,) and Wg[key].dtype == np.int32
        assert Wg["nz"][0] == -1 and Wg["m"][0] == 12 and Wg["p"].shape == (13,)
        nnz = int(np.count_nonzero(W))
        assert Wg["nzmax"][0] == nnz and Wg["i"].shape == (nnz,) and Wg["x"].shape == (nnz,)
        C = sp.csc_matrix((Wg["x"][()], Wg["i"][()], Wg["p"][()]), shape=(12, 12))
        np.testing.assert_array_equal(C.toarray(), W)
        np.testing.assert_array_equal(g["vectors/q"][()], q)
        np.testing.assert_array_equal(g["vectors/mu"][()], mu)
        assert g["info/title"][()] == b"T" and g["info/title"].dtype == np.dtype("S2")
    with pytest.raises(ValueError, match="already been written"):
        ex.write_fclib_local(path, W, q, mu, 3)


def test_fclib_symmetry_policy(tmp_path):
    W, q, mu = delassus(1, 4, 3)
    E = np.zeros_like(W)
    E[0, 3] = 1e-8 * np.abs(W).max()       # asymmetry inside the normal block
    p1 = ex.write_fclib_local(tmp_path / "small.hdf5", W + E, q, mu, 3)
    with pytest.warns(RuntimeWarning, match=r"W_nn: symmetrised the matrix .*1\.\d+e-08 relative"):
        lcp = ex.read_fclib_local(p1)
    A = lcp.dense()
    np.testing.assert_array_equal(A, A.T)
    p2 = ex.write_fclib_local(tmp_path / "big.hdf5", W + 1e5 * E, q, mu, 3)
    with pytest.raises(ValueError, match=r"not symmetric .*0\.001\d* relative"):
        ex.read_fclib_local(p2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")        # exactly symmetric: no warning
        ex.read_fclib_local(ex.write_fclib_local(tmp_path / "ok.hdf5", W, q, mu, 3))


def test_fclib_rejects_what_it_cannot_import(tmp_path):
    W, q, mu = delassus(2, 3, 3)
    path = ex.write_fclib_local(tmp_path / "vr.hdf5", W, q, mu, 3)
    with h5py.File(path, "a") as f:
        f.create_group("fclib_local/V")
        f.create_group("fclib_local/R")
    with pytest.raises(ValueError, match="equality constraints"):
        ex.read_fclib_local(path)
    glob = tmp_path / "global.hdf5"
    with h5py.File(glob, "w") as f:
        f.create_group("fclib_global")
    with pytest.raises(ValueError, match="not an FCLIB local problem.*global"):
        ex.read_fclib_local(glob)
    path = ex.write_fclib_local(tmp_path / "noq.hdf5", W, q, mu, 3)
    with h5py.File(path, "a") as f:
        del f["fclib_local/vectors/q"]
    with pytest.raises(ValueError, match="vectors must hold q and mu"):
        ex.read_fclib_local(path)
    (tmp_path / "junk.hdf5").write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="cannot open as HDF5"):
        ex.read_fclib_local(tmp_path / "junk.hdf5")
    with pytest.raises(ValueError, match="divisible by d = 3"):
        ex.write_fclib_local(tmp_path / "x.hdf5", np.eye(4), np.ones(4), np.ones(1), 3)


# ---------------------------------------------------------------------- plugins
def test_plugins(tmp_path):
    folder = tmp_path / "sic"
    folder.mkdir()
    for k in range(2):
        ex.write_siconos_lcp(folder / f"p{k}.dat", *spd(k, 4 + k))
    info = get_problem("siconos")
    lcps = info.func(make_params("siconos", info.params, {"path": str(folder)}))
    assert [lcp.n for lcp in lcps] == [4, 5] and lcps[1].name == "siconos/p1"
    one = info.func(make_params("siconos", info.params, {"path": str(folder / "p0.dat")}))
    np.testing.assert_array_equal(one[0].dense(), spd(0, 4)[0])
    with pytest.raises(FileNotFoundError, match="no such Siconos"):
        info.func(make_params("siconos", info.params, {"path": str(tmp_path / "none.dat")}))
    with pytest.raises(ValueError, match="path is required"):
        make_params("siconos", info.params, {})

    W, q, mu = delassus(3, 4, 3)
    ex.write_fclib_local(tmp_path / "f.hdf5", W, q, mu, 3)
    info = get_problem("fclib")
    lcps = info.func(make_params("fclib", info.params, {"path": str(tmp_path / "f.hdf5")}))
    assert len(lcps) == 1 and lcps[0].n == 4 and lcps[0].meta["family"] == "fclib"
    with pytest.raises(FileNotFoundError, match="no FCLIB files"):
        info.func(make_params("fclib", info.params, {"path": str(folder)}))


def test_fclib_folder_skips_and_lists_what_it_cannot_import(tmp_path):
    """A folder of FCLIB files is read as far as it goes, like a Siconos folder: a global
    problem, one with equality constraints and a non-symmetric one are skipped and listed."""
    W, q, mu = delassus(4, 4, 3)
    ex.write_fclib_local(tmp_path / "a_ok.hdf5", W, q, mu, 3)
    vr = ex.write_fclib_local(tmp_path / "b_vr.hdf5", W, q, mu, 3)
    with h5py.File(vr, "a") as f:
        f.create_group("fclib_local/V")
    with h5py.File(tmp_path / "c_global.hdf5", "w") as f:
        f.create_group("fclib_global")
    E = np.zeros_like(W)
    E[0, 3] = 1e-2 * np.abs(W).max()
    ex.write_fclib_local(tmp_path / "d_nonsym.hdf5", W + E, q, mu, 3)
    ex.write_fclib_local(tmp_path / "e_ok.hdf5", 2 * W, q, mu, 3)
    info = get_problem("fclib")
    with pytest.warns(UserWarning, match=r"skipped 3 of 5 files.*b_vr\.hdf5 \(equality "
                      r"constraints\).*c_global\.hdf5 \(FCLIB global problem\).*d_nonsym"):
        lcps = info.func(make_params("fclib", info.params, {"path": str(tmp_path)}))
    assert [lcp.name for lcp in lcps] == ["fclib/a_ok", "fclib/e_ok"]
    np.testing.assert_array_equal(lcps[1].dense(), 2 * W[np.ix_([0, 3, 6, 9], [0, 3, 6, 9])])
    with pytest.raises(ValueError, match="equality constraints"):     # one file: an error
        info.func(make_params("fclib", info.params, {"path": str(vr)}))


def _fclib(tmp_path: Path, name: str = "p.hdf5") -> Path:
    W, q, mu = delassus(3, 4, 3)
    return ex.write_fclib_local(tmp_path / name, W, q, mu, 3, storage="triplet")


def test_fclib_a_small_file_declaring_a_huge_matrix_is_refused_before_allocating(tmp_path):
    path = _fclib(tmp_path)
    with h5py.File(path, "a") as f:
        for key in ("m", "n"):
            del f[f"fclib_local/W/{key}"]
            f[f"fclib_local/W/{key}"] = np.array([4_000_000_000], dtype=np.int64)
    assert path.stat().st_size < 100_000
    with pytest.raises(ValueError, match="over the read budget") as exc:
        ex.read_fclib_local(path)
    assert "index arrays of an 4000000000 x 4000000000 matrix" in str(exc.value)
    assert "\n" not in str(exc.value)


def test_fclib_an_external_link_is_not_followed(tmp_path):
    path, outside = _fclib(tmp_path), _fclib(tmp_path, "outside.hdf5")
    with h5py.File(path, "a") as f:
        del f["fclib_local/vectors/q"]
        f["fclib_local/vectors/q"] = h5py.ExternalLink(str(outside), "/fclib_local/vectors/q")
    with pytest.raises(ValueError, match="'q' is an external link to .*outside.hdf5"):
        ex.read_fclib_local(path)


def test_fclib_complex_q_is_refused_not_cast(tmp_path):
    path = _fclib(tmp_path)
    with h5py.File(path, "a") as f:
        q = f["fclib_local/vectors/q"][()]
        del f["fclib_local/vectors/q"]
        f["fclib_local/vectors/q"] = q + 1j
    with pytest.raises(ValueError, match=r"complex data \(complex128\)"):
        ex.read_fclib_local(path)


def test_fclib_an_empty_nz_is_a_one_line_error(tmp_path):
    path = _fclib(tmp_path)
    with h5py.File(path, "a") as f:
        del f["fclib_local/W/nz"]
        f["fclib_local/W/nz"] = np.zeros(0, dtype=np.int32)
    with pytest.raises(ValueError) as exc:
        ex.read_fclib_local(path)
    assert str(exc.value) == (f"{path}: /fclib_local/W/nz must hold one integer, got 0 "
                              "value(s); the file is not a valid FCLIB problem")
