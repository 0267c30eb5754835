"""Property tests: on random SPD, singular PSD and degenerate LCPs every MVP solver is honest.

For each drawn LCP and each MVP-only solver: a claimed convergence is never
false (the framework's verified residual meets the bound), a solved run's
``w`` agrees with the consensus reference of the QP solvers, the counts are
consistent with the history, and the result is feasible up to the tolerance.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lcpbench
from lcpbench import LCP, Status
from lcpbench.problems.random import with_perturbed_lows

SOLVERS = sorted(name for name, info in lcpbench.list_solvers().items()
                 if not info.needs_dense and not info.reference and info.listed)


@st.composite
def lcps(draw):
    """A small PSD LCP: SPD, singular PSD, or with a degenerate planted solution."""
    kind = draw(st.sampled_from(["spd", "singular", "degenerate"]))
    n = draw(st.integers(1, 12))
    seed = draw(st.integers(0, 2**32 - 1))
    scale = 10.0 ** draw(st.integers(-3, 3))
    rng = np.random.default_rng(seed)
    if kind == "singular":
        rank = draw(st.integers(0, max(n - 1, 0)))
        B = rng.standard_normal((n, rank))
        A = B @ B.T
    else:
        Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
        A = (Q * np.logspace(0, draw(st.floats(0.0, 4.0)), n)) @ Q.T
    A = scale * (A + A.T) / 2
    u = rng.random(n)
    x = np.where(u < 0.4, rng.random(n) + 0.1, 0.0)
    w = np.where(u > 0.6, rng.random(n) + 0.1, 0.0)
    if kind != "degenerate":                         # strict complementarity
        w = np.where(x > 0, 0.0, rng.random(n) + 0.1)
    b = w - A @ x
    return with_perturbed_lows(LCP(A, b, name=f"{kind}-n{n}-s{seed}"), seed)


def _spec(name: str) -> str:
    return {"bi-pqn": "bi-pqn:low=low", "multi-pqn": "multi-pqn:lows=[low,lower]"}.get(name, name)


_SETTINGS = dict(deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@settings(max_examples=20, **_SETTINGS)
@given(lcp=lcps())
@pytest.mark.parametrize("solver", SOLVERS)
def test_solvers_are_honest_on_random_lcps(solver, lcp):
    _check_honest(solver, lcp)


@pytest.mark.slow
@settings(max_examples=150, **_SETTINGS)
@given(lcp=lcps())
@pytest.mark.parametrize("solver", SOLVERS)
def test_solvers_are_honest_on_many_random_lcps(solver, lcp):
    """The same properties on a wider sample (a different stream of examples)."""
    _check_honest(solver, lcp)


def _check_honest(solver: str, lcp: LCP) -> None:
    res = lcpbench.solve(lcp, solver=_spec(solver), stop="kkt", tol=1e-9, max_emvps=3000)
    assert not res.false_convergence, (lcp.name, res.summary())
    assert res.status != Status.failed, (lcp.name, res.message)
    framework = res.info.get("confirmation_mvps", 0) + res.info.get("infeasibility_mvps", 0)
    # the history has one row per reported iterate: products a solver spends after its last
    # iterate (a failed line search before it gives up) are counted but in no row
    recorded = res.history["mvps"].iloc[-1] + framework
    assert res.mvps >= recorded, (lcp.name, res.summary())
    if res.status == Status.converged:          # ended by the stop rule at a reported iterate
        assert res.mvps == recorded, (lcp.name, res.summary())
    assert np.all(res.x >= 0), "iterates must be feasible (x >= 0)"
    w = lcp.dense() @ res.x + lcp.b                 # the true w of the returned x
    ref = lcpbench.reference(lcp)
    if not ref.accepted:
        return
    # x >= 0 is feasible for min 1/2 x'Ax + b'x s.t. x >= 0: nobody beats the optimum
    f = 0.5 * res.x @ (w + lcp.b)
    assert f >= ref.objective - 1e-9 * max(1.0, abs(ref.objective)), (lcp.name, res.summary())
    if res.solved and not lcp.name.startswith("singular"):
        # error bound for SPD LCPs (Mathias & Pang 1990, with c(A) >= lambda_min / n):
        # ||x - x*||_inf <= (1 + ||A||) n / lambda_min * ||min(x, w)||_inf
        ev = np.linalg.eigvalsh(lcp.dense())
        n = lcp.n
        bound = ev[-1] * np.sqrt(n) * (1 + ev[-1]) * n / ev[0] * res.verified["kkt_abs_inf"]
        err = np.linalg.norm(w - ref.w)
        assert err <= 2 * bound + 1e-9 * max(1.0, np.linalg.norm(ref.w)), (lcp.name, err, bound)


def test_the_solver_list_is_not_empty():
    assert {"bb-pgd", "mono-pqn", "bi-pqn", "multi-pqn"} <= set(SOLVERS)
