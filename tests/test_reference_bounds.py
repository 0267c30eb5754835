"""Reference QP solvers that cannot hang.

ProxQP has no time limit of its own and, on some 2 x 2 infeasible problems of the
``infeasible`` family, spends minutes on its 10^5 outer iterations (367 s on the third
instance of ``infeasible:count=4,n=2``, the default seed, on a loaded machine) without
looking at a signal. The reference solvers and the runner's consensus
reference are held to a time limit whether or not one is given.

Each check that would hang on a faulty tree runs in a forked child under a generous
guard (:func:`call_with_deadline`), so a regression fails instead of stalling the suite;
the assertions are on the results, not on the time.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pandas as pd
import pytest
import qpsolvers  # noqa: F401 - imported once here, not inside the timed solves

import lcpbench
import lcpbench.toolkit.qp as qp
from lcpbench import LCP
from lcpbench.cli import main
from lcpbench.core import reference as reference_mod
from lcpbench.core.forked import call_with_deadline
from lcpbench.core.registry import get_problem
from lcpbench.core.result import Status
from lcpbench.core.specs import make_params
from lcpbench.run import runner
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep

#: ``infeasible:count=1,n=2,seed=1``: ProxQP spends minutes on it (killed at 6 s in a probe).
HANGING = "infeasible:count=1,n=2,seed=1"
#: The hang guard of every check below (each returns in a few seconds when fixed).
GUARD_S = 90.0


def _hanging_lcp() -> LCP:
    info = get_problem("infeasible")
    return info.func(make_params("infeasible", info.params,
                                 {"count": 1, "n": 2, "seed": 1}))[0]


def _within_guard(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a forked child; fails the test if it does not return in time."""
    kind, value = call_with_deadline(lambda: fn(*args, **kwargs), (), GUARD_S)
    assert kind == "ok", f"did not return within the {GUARD_S:g} s hang guard ({kind}: {value})"
    return value


def _solve_summary(solver: str, **kw) -> tuple[str, str, bool, int]:
    res = lcpbench.solve(_hanging_lcp(), solver=solver, **kw)
    return res.status.value, res.message, bool(res.solved), int(res.mvps)


def test_proxqp_honours_max_seconds_on_the_hanging_2x2():
    status, message, solved, mvps = _within_guard(_solve_summary, "proxqp", max_seconds=2.0)
    assert status == Status.timeout.value and not solved, message
    # killed by the backend's own limit, or (on a very loaded machine) by the solve's timer
    assert "proxqp: killed at its time limit" in message \
        or "inside the solver's own computation" in message, message
    assert "time budget of 2 s" in message
    assert mvps == 0                                    # no product: the start x0 = 0


def test_proxqp_without_max_seconds_stops_at_the_default_limit(monkeypatch):
    monkeypatch.setattr(reference_mod, "REFERENCE_BASE_SECONDS", 1.0, raising=False)
    status, message, solved, _ = _within_guard(_solve_summary, "proxqp")
    assert status == Status.timeout.value and not solved
    assert "default limit of 1 s at n = 2" in message and "max_seconds" in message


@pytest.mark.parametrize("solver", ["clarabel", "osqp"])
def test_clarabel_and_osqp_answer_the_hanging_2x2(solver):
    # They certify dual infeasibility at once: a failed reference, not a timeout.
    status, message, solved, _ = _within_guard(_solve_summary, solver, max_seconds=5.0)
    assert status in (Status.failed.value, Status.infeasible.value) and not solved
    assert "no solution" in message or "infeasib" in message


def test_default_reference_limit_grows_with_n():
    small, mid, large = (reference_mod.default_reference_seconds(n) for n in (2, 1000, 3000))
    assert 10.0 <= small < mid < large
    assert large / mid > 10                             # the backends' n^3 factorisations


def _stuck_proxqp(A, b, backend, tol, x0, max_seconds):
    if backend == "proxqp":
        while True:                                     # a compiled loop would not see signals
            time.sleep(1)
    return _REAL_SOLVE_HERE(A, b, backend, tol, x0, max_seconds)


_REAL_SOLVE_HERE = getattr(qp, "_solve_here", None)


def _consensus(lcp: LCP, seconds: float):
    ref = lcpbench.reference(lcp, max_seconds=seconds)
    return ref.accepted, ref.solvers, ref.details["proxqp"], ref.kkt_abs


def test_consensus_is_decided_by_the_others_when_one_backend_never_returns(monkeypatch):
    monkeypatch.setattr(qp, "_solve_here", _stuck_proxqp, raising=False)
    rng = np.random.default_rng(3)
    J = rng.standard_normal((6, 6))
    lcp = LCP(J @ J.T + np.eye(6), rng.standard_normal(6))
    accepted, solvers, proxqp, res = _within_guard(_consensus, lcp, 1.0)
    assert accepted and solvers == ["clarabel", "osqp"] and res < 1e-9
    assert proxqp["timeout"] and "killed at its time limit" in proxqp["message"]


def _run_cli(out: str, *extra: str) -> int:
    return main(["run", "--solver", "bb-pgd", "--problem", HANGING, "--out", out,
                 "--quiet", "--no-report", *extra])


