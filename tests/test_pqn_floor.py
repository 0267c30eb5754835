"""Bi-PQN at its floor: the low-fidelity start, the forcing term, the model check, the free
secant pair, the paper-code stop rule and the fidelity-advantage map."""

import json

import numpy as np
import pandas as pd
import pytest

import lcpbench
from lcpbench import LCP, Operator
from lcpbench.core.residuals import StopRule, make_stop_rule
from lcpbench.problems.synthetic_low import (
    SyntheticLowParams,
    low_error,
    parse_low_name,
    synthetic_low,
)
from lcpbench.report.fidelity_map import fidelity_map_section, fidelity_map_table
from lcpbench.solvers.pqn.bi import forcing_term, model_check
from lcpbench.solvers.pqn.params import BiPQNParams
from lcpbench.toolkit.quasinewton import free_secant_pair


def _problem(n=60, cond=30, rel=1e-3, seed=0, warm=False, ratio=0.1):
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = (Q * np.logspace(0, np.log10(cond), n)) @ Q.T
    A = (A + A.T) / 2
    E = rng.standard_normal((n, n))
    E = (E + E.T) / 2
    E *= rel * np.linalg.norm(A, 2) / np.linalg.norm(E, 2)
    b = rng.standard_normal(n)
    x0 = None
    if warm:   # a warm start near the answer, as a time stepper's previous forces
        x = lcpbench.solve(A, b, solver="mono-pqn", tol=1e-12).x
        x0 = np.maximum(x + 0.05 * np.abs(x).max() * rng.standard_normal(n), 0.0)
    return LCP(Operator(A, cost=1.0), b, x0=x0,
               low={"low": Operator(A + E, cost=ratio)}, psd_check=False)


@pytest.mark.parametrize("warm", [False, True])
def test_accurate_low_needs_two_or_three_high_mvps(warm):
    # low accurate to 1e-7: one high MVP at the low solve's answer, then outer steps whose
    # subproblems are solved to the model's accuracy; with the low start solved tighter
    # (warm_rtol) the first outer step already finishes
    for seed in range(3):
        lcp = _problem(rel=1e-7, seed=seed, warm=warm)
        res = lcpbench.solve(lcp, solver="bi-pqn", tol=1e-8)
        assert res.solved, res.summary()
        assert res.mvps <= 3, (res.mvps, res.info["decisions"])
        assert res.info["decisions"][0] == "start:low"
        assert res.info["forcing"][0] < 1e-6        # the subproblem follows the model's accuracy
        tight = lcpbench.solve(lcp, solver="bi-pqn:warm_rtol=1e-5", tol=1e-8)
        assert tight.solved and tight.mvps <= 2, (tight.mvps, tight.info["decisions"])


def test_low_start_spends_no_high_mvp_before_the_low_solve():
    res = lcpbench.solve(_problem(rel=1e-3, warm=True), solver="bi-pqn", tol=1e-8)
    hist = res.history
    # the first reported iterate already is the low solve's answer: low products before it
    assert hist["mvps"].iloc[0] == 1 and hist["lofi_mvps"].iloc[0] > 1


def test_old_start_is_kept_as_an_option_and_costs_a_high_mvp_more():
    hi = [lcpbench.solve(_problem(rel=1e-6, seed=s, warm=True), solver=f"bi-pqn:start={st}",
                         tol=1e-8).mvps for s in range(3) for st in ("low", "high")]
    assert sum(hi[1::2]) > sum(hi[0::2])


def test_useless_low_is_handed_to_mono_pqn():
    # a 60% random error: the model check must notice it and stop spending low products
    for seed in range(3):
        lcp = _problem(rel=0.6, seed=seed, warm=True, ratio=0.08)
        res = lcpbench.solve(lcp, solver="bi-pqn", tol=1e-8)
        mono = lcpbench.solve(lcp, solver="mono-pqn", tol=1e-8)
        assert res.solved, res.summary()
        assert res.info["abandoned_low"] and "mono:model" in res.info["decisions"]
        assert res.info["model_errors"][0] > 0.5
        assert res.emvps <= 1.3 * mono.emvps, (res.emvps, mono.emvps)


def test_model_check_and_forcing_term():
    A = np.diag([1.0, 2.0, 4.0])
    p = np.array([1.0, -1.0, 0.5])
    assert model_check(A @ p, A @ p) == 0.0
    assert model_check(A @ p, 0.5 * (A @ p)) == pytest.approx(0.5)
    assert forcing_term(None, 0.1) == 0.1                   # nothing measured: the cap
    assert forcing_term(1e-3, 0.1) == pytest.approx(5e-4)   # an accurate model: solve deeper
    assert forcing_term(0.9, 0.1) == 0.1                    # a poor one: not over-solved
    with pytest.raises(ValueError, match="start"):
        BiPQNParams(start="middle")


def test_free_secant_pair():
    rng = np.random.default_rng(1)
    A = np.diag(rng.uniform(1, 2, 5))
    b = rng.standard_normal(5)
    x = rng.uniform(0, 1, 5)
    s, y = free_secant_pair(x, A @ x + b, b)
    assert np.allclose(s, x) and np.allclose(y, A @ x)
    assert free_secant_pair(np.zeros(5), b, b) is None


