"""Siconos MLCP files are refused by name; a folder import skips and lists what it cannot
solve. Every file here is written by hand, in the layouts of Siconos numerics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lcpbench.problems.external as ex
from lcpbench.cli import main
from lcpbench.core.registry import get_problem
from lcpbench.core.specs import make_params

# mixedLinearComplementarity_printInFile, both storages: flags 1 1, n = 1, m = 1, block rows
# 0 1 2, block flags 0 1, M dense 2 x 2 (column-major), q, then A B C D a b. Read as an LCP
# it starts like a 1 x 1 LCP in sparse-block storage with no blocks: A = 0, b = 1.
MLCP_BOTH = ("1\n1\n1\n1\n0 1 2 \n0 1 \n0\n2\n2\n2\t2\n"
             "  2.0  0.5 \n  0.5  3.0 \n  1.0 \n -2.0 \n"
             "  2.0 \n  3.0 \n  0.5 \n  0.5 \n  1.0 \n -2.0 ")
# the M storage alone, n = 2 equality rows and m = 2 complementarity rows
MLCP_M = ("1\n0\n2\n2\n0 2 4 \n0 1 \n0\n4\n4\n4\t4\n"
          + "\n".join(" ".join(f"{4.0 if i == j else 0.1:.3f}" for j in range(4))
                      for i in range(4))
          + "\n1.0 -1.0 2.0 -2.0 \n")
# the older layout: n m NbLines, then A (1 x 1), B (1 x 1), C, D, a, b
MLCP_OLD = "1 1 2\n4.0\n5.0\n0.5\n0.5\n1.0\n-1.0\n"


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("text", [MLCP_BOTH, MLCP_M, MLCP_OLD], ids=["both", "M", "old"])
def test_an_mlcp_file_is_refused_naming_the_file(tmp_path, text):
    path = write(tmp_path / "circuit_mlcp.dat", text)
    with pytest.raises(ex.UnsupportedProblem, match="Siconos MLCP file") as err:
        ex.read_siconos_lcp(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)
    assert err.value.reason == "MLCP"


def test_small_lcps_that_start_like_an_mlcp_are_still_read(tmp_path):
    zero = ex.read_siconos_lcp(write(tmp_path / "zero.dat", "1\n1\n1\n1\n0\n5.0\n"))
    assert zero.n == 1 and zero.dense()[0, 0] == 0.0 and zero.b[0] == 5.0
    one = ex.read_siconos_lcp(write(tmp_path / "one.dat", "1\n0\n1\n1\n1\t1\n2.0\n-1.0\n\n"
                                                          "Remark 1.2: x = 0.5 solves it\n"))
    assert one.dense()[0, 0] == 2.0 and one.b[0] == -1.0
    numbered = ex.read_siconos_lcp(write(tmp_path / "numbered.dat", "1\n0\n1\n1\n1\t1\n2.0 "
                                                                   "-1.0 2. remark\n"))
    assert numbered.b[0] == -1.0


def test_numbers_after_q_that_are_no_mlcp_are_refused(tmp_path):
    path = write(tmp_path / "extra.dat", "2\n0\n2\n2\n2\t2\n2 0\n0 2\n-1 -1\n7 7 7\n")
    with pytest.raises(ex.SiconosFormatError, match=r"extra.dat, line 9: a number \(7\) "
                                                    r"follows the 2 entries of q"):
        ex.read_siconos_lcp(path)


def _collection(folder: Path) -> None:
    folder.mkdir()
    ex.write_siconos_lcp(folder / "a_spd.dat", np.array([[2.0, 1.0], [1.0, 3.0]]), [-1.0, 1.0])
    ex.write_siconos_lcp(folder / "b_nonsym.dat", np.array([[2.0, 1.0], [0.0, 2.0]]),
                         [-1.0, 1.0])
    write(folder / "c_mlcp.dat", MLCP_BOTH)
    ex.write_siconos_lcp(folder / "d_indefinite.dat", np.array([[1.0, 2.0], [2.0, 1.0]]),
                         [-1.0, 1.0])
    ex.write_siconos_lcp(folder / "e_spd.dat", 3 * np.eye(3), [-1.0, 0.0, 1.0])


def test_a_folder_import_runs_what_it_can_and_lists_the_rest(tmp_path):
    folder = tmp_path / "siconos"
    _collection(folder)
    info = get_problem("siconos")
    with pytest.warns(UserWarning) as caught:
        lcps = info.func(make_params("siconos", info.params, {"path": str(folder)}))
    assert [lcp.name for lcp in lcps] == ["siconos/a_spd", "siconos/e_spd"]
    [notice] = [str(w.message) for w in caught]
    assert notice == (f"siconos:path={folder}: skipped 3 of 5 files, problems lcpbench does "
                      "not solve: b_nonsym.dat (not symmetric, 0.5 relative), c_mlcp.dat "
                      "(MLCP), d_indefinite.dat (not positive semidefinite)")
    with pytest.raises(ex.UnsupportedProblem, match="b_nonsym.dat: Siconos LCP: the matrix "
                                                    "is not symmetric"):
        info.func(make_params("siconos", info.params, {"path": str(folder / "b_nonsym.dat")}))


def test_a_folder_with_nothing_lcpbench_solves_is_an_error(tmp_path):
    folder = tmp_path / "mlcps"
    folder.mkdir()
    write(folder / "one_mlcp.dat", MLCP_BOTH)
    write(folder / "two_mlcp.dat", MLCP_M)
    info = get_problem("siconos")
    with pytest.raises(ValueError, match=r"none of the 2 file\(s\) is an LCP lcpbench solves "
                                         r".*: one_mlcp.dat \(MLCP\), two_mlcp.dat \(MLCP\)"):
        info.func(make_params("siconos", info.params, {"path": str(folder)}))


def test_run_on_the_collection_goes_through_the_files_it_can(tmp_path, capsys):
    folder = tmp_path / "siconos"
    _collection(folder)
    out = tmp_path / "store"
    with pytest.warns(UserWarning, match="skipped 3 of 5 files"):
        assert main(["run", "--solver", "bb-pgd", "--problem", f"siconos:path={folder}",
                     "--out", str(out), "--quiet", "--no-report"]) == 0
    assert (out / "results.csv").read_text().count("\n") == 3      # header and two runs
    capsys.readouterr()
    assert main(["solve", "--solver", "bb-pgd", "--problem",
                 f"siconos:path={folder / 'c_mlcp.dat'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("lcpbench solve: error: ") and "c_mlcp.dat: a Siconos MLCP" in err
    assert "\n" not in err
