"""bb-pgd, a-pgd and zero-sr1: faithfulness to their sources, MVP counts, options."""

import numpy as np
import pytest
from lcp_cases import planted

import lcpbench
from lcpbench import LCP, Operator, Status
from lcpbench.core.registry import get_problem
from lcpbench.core.specs import make_params
from lcpbench.problems.hard import random_spd_matrix
from lcpbench.solvers.pgd import power_iteration
from lcpbench.solvers.zerosr1 import prox_rank1_nonneg


def _planted(seed, n=60, cond=50.0):
    return planted(n, seed=seed, cond=cond, solution=True)


def _family(name, **params):
    info = get_problem(name)
    return info.func(make_params(name, info.params, params))


@pytest.mark.parametrize("spec", ["bb-pgd", "bb-pgd:variant=bb2", "bb-pgd:variant=alternate",
                                  "bb-pgd:safeguard=true", "bb-pgd:safeguard=true,reference=gll",
                                  "a-pgd", "a-pgd:constants=oracle", "a-pgd:restart=gradient",
                                  "a-pgd:restart=function", "zero-sr1"])
def test_solves_planted_problem(spec):
    A, b, x_star = _planted(1)
    res = lcpbench.solve(A, b, solver=spec, tol=1e-10, stop="kkt")
    assert res.solved, res.summary()
    assert np.max(np.abs(res.x - x_star)) < 1e-7


def test_bb_pgd_is_one_mvp_per_iteration_plus_cauchy_step():
    A, b, _ = _planted(2)
    res = lcpbench.solve(A, b, solver="bb-pgd")
    # A 0 is free; the Cauchy step costs A w; then one product per iteration
    assert res.mvps == res.iterations + 1
    safe = lcpbench.solve(A, b, solver="bb-pgd:safeguard=true")
    assert safe.mvps == safe.iterations + 1


def test_bb_pgd_first_step_is_the_authors_cauchy_step():
    A, b, _ = _planted(3)
    res = lcpbench.solve(A, b, solver="bb-pgd", max_iter=1)
    w0 = b
    tau = (w0 @ w0) / (w0 @ A @ w0)
    assert np.allclose(res.x, np.maximum(-tau * w0, 0.0))


def test_bb1_step_is_the_papers_spectral_step():
    """After two iterations, x_2 = max(x_1 - tau_bb w_1, 0) with eq. spectralStepSize."""
    A, b, _ = _planted(4)
    r1 = lcpbench.solve(A, b, solver="bb-pgd", max_iter=1)
    r2 = lcpbench.solve(A, b, solver="bb-pgd", max_iter=2)
    x0, x1 = np.zeros_like(b), r1.x
    s, y = x1 - x0, A @ x1 - A @ x0
    tau = (s @ s) / (s @ y)
    assert np.allclose(r2.x, np.maximum(x1 - tau * (A @ x1 + b), 0.0))


def test_plain_bb_fails_on_bb_cycle_honestly_and_safeguard_solves():
    for lcp in _family("bb-cycle"):
        plain = lcpbench.solve(lcp, solver="bb-pgd", max_emvps=2000)
        assert plain.status.value != "converged" and not plain.solved
        safe = lcpbench.solve(lcp, solver="bb-pgd:safeguard=true")
        assert safe.solved, safe.summary()
        assert safe.info["line_search_cuts"] > 0


def test_safeguarded_bb_is_nonmonotone_but_never_above_its_reference():
    A, b, _ = _planted(5, n=80, cond=1e4)
    res = lcpbench.solve(A, b, solver="bb-pgd:safeguard=true,reference=gll,memory=1")
    f = res.history["objective"].to_numpy()
    assert np.all(np.diff(f) <= 1e-12 * np.abs(f[:-1]).max())    # memory 1: monotone
    res10 = lcpbench.solve(A, b, solver="bb-pgd:safeguard=true,reference=gll,memory=10")
    f10 = res10.history["objective"].to_numpy()
    for k in range(1, len(f10)):
        assert f10[k] <= f10[max(0, k - 10):k].max() + 1e-12 * abs(f10).max()


def test_a_pgd_power_iteration_mvps_are_counted():
    A, b, _ = _planted(6)
    res = lcpbench.solve(A, b, solver="a-pgd:power_iters=15")
    assert res.info["power_mvps"] == 15
    assert res.mvps == res.iterations + 15
    oracle = lcpbench.solve(A, b, solver="a-pgd:constants=oracle")
    assert oracle.info["oracle_constants"] and oracle.mvps == oracle.iterations
    ev = np.linalg.eigvalsh(A)
    assert oracle.info["L"] == pytest.approx(ev[-1]) and oracle.info["mu"] == pytest.approx(ev[0])


def test_a_pgd_given_constants_and_strong_momentum():
    A, b, _ = _planted(7, cond=1e3)
    ev = np.linalg.eigvalsh(A)
    fista = lcpbench.solve(A, b, solver=f"a-pgd:L={ev[-1]}", tol=1e-10, stop="kkt")
    strong = lcpbench.solve(A, b, solver=f"a-pgd:L={ev[-1]},mu={ev[0]}", tol=1e-10, stop="kkt")
    assert fista.solved and strong.solved
    assert fista.info["power_mvps"] == 0
    assert strong.mvps < fista.mvps              # the known mu helps at cond 1e3


