"""Reference QP solvers (clarabel, proxqp, osqp) and the bb-cycle instances."""

from __future__ import annotations

import numpy as np
import pytest

import lcpbench
from lcpbench.core.registry import get_problem, get_solver
from lcpbench.core.result import Status
from lcpbench.core.specs import make_params

REFERENCE = ("clarabel", "proxqp", "osqp")

#: Small instances of every family (spd-cond up to 1e8: OSQP picks a wrong
#: active set at condition number 1e10, a documented limitation).
FAMILIES = {
    "planted": {"count": 2, "n_active": 6, "n_inactive": 5, "n_degenerate": 2},
    "spd-cond": {"count": 4, "n": 12, "cond_max": 1e8},
    "singular-psd": {"count": 2, "n_independent": 8, "n_duplicate": 3, "n_combination": 3,
                     "dof": 12},
    "fathi": {"sizes": "[4,10,20]"},
    "tiny": {},
    "all-inactive": {"count": 2, "n": 10},
    "bad-scale": {"count": 2, "n": 12},
    "bb-cycle": {},
    "random-spd": {"count": 1, "n_min": 30, "n_max": 40},
    "bifidelity": {"count": 1, "n": 20, "indefinite": True},
}


def generate(name: str) -> list:
    info = get_problem(name)
    return info.func(make_params(name, info.params, FAMILIES[name]))


def all_instances() -> list:
    return [lcp for name in FAMILIES for lcp in generate(name)]


@pytest.mark.parametrize("name", REFERENCE)
def test_registered_as_reference(name):
    info = get_solver(name)
    assert info.needs_dense and info.reference and not info.mvp_only
    p = info.params()
    assert p.tol == 1e-10 and p.polish and p.refine_steps == 3 and p.retries == 2
    p2 = make_params(name, info.params, {"tol": "1e-9", "polish": "false", "refine_steps": "0"})
    assert (p2.tol, p2.polish, p2.refine_steps) == (1e-9, False, 0)
    with pytest.raises((ValueError, TypeError)):
        make_params(name, info.params, {"tol": "0"})
    with pytest.raises((ValueError, TypeError)):
        make_params(name, info.params, {"nope": "1"})


@pytest.mark.parametrize("solver", REFERENCE)
def test_reference_solvers_solve_every_family(solver):
    failures = []
    for lcp in all_instances():
        res = lcpbench.solve(lcp, solver=solver)
        assert res.mvps <= 1 and not res.mvp_only
        if not (res.solved and res.status == Status.converged):
            failures.append(f"{lcp.name}: {res.summary()}")
        if lcp.reference is not None and lcp.n:
            w = np.asarray(lcp.reference["w"])
            assert np.linalg.norm(res.w - w) <= 1e-7 * max(1.0, np.linalg.norm(w)), lcp.name
    assert not failures, "\n".join(failures)


def test_one_counted_mvp_for_w():
    lcp = generate("planted")[0]
    res = lcpbench.solve(lcp, solver="proxqp")
    assert res.mvps == 1 and res.iterations == 0
    np.testing.assert_allclose(res.w, lcp.dense() @ res.x + lcp.b, atol=1e-12)


def test_backend_failure_is_failed(monkeypatch):
    import lcpbench.toolkit.qp as mod

    lcp = generate("planted")[0]
    calls = []

    def fail(A, b, backend, tol, **limits):
        calls.append(tol)
        return None, f"{backend}: no solution (x)"

    monkeypatch.setattr(mod, "solve_nonneg_qp", fail)
    res = lcpbench.solve(lcp, solver="osqp")
    assert res.status == Status.failed and "no solution" in res.message and not res.solved
    assert calls == pytest.approx([1e-10, 1e-8, 1e-6])
    assert res.info["tol_used"] == pytest.approx(1e-6)

    def boom(*a, **k):
        raise RuntimeError("backend crashed")

    monkeypatch.setattr(mod, "solve_nonneg_qp", boom)
    res = lcpbench.solve(lcp, solver="clarabel")
    assert res.status == Status.failed and "backend crashed" in res.message


def test_refine_rescues_singular_active_set():
    from lcpbench.toolkit.qp import polish_active_set, refine_active_set, solve_nonneg_qp

    for lcp in generate("singular-psd"):
        A, b = lcp.dense(), lcp.b
        x, _ = solve_nonneg_qp(A, b, "clarabel", 1e-10)
        x = polish_active_set(A, b, x)
        xr = refine_active_set(A, b, x)
        r0 = np.linalg.norm(np.minimum(x, A @ x + b))
        r1 = np.linalg.norm(np.minimum(xr, A @ xr + b))
        assert r1 <= r0 and r1 < 1e-10 and np.all(xr >= 0)


# ---------------------------------------------------------------------- bb-cycle
@pytest.mark.parametrize("lcp", generate("bb-cycle"), ids=lambda lcp: lcp.name)
def test_bb_cycle_defeats_unsafeguarded_bb(lcp, benchmark_script):
    # The search script's own projected BB1 loop (independent of solvers/pgd.py).
    search = benchmark_script("find_bb_cycles")
    with np.errstate(all="ignore"):
        r = search.projected_bb(lcp.dense(), lcp.b, 2000)
    assert not np.min(np.nan_to_num(r[-500:], nan=np.inf)) <= 1e-8
    # The registered solver with default parameters, capped at 2000 iterations.
    with np.errstate(all="ignore"):
        res = lcpbench.solve(lcp, solver="bb-pgd", max_iter=2000, max_emvps=10000)
    assert res.status != Status.converged and not res.solved, res.summary()
    # ... while the consensus reference solves it.
    ref = lcpbench.reference(lcp)
    assert ref.accepted and ref.kkt_abs < 1e-10
