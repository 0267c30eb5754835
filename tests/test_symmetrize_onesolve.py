"""One forward solve per contact product (symmetrize=False) against the symmetrised pair.

The numbers behind docs/mobility.md, "One solve per product?": on the unsymmetrised
boundary-integral operator the solvers converge as on the symmetrised one, the products
spend no adjoint solves, and the answer moves by less than the operator's asymmetry.
"""

import numpy as np
import pytest

from lcpbench import run_solver
from lcpbench.core.operator import dense_uncounted
from lcpbench.problems.suspension.problem import build_contact_problem

C = np.array([[0.0, 0.0, 0.0], [2.05, 0.3, 0.0], [0.3, 2.2, 0.2], [0.2, 0.8, 2.1]])
F = -20.0 * (C - C[0])                 # pulls the others onto sphere 0: two active contacts
# a low makes the problem count inner applications per kind (info["applications"])
KW = dict(dt=1.0, delta=0.5, model="bim", p=4, eps_gmres=1e-10, low=("p3",))


@pytest.mark.parametrize("solver", ["bb-pgd", "mono-pqn"])
def test_one_solve_operator_converges_and_moves_the_answer_less_than_its_asymmetry(solver):
    pair = build_contact_problem(C, 1.0, F, symmetrize=True, **KW)
    one = build_contact_problem(C, 1.0, F, symmetrize=False, **KW)
    B = dense_uncounted(build_contact_problem(C, 1.0, F, symmetrize=False, **KW).lcp.A)
    asym = np.linalg.norm(B - B.T) / np.linalg.norm(B)
    assert asym > 1e-6                               # the discretisation's asymmetry is there
    rp = run_solver(pair.lcp, solver, tol=1e-9)
    ro = run_solver(one.lcp, solver, tol=1e-9)
    assert rp.solved and ro.solved
    assert not ro.false_convergence
    apps = ro.info["applications"]["high"]
    assert apps["forward"] > 0 and apps["adjoint"] == 0
    assert rp.info["applications"]["high"]["adjoint"] > 0
    assert abs(ro.mvps - rp.mvps) <= 2
    assert np.linalg.norm(ro.x - rp.x) <= asym * np.linalg.norm(rp.x)
    assert np.linalg.norm(ro.x - rp.x) > 0


def test_default_boundary_integral_contact_operator_is_one_forward_solve_per_product():
    """Without ``symmetrize`` the high and the boundary-integral lows are ``D' M D``: n
    products cost n forward solves and no adjoint; ``symmetrize=True`` still pairs them."""
    kw = dict(KW, low=("p3",))
    prob = build_contact_problem(C, 1.0, F, **kw)
    n = prob.lcp.n
    assert n >= 2 and not prob.lcp.meta["symmetrized"]
    before = prob.extra_solves
    dense_uncounted(prob.lcp.A)
    assert prob.extra_solves - before == n
    assert prob.lcp.A.applications_by_kind.get("adjoint", 0) == 0
    mob = prob.mobility
    assert len(mob.adjoint_iterations) == 0
    low = dense_uncounted(prob.lcp.low["p3"])
    assert np.linalg.norm(low - low.T) > 1e-8 * np.linalg.norm(low)   # not symmetrised
    paired = build_contact_problem(C, 1.0, F, symmetrize=True, **kw)
    before = paired.extra_solves
    dense_uncounted(paired.lcp.A)
    assert paired.lcp.meta["symmetrized"] and paired.extra_solves - before == 2 * n
