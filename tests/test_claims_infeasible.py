"""No ``infeasible`` on problems that have a solution.

The evidence test compared ``||(A d)_+||`` with ``1e-10 ||A||``, so a positive definite
``A = s I + M v v'`` (eigenvalues 0.1 ... 3.4e10) was "singular" along its small
eigenvectors; a warm start of 1e160 overflowed the estimate of ``||A||`` to inf, which
passed any direction; and a solver's own ``infeasible`` (Lemke's ray termination, PQN's
unbounded direction) was never checked. Every problem here except the last has a solution.
"""

from dataclasses import dataclass

import numpy as np
import pytest

import lcpbench
from lcpbench import register_solver
from lcpbench.core.result import Status
from lcpbench.problems.infeasible import infeasible_lcp, unbounded_lcp
from lcpbench.problems.synthetic import random_spd_matrix


@dataclass(frozen=True)
class NoParams:
    """No parameters."""


def _spike(seed: int, n: int = 12):
    rng = np.random.default_rng(seed)
    v = rng.standard_normal(n)
    v /= np.linalg.norm(v)
    A = 0.1 * np.eye(n) + 3.4e10 * np.outer(v, v)
    return (A + A.T) / 2, rng.standard_normal(n)


@pytest.mark.usefixtures("one_blas_thread")
@pytest.mark.parametrize("solver", ["a-pgd", "bb-pgd", "zero-sr1", "l-bfgs-b"])
def test_a_positive_definite_spike_is_never_infeasible(solver):
    # before: 'infeasible' on 13 of these 24 runs, e.g. bb-pgd with a bound ||x|| >= 5.7e-6
    for seed in range(6):
        A, b = _spike(seed)
        res = lcpbench.solve(A, b, solver=solver, max_emvps=100)
        assert res.status != Status.infeasible, (seed, res.message)


def test_an_overflowing_warm_start_proves_nothing():
    # x0 = 1e160 everywhere: ||A x0|| overflows the norm, the estimate of ||A|| became inf
    # and a-pgd ended 'infeasible' on 7 of these 7 (positive definite) problems
    for seed in range(1, 8):
        rng = np.random.default_rng(seed)
        A = random_spd_matrix(rng, 8, 10.0)
        res = lcpbench.solve(A, rng.standard_normal(8), solver="a-pgd", max_emvps=100,
                             x0=np.full(8, 1e160))
        assert res.status != Status.infeasible, (seed, res.message)


def test_pqn_unbounded_claim_from_a_huge_warm_start_is_checked():
    # x0 = 1e300 e_1 overflows PQN's step: it said "unbounded below" on a positive definite A
    rng = np.random.default_rng(0)
    A = random_spd_matrix(rng, 8, 10.0)
    x0 = np.zeros(8)
    x0[0] = 1e300
    with np.errstate(all="ignore"):
        res = lcpbench.solve(A, rng.standard_normal(8), solver="mono-pqn", max_emvps=100, x0=x0)
    assert res.status != Status.infeasible, res.message
    assert res.info["refuted_infeasibility"]
    assert "not confirmed by the framework" in res.message
    assert "unbounded below" in res.info["solver_claimed_infeasible"]


def test_lemke_ray_termination_on_a_solvable_problem_is_checked():
    # eigenvalues 2.6 ... 7.9e8: Lemke's pivots lose the ray test and stop on a ray
    rng = np.random.default_rng(28)
    n = int(rng.integers(5, 30))
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = (Q * np.geomspace(2.6, 7.9e8, n)) @ Q.T
    b = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3)
    res = lcpbench.solve((A + A.T) / 2, b, solver="lemke")
    assert res.status != Status.infeasible, res.message
    assert "ray termination" in res.info["solver_claimed_infeasible"]
    assert res.info["refuted_infeasibility"]


@register_solver("test-quitter", NoParams, listed=False)
def quitter(ctx, p):
    """Says 'infeasible' at x = 0 without any evidence."""
    x = np.zeros(ctx.n)
    ctx.report(x, ctx.b)
    return ctx.finish(x, ctx.b, Status.infeasible, "I give up: no solution")


def test_a_solver_claim_of_no_solution_needs_the_framework_certificate():
    res = lcpbench.solve(np.eye(3), np.array([-1.0, 1.0, -2.0]), solver="test-quitter")
    assert res.status == Status.stagnated
    assert "I give up" in res.message and res.info["refuted_infeasibility"]


@pytest.mark.parametrize("solver", ["lemke", "mono-pqn", "bi-pqn"])
def test_solver_claims_on_problems_without_a_solution_still_stand(solver):
    from lcpbench.problems.random import with_perturbed_lows

    A = np.diag([1.0, 0.0])                    # x_2 is free to grow: b_2 < 0, no solution
    lcp = with_perturbed_lows(lcpbench.LCP(A, np.array([0.0, -1.0])), 0)
    res = lcpbench.solve(lcp, solver="bi-pqn:low=low" if solver == "bi-pqn" else solver)
    assert res.status == Status.infeasible, res.summary()
    assert "refuted_infeasibility" not in res.info


@pytest.mark.usefixtures("one_blas_thread")
def test_the_families_without_a_solution_are_still_found():
    found = 0
    for seed in range(6):
        rng = np.random.default_rng(seed)
        for lcp in (infeasible_lcp(rng, int(rng.integers(2, 21))),
                    unbounded_lcp(rng, int(rng.integers(2, 21)))):
            res = lcpbench.solve(lcp, solver="mono-pqn", max_emvps=300)
            assert res.status != Status.converged
            found += res.status == Status.infeasible
    # 10 of 12 before; PQN's unbounded direction on A = J J' is null only to ~1e-11 ||A||,
    # short of the rounding of A along it, on 3 of them (they end 'stagnated', honestly);
    # how many of those pass the conclusive test depends on the BLAS's rounding (7 with one
    # OpenBLAS build, 6 with scipy-openblas 0.3.31): every one is still refused 'converged'
    assert found >= 6, found
