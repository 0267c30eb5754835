"""Contacts, the contact LCP, the lattice scene and ``lcpbench simulate``."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import scipy.sparse as sp

from lcpbench.cli import main
from lcpbench.core.api import run_solver
from lcpbench.core.registry import make_scene
from lcpbench.problems.suspension.contacts import Contacts, max_overlap
from lcpbench.problems.suspension.fidelity import parse_fidelity
from lcpbench.problems.suspension.problem import build_contact_problem, contact_lcp
from lcpbench.problems.suspension.scene import LatticeParams, LatticeScene, bisect_scale
from lcpbench.report.tables import online_table
from lcpbench.workflows.simulate import simulate


def _has_rpy() -> bool:
    try:
        from lcpbench.problems.suspension import mobility  # noqa: F401
    except ImportError:
        return False
    return True


#: The interacting model the tests run on: RPY once the backend provides it, else
#: the block-diagonal one-sphere mobility (model "self").
MODEL = "rpy" if _has_rpy() else "self"


def coupled_mobility(seed: int = 0):
    """A dense, symmetric positive definite stand-in for an interacting mobility."""
    def make(centers, radii):
        n = 6 * len(centers)
        G = np.random.default_rng(seed).normal(size=(n, n))
        return G @ G.T / n + np.eye(n)
    return make


def self_mobility_dense(radii, mu=1.0):
    t = 1.0 / (6 * np.pi * mu * np.asarray(radii))
    w = 1.0 / (8 * np.pi * mu * np.asarray(radii) ** 3)
    return np.diag(np.column_stack([t, t, t, w, w, w]).ravel())


def random_cluster(M=8, seed=1):
    scene = LatticeScene(2 if M == 8 else 3, model="self", seed=seed)
    return scene.centers, scene.radii


# ----------------------------------------------------------------------------- contacts


def test_d_sign_convention_two_spheres():
    c = np.array([[0.0, 0, 0], [2.1, 0, 0]])
    con = Contacts.from_configuration(c, 1.0, 0.3)
    assert con.n == 1 and con.pair_ids() == [(0, 1)]
    np.testing.assert_allclose(con.gaps, [0.1])
    np.testing.assert_allclose(con.normals, [[1.0, 0, 0]])
    D = con.D.toarray()
    np.testing.assert_allclose(D[:, 0], [-1, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0])
    # a positive force pushes the spheres apart: the gap grows at rate D' M D x > 0
    U = self_mobility_dense([1.0, 1.0]) @ (D @ np.array([1.0]))
    assert U[0] < 0 < U[6]
    assert float(D[:, 0] @ U) > 0


def test_d_structure_and_first_order_gap():
    c, r = random_cluster(27)
    con = Contacts.from_configuration(c, r, 0.3)
    assert con.n > 0 and sp.issparse(con.D) and con.D.shape == (6 * 27, con.n)
    D = con.D.toarray()
    assert np.all(np.count_nonzero(D, axis=0) <= 6)
    tor = D.reshape(27, 6, con.n)[:, 3:, :]
    assert not np.any(tor)                                   # frictionless: no torques
    np.testing.assert_allclose(D.reshape(27, 6, con.n)[:, :3, :].sum(axis=0), 0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(D, axis=0), np.sqrt(2))
    # a rigid translation leaves every gap unchanged
    Ut = np.tile([0.3, -0.2, 0.5, 0, 0, 0], 27)
    np.testing.assert_allclose(D.T @ Ut, 0, atol=1e-14)
    # D' U is the rate of change of the gaps (finite difference)
    U = np.random.default_rng(3).normal(size=6 * 27)
    h = 1e-7
    moved = c + h * U.reshape(27, 6)[:, :3]
    d = moved[con.pairs[:, 1]] - moved[con.pairs[:, 0]]
    new = np.linalg.norm(d, axis=1) - r[con.pairs[:, 0]] - r[con.pairs[:, 1]]
    np.testing.assert_allclose((new - con.gaps) / h, D.T @ U, rtol=1e-5, atol=1e-5)


def test_pairs_respect_delta_and_are_sorted():
    c, r = random_cluster(27)
    con = Contacts.from_configuration(c, r, 0.3)
    assert np.all(con.gaps <= 0.3)
    assert np.all(con.pairs[:, 0] < con.pairs[:, 1])
    keys = [tuple(p) for p in con.pairs]
    assert keys == sorted(keys)
    wider = Contacts.from_configuration(c, r, 1.0)
    assert wider.n >= con.n


def test_b_formula_with_external_loads():
    c, r = random_cluster(8)
    rng = np.random.default_rng(4)
    F, T = rng.normal(size=(8, 3)), rng.normal(size=(8, 3))
    dt = 0.05
    mob = coupled_mobility(5)
    prob = build_contact_problem(c, r, F, T, dt=dt, delta=0.3, model=mob)
    Mdense = mob(c, r)
    FT = np.concatenate([F, T], axis=1).ravel()
    U_nc = Mdense @ FT
    D = prob.contacts.D.toarray()
    np.testing.assert_allclose(prob.U_nc, U_nc)
    np.testing.assert_allclose(prob.lcp.b, (prob.contacts.gaps + dt * D.T @ U_nc) / dt,
                               rtol=1e-12, atol=1e-12)


def test_a_equals_dtmd_symmetric_psd_and_counted():
    c, r = random_cluster(8)
    mob = coupled_mobility(6)
    calls = {"n": 0}

    def counting(centers, radii):
        Md = mob(centers, radii)

        from scipy.sparse.linalg import LinearOperator

        def mv(v):
            calls["n"] += 1
            return Md @ v
        return LinearOperator(Md.shape, matvec=mv, dtype=float)

    lcp = contact_lcp(c, r, dt=0.1, delta=0.3, model=counting)
    n = lcp.n
    assert n >= 3
    before = calls["n"]
    lcp.A @ np.linspace(1, 2, n)
    assert lcp.A.count == 1 and calls["n"] - before == 1          # one solve per MVP
    A = lcp.dense()                                               # n uncounted products
    D = build_contact_problem(c, r, dt=0.1, delta=0.3, model=mob).contacts.D.toarray()
    np.testing.assert_allclose(A, D.T @ mob(c, r) @ D, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(A, A.T, atol=1e-12)
    assert np.linalg.eigvalsh(A).min() > -1e-12
    assert lcp.A.count == 1


def test_a_for_the_scene_model_is_symmetric_psd():
    scene = LatticeScene(2, model=MODEL, seed=2)
    lcp = scene.build().lcp
    A = lcp.dense()
    assert lcp.n >= 3
    np.testing.assert_allclose(A, A.T, atol=1e-12 * np.abs(A).max())
    assert np.linalg.eigvalsh(A).min() > -1e-10 * np.abs(A).max()
    assert lcp.meta["symmetric"] is True and lcp.meta["M"] == 8


def test_scene_step_uses_eq_defaandb_and_moves_with_u_nc_plus_mdx():
    from lcpbench.problems.suspension.problem import resolve_mobility

    scene = LatticeScene(2, model=MODEL, seed=4)
    for _ in range(10):                         # until the cluster presses together
        scene.step("bb-pgd", tol=1e-10, stop="kkt")
    c0, o0 = scene.centers.copy(), scene.orientations.copy()
    F, T = scene.loads()
    prob = scene.build(warm_start=False)
    Md = resolve_mobility(c0, scene.radii, MODEL) @ np.eye(6 * scene.M)
    D = prob.contacts.D.toarray()
    U_nc = Md @ np.concatenate([F, T], axis=1).ravel()
    dt = scene.params.dt
    np.testing.assert_allclose(prob.lcp.b, (prob.contacts.gaps - scene.params.separation) / dt
                               + D.T @ U_nc,
                               rtol=1e-10, atol=1e-10)
    res = run_solver(prob.lcp, "bb-pgd", stop="kkt", tol=1e-10)
    assert res.solved and np.any(res.x > 0)
    overlap, solves = scene.advance(prob, res.x)
    assert solves == 0 and overlap == 0.0
    U = (U_nc + Md @ D @ res.x).reshape(-1, 6)
    np.testing.assert_allclose(scene.centers, c0 + dt * U[:, :3], rtol=1e-12, atol=1e-12)
    o = o0 + dt * np.cross(U[:, 3:], o0)
    np.testing.assert_allclose(scene.orientations, o / np.linalg.norm(o, axis=1)[:, None])
    # the linearised constraint holds after the move: Phi + dt D' U >= 0 (to the tolerance)
    assert np.all(prob.contacts.gaps + dt * D.T @ U.ravel() >= scene.params.separation - 1e-8)


def test_low_fidelity_operators_are_priced_by_their_own_products():
    # no cost is declared and no product is made to time one: the solve's counted
    # products price every fidelity
    c, r = random_cluster(8)
    lcp = contact_lcp(c, r, dt=0.1, delta=0.3, model=MODEL, low=["self"])
    assert set(lcp.low) == {"self"}
    assert lcp.A.declared_cost is None and lcp.low["self"].declared_cost is None
    assert lcp.A.count == 0 and lcp.low["self"].count == 0
    Alow = lcp.low["self"] @ np.eye(lcp.n)
    D = Contacts.from_configuration(c, r, 0.3).D.toarray()
    np.testing.assert_allclose(Alow, D.T @ self_mobility_dense(r) @ D, rtol=1e-12)


def test_parse_fidelity_names():
    assert parse_fidelity("p4e6", 8, 1e-8).knobs() == {"model": "bim", "p": 4,
                                                       "eps_gmres": 1e-6}
    assert parse_fidelity("p3", 8, 1e-8).knobs() == {"model": "bim", "p": 3, "eps_gmres": 1e-8}
    assert parse_fidelity("rpy", 8, 1e-8).model == "rpy"
    # p and eps_gmres are checked where the name is parsed, naming the fidelity
    with pytest.raises(ValueError, match="fidelity 'p0': p = 0 must be an integer"):
        parse_fidelity("p0", 8, 1e-8)
    with pytest.raises(ValueError, match=r"fidelity 'p4e0': eps_gmres = 1.0 must be"):
        parse_fidelity("p4e0", 8, 1e-8)
    with pytest.raises(ValueError, match="unknown fidelity 'q4'"):
        parse_fidelity("q4", 8, 1e-8)


def test_no_contacts_gives_empty_lcp():
    lcp = contact_lcp([[0, 0, 0], [5, 0, 0]], 1.0, dt=0.1, delta=0.3, model="self")
    assert lcp.n == 0
    res = run_solver(lcp, "bb-pgd")
    assert res.solved and res.mvps == 0


def test_contact_lcp_rejects_bad_input():
    with pytest.raises(ValueError, match="dt"):
        contact_lcp([[0, 0, 0], [2.1, 0, 0]], 1.0, dt=0.0, model="self")
    with pytest.raises(ValueError, match="delta"):
        contact_lcp([[0, 0, 0], [2.1, 0, 0]], 1.0, delta=-1.0, model="self")
    with pytest.raises(ValueError, match="F_ext must have shape"):
        contact_lcp([[0, 0, 0], [2.1, 0, 0]], 1.0, F_ext=np.zeros(3), model="self")
    with pytest.raises(ValueError, match="unknown mobility model"):
        contact_lcp([[0, 0, 0], [2.1, 0, 0]], 1.0, model="stokeslet")


# ----------------------------------------------------------------------------- scene


@pytest.mark.parametrize("m", [2, 3, 4])
def test_bisection_gives_about_half_m_cubed_pairs(m):
    scene = LatticeScene(m, model="self", seed=m)
    M = m ** 3
    assert abs(scene.initial_pairs - M / 2) <= M / 10
    assert scene.initial_pairs == Contacts.from_configuration(
        scene.centers, scene.radii, scene.params.delta).n
    assert max_overlap(scene.centers, scene.radii) == 0.0
    con = Contacts.from_configuration(scene.centers, scene.radii, 0.0)
    assert con.n == 0                                   # nobody touches at the start


def test_bisection_polydisperse_and_single_sphere():
    near = LatticeScene(3, model="self", polydisperse=0.05, seed=1)
    assert abs(near.initial_pairs - 13.5) <= 2.7
    # strong polydispersity: the window needs overlapping spheres, so the scale stops
    # just above touching with the most candidate pairs an overlap-free start allows
    scene = LatticeScene(3, model="self", polydisperse=0.3, seed=7)
    assert scene.radii.min() >= 0.7 and scene.radii.max() <= 1.3
    assert 0 < scene.initial_pairs < 13.5 - 2.7
    assert max_overlap(scene.centers, scene.radii) == 0.0
    assert Contacts.from_configuration(0.999 * scene.centers, scene.radii, 0.0).n > 0
    one = LatticeScene(1, model="self")
    assert one.M == 1 and one.initial_pairs == 0
    assert bisect_scale(np.zeros((1, 3)), np.ones(1), 0.3, 0.5, 0.1) == (1.0, 0)


def test_janus_loads_pull_inwards_and_align():
    scene = LatticeScene(3, model="self", seed=1)
    F, T = scene.loads()
    rel = scene.centers - scene.centers.mean(axis=0)
    far = np.linalg.norm(rel, axis=1) > 1
    assert np.all(np.sum(F[far] * rel[far], axis=1) < 0)        # towards the centroid
    np.testing.assert_allclose(T, 0, atol=1e-12)                  # poles start aligned
    scene.orientations = np.tile([0.0, 0.0, 1.0], (scene.M, 1))   # misalign every pole
    F2, T2 = scene.loads()
    inward = -rel / np.linalg.norm(rel, axis=1, keepdims=True)
    # the torque turns each pole towards the centroid: d o / dt ~ T x o points inwards
    turn = np.sum(np.cross(T2, scene.orientations) * inward, axis=1)
    tilted = np.linalg.norm(np.cross(scene.orientations, inward), axis=1) > 1e-6
    assert np.all(turn[far & tilted] > 0)
    assert np.linalg.norm(F2[far]) < np.linalg.norm(F[far])       # misaligned: weaker pull


def test_short_simulation_packs_without_overlap():
    scene = make_scene(f"lattice:m=3,model={MODEL},seed=3")
    ns, overlaps = [], []
    for _ in range(12):
        rec = scene.step("bb-pgd", tol=1e-8, stop="kkt")
        assert rec.result.solved, rec.result.message
        assert rec.result.verified["kkt_abs"] <= rec.result.threshold
        assert rec.update_solves == 0          # U = U_nc + M D x reused the verification
        ns.append(rec.n)
        overlaps.append(rec.max_overlap)
    assert max(overlaps) <= 1e-2 * scene.radii.min()
    assert max(ns) >= scene.M                  # the paper's workload: n >= M contacts
    assert scene.step_index == 12


def test_warm_start_matches_pairs():
    old = Contacts.from_configuration([[0, 0, 0], [2.1, 0, 0], [0, 2.2, 0]], 1.0, 0.3)
    assert old.pair_ids() == [(0, 1), (0, 2)]
    new = Contacts.from_configuration([[0, 0, 0], [2.05, 0, 0], [0, 5, 0], [2.05, 2.1, 0]],
                                      1.0, 0.3)
    assert new.pair_ids() == [(0, 1), (1, 3)]
    np.testing.assert_allclose(new.carry(old.pairs, [3.0, 7.0]), [3.0, 0.0])
    with pytest.raises(ValueError, match="2 pairs but 1 forces"):
        new.carry(old.pairs, [1.0])


def test_scene_warm_start_carries_forces_by_pair_identity():
    scene = LatticeScene(3, model=MODEL, seed=3)
    rec = None
    for _ in range(8):
        rec = scene.step("bb-pgd", tol=1e-8, stop="kkt")
    assert np.count_nonzero(rec.x) > 0
    prev = {tuple(p): v for p, v in zip(rec.pairs.tolist(), rec.x)}
    prob = scene.build(warm_start=True)
    x0 = prob.lcp.x0
    assert x0 is not None
    for k, pair in enumerate(prob.contacts.pairs.tolist()):
        assert x0[k] == pytest.approx(prev.get(tuple(pair), 0.0))
    assert scene.build(warm_start=False).lcp.x0 is None


def test_bad_scene_parameters():
    with pytest.raises(ValueError, match="m must be an integer >= 1, got 0"):
        make_scene("lattice:m=0")
    with pytest.raises(ValueError, match="dt must be a finite number > 0, got -0.1"):
        make_scene("lattice:m=2,dt=-0.1")
    with pytest.raises(ValueError, match="unknown fidelity"):
        LatticeParams(m=2, low=("x9",))
    with pytest.raises(TypeError, match="unknown parameter 'mm'"):
        make_scene("lattice:mm=2")
    with pytest.raises(KeyError, match="unknown scene 'cube'"):
        make_scene("cube:m=2")


# ----------------------------------------------------------------------------- simulate


def test_simulate_rows_and_report_table(tmp_path):
    scene = f"lattice:m=2,model={MODEL},low=[self]"
    rows = simulate(scene, ["bb-pgd", "bi-pqn:low=self"], 10, tmp_path, progress=False,
                    stop="kkt")
    assert len(rows) == 20
    res = pd.read_csv(tmp_path / "results.csv")
    assert len(res) == 20 and set(res["kind"]) == {"online"}
    # the two simulations take their steps in turn (same machine load for both)
    assert list(res["step"][:4]) == [0, 0, 1, 1]
    assert res["solver"][0] != res["solver"][1]
    for _, part in res.groupby("solver"):
        assert list(part["step"]) == list(range(10))
    # no step times a product of any fidelity: the set-up solves are the non-collisional
    # solve's, whether the step builds the low fidelity or not
    setup = {s: [json.loads(i)["setup_solves"] for i in part["info"]]
             for s, part in res.groupby("solver")}
    assert set(setup["bb-pgd"]) == set(setup["bi-pqn:low=self"]) == {1}
    assert res["solved"].astype(bool).all()
    assert (res["max_overlap"] <= 1e-2).all()
    assert (res["sim_total_s"] >= res["time_s"]).all()
    info = [json.loads(i) for i in res["info"]]
    assert {"setup_s", "update_s", "overlap_ok", "warm_entries"} <= set(info[1])
    assert any(i["warm_entries"] > 0 for i in info)          # forces carried over
    assert (res["mvps"] > 0).any()
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["simulations"][0]["scene"] == scene
    table = online_table(res, "bb-pgd")
    assert set(table["solver"]) == {"bb-pgd", "bi-pqn:low=self"}
    assert (table["steps"] == 10).all()
    with pytest.raises(ValueError, match=r"under other settings \(stop\)"):
        simulate(scene, "bb-pgd", 2, tmp_path, progress=False)      # stop="paper" now
    again = simulate(scene, ["bb-pgd", "bi-pqn:low=self"], 10, tmp_path, progress=False,
                     stop="kkt")                                     # finished: nothing to do
    assert len(again) == 20 and len(pd.read_csv(tmp_path / "results.csv")) == 20
    cold = simulate(scene, "bb-pgd", 10, tmp_path, progress=False, stop="kkt",
                    warm_start=False)
    assert set(cold["solver"]) == {"bb-pgd (cold)"}
    assert all(json.loads(i)["warm_entries"] == 0 for i in cold["info"])
    res = pd.read_csv(tmp_path / "results.csv")
    assert len(res) == 30 and len(online_table(res, "bb-pgd")) == 3
    assert len(json.loads((tmp_path / "meta.json").read_text())["simulations"]) == 2


def test_simulate_flags_overlap(tmp_path):
    rows = simulate("lattice:m=2,model=self,delta=0,dt=1.5,force=2", "bb-pgd", 3, tmp_path,
                    progress=False, stop="kkt")
    info = [json.loads(s) for s in rows["info"]]
    flagged = [not i["overlap_ok"] for i in info]
    assert any(flagged)
    for f, msg, over in zip(flagged, rows["message"], rows["max_overlap"]):
        assert f == ("overlap" in msg) == (over > 1e-2)


def test_simulate_rejects_bad_input(tmp_path):
    with pytest.raises(KeyError, match="unknown solver 'nope'"):
        simulate("lattice:m=2,model=self", "nope", 2, tmp_path, progress=False)
    with pytest.raises(ValueError, match="needs low-fidelity operators"):
        simulate("lattice:m=2,model=self", "bi-pqn", 2, tmp_path, progress=False)
    with pytest.raises(ValueError, match="steps = 0"):
        simulate("lattice:m=2,model=self", "bb-pgd", 0, tmp_path, progress=False)
    assert not (tmp_path / "results.csv").exists()


def test_cli_simulate(tmp_path, capsys):
    out = tmp_path / "sim"
    rc = main(["simulate", "--scene", f"lattice:m=2,model={MODEL}", "--solver", "bb-pgd",
               "--solver", "mono-pqn", "--steps", "3", "--out", str(out), "--stop", "kkt",
               "--quiet"])
    assert rc == 0
    res = pd.read_csv(out / "results.csv")
    assert len(res) == 6 and set(res["solver"]) == {"bb-pgd", "mono-pqn"}
    assert "results:" in capsys.readouterr().out
    hist = pd.read_csv(out / "history.csv") if (out / "history.csv").exists() else None
    assert hist is None or set(hist["run_id"]) <= set(res["run_id"])


@pytest.mark.parametrize("argv, msg", [
    (["--scene", "lattice:m=0"], "m must be an integer >= 1, got 0"),
    (["--scene", "lattice:m=2,dt=0"], "dt must be a finite number > 0, got 0.0"),
    (["--scene", "lattice:m=2,model=self", "--solver", "nope"], "unknown solver 'nope'"),
])
def test_cli_simulate_errors_exit_2(tmp_path, capsys, argv, msg):
    rc = main(["simulate", *argv, "--steps", "1", "--out", str(tmp_path / "x"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and msg in err and err.count("\n") == 1


def test_paper_lattice_keeps_the_authors_gaps():
    from scipy.spatial.distance import pdist

    from lcpbench.core.registry import make_scene
    from lcpbench.problems.suspension.scene import LatticeParams, PaperLatticeParams

    scene = make_scene("paper-lattice:m=3,model=rpy")
    P = scene.params
    assert isinstance(P, PaperLatticeParams)
    assert (P.spacing, P.separation, P.delta, P.dt, P.radius) == (2.5, 0.3, 0.63, 0.1, 1.0)
    assert LatticeParams().separation == 0.1            # the default scene is unchanged
    ns = [scene.step("bb-pgd").n for _ in range(25)]
    assert ns[-1] > 20                                  # it packs
    gaps = pdist(scene.centers) - 2.0
    assert gaps.min() > 0.3 - 1e-4                      # and keeps 0.3a, not the 0.1a default
    assert gaps.min() < 0.35                            # with contacts sitting at it
    spec = make_scene("paper-lattice:m=2,separation=0.2,model=rpy")
    assert spec.params.separation == 0.2 and spec.params.spacing == 2.5


def test_a_new_low_fidelity_is_one_registration():
    """The worked example of docs/architecture.md, "Adding a low fidelity": a new kind of
    fidelity name is one registered builder (here the one-sphere mobility halved, named
    ``half<k>`` for a factor 1/k); scenes and contact problems then find it by name."""
    from lcpbench.problems.suspension.fidelity import (
        Fidelity,
        FidelityKind,
        register_fidelity,
        self_mobility,
        unregister_fidelity,
    )

    def describe(match, p, eps_gmres):
        return Fidelity(match.group(0), "scaled-self", "self", p, eps_gmres,
                        {"factor": 1.0 / int(match.group(1))})

    def build(fid, config):
        return fid.extra["factor"] * self_mobility(config.centers, config.radii, config.mu)

    register_fidelity(FidelityKind("scaled-self", r"half(\d+)", describe, build, "half2"))
    try:
        scene = make_scene("lattice:m=2,model=rpy,low=[self,half2]")
        assert scene.fidelity_knobs("half2") == {"model": "self", "p": 8, "eps_gmres": 1e-8,
                                                 "factor": 0.5}
        lcp = scene.build().lcp
        assert lcp.n > 0 and set(lcp.low) == {"self", "half2"}
        E = np.eye(lcp.n)
        np.testing.assert_allclose(lcp.low["half2"] @ E, 0.5 * (lcp.low["self"] @ E),
                                   rtol=1e-14)
    finally:
        unregister_fidelity("scaled-self")
    with pytest.raises(ValueError, match="unknown fidelity 'half2'"):
        make_scene("lattice:m=2,model=rpy,low=[half2]")


def test_contact_options_are_one_parameter_object():
    """build_contact_problem and contact_lcp share ContactOptions; keywords replace fields,
    and an unknown keyword names the options."""
    from lcpbench.problems.suspension.problem import ContactOptions

    c = [[0, 0, 0], [2.1, 0, 0]]
    opts = ContactOptions(dt=0.05, delta=0.3, model="self")
    lcp = build_contact_problem(c, 1.0, options=opts).lcp
    assert lcp.meta["dt"] == 0.05 and float(lcp.b[0]) == pytest.approx(0.1 / 0.05)
    assert contact_lcp(c, 1.0, options=opts, dt=0.1).meta["dt"] == 0.1
    with pytest.raises(TypeError, match="unknown contact option.*tdt.*the options are"):
        contact_lcp(c, 1.0, tdt=0.1)
    with pytest.raises(ValueError, match="separation = -1.0 must be"):
        ContactOptions(separation=-1)


def test_live_operators_declare_their_products_accuracy():
    """A boundary-integral contact operator declares its GMRES tolerance as the relative
    accuracy of its products (high and every iterative low), an analytic one declares 0:
    the framework then neither measures them nor needs a counted product to trust a PQN
    solver's drift bound."""
    c = [[0, 0, 0], [2.1, 0, 0], [0, 2.1, 0]]
    lcp = contact_lcp(c, 1.0, dt=0.1, delta=0.3, model="bim", p=3, eps_gmres=1e-7,
                      low=["rpy", "p2e5", "p3f2e4"])
    assert lcp.A.rtol == 1e-7
    assert {k: op.rtol for k, op in lcp.low.items()} == {"rpy": 0.0, "p2e5": 1e-5,
                                                         "p3f2e4": 1e-4}
    assert contact_lcp(c, 1.0, dt=0.1, delta=0.3, model="rpy").A.rtol == 0.0
    res = run_solver(lcp, "mono-pqn")
    assert res.solved and res.info.get("operator_accuracy_source", "declared") == "declared"
