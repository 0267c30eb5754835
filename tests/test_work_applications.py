"""Work in inner applications beside E-MVPs: the ``work`` hook of the
counted operator, the application-weighted cost in results, and the live BIM operator."""

import numpy as np
import pandas as pd
import pytest

from lcpbench import LCP, Operator, solve
from lcpbench.core.operator import OperatorError, apply_uncounted
from lcpbench.problems.suspension.problem import build_contact_problem
from lcpbench.run.runner import result_fields
from lcpbench.run.store import RESULT_COLUMNS


def _spd(n=20, seed=0):
    rng = np.random.default_rng(seed)
    B = rng.standard_normal((n, n))
    return B @ B.T + n * np.eye(n), rng.standard_normal(n)


class _Growing:
    """A user's operator whose k-th product (counted or not) reports k inner applications,
    split 2:1 into made-up kinds "fwd" and "adj" when k is divisible by 3."""

    def __init__(self, A):
        self.A, self.k, self.fwd, self.adj = A, 0, 0, 0

    def matvec(self, v):
        self.k += 1
        if self.k % 3 == 0:
            self.fwd += 2 * self.k // 3
            self.adj += self.k // 3
        else:
            self.fwd += self.k
        return self.A @ v

    def work(self):
        return {"fwd": self.fwd, "adj": self.adj}


def test_user_hook_charges_each_counted_product_and_never_an_uncounted_one():
    A, _ = _spd()
    g = _Growing(A)
    op = Operator(g.matvec, shape=A.shape, work=g.work)
    v = np.linspace(1.0, 2.0, A.shape[0])
    op @ v                                  # product 1: 1 application
    apply_uncounted(op, v)                  # product 2 (uncounted): 2, not charged
    op @ (2 * v)                            # product 3: 3 = 2 fwd + 1 adj
    op @ np.zeros_like(v)                   # free: no product at all
    op @ (3 * v)                            # product 4: 4
    assert op.count == 3 and g.k == 4
    assert op.applications == 1 + 3 + 4
    assert op.applications_by_kind == {"fwd": 1 + 2 + 4, "adj": 1}
    assert op.cold_applications == 1        # the first counted product's applications
    fresh = op.copy()                       # a solve's copy: same hook, zeroed tallies
    assert fresh.applications == 0 and fresh.has_work_hook


def test_solve_reports_the_hooks_totals_and_the_weighted_cost():
    A, b = _spd()
    g = _Growing(A)
    lcp = LCP(Operator(g.matvec, shape=A.shape, work=g.work, cold_applications=4.0), b)
    res = solve(lcp, solver="bb-pgd")
    assert res.solved
    # products 1..mvps were the counted ones (verification runs after the solve)
    assert res.applications == sum(range(1, res.mvps + 1))
    assert sum(res.info["applications"]["high"].values()) == res.applications
    assert res.app_cost == pytest.approx(res.applications / 4.0)
    assert res.emvps == res.mvps                    # E-MVPs stay the paper's count
    row = result_fields(res)
    assert row["applications"] == res.applications and row["app_cost"] == res.app_cost
    assert {"applications", "lofi_applications_total", "app_cost"} <= set(RESULT_COLUMNS)
    assert RESULT_COLUMNS[-1] == "row_crc"


def test_constant_applications_per_product_reduce_to_emvps_with_lows():
    """Every product takes its operator's cold number of applications: app_cost == E-MVPs."""
    A, b = _spd()
    made = {"high": 0, "low": 0}

    def counted(key, M, k):
        def mv(v):
            made[key] += k
            return M @ v
        return Operator(mv, shape=M.shape, work=lambda: made[key], cold_applications=k,
                        name=key, cost={"high": 1.0, "low": 0.25}[key])

    lcp = LCP(counted("high", A, 7), b, low={"low": counted("low", A + 0.1 * np.eye(20), 3)})
    res = solve(lcp, solver="bi-pqn:low=low")
    assert res.lofi_mvps["low"] > 0 and res.mvps > 0
    assert res.applications == 7 * res.mvps and res.lofi_applications["low"] == 3 * res.lofi_mvps["low"]
    assert res.app_cost == pytest.approx(res.emvps, rel=1e-12)


@pytest.mark.parametrize("solver", ["bb-pgd", "mono-pqn"])
def test_without_a_hook_applications_are_products(solver):
    A, b = _spd()
    res = solve(LCP(A, b), solver=solver)
    assert res.applications == res.mvps > 0
    assert res.app_cost == res.emvps
    assert res.info["applications"] == {"high": {"product": res.mvps}}


def test_a_bad_hook_is_named():
    A, _ = _spd()
    with pytest.raises(TypeError, match="work must be a callable"):
        Operator(A, work=5)
    with pytest.raises(ValueError, match="cold_applications must be a positive"):
        Operator(A, work=lambda: 0, cold_applications=0)
    down = iter([5, 3])
    op = Operator(A, work=lambda: next(down))
    with pytest.raises(OperatorError, match="went down"):
        op @ np.ones(20)


