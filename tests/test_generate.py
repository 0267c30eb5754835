"""``lcpbench generate``: dense stored sets from the live lattice scene (model rpy)."""

import h5py
import numpy as np
import pytest

from lcpbench.cli import main
from lcpbench.core.operator import dense_uncounted
from lcpbench.core.registry import make_scene
from lcpbench.sets import instance_ids, read_instance, read_set, set_info
from lcpbench.sets.seal import seal_image
from lcpbench.workflows.generate import generate, instance_id, parse_lows, parse_steps

SCENE = "lattice:m=3,model=rpy"
STEPS = "20-21"          # the cluster has formed: n ~ 45 contacts, many active


def _gen(path, steps=STEPS, lows=("self",)):
    args = ["generate", "--scene", SCENE, "--steps", steps, "--out", str(path), "--quiet"]
    for low in lows:
        args += ["--low", low]
    return main(args)


@pytest.fixture(scope="module")
def small_set(tmp_path_factory):
    path = tmp_path_factory.mktemp("gen") / "small.h5"
    assert _gen(path) == 0
    return path


def test_parse_steps_and_lows(tmp_path):
    assert parse_steps("31-33,40") == [31, 32, 33, 40]
    assert parse_steps("5") == [5]
    with pytest.raises(ValueError, match="reversed"):
        parse_steps("9-3")
    with pytest.raises(ValueError, match="cannot parse"):
        parse_steps("a-b")
    assert parse_lows(["p=3,4", "rpy"], [1e-6, 1e-8]) == ["p3e6", "p3e8", "p4e6", "p4e8", "rpy"]
    assert parse_lows(["p=4"]) == ["p4"]
    assert parse_lows(["self,rpy", "rpy"]) == ["self", "rpy"]
    with pytest.raises(ValueError, match="powers of ten"):
        parse_lows(["p=4"], [3e-7])
    # the scene validates the names, before any step is simulated or anything is written
    out = tmp_path / "never.h5"
    with pytest.raises(ValueError, match="unknown fidelity"):
        generate("lattice:m=2,model=rpy", "0", out, lows=parse_lows(["fast"]), progress=False)
    assert not out.exists()


def test_layout_provenance_and_costs(small_set):
    info = set_info(small_set)
    assert info["ids"] == [instance_id(20), instance_id(21)]
    for key in ("generator", "created", "lcpbench_version", "title", "description", "scene",
                "scene_params", "versions", "solver", "name"):
        assert info[key], key
    assert "--steps 20-21" in info["generator"] and info["scene"] == SCENE
    with h5py.File(small_set, "r") as f:
        g = f["instances"][instance_id(20)]
        assert {"A", "b", "low", "reference"} <= set(g.keys())
        assert "sha256:A" in g.attrs and "sha256:low/self/A" in g.attrs
        assert g.attrs["step"] == 20 and g.attrs["M"] == 27
        assert g.attrs["t_mvp_high"] > 0
        la = g["low/self"].attrs
        assert la["cost_ratio"] > 0 and la["t_mvp"] > 0 and la["model"] == "self"
        assert np.isclose(la["cost_ratio"], la["t_mvp"] / g.attrs["t_mvp_high"])
    lcp = read_instance(small_set, instance_id(21))
    assert lcp.n > 20 and lcp.low["self"].cost > 0
    assert lcp.reference["accepted"]
    x, w = lcp.reference["x"], lcp.reference["w"]
    assert np.count_nonzero(x) > 0                      # contacts are active
    np.testing.assert_allclose(w, lcp.dense() @ x + lcp.b, atol=1e-9 * np.abs(lcp.b).max())


