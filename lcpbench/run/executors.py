"""Where runs execute: in this process, in forked children, or on a Dask cluster.

All executors give the same rows (up to timings) for the same sweep, because
every run is the same pure function of its :class:`~lcpbench.run.sweep.RunSpec`.

Isolation: outside the plain in-process path, every run executes in a child
forked for it (:class:`lcpbench.core.forked.ForkedCall`, ``os.fork`` and a pipe, which also works
inside a daemonic Dask worker where ``multiprocessing`` refuses to start
children). The parent kills a child that outlives its deadline (the run is
recorded as ``timeout``) and records a child that dies (killed, segfault) as
``failed`` with its exit status, so per-run timeouts and crash containment
hold on every executor. A run whose child or Dask worker died is run once more
on resume (:meth:`lcpbench.run.store.RunStore.done_ids`).

Dask is an optional dependency (``pip install -e .[dask]``); problem data
reaches workers as the problem *spec* (a few bytes): each worker regenerates
the instance from the registry (deterministic by seed) or reads it from the
shared file a stored set names, never a pickled matrix.
"""

from __future__ import annotations

import select
import time
from collections.abc import Callable
from typing import Optional

from lcpbench.core.forked import ForkedCall
from lcpbench.run.store import DIED_PREFIX

__all__ = ["LocalExecutor", "ProcessExecutor", "DaskExecutor", "make_executor", "EXECUTORS"]

EXECUTORS = ("local", "process", "dask")

#: Extra seconds a child gets beyond ``timeout`` (the solver's own time budget stops it
#: first, cleanly; the kill is for code that never returns to the budget check).
GRACE_S = 5.0

Record = Callable[[dict, object], None]
Failure = Callable[[object, str, str, Optional[float]], dict]


def _deadline(timeout: Optional[float]) -> Optional[float]:
    return None if timeout is None else time.monotonic() + timeout + GRACE_S


def outcome(call_result, run, timeout, failure: Failure, elapsed: Optional[float] = None):
    """``(row, history)`` from a :class:`ForkedCall` result (``elapsed``: the child's seconds)."""
    kind, value = call_result
    if kind == "ok":
        return value
    if kind == "timeout":
        return failure(run, "timeout", f"killed after {timeout:g} s (+{GRACE_S:g} s grace)",
                       elapsed), None
    return failure(run, "failed", value, elapsed), None


class LocalExecutor:
    """Runs one after another; in this process, or in a forked child when a timeout is set."""

    def __init__(self, timeout: Optional[float] = None):
        self.timeout = timeout

    def run(self, todo: list, work: Callable, failure: Failure, record: Record) -> None:
        if self.timeout is None:
            for run in todo:
                record(*work(run))
            return
        ProcessExecutor(1, self.timeout).run(todo, work, failure, record)


class ProcessExecutor:
    """Up to ``jobs`` forked children at a time, one per run."""

    def __init__(self, jobs: int, timeout: Optional[float] = None):
        if jobs < 1:
            raise ValueError(f"jobs must be >= 1, got {jobs}")
        self.jobs, self.timeout = jobs, timeout

    def run(self, todo: list, work: Callable, failure: Failure, record: Record) -> None:
        pending = list(reversed(todo))
        active: list[tuple] = []
        while pending or active:
            while pending and len(active) < self.jobs:
                run = pending.pop()
                active.append((run, ForkedCall(work, (run,), _deadline(self.timeout))))
            fds = [c.fd for _, c in active]
            select.select(fds, [], [], 0.05)
            still = []
            for run, call in active:
                if call.poll():
                    record(*outcome(call.result, run, self.timeout, failure, call.elapsed))
                else:
                    still.append((run, call))
            active = still


def _dask_task(work: Callable, run, timeout: Optional[float]):
    """On a Dask worker: the run in a forked child, with its deadline."""
    call = ForkedCall(work, (run,), _deadline(timeout))
    while not call.poll(wait=0.05):
        pass
    return call.result, call.elapsed


class DaskExecutor:
    """Runs as tasks on a Dask cluster (an existing scheduler, or a LocalCluster).

    Parameters
    ----------
    jobs : int
        Workers of the LocalCluster started when no scheduler is given (one
        thread each: the solvers' BLAS calls are the parallelism).
    timeout : float, optional
    scheduler : str, optional
        Address of a running scheduler, e.g. ``tcp://10.0.0.5:8786`` (see
        docs/executors.md for dask-jobqueue on SLURM).
    """

    def __init__(self, jobs: int = 2, timeout: Optional[float] = None,
                 scheduler: Optional[str] = None):
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise ImportError("the dask executor needs dask.distributed: pip install -e "
                              "'.[dask]'") from None
        self.jobs, self.timeout, self.scheduler = jobs, timeout, scheduler

    def run(self, todo: list, work: Callable, failure: Failure, record: Record) -> None:
        from distributed import Client, LocalCluster, as_completed

        cluster = None
        if self.scheduler:
            client = Client(self.scheduler)
        else:
            cluster = LocalCluster(n_workers=self.jobs, threads_per_worker=1, processes=True,
                                   dashboard_address=None, host="127.0.0.1")
            client = Client(cluster)
        try:
            futures = {client.submit(_dask_task, work, run, self.timeout, pure=False,
                                     key=f"lcpbench-{run.run_id}-{time.time_ns()}"): run
                       for run in todo}
            for fut in as_completed(futures):
                self.collect(fut, futures[fut], failure, record)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()


    def collect(self, fut, run, failure: Failure, record: Record) -> None:
        """Record the row of one finished future.

        A task whose worker died under it (``distributed.KilledWorker``: the
        scheduler lost its worker, out of memory, killed) gets a ``failed`` row
        whose message starts with :data:`~lcpbench.run.store.DIED_PREFIX`, so a
        resume runs it once more, as for a dead child on the process executor.
        Any other exception of the task is the run's own ``failed`` row.
        """
        from distributed import KilledWorker

        try:
            result, elapsed = fut.result()
        except KilledWorker as exc:
            record(failure(run, "failed", f"{DIED_PREFIX} (dask KilledWorker: {exc})", None),
                   None)
            return
        except Exception as exc:  # noqa: BLE001 - the task's own failure, recorded as a row
            record(failure(run, "failed", f"dask task failed: {type(exc).__name__}: {exc}",
                           None), None)
            return
        record(*outcome(result, run, self.timeout, failure, elapsed))


def make_executor(kind: str, jobs: int = 1, timeout: Optional[float] = None,
                  scheduler: Optional[str] = None):
    """The executor named ``kind`` (``local``, ``process`` or ``dask``)."""
    if kind == "local":
        if jobs != 1:
            raise ValueError("--jobs needs --executor process or dask (local runs one at a time)")
        return LocalExecutor(timeout)
    if kind == "process":
        return ProcessExecutor(jobs, timeout)
    if kind == "dask":
        return DaskExecutor(jobs, timeout, scheduler)
    raise ValueError(f"unknown executor {kind!r}; use one of {', '.join(EXECUTORS)}")
