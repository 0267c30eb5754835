"""minmap-newton: convergence per Krylov method, counters, budget, warm start."""

import numpy as np
import pytest
from lcp_cases import planted

import lcpbench
from lcpbench import LCP, Status

COUNTERS = ("newton_iterations", "krylov_mvps", "ls_mvps", "backtracks", "fallbacks",
            "ls_failures", "retries")


@pytest.mark.parametrize("krylov", ["gmres", "cg", "minres"])
@pytest.mark.parametrize("seed", range(2))
def test_converges_spd(krylov, seed):
    A, b = planted(40, seed=seed)
    res = lcpbench.solve(A, b, solver=f"minmap-newton:krylov={krylov}", stop="kkt", tol=1e-9)
    assert res.status is Status.converged and res.solved, res.summary()
    for k in COUNTERS:
        assert isinstance(res.info[k], int) and res.info[k] >= 0
    assert res.info["krylov_mvps"] + res.info["ls_mvps"] <= res.mvps
    ref = lcpbench.reference(LCP(A, b))
    np.testing.assert_allclose(res.w, ref.w, atol=1e-7)


@pytest.mark.parametrize("krylov", ["gmres", "cg", "minres"])
def test_regularised_singular_psd(krylov):
    for seed in range(3):
        A, b = planted(40, rank=10, seed=seed)
        res = lcpbench.solve(A, b, solver=f"minmap-newton:krylov={krylov},reg=0.1",
                             stop="kkt", tol=1e-8)
        assert res.solved, res.summary()


def test_fallback_counted_on_singular_problem():
    # Unregularised Newton on a rank-10 PSD matrix: J is singular, some Newton
    # directions do not descend and the gradient fallback takes over.
    A, b = planted(50, rank=10, seed=0)
    res = lcpbench.solve(A, b, solver="minmap-newton:krylov=cg", stop="kkt", tol=1e-8)
    assert res.info["fallbacks"] >= 1
    assert res.solved, res.summary()


@pytest.mark.parametrize("projection", ["always", "retry", "never"])
def test_projection_modes(projection):
    for seed in range(2):
        A, b = planted(40, seed=seed)
        res = lcpbench.solve(A, b, solver=f"minmap-newton:projection={projection}",
                             stop="kkt", tol=1e-9)
        assert res.solved, res.summary()
        if projection != "retry":
            assert res.info["retries"] == 0
        if projection == "never":
            # Unprojected trials along the Newton direction reuse w + tau A dx.
            assert res.info["ls_mvps"] <= res.info["fallbacks"] * (res.params["max_backtracks"] + 1)


def test_reported_w_is_exact():
    A, b = planted(30, seed=3)
    res = lcpbench.solve(A, b, solver="minmap-newton:krylov=cg", stop="kkt", tol=1e-9)
    h = res.history
    np.testing.assert_allclose(h["kkt_abs"], h["kkt_abs_verified"], rtol=1e-6, atol=1e-12)




def test_all_inactive_is_free():
    A, b = planted(10, seed=0)
    res = lcpbench.solve(A, np.abs(b) + 1.0, solver="minmap-newton", stop="kkt")
    assert res.solved and res.mvps == 0


@pytest.mark.parametrize("bad", ["krylov=bicg", "inner_tol=0", "alpha=1", "beta=0",
                                 "max_backtracks=-1", "reg=-1", "projection=maybe"])
def test_parameters_validated(bad):
    A, b = planted(5)
    with pytest.raises((ValueError, TypeError)):
        lcpbench.solve(A, b, solver=f"minmap-newton:{bad}")
