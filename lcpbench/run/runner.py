"""Run a sweep: plan the runs, solve each, verify it, append it to the run store.

Every run is verified by the framework (one uncounted product, inside
:func:`lcpbench.core.api.run_solver`) and compared with the instance's reference
when one exists: a stored one (planted solutions, stored sets) or the
consensus of the QP solvers (:func:`lcpbench.reference`) for explicit
matrices up to ``reference_max_n``, always in a forked child and under a time
limit, whether or not the sweep has a timeout: each backend gets the per-run
timeout, or without one :func:`lcpbench.core.reference.default_reference_seconds`
(a reference that fails or hangs is recorded in the rows' ``ref_solvers``, not
waited for; the rows are written all the same).

Execution is delegated to an executor (:mod:`lcpbench.run.executors`): in this
process, in forked children (at most ``jobs`` at a time, each inheriting the
problem instances: nothing is pickled but the result) or on Dask. A run over
its timeout is killed and recorded as ``timeout``; a run whose process dies
is recorded as ``failed`` with its exit status (and run once more on resume,
see :meth:`lcpbench.run.store.RunStore.done_ids`). The sweep never stops for
one run.
"""

from __future__ import annotations

import json
import os
import platform
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
import pandas as pd

from lcpbench.core.api import run_solver
from lcpbench.core.clock import utc_now
from lcpbench.core.context import Budget
from lcpbench.core.forked import call_with_deadline
from lcpbench.core.lcp import LCP
from lcpbench.core.reference import default_reference_seconds, reference_without
from lcpbench.core.reference import reference as consensus_reference
from lcpbench.core.registry import get_problem, get_solver
from lcpbench.core.specs import make_params
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import RunSpec, Spec, Sweep, per_low

__all__ = ["Plan", "plan", "result_fields", "execute", "perform", "instance_reference", "machine_info"]

#: Consensus references are computed for explicit instances up to this size.
REFERENCE_MAX_N = 3000
#: QP backends of the consensus (each held to the reference time limit in turn).
REFERENCE_BACKENDS = ("clarabel", "proxqp", "osqp")


@dataclass
class Plan:
    """The runs of a sweep and the instances they need."""

    sweep: Sweep
    runs: list[RunSpec]
    instances: dict[str, list[LCP]]
    skipped: list[str] = field(default_factory=list)

    def lcp(self, run: RunSpec) -> LCP:
        """The instance a run solves."""
        return self.instances[_problem_key(run.problem)][run.instance]


def _problem_key(spec: Spec) -> str:
    return spec.name + json.dumps(spec.params, sort_keys=True)


def generate(spec: Spec) -> list[LCP]:
    """The instances of one problem spec."""
    info = get_problem(spec.name)
    lcps = info.func(make_params(spec.name, info.params, spec.values()))
    if not isinstance(lcps, (list, tuple)) or not all(isinstance(p, LCP) for p in lcps):
        raise TypeError(f"problem {spec.name!r} must return a list of LCP, got {type(lcps)}")
    return list(lcps)


def plan(sweep: Sweep, progress: bool = False) -> Plan:
    """Expand the sweep into runs (validating every spec first); ``progress``: a bar on stderr."""
    from tqdm.auto import tqdm

    solver_specs = sweep.solver_specs()
    problem_specs = sweep.problem_specs()
    instances, runs, skipped = {}, [], []
    for ps in tqdm(problem_specs, desc="planning", unit="spec", file=sys.stderr,
                   disable=not progress, delay=2.0):
        lcps = generate(ps)
        instances[_problem_key(ps)] = lcps
        for ss in solver_specs:
            info = get_solver(ss.name)
            for i, lcp in enumerate(lcps):
                if info.multifidelity and not lcp.low:
                    skipped.append(f"{ss.label} on {ps.label}/{lcp.name}: no low-fidelity operator")
                    continue
                for spec in (per_low(ss, lcp.low) if info.multifidelity else [ss]):
                    for r in range(sweep.repeat):
                        runs.append(RunSpec(ps, i, lcp.name or str(i), spec, r, sweep.tol,
                                            sweep.stop, sweep.max_emvps))
    return Plan(sweep, runs, instances, skipped)


