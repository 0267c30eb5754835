"""The two mobility models against each other, and a live boundary-integral scene end to end."""

import numpy as np
import pytest

from lcpbench.problems.suspension import mobility
from lcpbench.problems.suspension.scene import LatticeScene


def _dense(op, n):
    return op @ np.eye(n)


@pytest.mark.parametrize("d", [6.0, 10.0, 20.0])
def test_rpy_agrees_with_bim_for_well_separated_spheres(d):
    """RPY is the far-field expansion of the exact mobility: exact to O((a/d)^3) in the pair
    blocks and to O((a/d)^4) in the self blocks (the first reflection, -15/4 (a/d)^4, is the
    first term RPY lacks)."""
    rng = np.random.default_rng(0)
    e = rng.standard_normal(3)
    e /= np.linalg.norm(e)
    X = np.array([np.zeros(3), d * e, d * np.array([e[1], -e[0], 0.0]) / np.hypot(e[0], e[1])])
    bim = _dense(mobility(X, 1.0, model="bim", p=6, eps_gmres=1e-12), 18)
    rpy = _dense(mobility(X, 1.0, model="rpy"), 18)
    scale = 1.0 / (6 * np.pi)                      # the self translational mobility
    err = np.abs(bim - rpy).max() / scale
    assert err <= 8 * (1.0 / d) ** 4, err
    # and the symmetric positive definite part agrees in its extreme eigenvalues
    ev_b = np.linalg.eigvalsh((bim + bim.T) / 2)
    ev_r = np.linalg.eigvalsh(rpy)
    assert ev_b[0] > 0
    np.testing.assert_allclose(ev_b[[0, -1]], ev_r[[0, -1]], rtol=8 * (1.0 / d) ** 3)


def test_rpy_error_decays_like_the_fourth_power():
    errs = []
    for d in (8.0, 16.0):
        X = np.array([[0.0, 0.0, 0.0], [d, 0.3, 0.1]])
        bim = _dense(mobility(X, 1.0, model="bim", p=6, eps_gmres=1e-12), 12)
        rpy = _dense(mobility(X, 1.0, model="rpy"), 12)
        errs.append(np.abs(bim - rpy).max())
    rate = np.log2(errs[0] / errs[1])
    assert rate > 3.5, (errs, rate)


def test_live_bim_scene_keeps_spheres_apart_and_solves_every_step():
    scene = LatticeScene(2, model="bim", p=3, eps_gmres=1e-8, low=("rpy",), dt=0.2,
                         separation=0.02)
    active = 0
    for _ in range(8):
        rec = scene.step("bi-pqn:low=rpy", tol=1e-8, stop="kkt")
        assert rec.result.solved, rec.result.summary()
        assert rec.max_overlap == 0.0                # BIM would refuse overlapping spheres
        if rec.result.mvps:                          # contacts pushed: the low model was used
            active += 1
            assert rec.result.lofi_mvps["rpy"] > 0
    assert active > 0


def test_live_bim_contact_operator_is_symmetrised_with_the_adjoint():
    """With symmetrize=True the boundary-integral contact operator is D'(M + M')D/2:
    symmetric to the GMRES tolerance, two mobility solves per product, while the one-solve
    operator (symmetrize=False, the default) keeps the discretisation's asymmetry."""
    from lcpbench.core.operator import dense_uncounted
    from lcpbench.problems.suspension.problem import build_contact_problem

    c = np.array([[0.0, 0.0, 0.0], [2.05, 0.3, 0.0], [0.3, 2.2, 0.2], [0.2, 0.8, 2.1]])
    F = np.array([[1.0, 0.5, 0.0], [-1.0, 0.0, 0.2], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    kw = dict(dt=0.1, delta=0.5, model="bim", p=4, eps_gmres=1e-11, low=("p3",))
    prob = build_contact_problem(c, 1.0, F, symmetrize=True, **kw)
    n = prob.lcp.n
    assert n >= 3 and prob.lcp.meta["symmetrized"] and prob.lcp.meta["symmetric"]
    before = prob.extra_solves
    A = dense_uncounted(prob.lcp.A)
    assert prob.extra_solves - before == 2 * n          # forward + adjoint per column
    scale = np.abs(A).max()
    assert np.abs(A - A.T).max() <= 1e-8 * scale
    L = dense_uncounted(prob.lcp.low["p3"])
    assert np.abs(L - L.T).max() <= 1e-8 * np.abs(L).max()
    raw = build_contact_problem(c, 1.0, F, symmetrize=False, **kw)
    B = dense_uncounted(raw.lcp.A)
    assert not raw.lcp.meta["symmetrized"]
    assert np.abs(B - B.T).max() > 1e-6 * scale          # the discretisation's asymmetry
    np.testing.assert_allclose(A, (B + B.T) / 2, atol=1e-8 * scale)
    # the position update uses the forward mobility M D x, not the symmetrised one
    x = np.linspace(0.1, 1.0, n)
    np.testing.assert_allclose(prob.velocities(x), raw.velocities(x), atol=1e-8)
