"""The fidelity study of stored sets: table, Cottle's c(A), heatmaps and the report section."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from lcpbench import LCP, Operator
from lcpbench.problems.suspension.scene import LATTICE_AXES, LatticeParams
from lcpbench.report.fidelity import cottle_heatmap_svg, fidelity_section, heatmap_svg, heatmaps
from lcpbench.sets import SetWriter
from lcpbench.workflows.cottle import cottle_bounds, cottle_c
from lcpbench.workflows.fidelity import fidelity_table, stored_set_specs, table_columns

N = 20
# Diagonal positive high-fidelity matrices: c(A) = min_i A_ii exactly.
DIAGS = [np.linspace(1.0, 3.0, N), np.linspace(2.0, 5.0, N), np.linspace(0.5, 4.0, N)]
C_EXACT = [1.0, 2.0, 0.5]
# name -> (knobs, errors ||A_low - A||_inf per instance, cost ratios t_low/t_high per instance)
LOWS = {
    "p3e6": ({"p": 3, "eps_gmres": 1e-6, "model": "bim"}, [0.8, 2.5, 0.3], [0.05, 0.04, 0.05]),
    "p3e8": ({"p": 3, "eps_gmres": 1e-8, "model": "bim"}, [0.9, 1.5, 0.6], [0.06, 0.06, 0.08]),
    "p4e6": ({"p": 4, "eps_gmres": 1e-6, "model": "bim"}, [1e-2, 3e-3, 2e-2], [0.1, 0.125, 0.1]),
    "p4e8": ({"p": 4, "eps_gmres": 1e-8, "model": "bim"}, [1e-3, 4e-4, 1e-3], [0.2, 0.25, 0.2]),
    # as `lcpbench generate` writes it: the high fidelity's knobs on another model
    "rpy": ({"model": "rpy", "p": 8, "eps_gmres": 1e-8}, [1.2, 0.15, 0.7], [0.001, 0.002, 0.001]),
    "self": ({}, [5.0, 5.0, 5.0], [1e-4, 1e-4, 1e-4]),
}


def _perturbation(rng, n: int, err: float) -> np.ndarray:
    """A symmetric matrix with induced infinity norm exactly ``err`` (up to rounding)."""
    R = rng.standard_normal((n, n))
    R = R + R.T
    return err * R / np.abs(R).sum(axis=1).max()


@pytest.fixture(scope="module")
def stored_set(tmp_path_factory):
    path = tmp_path_factory.mktemp("fid") / "fid.h5"
    rng = np.random.default_rng(7)
    with SetWriter(path, title="fidelity test", description="diagonal A, known errors",
                   generator="tests/test_fidelity.py") as w:
        w.file.attrs["scene"] = "lattice:m=2,model=bim"     # whose knobs span the grid
        for k, d in enumerate(DIAGS):
            A = np.diag(d)
            low = {name: (A + _perturbation(rng, N, errs[k]), ratios[k], knobs)
                   for name, (knobs, errs, ratios) in LOWS.items()}
            w.write_instance(str(k), A, rng.standard_normal(N), low=low)
    return path


@pytest.fixture(scope="module")
def table(stored_set):
    return fidelity_table(stored_set)


# ---------------------------------------------------------------------- table
def test_table_columns_match_hand_computed_values(table) -> None:
    assert list(table.columns) == table_columns(LATTICE_AXES)
    assert table.attrs["axes"] == LATTICE_AXES
    assert len(table) == len(LOWS)
    for name, (knobs, errs, ratios) in LOWS.items():
        row = table[table["fidelity"] == name].iloc[0]
        assert row["model"] == knobs.get("model", "")
        if "p" in knobs:
            assert row["p"] == knobs["p"] and row["eps_gmres"] == knobs["eps_gmres"]
        else:
            assert math.isnan(row["p"]) and math.isnan(row["eps_gmres"])
        assert row["instances"] == 3
        assert row["log10_max_err"] == pytest.approx(math.log10(max(errs)), abs=1e-12)
        assert row["median_low_per_high"] == pytest.approx(np.median(1.0 / np.array(ratios)))
        share = np.mean([e < c for e, c in zip(errs, C_EXACT)])
        assert row["share_err_below_c"] == pytest.approx(share)
        # lambda_min / n of a diagonal A is min(diag) / n
        sure = np.mean([e < c / N for e, c in zip(errs, C_EXACT)])
        assert row["share_err_below_lower"] == pytest.approx(sure)


def test_table_hand_values_spelled_out(table) -> None:
    row = table.set_index("fidelity")
    assert row.loc["p3e6", "share_err_below_c"] == pytest.approx(2 / 3)   # 0.8<1, 0.3<0.5
    assert row.loc["p3e8", "share_err_below_c"] == pytest.approx(2 / 3)   # 0.6 > 0.5
    assert row.loc["p4e6", "share_err_below_c"] == 1.0
    assert row.loc["rpy", "share_err_below_c"] == pytest.approx(1 / 3)    # only 0.15 < 2
    assert row.loc["p4e6", "median_low_per_high"] == pytest.approx(10.0)
    assert row.loc["rpy", "median_low_per_high"] == pytest.approx(1000.0)
    assert row.loc["p4e8", "log10_max_err"] == pytest.approx(-3.0)
    # c / 20 = 0.05, 0.1, 0.025: p4e6 (0.01, 0.003, 0.02) is certainly inside everywhere
    assert row.loc["p4e6", "share_err_below_lower"] == 1.0
    assert row.loc["p3e6", "share_err_below_lower"] == 0.0


def test_table_subset_of_instances_and_given_c(stored_set) -> None:
    t = fidelity_table(stored_set, instances=["1"], c_values=[0.5])
    row = t.set_index("fidelity")
    assert (t["instances"] == 1).all()
    assert row.loc["rpy", "log10_max_err"] == pytest.approx(math.log10(0.15))
    assert row.loc["p3e8", "share_err_below_c"] == 0.0    # 1.5 >= 0.5
    assert row.loc["rpy", "share_err_below_c"] == 1.0     # 0.15 < 0.5
    with pytest.raises(ValueError, match="one c\\(A\\) per instance"):
        fidelity_table(stored_set, c_values=[1.0])


def test_table_from_lcps_uses_operator_costs() -> None:
    A = np.diag([1.0, 2.0, 4.0])
    E = np.array([[0.0, 0.1, 0.1], [0.1, 0.0, 0.0], [0.1, 0.0, 0.0]])   # ||E||_inf = 0.2
    lcp = LCP(Operator(A, cost=2.0), np.ones(3), low={"cheap": Operator(A + E, cost=0.5)})
    t = fidelity_table([lcp])
    assert t.loc[0, "fidelity"] == "cheap"
    assert t.loc[0, "log10_max_err"] == pytest.approx(math.log10(0.2))
    assert t.loc[0, "median_low_per_high"] == pytest.approx(4.0)
    assert t.loc[0, "share_err_below_c"] == 1.0


# ---------------------------------------------------------------------- c(A)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cottle_c_of_diagonal_is_min_diagonal(seed) -> None:
    d = np.random.default_rng(seed).uniform(0.1, 5.0, size=9)
    assert cottle_c(np.diag(d)) == pytest.approx(d.min(), rel=1e-12)


def _brute_force_2x2(A: np.ndarray, m: int = 200_001) -> float:
    t = np.linspace(-1.0, 1.0, m)
    best = math.inf
    for Z in (np.vstack([np.ones(m), t]), np.vstack([t, np.ones(m)])):
        best = min(best, float(np.max(Z * (A @ Z), axis=0).min()))
    return best


@pytest.mark.parametrize("A", [
    [[2.0, 1.0], [1.0, 1.0]],          # SPD
    [[1.0, 0.9], [0.9, 1.0]],          # SPD, nearly singular
    [[1.0, 2.0], [-1.5, 0.5]],         # non-symmetric, positive definite symmetric part
    [[1.0, 3.0], [3.0, 1.0]],          # indefinite: c(A) < 0
    [[0.2, -0.7], [0.1, 3.0]],
])
def test_cottle_c_2x2_matches_brute_force(A) -> None:
    A = np.asarray(A)
    brute = _brute_force_2x2(A)
    est = cottle_c(A)
    # The grid minimum is itself an upper bound of c(A): the estimate must be as good,
    # and cannot be lower than the grid by more than the grid's resolution.
    assert est <= brute + 1e-9
    assert est >= brute - 1e-4 * max(1.0, np.abs(A).max())


def test_cottle_c_3x3_matches_brute_force_on_faces() -> None:
    rng = np.random.default_rng(3)
    B = rng.standard_normal((3, 3))
    A = B @ B.T + 0.1 * np.eye(3)
    t = np.linspace(-1.0, 1.0, 801)
    U, V = (g.ravel() for g in np.meshgrid(t, t))
    brute = math.inf
    for i in range(3):
        Z = np.empty((3, U.size))
        j, k = [m for m in range(3) if m != i]
        Z[i], Z[j], Z[k] = 1.0, U, V
        brute = min(brute, float(np.max(Z * (A @ Z), axis=0).min()))
    est = cottle_c(A)
    assert est <= brute + 1e-9
    assert est >= brute - 2e-2 * np.abs(A).max()


def test_cottle_bounds_bracket_for_spd() -> None:
    rng = np.random.default_rng(4)
    B = rng.standard_normal((15, 15))
    A = B @ B.T / 15 + 0.2 * np.eye(15)
    b = cottle_bounds(A)
    lam = np.linalg.eigvalsh(A)[0]
    assert b.lambda_min == pytest.approx(lam)
    assert b.lower == pytest.approx(lam / 15)
    assert b.lower <= b.estimate <= b.lambda_min + 1e-12
    z = b.z
    assert np.max(np.abs(z)) == pytest.approx(1.0, abs=0.0)
    assert b.estimate == pytest.approx(float(np.max(z * (A @ z))), rel=1e-12)
    assert b.starts == 15 + 8


@pytest.mark.parametrize("bad, match", [
    (np.ones((2, 3)), "square"),
    (np.array([[1.0, np.nan], [0.0, 1.0]]), "non-finite"),
])
def test_cottle_c_rejects_bad_input(bad, match) -> None:
    with pytest.raises(ValueError, match=match):
        cottle_c(bad)


# ---------------------------------------------------------------------- figures
def test_heatmap_svg_is_valid_xml_with_two_heatmaps(table) -> None:
    svg = heatmap_svg(table)
    root = ET.fromstring(svg)
    ns = "{http://www.w3.org/2000/svg}"
    assert root.tag == ns + "svg"
    images = root.findall(f".//{ns}image")
    assert len(images) == 2 + 2        # two heatmaps and their two colour bars
    axes = [g for g in root.iter(ns + "g") if g.get("id", "").startswith("axes_")]
    assert len(axes) == 4
    assert "log10 max" in svg and "low MVPs per high MVP" in svg
    ET.fromstring(cottle_heatmap_svg(table))


def test_heatmaps_list_fidelities_off_the_grid(table) -> None:
    out = heatmaps(table)
    assert out.count("<svg") == 1
    listed = out.split("</svg>")[1]
    assert "rpy" in listed and "self" in listed and "p4e6" not in listed
    assert heatmap_svg(table[table["fidelity"].isin(["rpy", "self"])]) == ""


# ---------------------------------------------------------------------- report
def test_report_of_a_stored_set_run_has_the_fidelity_section(stored_set, tmp_path) -> None:
    from lcpbench.cli import main

    out = tmp_path / "run"
    assert main(["run", "--problem", f"stored:path={stored_set},instances=0-1",
                 "--solver", "bb-pgd", "--out", str(out)]) == 0
    assert main(["report", str(out)]) == 0
    page = (out / "report.html").read_text()
    assert "Fidelity study of the stored sets" in page
    assert "(file fid.h5): 2 selected instance(s)" in page
    assert "share_err_below_c" in page and "p4e8" in page
    import pandas as pd

    specs = stored_set_specs(pd.read_csv(out / "results.csv"))
    assert [(p.name, ids) for p, ids in specs] == [("fid.h5", ["0", "1"])]


def test_fidelity_section_is_empty_without_low_fidelities(tmp_path) -> None:
    path = tmp_path / "nolow.h5"
    with SetWriter(path, title="t", description="d", generator="g") as w:
        w.write_instance("0", np.eye(3), np.ones(3))
    assert fidelity_section([path]) == ""
    assert stored_set_specs(None) == []


def test_cottle_c_restores_blas_threads() -> None:
    from threadpoolctl import threadpool_info

    before = [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]
    cottle_c(np.diag([2.0, 1.0, 3.0]) + 0.1)
    assert [lib["num_threads"] for lib in threadpool_info()
            if lib["user_api"] == "blas"] == before


def _knob_set(path, scene, lows):
    """A one-instance set whose lows carry the given knobs, from scene ``scene``."""
    rng = np.random.default_rng(3)
    A = np.diag(DIAGS[0])
    with SetWriter(path, title="t", description="d", generator="tests") as w:
        if scene:
            w.file.attrs["scene"] = scene
        w.write_instance("0", A, rng.standard_normal(N),
                         low={name: (A + _perturbation(rng, N, 0.1 * (k + 1)), 0.1, knobs)
                              for k, (name, knobs) in enumerate(lows.items())})
    return path


def test_the_grid_is_spanned_by_the_knobs_the_scene_declares(tmp_path, monkeypatch) -> None:
    """The framework names no knob: a scene that declares other axes gets its own grid,
    labelled with its knob names, and a set without a known scene gets no grid at all."""
    from lcpbench.core import registry
    from lcpbench.core.registry import register_scene
    from lcpbench.core.scene import FidelityAxes

    # registered for this test only: the registry is restored afterwards
    monkeypatch.setattr(registry, "_SCENES", dict(registry.scenes()))

    axes = FidelityAxes(rows="levels", columns="tol", model_knob="kind",
                        grid_models=("multigrid",))

    @register_scene("test-knob-scene", LatticeParams)      # its parameters do not matter
    def _make(p):
        """A scene that only declares its fidelity axes."""
        return type("S", (), {"fidelity_axes": axes})()

    lows = {"mg2": {"levels": 2, "tol": 1e-3, "kind": "multigrid"},
            "mg3": {"levels": 3, "tol": 1e-3, "kind": "multigrid"},
            "mg3t": {"levels": 3, "tol": 1e-6, "kind": "multigrid"},
            "jac": {"levels": 1, "tol": 1e-3, "kind": "jacobi"}}
    t = fidelity_table(_knob_set(tmp_path / "k.h5", "test-knob-scene:low=[]", lows))
    assert list(t.columns) == table_columns(axes)
    assert t.set_index("fidelity").loc["mg3t", "tol"] == 1e-6
    svg = heatmap_svg(t)
    assert ">levels<" in svg and ">tol<" in svg and ">eps_gmres<" not in svg
    out = heatmaps(t)
    assert "(levels, tol) grid" in out and "jac" in out.split("</svg>")[1]

    bare = fidelity_table(_knob_set(tmp_path / "b.h5", "", lows))
    assert list(bare.columns) == table_columns(None) and "levels" not in bare.columns
    assert heatmap_svg(bare) == "" and "mg2" in heatmaps(bare)