def test_run_without_timeout_finishes_and_writes_its_row(tmp_path, monkeypatch):
    # The command on the hanging instance, no --timeout: the consensus reference is
    # held to the default limit (lowered here to 1 s per backend to keep the test short).
    monkeypatch.setattr(reference_mod, "REFERENCE_BASE_SECONDS", 1.0, raising=False)
    out = tmp_path / "store"
    assert _within_guard(_run_cli, str(out)) == 0
    rows = pd.read_csv(out / "results.csv")
    assert len(rows) == 1 and rows["solver"].iloc[0] == "bb-pgd"
    assert rows["status"].iloc[0] != "converged"
    ref = rows["ref_solvers"].iloc[0]
    assert ref.startswith("none (") and "proxqp: killed at its time limit of 1 s" in ref


def test_reference_solver_runs_of_a_sweep_without_timeout_end(tmp_path, monkeypatch):
    monkeypatch.setattr(reference_mod, "REFERENCE_BASE_SECONDS", 1.0, raising=False)
    sweep = Sweep(solvers=["proxqp", "bb-pgd"], problems=[HANGING])

    def work():
        return execute(plan(sweep), RunStore(tmp_path), quiet=True)

    counts = _within_guard(work)
    assert counts["ran"] == 2
    rows = pd.read_csv(tmp_path / "results.csv").set_index("solver")
    assert rows.loc["proxqp", "status"] == "timeout"
    assert "default limit of 1 s" in rows.loc["proxqp", "message"]
    assert rows.loc["bb-pgd", "status"] != "converged"


def _die(*args, **kwargs):
    os._exit(3)


def test_reference_is_isolated_without_timeout(tmp_path, monkeypatch):
    # A reference backend that takes its process down must not take the runner with it,
    # with or without --timeout.
    monkeypatch.setattr(runner, "consensus_reference", _die)
    out = tmp_path / "store"
    assert _within_guard(_run_cli, str(out)) == 0
    rows = pd.read_csv(out / "results.csv")
    assert len(rows) == 1
    assert "reference solve failed: worker process died (exit code 3)" in rows["ref_solvers"][0]


def _interrupted_wait(pid_file: str) -> str:
    def write_pid_and_hang():
        with open(pid_file, "w") as fh:
            fh.write(str(os.getpid()))
        while True:
            time.sleep(1)

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGALRM, interrupt)
    signal.setitimer(signal.ITIMER_REAL, 1.0)
    try:
        call_with_deadline(write_pid_and_hang, (), None)
    except KeyboardInterrupt:
        pass
    pid = int(open(pid_file).read())
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return "gone"
    os.kill(pid, signal.SIGKILL)
    return "left running"


def test_an_interrupted_wait_kills_its_child(tmp_path):
    # Ctrl-C while the runner waits on a reference: the child must not outlive the wait.
    assert _within_guard(_interrupted_wait, str(tmp_path / "pid")) == "gone"


def test_time_running_out_inside_a_backend_is_a_timeout_not_a_retry(monkeypatch):
    # The solve's own timer (or the operator's budget check) ending the time budget while a
    # backend runs must end the solve as timeout, not count as a backend failure that is
    # retried at a looser tolerance.
    from lcpbench.core.operator import BudgetExhausted

    calls = []

    def out_of_time(A, b, backend, tol, *args, **kwargs):
        calls.append(tol)
        raise BudgetExhausted("time budget of 1 s exhausted", kind="time")

    monkeypatch.setattr(qp, "solve_nonneg_qp", out_of_time)
    res = lcpbench.solve(_hanging_lcp(), solver="osqp", max_seconds=1.0)
    assert res.status == Status.timeout and calls == [1e-10]


def test_time_limits_that_are_not_positive_are_refused(tmp_path):
    with pytest.raises(ValueError, match="max_seconds must be > 0"):
        lcpbench.reference(_hanging_lcp(), max_seconds=0)
    sweep = Sweep(solvers=["bb-pgd"], problems=[HANGING])
    with pytest.raises(ValueError, match="reference_timeout must be > 0 seconds, got -1"):
        execute(plan(sweep), RunStore(tmp_path), quiet=True, reference_timeout=-1)
    assert not (tmp_path / "results.csv").exists()


def _running(pid: int) -> bool:
    """True while ``pid`` runs (a zombie waiting to be reaped has ended)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _orphaned_backend(pid_file: str) -> str:
    """A backend call whose parent is SIGKILLed must not run on without it."""
    lcp = _hanging_lcp()
    A, b = lcp.dense(), lcp.b

    def parent():                       # e.g. a run's child, the backend in a grandchild
        return qp.solve_nonneg_qp(A, b, "proxqp", 1e-10, max_seconds=2.0)

    kind, _ = call_with_deadline(parent, (), 0.5)      # the parent is killed at 0.5 s
    assert kind == "timeout"
    deadline = time.monotonic() + 10.0
    while not os.path.exists(pid_file) and time.monotonic() < deadline:
        time.sleep(0.05)
    backend = int(open(pid_file).read())
    time.sleep(2.0 + qp.ORPHAN_SLACK_S + 1.0)           # past the backend's limit and slack
    if not _running(backend):
        return "gone"
    os.kill(backend, signal.SIGKILL)
    return "left running"


def _noting_pid(pid_file):
    real = qp._solve_here

    def solve_here(*args):
        with open(pid_file, "w") as fh:
            fh.write(str(os.getpid()))
        return real(*args)

    return solve_here


def test_a_backend_whose_parent_is_killed_ends_at_its_limit(tmp_path, monkeypatch):
    pid_file = str(tmp_path / "pid")
    monkeypatch.setattr(qp, "_solve_here", _noting_pid(pid_file))
    assert _within_guard(_orphaned_backend, pid_file) == "gone"