def instance_reference(lcp: LCP, max_n: int = REFERENCE_MAX_N,
                       timeout: Optional[float] = None) -> Optional[dict]:
    """The reference of an instance: stored, else the QP consensus for explicit A.

    The consensus always runs in a forked child. Each of its backends is held
    to ``timeout`` seconds (default :func:`default_reference_seconds` of ``n``,
    10 s for small problems: a backend still running then is killed and the
    others decide), and the child is killed after ``(backends + 1) * timeout``
    (the backends plus their dense polish), so neither a backend that never
    returns nor a stuck polish can stall the sweep. A reference that fails,
    dies or times out is recorded as ``{"failed": reason}`` (the runs of the
    instance then carry the reason in ``ref_solvers``) instead of being waited
    for. None: the instance gets no reference (matrix-free or too large).
    """
    if lcp.reference is not None:
        ref = dict(lcp.reference)
        ref.setdefault("solvers", ref.get("solvers", ["stored"]))
        return ref
    if not lcp.A.explicit or lcp.n > max_n:
        return None
    seconds = default_reference_seconds(lcp.n) if timeout is None else float(timeout)
    whole = (len(REFERENCE_BACKENDS) + 1) * seconds
    kind, value = call_with_deadline(_consensus_dict, (lcp, seconds), whole)
    if kind == "ok":
        return value
    if kind == "timeout":
        return {"failed": f"reference solve killed after {whole:g} s"}
    return {"failed": f"reference solve failed: {value}"}


def _consensus_dict(lcp: LCP, seconds: float) -> dict:
    try:
        return consensus_reference(lcp, REFERENCE_BACKENDS, max_seconds=seconds).as_dict()
    except RuntimeError as exc:          # no backend solved it: a reason, not an error
        return {"failed": str(exc)}


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / max(1.0, float(np.linalg.norm(b))))


def result_fields(res) -> dict:
    """The run-store columns that come from a :class:`~lcpbench.SolveResult` alone."""
    v = res.verified
    return {
        "solved": bool(res.solved), "false_convergence": bool(res.false_convergence),
        "float64_floor": "float64_floor" in v,
        "claimed_kkt_abs": res.claimed_kkt_abs, "verified_kkt_abs": v.get("kkt_abs"),
        "verified_kkt_inf": v.get("kkt_abs_inf"), "verified_comp_gap": v.get("comp_gap"),
        "verified_infeas_x": v.get("infeas_x"), "verified_infeas_w": v.get("infeas_w"),
        "threshold": res.threshold, "mvps": res.mvps,
        "lofi_mvps": json.dumps(res.lofi_mvps, sort_keys=True),
        "lofi_mvps_total": int(sum(res.lofi_mvps.values())), "emvps": res.emvps,
        "iterations": res.iterations, "time_s": res.time_s, "mvp_time_s": res.mvp_time_s,
        "applications": res.applications,
        "lofi_applications_total": float(sum(res.lofi_applications.values())),
        "app_cost": res.app_cost, "framework_mvps": res.framework_mvps,
    }


def perform(run: RunSpec, lcp: LCP, ref: Optional[dict], timeout: Optional[float] = None
            ) -> tuple[dict, pd.DataFrame]:
    """Solve one run and build its result row and history."""
    started = utc_now()
    budget = Budget(max_emvps=run.max_emvps, max_seconds=timeout)
    res = run_solver(lcp, run.solver.name, stop=run.stop, tol=run.tol, budget=budget,
                     params=run.solver.values())
    v = res.verified
    row = _base_row(run, lcp)
    row.update({"status": res.status.value, "message": res.message, **result_fields(res),
                "info": json.dumps(res.info, sort_keys=True, default=str), "started": started})
    if ref is not None and "failed" in ref:
        row["ref_solvers"] = f"none ({ref['failed']})"
    elif ref is not None and lcp.n > 0 and np.all(np.isfinite(res.x)):
        w = lcp.residual_w(res.x)
        row["ref_err_w"] = _rel(w, np.asarray(ref["w"]))
        f = float(v.get("objective", np.nan))
        row["ref_err_objective"] = abs(f - float(ref["objective"])) / max(
            1.0, abs(float(ref["objective"])))
        row["ref_solvers"] = ",".join(ref.get("solvers", []))
        other = reference_without(ref, run.solver.name) if run.solver.name in ref.get(
            "answers", {}) else None
        if other is not None:               # a reference backend: scored against the others
            row["ref_err_w_others"] = _rel(w, other[1])
    row["finished"] = utc_now()
    return row, res.history


