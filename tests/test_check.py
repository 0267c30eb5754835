"""``lcpbench check``: regression checks against stored references and E-MVP baselines."""

import json

import numpy as np
import pytest

import lcpbench
from lcpbench.cli import main
from lcpbench.core import registry
from lcpbench.problems import stored as stored_mod
from lcpbench.problems.stored import register_shipped_sets
from lcpbench.sets import SetWriter, read_set, set_info
from lcpbench.workflows.check import check, default_baseline, default_specs, load_baselines
from lcpbench.workflows.generate import generate

SCENE = "lattice:m=3,model=rpy"


@pytest.fixture(scope="module")
def set_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("check") / "mini.h5"
    generate(SCENE, "24-25", path, lows=["self"], progress=False)
    return path


@pytest.fixture
def baseline(tmp_path, set_path, capsys):
    path = tmp_path / "baselines.json"
    code = main(["check", "--set", str(set_path), "--baseline", str(path), "--update-baseline",
                 "--quiet"])
    capsys.readouterr()
    assert code == 0
    return path


def _check(set_path, base, capsys):
    code = main(["check", "--set", str(set_path), "--baseline", str(base), "--quiet"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_default_solvers_are_the_mvp_only_ones():
    specs = default_specs(["p3", "p4"])
    assert "mono-pqn" in specs and "bi-pqn:low=p3" in specs and "bi-pqn:low=p4" in specs
    assert not {"clarabel", "osqp", "proxqp", "pgs", "lemke"} & set(specs)
    assert "bi-pqn" in default_specs(["self"])
    assert not any(s.startswith(("bi-pqn", "multi-pqn")) for s in default_specs([]))
    assert default_baseline().name == "baselines.json"


def test_update_baseline_writes_a_versioned_file_and_check_passes(set_path, baseline, capsys):
    data = json.loads(baseline.read_text())
    assert data["format"] == "lcpbench.baselines" and data["version"] == 1
    assert data["lcpbench_version"] == lcpbench.__version__ and data["updated"]
    entries = data["sets"]["mini"]
    assert set(entries) == set(default_specs(["self"]))
    assert all(v > 0 for v in entries.values())
    code, out, _ = _check(set_path, baseline, capsys)
    assert code == 0
    assert "mono-pqn" in out and "2/2" in out and "REGRESSED" not in out


def test_lowered_baseline_fails_and_names_the_solver(set_path, baseline, capsys):
    data = json.loads(baseline.read_text())
    data["sets"]["mini"]["mono-pqn"] *= 0.5
    baseline.write_text(json.dumps(data))
    code, out, err = _check(set_path, baseline, capsys)
    assert code == 1
    bad = [line for line in out.splitlines() if "REGRESSED" in line]
    assert len(bad) == 1 and "mono-pqn" in bad[0] and "baseline" in bad[0]
    assert "regressed" in err
    # --update-baseline rewrites the entry on purpose; the check passes again
    assert main(["check", "--set", str(set_path), "--baseline", str(baseline),
                 "--update-baseline", "--quiet"]) == 0
    assert json.loads(baseline.read_text())["sets"]["mini"]["mono-pqn"] > \
        data["sets"]["mini"]["mono-pqn"]
    capsys.readouterr()
    assert _check(set_path, baseline, capsys)[0] == 0


def test_tampered_reference_fails(tmp_path, set_path, baseline, capsys):
    info = set_info(set_path)
    bad = tmp_path / "mini.h5"                # same stem: same baseline entries
    with SetWriter(bad, title=info["title"], description=info["description"],
                   generator=info["generator"]) as w:
        for k, lcp in enumerate(read_set(set_path)):
            ref = dict(lcp.reference)
            if k == 1:
                ref["w"] = ref["w"] + 1e-3 * np.linalg.norm(ref["w"]) / np.sqrt(lcp.n)
            low = {name: (op.matmat(np.eye(lcp.n)), op.cost) for name, op in lcp.low.items()}
            w.write_instance(lcp.meta["instance"], lcp.dense(), lcp.b, x0=lcp.x0, low=low,
                             reference=ref)
    code, out, _ = _check(bad, baseline, capsys)
    assert code == 1
    rows = [line for line in out.splitlines() if "REGRESSED" in line]
    assert rows and all("w differs from the reference" in r for r in rows)
    assert any("mono-pqn" in r for r in rows)


def test_missing_baseline_entry_is_new_not_a_failure(set_path, tmp_path, capsys):
    base = tmp_path / "none.json"
    code, out, _ = _check(set_path, base, capsys)
    assert code == 0 and "new" in out and "--update-baseline" in out
    assert not base.exists()
    assert load_baselines(base)["sets"] == {}


def test_bad_inputs_exit_2(tmp_path, set_path, capsys):
    assert main(["check", "--set", "no-such-set", "--quiet"]) == 2
    assert "no-such-set" in capsys.readouterr().err
    junk = tmp_path / "junk.json"
    junk.write_text("{not json")
    assert main(["check", "--set", str(set_path), "--baseline", str(junk), "--quiet"]) == 2
    assert "junk.json" in capsys.readouterr().err
    broken = tmp_path / "broken.h5"
    broken.write_bytes(set_path.read_bytes())
    import h5py
    with h5py.File(broken, "a") as f:
        del f["instances"][list(f["instances"])[0]]["b"]
    assert main(["check", "--set", str(broken), "--quiet"]) == 2
    assert "file checksum mismatch" in capsys.readouterr().err    # found before HDF5 reads
    from lcpbench.sets.seal import seal_image
    broken.write_bytes(seal_image(broken.read_bytes()))     # past it: the dataset checks
    assert main(["check", "--set", str(broken), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'b'" in err and "step00024" in err


def test_shipped_sets_are_problem_plugins(tmp_path, set_path, monkeypatch, capsys):
    data = tmp_path / "data"
    data.mkdir()
    (data / "Lattice_demo.h5").write_bytes(set_path.read_bytes())
    monkeypatch.setattr(stored_mod, "DATA_DIR", data)
    try:
        assert register_shipped_sets() == ["set-lattice-demo"]
        assert main(["list", "problems"]) == 0
        assert "set-lattice-demo" in capsys.readouterr().out
        lcps = registry.get_problem("set-lattice-demo").func(
            registry.make_params("set-lattice-demo",
                                 registry.get_problem("set-lattice-demo").params,
                                 {"instances": "1"}))
        assert len(lcps) == 1 and lcps[0].meta["step"] == 25
        # the stored plugin takes the shipped name too
        assert len(registry.get_problem("stored").func(
            stored_mod.StoredParams(path="Lattice_demo"))) == 2
        rows = check(["Lattice_demo"], baseline=tmp_path / "b.json",
                     solver_specs=["mono-pqn"])
        assert [r.verdict for r in rows] == ["new"]
    finally:
        registry._PROBLEMS.pop("set-lattice-demo", None)
        registry._SETS.pop("Lattice_demo", None)


def test_a_multi_fidelity_solver_without_a_low_runs_once_per_low(tmp_path, capsys):
    """``--solver bi-pqn`` on a set with two lows checks ``bi-pqn:low=A`` and ``low=B`` (as
    ``lcpbench run`` does), and a run that fails shows the solver's own message."""
    path = tmp_path / "two.h5"
    generate(SCENE, "24", path, lows=["self", "rpy"], progress=False)
    base = tmp_path / "b.json"
    code = main(["check", "--set", str(path), "--baseline", str(base), "--solver", "bi-pqn",
                 "--update-baseline", "--quiet"])
    out = capsys.readouterr().out
    assert code == 0
    assert set(json.loads(base.read_text())["sets"]["two"]) == {"bi-pqn:low=rpy",
                                                               "bi-pqn:low=self"}
    assert "bi-pqn:low=rpy" in out and "bi-pqn:low=self" in out and "REGRESSED" not in out
    # a failed run says why (here: a solver whose code raises)
    import misbehave_plugin  # noqa: F401  (registers test-misbehave)

    rows = check([str(path)], baseline=base, solver_specs=["test-misbehave:mode=raise"])
    assert len(rows) == 1 and rows[0].regressed
    assert any("1 of 1 run(s) failed" in p and "boom on purpose" in p
               for p in rows[0].problems), rows[0].problems