def test_A_is_the_dense_DMD_of_the_simulated_step(small_set):
    scene = make_scene(SCENE + ",low=[self]")
    while scene.step_index < 21:
        scene.step("mono-pqn")
    problem = scene.build()
    A = dense_uncounted(problem.lcp.A)
    A_self = dense_uncounted(problem.lcp.low["self"])
    stored = read_instance(small_set, instance_id(21))
    scale = np.abs(A).max()
    np.testing.assert_allclose(stored.dense(), A, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(stored.low["self"].matmat(np.eye(stored.n)), A_self,
                               rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(stored.b, problem.lcp.b, rtol=1e-13, atol=0)


def test_resume_keeps_instances_and_appends(tmp_path, small_set, capsys):
    path = tmp_path / "resume.h5"
    path.write_bytes(small_set.read_bytes())
    with h5py.File(path, "r") as f:
        before = f["instances"][instance_id(20)]["A"][()]
    assert _gen(path, steps="20-23") == 0
    out = capsys.readouterr().out
    assert "wrote 2 instance(s), kept 2" in out
    assert instance_ids(path) == [instance_id(k) for k in (20, 21, 22, 23)]
    with h5py.File(path, "r") as f:
        np.testing.assert_array_equal(f["instances"][instance_id(20)]["A"][()], before)
    # a one-shot run writes the same instances (the simulation is deterministic)
    fresh = generate(SCENE, "22-23", tmp_path / "fresh.h5", lows=["self"], progress=False)
    assert fresh.written == [instance_id(22), instance_id(23)] and fresh.simulated == 24
    a, b = read_set(path, [instance_id(23)])[0], read_set(tmp_path / "fresh.h5")[1]
    np.testing.assert_array_equal(a.dense(), b.dense())
    np.testing.assert_array_equal(a.b, b.b)
    assert len(read_set(path)) == 4


def test_resume_with_other_settings_is_refused(tmp_path, small_set, capsys):
    path = tmp_path / "other.h5"
    path.write_bytes(small_set.read_bytes())
    assert _gen(path, lows=("rpy",)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "lows" in err and "--out" in err


def test_corrupted_file_names_instance_and_dataset(tmp_path, small_set, capsys):
    path = tmp_path / "bad.h5"
    path.write_bytes(small_set.read_bytes())
    with h5py.File(path, "a") as f:
        f["instances"][instance_id(21)]["low/self/A"][0, 0] += 1.0
    path.write_bytes(seal_image(path.read_bytes()))      # past the whole-file checksum
    assert _gen(path) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert instance_id(21) in err and "low/self/A" in err and "checksum" in err
    assert "Traceback" not in err


def test_truncated_file_is_a_one_line_error(tmp_path, small_set, capsys):
    path = tmp_path / "cut.h5"
    data = small_set.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert _gen(path) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "cut.h5" in err


def test_usage_errors_exit_2(tmp_path, capsys):
    assert main(["generate", "--scene", SCENE + ",low=[self]", "--steps", "1",
                 "--out", str(tmp_path / "x.h5"), "--quiet"]) == 2
    assert "--low" in capsys.readouterr().err
    assert main(["generate", "--scene", SCENE, "--steps", "3-1",
                 "--out", str(tmp_path / "x.h5"), "--quiet"]) == 2
    assert "reversed" in capsys.readouterr().err
    assert main(["generate", "--scene", SCENE, "--steps", "1", "--solver", "bi-pqn",
                 "--out", str(tmp_path / "x.h5"), "--quiet"]) == 2
    assert "needs low-fidelity" in capsys.readouterr().err


def test_split_low_is_stored_with_its_knobs(tmp_path):
    """A distance-split low (p<k>f<q>e<j>) of the boundary-integral scene is generated, stored
    with its far-field degree and read back with its measured cost."""
    out = tmp_path / "split.h5"
    s = generate("paper-lattice:m=2,model=bim,p=3", "3", out,
                 lows=["p3f1e3", "p2e6", "p3f1r1e3"], progress=False)
    assert len(s.written) == 1
    iid = instance_ids(out)[0]
    with h5py.File(out, "r") as f:
        la = f[f"instances/{iid}/low/p3f1e3"].attrs
        assert int(la["far_degree"]) == 1 and int(la["p"]) == 3 and float(la["eps_gmres"]) == 1e-3
        ratio = float(la["cost_ratio"])
        assert 0 < ratio
        A = f[f"instances/{iid}/A"][()]
        L = f[f"instances/{iid}/low/p3f1e3/A"][()]
        L2 = f[f"instances/{iid}/low/p2e6/A"][()]
        # the compressed split low: stored with its cut, and coarser than the uncut one
        lr = f[f"instances/{iid}/low/p3f1r1e3"].attrs
        assert float(lr["rank_tol"]) == 0.1 and int(lr["far_degree"]) == 1
        Lr = f[f"instances/{iid}/low/p3f1r1e3/A"][()]
    assert A.shape[0] >= 1
    assert np.linalg.norm(Lr - L) > 1e-6 * np.linalg.norm(L)
    err = np.linalg.norm(L - A) / np.linalg.norm(A)
    assert 0 < err < 0.5
    lcp = read_instance(out, iid)
    assert set(lcp.low) == {"p3f1e3", "p2e6", "p3f1r1e3"}
    assert np.isclose(lcp.low["p3f1e3"].cost, ratio)
    assert np.linalg.norm(L2 - A) > 0


def test_resume_starts_from_the_checkpoint_not_step_0(tmp_path, capsys):
    """An interrupted run resumes from the state after its last simulated step."""
    from lcpbench.workflows.generate import checkpoint_file

    path = tmp_path / "ckpt.h5"
    first = generate(SCENE, "20", path, lows=["self"], progress=False)
    assert first.simulated == 21 and checkpoint_file(path).exists()
    more = generate(SCENE, "20-22", path, lows=["self"], progress=False)
    assert more.kept == [instance_id(20)] and more.written == [instance_id(21), instance_id(22)]
    assert more.simulated == 2                      # steps 21 and 22 only, not 0-22
    generate(SCENE, "21-22", tmp_path / "fresh.h5", lows=["self"], progress=False)
    for iid in (instance_id(21), instance_id(22)):
        a, b = read_instance(path, iid), read_instance(tmp_path / "fresh.h5", iid)
        np.testing.assert_array_equal(a.dense(), b.dense())
        np.testing.assert_array_equal(a.b, b.b)
        np.testing.assert_array_equal(a.x0, b.x0)   # the carried warm start survived too


def test_a_checkpoint_that_cannot_serve_is_set_aside_with_a_reason(tmp_path, capsys):
    from lcpbench.workflows.generate import checkpoint_file

    path = tmp_path / "late.h5"
    generate(SCENE, "21", path, lows=["self"], progress=False)
    capsys.readouterr()
    # step 20 lies before the checkpoint (after step 21): simulate from 0, say why
    back = generate(SCENE, "20-21", path, lows=["self"], progress=False)
    err = capsys.readouterr().err
    assert back.simulated == 21 and back.written == [instance_id(20)]
    assert "not resuming" in err and "step 20 still has to be stored" in err
    # another tolerance: the checkpoint's trajectory is not this run's
    other = tmp_path / "tol.h5"
    generate(SCENE, "20", other, lows=["self"], progress=False)
    capsys.readouterr()
    again = generate(SCENE, "20-21", other, lows=["self"], tol=1e-6, progress=False)
    assert again.simulated == 22 and "other settings (tol)" in capsys.readouterr().err
    # an unreadable checkpoint is named and set aside, never a crash
    checkpoint_file(other).write_bytes(b"not a checkpoint")
    last = generate(SCENE, "20-22", other, lows=["self"], tol=1e-6, progress=False)
    assert last.simulated == 23 and last.written == [instance_id(22)]
    assert checkpoint_file(other).name in capsys.readouterr().err


def test_implicit_matrices_are_formed_column_by_column_under_a_bar(monkeypatch, capsys):
    """An implicit operator is formed from its columns a few at a time (the same matrix
    as one product with the identity), with a progress bar in columns."""
    from lcpbench.core.operator import Operator
    from lcpbench.workflows import generate as gen

    B = np.random.default_rng(3).standard_normal((11, 11))
    calls = []

    def mv(v):
        calls.append(v.copy())
        return B @ v

    op = Operator(_matvec_operator(mv, 11), cost=1.0)
    monkeypatch.setattr(gen, "_PROGRESS_DELAY", 0.0)
    A, asym = gen._dense_sym(op, "step 3: high", progress=True)
    np.testing.assert_allclose(A, 0.5 * (B + B.T), rtol=1e-14)
    assert asym == pytest.approx(np.max(np.abs(B - B.T)) / np.max(np.abs(B)))
    # every column of the identity, in order, once
    assert len(calls) == 11
    assert all(np.array_equal(np.ravel(v), np.eye(11)[:, j]) for j, v in enumerate(calls))
    err = capsys.readouterr().err
    assert "step 3: high" in err and "/11" in err and "column" in err
    # quiet: no bar
    gen._dense_sym(op, "step 3: high", progress=False)
    assert "step 3" not in capsys.readouterr().err


def _matvec_operator(mv, n):
    from scipy.sparse.linalg import LinearOperator

    return LinearOperator((n, n), matvec=mv, dtype=np.float64)