def _base_row(run: RunSpec, lcp: LCP) -> dict:
    """The columns that describe a run, whatever its outcome."""
    info = get_solver(run.solver.name)
    return {"run_id": run.run_id, "kind": "offline", "problem": run.problem.label,
            "problem_params": json.dumps(run.problem.params, sort_keys=True),
            "family": lcp.meta.get("family", run.problem.name), "instance": run.instance_name,
            "instance_index": run.instance, "n": lcp.n, "solver": run.solver.label,
            "solver_name": run.solver.name,
            "solver_params": json.dumps(run.solver.params, sort_keys=True),
            "mvp_only": info.mvp_only, "multifidelity": info.multifidelity,
            "reference_solver": info.reference, "tol": run.tol, "stop": run.stop,
            "repeat": run.repeat}


def _failure_row(run: RunSpec, lcp: LCP, status: str, message: str,
                 elapsed: Optional[float] = None) -> dict:
    """The row of a run that produced no result (timeout, died, framework error)."""
    row = _base_row(run, lcp)
    row.update({"status": status, "message": message, "solved": False,
                "false_convergence": False, "started": utc_now(), "finished": utc_now()})
    if elapsed is not None:
        row["time_s"] = float(elapsed)
    return row


def _safe_perform(run, lcp, ref, timeout):
    import time

    t0 = time.monotonic()
    try:
        return perform(run, lcp, ref, timeout)
    except (Exception, SystemExit) as exc:  # the framework (or a plugin's sys.exit) failed
        return _failure_row(run, lcp, "failed", f"{type(exc).__name__}: {exc}",
                            time.monotonic() - t0), None


def machine_info() -> dict:
    """Package versions, CPU, BLAS and thread settings for ``meta.json``."""
    import importlib.metadata as md

    versions: dict[str, Optional[str]] = {}
    for pkg in ("lcpbench", "numpy", "scipy", "pandas", "qpsolvers", "clarabel", "osqp",
                "proxsuite", "matplotlib"):
        try:
            versions[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            versions[pkg] = None
    try:
        cfg: Any = np.show_config(mode="dicts")
        blas = cfg.get("Build Dependencies", {}).get("blas", {})
    except (TypeError, ValueError, AttributeError) as exc:   # numpy without mode="dicts"
        blas = {"unknown": f"{type(exc).__name__}: {exc}"}
    threads = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                               "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")}
    return {"python": sys.version.split()[0], "platform": platform.platform(),
            "cpu": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
            "versions": versions, "blas": blas, "threads": threads}