def test_bim_operator_reports_its_forward_and_adjoint_krylov_applications():
    """p = 3, three spheres: the counted contact operator charges each counted product the
    GCR iterations the mobility itself records, forward and adjoint separately."""
    c = np.array([[0.0, 0.0, 0.0], [2.2, 0.0, 0.0], [1.1, 1.95, 0.0]])
    F = np.tile([[0.0, -1.0, 0.0]], (3, 1))
    prob = build_contact_problem(c, 1.0, F, None, dt=0.1, delta=0.4, model="bim", p=3,
                                 eps_gmres=1e-8, symmetrize=True)
    op, mob = prob.lcp.A, prob.mobility
    assert prob.lcp.n > 0 and op.has_work_hook
    rng = np.random.default_rng(1)
    fwd, adj = [], []
    for _ in range(3):
        nf, na = len(mob.gmres_iterations), len(mob.adjoint_iterations)
        op @ rng.random(prob.lcp.n)
        fwd += mob.gmres_iterations[nf:]
        adj += mob.adjoint_iterations[na:]
        apply_uncounted(op, rng.random(prob.lcp.n))       # not charged
    assert len(fwd) == 3 and len(adj) == 3                # symmetrised: one of each per product
    assert op.applications_by_kind == {"forward": sum(fwd), "adjoint": sum(adj)}
    assert sum(fwd) > 0 and sum(adj) > 0
    # recycling: the later products need fewer new directions than the first
    assert fwd[-1] + adj[-1] < fwd[0] + adj[0]


def test_bim_declares_the_cold_applications_of_its_non_collisional_solve():
    """The non-collisional solve is the high mobility's first (cold) product: the high
    operator declares its inner applications as its cold_applications, and no cost is
    declared (the step's own counted products price the fidelities)."""
    c = np.array([[0.0, 0.0, 0.0], [2.2, 0.0, 0.0], [1.1, 1.95, 0.0]])
    F = np.tile([[0.0, -1.0, 0.0]], (3, 1))
    prob = build_contact_problem(c, 1.0, F, None, dt=0.1, delta=0.4, model="bim", p=3,
                                 eps_gmres=1e-8, low=["rpy"])
    op, mob = prob.lcp.A, prob.mobility
    cold = op.cold_applications
    assert cold is not None and cold == prob.nc_applications and op.declared_cost is None
    assert len(mob.gmres_iterations) == 1                   # U_nc only: nothing was timed
    before = mob.work_counts()
    with mob.cold_products():
        apply_uncounted(op, np.linspace(3.0, 1.0, prob.lcp.n))    # not a cached vector
    one_cold = sum(mob.work_counts().values()) - sum(before.values())
    assert abs(cold - one_cold) <= 0.25 * one_cold
    assert prob.lcp.low["rpy"].cold_applications == 1.0     # no hook: one per product


def test_report_table_shows_the_median_application_cost():
    from lcpbench.report import ranking
    rows = []
    for i, (e, a) in enumerate([(10, 4.0), (12, 5.0), (14, 9.0)]):
        rows.append({"run_id": f"s/i{i}/bb-pgd", "problem": "s", "family": "s", "instance": f"i{i}",
                     "repeat": 0, "solver": "bb-pgd", "emvps": e, "mvps": e, "solved": True,
                     "multifidelity": False, "mvp_only": True, "time_s": 0.1,
                     "false_convergence": False, "app_cost": a})
    table = ranking.ranking_table(pd.DataFrame(rows), "bb-pgd").set_index("solver")
    assert table.loc["bb-pgd", "median app. cost"] == "5"
    old = pd.DataFrame(rows).drop(columns="app_cost")       # a store from before the column
    assert ranking.ranking_table(old, "bb-pgd").set_index("solver").loc[
        "bb-pgd", "median app. cost"] == "-"


def test_online_table_shows_the_median_application_cost_of_simulate_rows():
    from lcpbench.report import tables
    rows = [{"run_id": f"sim/{k}", "kind": "online", "problem": "lattice:m=2", "solver": "bb-pgd",
             "step": k, "n": 5, "sim_total_s": 1.0, "time_s": 0.5, "emvps": 7.0, "mvps": 7,
             "max_overlap": 0.0, "solved": True, "app_cost": a, "status": "converged",
             "multifidelity": False, "mvp_only": True}
            for k, a in enumerate([2.0, 3.0, 6.0])]
    t = tables.online_table(pd.DataFrame(rows), "bb-pgd")
    assert t.loc[0, "median_app_cost"] == 3.0 and t.loc[0, "median_emvps"] == 7.0


def test_a_store_from_before_the_application_columns_keeps_its_header(tmp_path):
    from lcpbench.run.runner import execute, plan
    from lcpbench.run.store import RunStore
    from lcpbench.run.sweep import Sweep
    sweep = Sweep(solvers=["bb-pgd"], problems=["fathi:sizes=[4,6]"])
    execute(plan(sweep), RunStore(tmp_path), quiet=True)
    new = pd.read_csv(tmp_path / "results.csv")
    assert (new["applications"] == new["mvps"]).all() and (new["app_cost"] == new["emvps"]).all()
    old = new.drop(columns=["applications", "lofi_applications_total", "app_cost",
                            "row_crc"]).iloc[:1]
    old.to_csv(tmp_path / "results.csv", index=False)   # written before the new columns
    store = RunStore(tmp_path)
    assert store.corrupt == []
    execute(plan(sweep), store, quiet=True)
    res = pd.read_csv(tmp_path / "results.csv")
    assert list(res.columns) == list(old.columns) and len(res) == 2
