"""What every MVP-only solver owes the framework: the E-MVP budget, and a free start at a solution."""

import pytest
from lcp_cases import planted

import lcpbench
from lcpbench import LCP, Status

MVP_SOLVERS = sorted(n for n, i in lcpbench.list_solvers().items()
                     if i.listed and i.mvp_only and not i.reference and not i.multifidelity)


def test_the_contract_covers_the_paper_baselines():
    assert {"bb-pgd", "a-pgd", "zero-sr1", "l-bfgs-b", "minmap-newton", "mono-pqn"} <= \
        set(MVP_SOLVERS)


@pytest.mark.parametrize("solver", MVP_SOLVERS)
def test_budget_honoured(solver):
    A, b = planted(40, seed=2, cond=1e3)
    res = lcpbench.solve(A, b, solver=solver, stop="kkt", tol=1e-12, max_emvps=5)
    assert res.status is Status.budget, res.summary()
    assert res.mvps <= 5


@pytest.mark.parametrize("solver", MVP_SOLVERS)
def test_warm_start_at_the_solution_costs_one_product(solver):
    A, b = planted(30, seed=6)
    ref = lcpbench.reference(LCP(A, b))
    res = lcpbench.solve(A, b, solver=solver, stop="kkt", tol=1e-7, x0=ref.x)
    assert res.solved and res.mvps == 1 and res.iterations == 0, res.summary()
