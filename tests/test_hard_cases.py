"""Every registered solver on every hard-case family: honest statuses, safeguarded ones solve.

An unsafeguarded method (projected BB without line search, FISTA, zero-memory
SR1, PGS) may fail on a hard case, but then its status must say so: a
"converged" whose verified residual exceeds 10 x tol fails the test for every
solver. The safeguarded and reference solvers must solve every instance (on spd-cond up
to the measured condition-number limits of COND_LIMIT).

The inexact family (every product a CG solve at a declared relative accuracy, 1e-6 and the
looser 1e-4, where CG's actual error exceeds the declaration by up to 2.4x) is checked
against what such an operator allows: its stop threshold is the accuracy floor the
framework announces, a "converged" must hold for a fresh product of the operator at that
accuracy (computed here, outside the framework) and within 10 x the threshold for the
exact operator it approximates (a direct solve), and the safeguarded solvers must meet the
announced threshold.
"""

import numpy as np
import pytest

import lcpbench
from lcpbench.core.context import accuracy_floor
from lcpbench.core.registry import get_problem, solvers
from lcpbench.core.specs import make_params, parse_spec
from lcpbench.problems.inexact import exact_product
from lcpbench.problems.random import with_perturbed_lows

HARD = ["planted", "spd-cond", "singular-psd", "fathi", "tiny", "all-inactive", "bad-scale",
        "bb-cycle", "inexact", "inexact:rtol=1e-4"]
#: Solvers with a globalisation (line search, optimal step on a descent direction, pivoting)
#: or exact QP solves: they must solve every hard case.
SAFEGUARDED = ["bb-pgd:safeguard=true", "l-bfgs-b", "minmap-newton", "mono-pqn", "bi-pqn",
               "multi-pqn", "lemke", "clarabel", "proxqp", "osqp"]
#: spd-cond reaches condition number 1e10. Within the default budget (5000 E-MVPs) these
#: solvers are required to solve spd-cond only up to the condition number given, measured
#: (tol 1e-8, n = 50): safeguarded BB needs 13.5k E-MVPs at 1e7 and does not finish 1e9 in
#: 20k; min-map Newton in the source's configuration (Krylov capped at 200 products,
#: rtol 1e-6) stalls from 1e5 on; L-BFGS-B and OSQP stall at 1e10. Above the limit the
#: run must still report honestly (no "converged" without a verified residual).
COND_LIMIT = {"bb-pgd:safeguard=true": 1e6, "minmap-newton": 1e4, "l-bfgs-b": 1e9,
              "osqp": 1e9}


def _instances(family):
    name, raw = parse_spec(family)
    info = get_problem(name)
    return info.func(make_params(name, info.params, raw))


def _all_solvers():
    return sorted(n for n, info in solvers().items() if info.listed)


def _spec_for(solver, lcp):
    if solver == "bi-pqn":
        return "bi-pqn:low=low"
    if solver == "multi-pqn":
        return "multi-pqn:lows=[low,lower]"
    return solver


def _fresh_residual(lcp, x) -> float:
    """``||min(x, A x + b)||`` by one fresh product of the instance's own (inexact) operator."""
    x = np.asarray(x, dtype=float)
    return float(np.linalg.norm(np.minimum(x, lcp.fresh().A @ x + lcp.b)))


def _exact_residual(lcp, x) -> float:
    """``||min(x, A x + b)||`` with the exact operator the inexact products approximate."""
    x = np.asarray(x, dtype=float)
    return float(np.linalg.norm(np.minimum(x, exact_product(lcp, x) + lcp.b)))


SLOW_FAMILIES = ("spd-cond", "bb-cycle", "inexact:rtol=1e-4")


@pytest.mark.usefixtures("one_blas_thread")
@pytest.mark.parametrize("family", [
    # spd-cond (condition numbers to 1e10, every solver to its budget) takes over 30 s, and
    # bb-cycle (BB-PGD's cycles to its budget; test_pgd.py checks the failure and the
    # safeguard on them) and the looser inexact operator (the exact-rtol one stays) 8-15 s:
    # slow
    pytest.param(f, marks=pytest.mark.slow) if f in SLOW_FAMILIES else f for f in HARD])
def test_no_false_convergence_and_safeguarded_solve(family, true_residual):
    lcps = _instances(family)
    inexact = lcps[0].A.rtol is not None
    assert inexact == family.startswith("inexact")
    failures = []
    for solver in sorted(set(_all_solvers()) | set(SAFEGUARDED)):
        name = solver.split(":")[0]
        multi = solvers()[name].multifidelity
        for i, lcp in enumerate(lcps):
            run = with_perturbed_lows(lcp, i) if multi else lcp
            assert run.A.rtol == lcp.A.rtol      # the lows never replace an inexact operator
            res = lcpbench.solve(run, solver=_spec_for(solver, run) if multi else solver,
                                 tol=1e-8)
            assert not res.false_convergence, (solver, lcp.name, res.summary())
            if inexact:      # the threshold announced is the operator's accuracy floor
                assert res.threshold == pytest.approx(accuracy_floor(lcp), rel=1e-12)
                assert f"{res.threshold:.3g}" in res.message or res.status.value != "converged"
                check = _fresh_residual
            else:
                check = true_residual
            if np.all(np.isfinite(res.x)):   # the framework's verification, recomputed here
                assert check(lcp, res.x) == pytest.approx(
                    res.verified_kkt_abs, rel=1e-6, abs=1e-12 * res.threshold), (solver, lcp.name)
            if res.status.value == "converged":
                if inexact:   # confirmed by a fresh product at the operator's stated accuracy
                    assert _fresh_residual(lcp, res.x) <= res.threshold, \
                        (solver, lcp.name, res.summary())
                    assert _exact_residual(lcp, res.x) <= 10 * res.threshold, \
                        (solver, lcp.name, res.summary())
                else:
                    assert true_residual(lcp, res.x) <= 10 * res.threshold, \
                        (solver, lcp.name, res.summary())
            if solver in SAFEGUARDED and not res.solved:
                cond = lcp.meta.get("cond") or 0
                if family == "spd-cond" and cond > COND_LIMIT.get(solver, np.inf):
                    continue
                failures.append((solver, lcp.name, res.summary()))
    assert not failures, "\n".join(map(str, failures))
