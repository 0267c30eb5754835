"""Executor speedup and per-run overhead, measured side by side in one run.

Usage::

    python benchmarks/executors.py              # ~300 small runs per executor
    python benchmarks/executors.py --runs-per-solver 40

The same sweep (small planted and random LCPs x bb-pgd, zero-sr1, mono-pqn) is
executed into fresh stores by ``local`` (in-process), ``process`` with 1 and 2
jobs (one forked child per run), and ``dask`` with 2 workers (LocalCluster on
loopback, cluster start included). Prints wall seconds, the speedup against
``local`` and the per-run overhead ``(T - T_local x jobs_factor) / runs`` for the
one-job executors. All executors must produce the same rows (checked).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import pandas as pd

from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep

DROP = ["time_s", "mvp_time_s", "started", "finished", "info", "message"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs-per-solver", type=int, default=100,
                    help="instances per solver (3 solvers)")
    args = ap.parse_args()
    k = args.runs_per_solver
    sweep = Sweep(solvers=["bb-pgd", "zero-sr1", "mono-pqn"],
                  problems=[f"planted:count={k // 2},n_active=10,n_inactive=10,n_degenerate=0",
                            f"random-spd:count={k - k // 2},n_min=30,n_max=60"])
    p = plan(sweep)
    runs = len(p.runs)
    rows, times = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, kind, jobs in (("local", "local", 1), ("process x1", "process", 1),
                                  ("process x2", "process", 2), ("dask x2", "dask", 2)):
            store = RunStore(Path(tmp) / label.replace(" ", ""))
            t0 = time.perf_counter()
            execute(p, store, executor=kind, jobs=jobs, quiet=True)
            times[label] = time.perf_counter() - t0
            rows[label] = store.results().sort_values("run_id").drop(columns=DROP)
            rows[label] = rows[label].reset_index(drop=True)
    for label in rows:
        pd.testing.assert_frame_equal(rows["local"], rows[label])
    base = times["local"]
    print(f"{runs} runs (3 solvers x {k} small LCPs); identical rows on every executor\n")
    print("| executor | wall s | speedup vs local | overhead per run (ms) |")
    print("|---|---|---|---|")
    for label, t in times.items():
        over = f"{1e3 * (t - base) / runs:.1f}" if label in ("local", "process x1") else "-"
        print(f"| {label} | {t:.2f} | {base / t:.2f}x | {over} |")


if __name__ == "__main__":
    main()