def git_commit() -> Optional[str]:
    import subprocess

    try:
        here = os.path.dirname(os.path.abspath(__file__))
        out = subprocess.run(["git", "-C", here, "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=5)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):   # no git, or not a checkout
        return None


_WORKER_CACHE: dict = {}


def remote_work(run: RunSpec, timeout: Optional[float] = None,
                reference_max_n: int = REFERENCE_MAX_N,
                reference_timeout: Optional[float] = None):
    """One run from its spec alone (for workers that do not share the planner's memory).

    The instance is regenerated from the problem spec (deterministic by seed)
    and cached per worker process with its reference, so no matrix travels.
    ``reference_timeout`` as in :func:`execute`.
    """
    key = _problem_key(run.problem)
    if key not in _WORKER_CACHE:
        _WORKER_CACHE.clear()                      # keep one family in memory at a time
        _WORKER_CACHE[key] = (generate(run.problem), {})
    lcps, refs = _WORKER_CACHE[key]
    if run.instance not in refs:
        refs[run.instance] = instance_reference(
            lcps[run.instance], reference_max_n,
            timeout if reference_timeout is None else reference_timeout)
    return _safe_perform(run, lcps[run.instance], refs[run.instance], timeout)


def _reference_seconds(timeout: Optional[float],
                       reference_timeout: Optional[float]) -> Optional[float]:
    """The backend limit of the consensus references: ``reference_timeout``, else ``timeout``."""
    if reference_timeout is None:
        return timeout
    if not reference_timeout > 0:
        raise ValueError(f"reference_timeout must be > 0 seconds, got {reference_timeout!r}")
    return float(reference_timeout)


class _InstanceReferences:
    """Each instance's reference, computed once (bounded, isolated: :func:`instance_reference`)."""

    def __init__(self, p: Plan, max_n: int, seconds: Optional[float]):
        self.plan, self.max_n, self.seconds = p, max_n, seconds
        self.refs: dict[tuple, Optional[dict]] = {}

    def __call__(self, run: RunSpec) -> Optional[dict]:
        key = (_problem_key(run.problem), run.instance)
        if key not in self.refs:
            self.refs[key] = instance_reference(self.plan.lcp(run), self.max_n, self.seconds)
        return self.refs[key]


def execute(p: Plan, store: RunStore, *, executor: Optional[str] = None, jobs: int = 1,
            timeout: Optional[float] = None, scheduler: Optional[str] = None,
            quiet: bool = False, reference_max_n: int = REFERENCE_MAX_N,
            reference_timeout: Optional[float] = None,
            on_row: Optional[Callable[[dict], None]] = None) -> dict:
    """Run every planned run that has no row yet; returns counts.

    Rows are appended as runs finish; a run already in the store is skipped.

    Parameters
    ----------
    executor : {"local", "process", "dask"}, optional
        Default: ``process`` when ``jobs > 1``, else ``local``.
    jobs : int
        Parallel runs (processes or LocalCluster workers).
    timeout : float, optional
        Per-run seconds; a run over it is stopped and recorded as ``timeout``.
    reference_timeout : float, optional
        Seconds each QP backend of an instance's consensus reference may take
        (see :func:`instance_reference`). Default: ``timeout``, and without one
        :func:`~lcpbench.core.reference.default_reference_seconds` of ``n``;
        the reference is bounded and isolated either way.
    scheduler : str, optional
        Dask scheduler address (``dask`` executor only).
    """
    from functools import partial

    from tqdm import tqdm

    from lcpbench.run.executors import make_executor

    ref_seconds = _reference_seconds(timeout, reference_timeout)
    ref_of = _InstanceReferences(p, reference_max_n, ref_seconds)
    kind = executor or ("process" if jobs > 1 else "local")
    runner = make_executor(kind, jobs, timeout, scheduler)
    for path, line, reason in store.corrupt:
        print(f"lcpbench run: {path}:{line}: {reason}; the line was moved to {path}.corrupt and "
              "its run is run again", file=sys.stderr)
    store.compact_history()
    done = store.done_ids()
    todo = [r for r in p.runs if r.run_id not in done]
    counts = {"planned": len(p.runs), "kept": len(p.runs) - len(todo), "ran": 0, "failed": 0,
              "timeout": 0, "false_convergence": 0, "float64_floor": 0}

    def local_work(run: RunSpec):
        return _safe_perform(run, p.lcp(run), ref_of(run), timeout)

    work: Callable[[RunSpec], object]
    if kind == "dask":
        work = partial(remote_work, timeout=timeout, reference_max_n=reference_max_n,
                       reference_timeout=reference_timeout)
    else:
        work = local_work
        for run in todo:        # references before the runs (each bounded, in a child of its
            ref_of(run)         # own), so the runs' children inherit them

    bar = tqdm(total=len(todo), disable=quiet, unit="run", desc="lcpbench run", file=sys.stderr)

    def record(row: dict, hist) -> None:
        store.append(row, hist)
        counts["ran"] += 1
        if row["status"] == "timeout":
            counts["timeout"] += 1
        elif not row.get("solved", False):
            counts["failed"] += 1
        if row.get("false_convergence") in (True, "True"):
            counts["false_convergence"] += 1
        if row.get("float64_floor") in (True, "True"):
            counts["float64_floor"] += 1
        if on_row is not None:
            on_row(row)
        bar.update(1)
        bar.set_postfix(unsolved=counts["failed"], timeout=counts["timeout"])

    def failure(run: RunSpec, status: str, message: str,
                elapsed: Optional[float] = None) -> dict:
        return _failure_row(run, p.lcp(run), status, message, elapsed)

    try:
        runner.run(todo, work, failure, record)
    finally:
        bar.close()
    return counts


def describe_counts(counts: dict) -> str:
    return (f"{counts['ran']} run(s) done, {counts['kept']} kept from before; "
            f"{counts['failed']} not solved, {counts['timeout']} timed out, "
            f"{counts['false_convergence']} false 'converged'"
            + (f", {counts['float64_floor']} with a tolerance below the float64 floor"
               if counts.get("float64_floor") else ""))
