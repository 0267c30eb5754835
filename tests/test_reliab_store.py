"""The run store and runner under adversity: corrupted rows, killed workers, hanging references,
timeout rows with their time, history without duplicate blocks."""

import time
from types import SimpleNamespace

import misbehave_plugin  # noqa: F401  (registers test-misbehave)
import pandas as pd

from lcpbench.cli import main
from lcpbench.run import executors, runner
from lcpbench.run.runner import execute, plan
from lcpbench.run.store import RunStore
from lcpbench.run.sweep import Sweep

SMALL = "fathi:sizes=[4,6,8]"


def _lines(path):
    return path.read_text().split("\n")


def test_corrupted_rows_are_reported_with_file_and_line_and_rerun(tmp_path, capsys):
    sweep = Sweep(solvers=["bb-pgd"], problems=[SMALL])
    execute(plan(sweep), RunStore(tmp_path), quiet=True)
    results = tmp_path / "results.csv"
    lines = _lines(results)
    assert len(lines) == 5 and lines[-1] == ""          # header, 3 rows, final newline
    cut_id = lines[1].split(",")[0]
    lines[1] = lines[1][: len(lines[1]) // 2]           # a half row that still ends in a newline
    lines[3] = lines[3].replace(",", ',"', 1)           # a stray quote
    results.write_text("\n".join(lines))

    store = RunStore(tmp_path)
    assert [(line, "checksum" in why) for _, line, why in store.corrupt] == [(2, True), (4, True)]
    assert all(path == str(results) for path, _, _ in store.corrupt)
    assert len(store.results()) == 1                    # pandas reads the rest without errors
    assert cut_id not in store.done_ids()
    assert len(_lines(tmp_path / "results.csv.corrupt")) == 3

    counts = execute(plan(sweep), store, quiet=True)
    err = capsys.readouterr().err
    assert f"{results}:2:" in err and f"{results}:4:" in err
    assert counts["ran"] == 2
    res = RunStore(tmp_path).results()
    assert len(res) == 3 and res["run_id"].is_unique and cut_id in set(res["run_id"])
    assert RunStore(tmp_path).corrupt == []


def test_a_store_without_the_checksum_column_still_loads_and_appends(tmp_path):
    sweep = Sweep(solvers=["bb-pgd"], problems=["fathi:sizes=[4,6]"])
    execute(plan(sweep), RunStore(tmp_path), quiet=True)
    old = pd.read_csv(tmp_path / "results.csv").drop(columns=["row_crc"]).iloc[:1]
    old.to_csv(tmp_path / "results.csv", index=False)   # a store written before the checksum
    store = RunStore(tmp_path)
    assert store.corrupt == []
    execute(plan(sweep), store, quiet=True)
    res = pd.read_csv(tmp_path / "results.csv")
    assert len(res) == 2 and "row_crc" not in res.columns


def test_a_killed_worker_is_retried_once_on_resume(tmp_path, monkeypatch):
    monkeypatch.setattr(executors, "GRACE_S", 0.5)
    sweep = Sweep(solvers=["test-misbehave:mode=kill", "bb-pgd"], problems=["fathi:sizes=[4]"])
    ran = [execute(plan(sweep), RunStore(tmp_path), executor="process", quiet=True)["ran"]
           for _ in range(3)]
    assert ran == [2, 1, 0]                              # the dead run once more, then done
    rows = pd.read_csv(tmp_path / "results.csv")
    died = rows[rows["solver"] == "test-misbehave:mode=kill"]
    assert len(died) == 2 and died["message"].str.startswith("worker process died").all()
    assert RunStore(tmp_path).results()["run_id"].is_unique


def test_timeout_rows_carry_their_elapsed_time(tmp_path, monkeypatch):
    monkeypatch.setattr(executors, "GRACE_S", 0.5)
    sweep = Sweep(solvers=["test-misbehave:mode=sleep"], problems=["fathi:sizes=[4]"],
                  timeout=1.0)
    execute(plan(sweep), RunStore(tmp_path), executor="process", timeout=1.0, quiet=True)
    row = pd.read_csv(tmp_path / "results.csv").iloc[0]
    assert row["status"] == "timeout"
    assert row["time_s"] >= 1.0                          # killed at timeout + grace


def test_history_keeps_one_block_per_run_after_interrupted_attempts(tmp_path):
    sweep = Sweep(solvers=["bb-pgd"], problems=["fathi:sizes=[4,6]"])
    execute(plan(sweep), RunStore(tmp_path), quiet=True)
    hist_path = tmp_path / "history.csv"
    hist = pd.read_csv(hist_path, dtype={"run_id": str})
    first = hist["run_id"].iloc[0]
    orphan = hist[hist["run_id"] == first].assign(run_id="no-such-run")
    # an interrupted earlier attempt of `first` and one of a run that never finished
    pd.concat([hist[hist["run_id"] == first], orphan, hist]).to_csv(hist_path, index=False)
    store = RunStore(tmp_path)
    assert store.compact_history() == 2 * (hist["run_id"] == first).sum()
    after = pd.read_csv(hist_path, dtype={"run_id": str})
    assert len(after) == len(hist) and set(after["run_id"]) == set(hist["run_id"])
    assert ((after["iter"] == 0).groupby(after["run_id"]).sum() == 1).all()


def test_run_with_timeout_writes_rows_when_the_reference_hangs(tmp_path, monkeypatch):
    def hang(lcp, *args, **kwargs):
        time.sleep(600)

    monkeypatch.setattr(runner, "consensus_reference", hang)
    monkeypatch.setattr(executors, "GRACE_S", 0.5)
    out = tmp_path / "store"
    t0 = time.monotonic()
    assert main(["run", "--solver", "bb-pgd", "--solver", "mono-pqn", "--problem",
                 "infeasible:count=1,n=5", "--timeout", "1", "--out", str(out), "--quiet",
                 "--no-report"]) == 0
    assert time.monotonic() - t0 < 120                  # not the reference's 600 s
    rows = pd.read_csv(out / "results.csv")
    assert len(rows) == 2
    # each of the 3 backends gets the 1 s, the consensus (3 + 1) x 1 s in all
    assert rows["ref_solvers"].str.contains("reference solve killed after 4 s").all()
    assert not (rows["status"] == "converged").any()


class _FakeDask:
    """Stand-ins for distributed's Client, LocalCluster and as_completed: tasks run here, and
    every task of the solver ``doomed`` loses its worker (``KilledWorker``)."""

    def __init__(self, doomed: str):
        self.doomed = doomed

    def install(self, monkeypatch) -> None:
        import distributed

        fake = self

        class Future:
            def __init__(self, fn, args):
                self.fn, self.args = fn, args

            def result(self):
                if self.args[1].solver.label == fake.doomed:
                    raise distributed.KilledWorker(
                        "lcpbench-task", SimpleNamespace(address="tcp://127.0.0.1:40000"), 3)
                return self.fn(*self.args)

        class Client:
            def __init__(self, *args, **kwargs):
                pass

            def submit(self, fn, *args, **kwargs):
                return Future(fn, args)

            def close(self):
                pass

        class Cluster(Client):
            pass

        monkeypatch.setattr(distributed, "Client", Client)
        monkeypatch.setattr(distributed, "LocalCluster", Cluster)
        monkeypatch.setattr(distributed, "as_completed", lambda futures: list(futures))


def test_a_dask_killed_worker_is_retried_once_on_resume(tmp_path, monkeypatch):
    _FakeDask("test-misbehave:mode=kill").install(monkeypatch)
    sweep = Sweep(solvers=["test-misbehave:mode=kill", "bb-pgd"], problems=["fathi:sizes=[4]"])
    ran = [execute(plan(sweep), RunStore(tmp_path), executor="dask", jobs=2, quiet=True)["ran"]
           for _ in range(3)]
    assert ran == [2, 1, 0]                              # the lost run once more, then done
    rows = pd.read_csv(tmp_path / "results.csv")
    lost = rows[rows["solver"] == "test-misbehave:mode=kill"]
    assert len(lost) == 2 and (lost["status"] == "failed").all()
    assert lost["message"].str.startswith("worker process died (dask KilledWorker:").all()
    assert bool(rows.loc[rows["solver"] == "bb-pgd", "solved"].iloc[0])