def test_a_pgd_rejects_bad_constants():
    with pytest.raises(ValueError, match="mu"):
        lcpbench.solve(np.eye(2), -np.ones(2), solver="a-pgd:L=1,mu=2")
    with pytest.raises(ValueError, match="restart"):
        lcpbench.solve(np.eye(2), -np.ones(2), solver="a-pgd:restart=always")


def test_power_iteration_approaches_lambda_max_from_below():
    rng = np.random.default_rng(0)
    A = random_spd_matrix(rng, 50, 100.0)
    lam = np.linalg.eigvalsh(A)[-1]
    est = power_iteration(lambda v: A @ v, 50, 200)
    assert est <= lam * (1 + 1e-12) and est >= 0.99 * lam


def test_zero_sr1_first_iteration_is_cauchy_pgd_then_rank_one_prox():
    A, b, _ = _planted(8)
    r1 = lcpbench.solve(A, b, solver="zero-sr1", max_iter=1)
    tau = (b @ b) / (b @ A @ b)
    assert np.allclose(r1.x, np.maximum(-tau * b, 0.0))
    r2 = lcpbench.solve(A, b, solver="zero-sr1", max_iter=2)
    x1, w1 = r1.x, A @ r1.x + b
    s, y = x1, A @ x1
    t = 0.8 * (s @ y) / (y @ y)
    v = (s - t * y) / np.sqrt((s - t * y) @ y)
    H = t * np.eye(len(b)) + np.outer(v, v)
    # x2 = argmin_{z>=0} 1/2 ||z - c||^2_{H^-1}, c = x1 - H w1: check its KKT conditions
    c = x1 - H @ w1
    z = r2.x
    g = np.linalg.solve(H, z - c)                # gradient of the prox objective
    scale = np.abs(g).max()
    assert np.all(z >= 0) and np.all(g >= -1e-9 * scale)
    assert np.max(np.abs(np.minimum(z, g))) <= 1e-9 * scale
    assert r2.mvps == r2.iterations + 1


@pytest.mark.parametrize("sigma", [1.0, -1.0])
def test_rank_one_prox_meets_kkt_conditions_and_handles_ties(sigma):
    rng = np.random.default_rng(11)
    for trial in range(20):
        n = int(rng.integers(1, 40))
        d = rng.uniform(0.2, 3.0, n)
        u = rng.standard_normal(n)
        if trial % 3 == 0:
            u[: n // 2] = 0.0                    # components without rank-1 coupling
        if trial % 4 == 0:
            u = np.round(u)                      # repeated breakpoints
        if sigma < 0:
            u *= np.sqrt(0.9 / max(float(u @ (u / d)), 1e-300))
        x = rng.standard_normal(n) * 2
        B = np.diag(d) + sigma * np.outer(u, u)
        z = prox_rank1_nonneg(x, d, u, sigma)
        g = B @ (z - x)                           # gradient of the prox objective at z
        scale = max(np.abs(B @ x).max(), 1.0)
        assert np.all(z >= 0) and np.all(g >= -1e-12 * scale), trial
        assert np.max(np.abs(np.minimum(z, g))) <= 1e-12 * scale, trial


def test_rank_one_prox_rejects_indefinite_metric():
    with pytest.raises(ValueError, match="positive definite"):
        prox_rank1_nonneg(np.ones(2), np.ones(2), np.array([1.0, 1.0]), -1.0)
    with pytest.raises(ValueError, match="sigma"):
        prox_rank1_nonneg(np.ones(2), np.ones(2), np.ones(2), 2.0)
    with pytest.raises(ValueError, match="positive"):
        prox_rank1_nonneg(np.ones(2), np.array([1.0, 0.0]), np.ones(2))


def test_singular_psd_keeps_step_when_curvature_vanishes():
    """A = J J' with a null space: s'y = 0 steps keep tau instead of dividing by zero."""
    for lcp in _family("singular-psd", count=2):
        for spec in ("bb-pgd", "zero-sr1", "a-pgd"):
            res = lcpbench.solve(lcp, solver=spec)
            assert res.status.value in ("converged", "stagnated", "max_iter", "budget")
            assert np.all(np.isfinite(res.x))


def test_matrix_free_operator_gives_identical_iterates():
    A, b, _ = _planted(9)
    dense = lcpbench.solve(A, b, solver="bb-pgd")
    op = Operator(lambda v: A @ v, shape=A.shape)
    free = lcpbench.solve(LCP(op, b), solver="bb-pgd")
    assert free.mvps == dense.mvps and np.allclose(free.x, dense.x, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_zero_sr1_never_hands_the_prox_an_indefinite_model(seed):
    # diag_weight one ulp below 1 makes r'y ~ 1e-16 s'y, so v'v / t exceeds 2^53 and the
    # rank-1 model B = I/t - q q' is indefinite in floating point. The solver must drop the
    # rank-1 term for that iteration (counted) instead of failing inside the prox.
    A, b = planted(40, seed=seed, cond=100)
    res = lcpbench.solve(A, b, solver="zero-sr1:diag_weight=0.9999999999999999", stop="kkt",
                         tol=1e-8, max_emvps=300)
    assert res.status is not Status.failed, res.summary()
    assert res.info["skipped_rank1"] > 0
    assert res.status is not Status.converged or res.solved