def test_bb_pgd_first_step_from_the_free_pair_saves_the_cauchy_product():
    # A = c I: the BB step of the pair (x0, A x0) is 1/c, exact, so one step solves it
    c, n = 3.0, 6
    x_star = np.linspace(0.5, 1.5, n)
    b = -c * x_star
    lcp = LCP(Operator(c * np.eye(n)), b, x0=np.ones(n))
    free = lcpbench.solve(lcp, solver="bb-pgd", tol=1e-10)
    cauchy = lcpbench.solve(lcp, solver="bb-pgd:free_pair=false", tol=1e-10)
    assert free.solved and cauchy.solved
    assert free.mvps == 2 and cauchy.mvps == 3


def test_zero_sr1_and_mono_pqn_use_the_free_pair():
    lcp = _problem(seed=2, warm=True)
    for spec, off in (("zero-sr1", "zero-sr1:first_step=1e-3"),
                      ("mono-pqn", "mono-pqn:free_pair=false")):
        for s in (spec, off):
            res = lcpbench.solve(lcp, solver=s, tol=1e-9)
            assert res.solved, res.summary()
    assert lcpbench.solve(lcp, solver="mono-pqn", tol=1e-9).info.get("free_pair")
    assert "free_pair" not in lcpbench.solve(lcp, solver="mono-pqn:free_pair=false",
                                             tol=1e-9).info


def test_paper_code_stop_rule_is_the_squared_norm():
    rule = make_stop_rule("paper-code", 1e-8)
    assert rule == StopRule("paper-code", tol=1e-8)
    assert rule.threshold(np.ones(3)) == pytest.approx(1e-4)
    assert rule.check(0.9e-4, float("nan"), np.ones(3)) == "converged"
    assert rule.check(1.1e-4, 1e-12, np.ones(3)) is None          # no relative test
    lcp = _problem(seed=4)
    loose = lcpbench.solve(lcp, solver="bb-pgd", stop="paper-code", tol=1e-8)
    tight = lcpbench.solve(lcp, solver="bb-pgd", stop="paper", tol=1e-8)
    assert loose.solved and tight.solved
    assert 1e-8 < loose.verified["kkt_abs"] <= 1e-4 and loose.emvps < tight.emvps
    with pytest.raises(ValueError, match="paper-code"):
        make_stop_rule("paper_code", 1e-8)


def test_synthetic_low_errors_are_as_named():
    lcps = synthetic_low(SyntheticLowParams(path="lattice-bim-m4", instances="0",
                                            errors=(1e-1, 1e-4)))
    lcp = lcps[0]
    A = lcpbench.core.operator.dense_uncounted(lcp.A)
    names = set(lcp.low)
    assert {"random~0.1", "random~0.0001", "like~0.1", "like~0.0001"} <= names
    for name, op in lcp.low.items():
        shape, err = parse_low_name(name)
        M = lcpbench.core.operator.dense_uncounted(op)
        assert low_error(A, M) == pytest.approx(err, rel=0.05 if shape in ("random", "like")
                                                else 0.03)
        assert np.allclose(M, M.T)
    real = [n for n in names if not n.startswith(("random", "like"))]
    assert {n.split("~")[0] for n in real} == {"p3e6", "p4e6", "rpy"}
    with pytest.raises(ValueError, match="like"):
        synthetic_low(SyntheticLowParams(path="lattice-bim-m4", instances="0", like="p9"))
    with pytest.raises(ValueError, match="errors"):
        SyntheticLowParams(errors=(0.0,))


def _row(solver, low, emvps, mvps, problem="synthetic-low:x", solved=True):
    params = {"low": low} if low else {}
    return {"problem": problem, "solver_name": solver, "solver_params": json.dumps(params),
            "emvps": emvps, "mvps": mvps, "solved": solved}


def test_fidelity_map_table_from_run_rows():
    rows = [_row("bi-pqn", "like~0.001", 4.0, 3, solved=True),
            _row("bi-pqn", "like~0.001", 6.0, 5, solved=True),
            _row("bi-pqn", "like~0.001", 99.0, 99, solved=False),   # unsolved: not counted
            _row("bi-pqn", "random~0.1", 9.0, 8),
            _row("bi-pqn", "p4e6~0.21", 10.0, 7), _row("bi-pqn", "p4e6~0.23", 10.4, 7),
            _row("mono-pqn", "", 12.0, 12), _row("bb-pgd", "", 14.0, 14),
            _row("bi-pqn", "p4e6", 8.0, 7, problem="set-lattice-bim-m3")]  # no error: ignored
    table = fidelity_map_table(pd.DataFrame(rows))
    assert set(table["problem"]) == {"synthetic-low:x"}
    like = table[table["low"] == "like"].iloc[0]
    assert like["high_mvps"] == 4 and like["emvps"] == 5.0 and like["runs"] == 2
    real = table[table["low"] == "real p4e6"].iloc[0]
    assert real["rel_error"] == pytest.approx(0.22) and real["runs"] == 2
    assert (table["best_single_fidelity"] == 12.0).all()
    html, _ = fidelity_map_section(pd.DataFrame(rows))
    assert "Fidelity advantage" in html and "<svg" in html
    assert fidelity_map_section(pd.DataFrame([_row("bi-pqn", "p4e6", 8.0, 7)]))[0] == ""
