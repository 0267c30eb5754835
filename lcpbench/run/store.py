"""The run store: a folder of ``results.csv``, ``history.csv`` and ``meta.json``.

Rows are appended and flushed one run at a time, so an interrupted sweep loses
at most the runs in flight; a line cut short by a crash is dropped on the next
open. ``meta.json`` is written atomically (temporary file, then rename).
``pandas.read_csv`` loads both CSV files without options.
"""

from __future__ import annotations

import csv
import fcntl
import io
import json
import os
from pathlib import Path
from typing import Iterable, Optional

import pandas as pd

from lcpbench.core.result import HISTORY_COLUMNS

__all__ = ["RunStore", "RunLock", "StoreLocked", "RESULT_COLUMNS", "HISTORY_STORE_COLUMNS", "atomic_write"]

#: Columns of ``results.csv``, in order.
RESULT_COLUMNS = [
    "run_id", "kind", "problem", "problem_params", "family", "instance", "instance_index", "n",
    "solver", "solver_name", "solver_params", "mvp_only", "multifidelity", "reference_solver",
    "tol", "stop", "repeat", "status", "message", "solved", "false_convergence",
    "claimed_kkt_abs", "verified_kkt_abs", "verified_kkt_inf", "verified_comp_gap",
    "verified_infeas_x", "verified_infeas_w", "threshold", "ref_err_w", "ref_err_objective",
    "ref_solvers", "mvps", "lofi_mvps", "lofi_mvps_total", "emvps", "iterations", "time_s",
    "mvp_time_s", "info", "step", "sim_total_s", "max_overlap", "started", "finished",
]
#: Columns of ``history.csv``, in order.
HISTORY_STORE_COLUMNS = ["run_id"] + HISTORY_COLUMNS


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class StoreLocked(RuntimeError):
    """Another runner holds the folder's lock."""


class RunLock:
    """An exclusive ``flock`` on ``DIR/.lock`` held while one runner writes ``DIR``.

    A second runner pointed at the same folder fails at once with a message
    naming the holder's PID instead of interleaving rows. The kernel drops the
    lock when its holder exits, however it exits (``kill -9`` included), so a
    stale lock cannot block a resume. Children forked for runs close their copy
    of the descriptor, so a run outliving a killed runner does not keep the lock.
    """

    _held: list = []

    def __init__(self, path: Path):
        self.path = Path(path)
        self.fd: Optional[int] = None

    def __enter__(self) -> "RunLock":
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 64).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise StoreLocked(
                f"{self.path.parent} is being written by another lcpbench run (pid {holder}); "
                "wait for it to finish, or choose another --out") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self.fd = fd
        RunLock._held.append(fd)
        return self

    def __exit__(self, *exc) -> None:
        if self.fd is not None:
            RunLock._held.remove(self.fd)
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None


def _close_held_locks_in_child() -> None:
    for fd in RunLock._held:
        try:
            os.close(fd)
        except OSError:
            pass
    RunLock._held.clear()


os.register_at_fork(after_in_child=_close_held_locks_in_child)


def _repair_tail(path: Path) -> int:
    """Drop a final line without its newline (a row cut short); returns bytes dropped."""
    if not path.exists() or path.stat().st_size == 0:
        return 0
    with open(path, "rb+") as fh:
        fh.seek(0, os.SEEK_END)
        size = fh.tell()
        fh.seek(max(0, size - 1))
        if fh.read(1) == b"\n":
            return 0
        fh.seek(0)
        data = fh.read()
        keep = data.rfind(b"\n") + 1
        fh.truncate(keep)
        return size - keep


class RunStore:
    """Append-only results of one sweep.

    Parameters
    ----------
    path : str or Path
        The folder (created if missing).
    """

    def __init__(self, path) -> None:
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise NotADirectoryError(f"run store {str(self.path)!r} exists and is not a folder; "
                                     "choose another --out")
        self.path.mkdir(parents=True, exist_ok=True)
        self.results_path = self.path / "results.csv"
        self.history_path = self.path / "history.csv"
        self.meta_path = self.path / "meta.json"
        self.repaired = _repair_tail(self.results_path) + _repair_tail(self.history_path)

    # ------------------------------------------------------------------ lock
    def lock(self) -> "RunLock":
        """Exclusive writer lock on this folder (see :class:`RunLock`)."""
        return RunLock(self.path / ".lock")

    # ------------------------------------------------------------------ meta
    def read_meta(self) -> Optional[dict]:
        if not self.meta_path.exists():
            return None
        try:
            return json.loads(self.meta_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{self.meta_path} is not valid JSON ({exc}); it was not written "
                             "by lcpbench or was edited by hand: fix or delete it") from None

    def write_meta(self, meta: dict) -> None:
        atomic_write(self.meta_path, json.dumps(meta, indent=2, sort_keys=True, default=str))

    # ------------------------------------------------------------------ rows
    def done_ids(self) -> set[str]:
        """Run ids that already have a row."""
        if not self.results_path.exists() or self.results_path.stat().st_size == 0:
            return set()
        return set(pd.read_csv(self.results_path, usecols=["run_id"], dtype=str)["run_id"])

    def append(self, row: dict, history: Optional[pd.DataFrame] = None) -> None:
        """Append one result row (and its history) and flush both to disk.

        The history goes first: a crash between the two leaves orphan history
        rows (ignored, and overwritten on resume) but never a result without its
        history.
        """
        if history is not None and len(history):
            h = history.copy()
            h.insert(0, "run_id", row["run_id"])
            for col in HISTORY_STORE_COLUMNS:
                if col not in h:
                    h[col] = float("nan")
            self._append_csv(self.history_path, HISTORY_STORE_COLUMNS,
                             h[HISTORY_STORE_COLUMNS].itertuples(index=False, name=None))
        unknown = set(row) - set(RESULT_COLUMNS)
        if unknown:
            raise KeyError(f"result row has unknown column(s) {sorted(unknown)}")
        self._append_csv(self.results_path, RESULT_COLUMNS,
                         [tuple(row.get(c, "") for c in RESULT_COLUMNS)])

    @staticmethod
    def _append_csv(path: Path, columns: list[str], rows: Iterable[tuple]) -> None:
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        new = not path.exists() or path.stat().st_size == 0
        if new:
            writer.writerow(columns)
        for r in rows:
            writer.writerow(["" if v is None else v for v in r])
        with open(path, "a", encoding="utf-8", newline="") as fh:
            fh.write(buf.getvalue())
            fh.flush()
            os.fsync(fh.fileno())

    def results(self) -> pd.DataFrame:
        """All result rows (empty frame with the columns if none)."""
        if not self.results_path.exists() or self.results_path.stat().st_size == 0:
            return pd.DataFrame(columns=RESULT_COLUMNS)
        return pd.read_csv(self.results_path)

    def history(self) -> pd.DataFrame:
        """Iterate rows of the runs that have a result row (latest attempt only)."""
        if not self.history_path.exists() or self.history_path.stat().st_size == 0:
            return pd.DataFrame(columns=HISTORY_STORE_COLUMNS)
        h = pd.read_csv(self.history_path)
        ids = self.done_ids()
        h = h[h["run_id"].isin(ids)]
        # an attempt interrupted after its history was written and then re-run leaves two
        # blocks for one id: keep the last block (iterations restart at 0)
        block = (h["iter"] == 0).groupby(h["run_id"]).cumsum()
        last = block.groupby(h["run_id"]).transform("max")
        return h[block == last].reset_index(drop=True)
