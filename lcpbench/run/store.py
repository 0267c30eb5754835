"""The run store: a folder of ``results.csv``, ``history.csv`` and ``meta.json``.

Rows are appended and flushed one run at a time, so an interrupted sweep loses
at most the runs in flight; a line cut short by a crash is dropped on the next
open. Every result row is one line ending in ``row_crc``, the CRC-32 of the
rest of the line: on open, a line whose checksum does not match (a half row,
a stray quote, an edit) is moved to ``results.csv.corrupt``, reported with its
file and line (:attr:`RunStore.corrupt`), and its run is run again on resume.
A run whose worker process was killed from outside is run once more on resume.
``meta.json`` is written atomically (temporary file, then rename).
``pandas.read_csv`` loads both CSV files without options.
"""

from __future__ import annotations

import csv
import fcntl
import io
import json
import os
import zlib
from collections.abc import Iterable
from pathlib import Path
from typing import Optional

import pandas as pd

from lcpbench.core.result import HISTORY_COLUMNS

__all__ = ["RunStore", "RunLock", "StoreLocked", "RESULT_COLUMNS", "HISTORY_STORE_COLUMNS",
           "atomic_write", "DIED_PREFIX"]

#: Columns of ``results.csv``, in order.
RESULT_COLUMNS = [
    "run_id", "kind", "problem", "problem_params", "family", "instance", "instance_index", "n",
    "solver", "solver_name", "solver_params", "mvp_only", "multifidelity", "reference_solver",
    "tol", "stop", "repeat", "status", "message", "solved", "false_convergence",
    "claimed_kkt_abs", "verified_kkt_abs", "verified_kkt_inf", "verified_comp_gap",
    "verified_infeas_x", "verified_infeas_w", "threshold", "ref_err_w", "ref_err_objective",
    "ref_solvers", "mvps", "lofi_mvps", "lofi_mvps_total", "emvps", "iterations", "time_s",
    "mvp_time_s", "info", "step", "sim_total_s", "max_overlap", "started", "finished",
    "row_crc",
]
#: How a row of a run whose worker process died starts its message (retried once on resume).
DIED_PREFIX = "worker process died"
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

    def __enter__(self) -> RunLock:
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
        except OSError:         # already closed in this child: nothing is held, nothing to do
            continue
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


def _crc(text: str) -> str:
    return f"{zlib.crc32(text.encode('utf-8')):08x}"


def _one_line(value):
    """A value as it goes into a CSV cell: no line breaks (one row, one line)."""
    if value is None:
        return ""
    if isinstance(value, str) and ("\n" in value or "\r" in value):
        return value.replace("\r", " ").replace("\n", " | ")
    return value


def _scan(path: Path, checksum_column: Optional[str]) -> tuple[list[str], list[tuple[int, str]]]:
    """The good lines of a CSV file (header first) and the bad ones as ``(line number, reason)``.

    With ``checksum_column`` (the header's last column) a line is good when its
    last field is the CRC-32 of the rest; without it (files written before
    the checksum), when it parses to as many fields as the header has.
    """
    with open(path, encoding="utf-8", newline="") as fh:
        lines = fh.read().split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    if not lines:
        return [], []
    header = next(csv.reader([lines[0]]))
    crc = checksum_column is not None and header[-1:] == [checksum_column]
    good, bad = [lines[0]], []
    for i, line in enumerate(lines[1:], start=2):
        if crc:
            body, _, tail = line.rpartition(",")
            ok = bool(body) and tail == _crc(body)
            reason = "checksum mismatch (a cut, merged or edited row)"
        else:
            try:
                ok = len(next(csv.reader([line]))) == len(header)
            except (csv.Error, StopIteration):
                ok = False
            reason = f"not {len(header)} fields"
        if ok:
            good.append(line)
        else:
            bad.append((i, reason))
    return good, bad


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
        #: Lines set aside on open: ``(file, line number, reason)``.
        self.corrupt: list[tuple[str, int, str]] = []
        self._set_aside(self.results_path, "row_crc")
        self._set_aside(self.history_path, None)

    def _set_aside(self, path: Path, checksum_column: Optional[str]) -> None:
        """Move the bad lines of ``path`` to ``path.corrupt`` and rewrite it without them."""
        if not path.exists() or path.stat().st_size == 0:
            return
        good, bad = _scan(path, checksum_column)
        if not bad:
            return
        with open(path, encoding="utf-8", newline="") as fh:
            lines = fh.read().split("\n")
        with open(str(path) + ".corrupt", "a", encoding="utf-8", newline="") as fh:
            for i, _ in bad:
                fh.write(lines[i - 1] + "\n")
        atomic_write(path, "".join(line + "\n" for line in good))
        self.corrupt += [(str(path), i, reason) for i, reason in bad]

    # ------------------------------------------------------------------ lock
    def lock(self) -> RunLock:
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
        """Run ids that already have a row, except a first death of the worker process.

        A run whose only row says its worker died (killed from outside, out of
        memory, a crash) is not done: a resume runs it once more. After a
        second such row it is done (the death is then the run's own).
        """
        if not self.results_path.exists() or self.results_path.stat().st_size == 0:
            return set()
        rows = pd.read_csv(self.results_path, usecols=["run_id", "status", "message"], dtype=str)
        died = (rows["status"] == "failed") & rows["message"].fillna("").str.startswith(DIED_PREFIX)
        deaths = died.groupby(rows["run_id"]).sum()
        last_died = died.groupby(rows["run_id"]).last()
        retry = set(deaths.index[(deaths == 1) & last_died])
        return set(rows["run_id"]) - retry

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
        columns = self._result_columns()
        cells = [row.get(c, "") for c in columns if c != "row_crc"]
        self._append_csv(self.results_path, columns, [tuple(cells)],
                         checksum="row_crc" in columns)

    def _result_columns(self) -> list[str]:
        """The columns of ``results.csv``: its header (a store from before the checksum
        keeps its own columns), or :data:`RESULT_COLUMNS` for a new file."""
        if self.results_path.exists() and self.results_path.stat().st_size > 0:
            with open(self.results_path, encoding="utf-8", newline="") as fh:
                header = next(csv.reader([fh.readline().rstrip("\n")]))
            if set(header) <= set(RESULT_COLUMNS) and header[:1] == ["run_id"]:
                return header
        return RESULT_COLUMNS

    @staticmethod
    def _append_csv(path: Path, columns: list[str], rows: Iterable[tuple],
                    checksum: bool = False) -> None:
        buf = io.StringIO()
        new = not path.exists() or path.stat().st_size == 0
        if new:
            csv.writer(buf, lineterminator="\n").writerow(columns)
        for r in rows:
            line = io.StringIO()
            csv.writer(line, lineterminator="").writerow([_one_line(v) for v in r])
            text = line.getvalue()
            buf.write(f"{text},{_crc(text)}\n" if checksum else text + "\n")
        with open(path, "a", encoding="utf-8", newline="") as fh:
            fh.write(buf.getvalue())
            fh.flush()
            os.fsync(fh.fileno())

    def results(self) -> pd.DataFrame:
        """The latest row of every run (empty frame with the columns if none)."""
        if not self.results_path.exists() or self.results_path.stat().st_size == 0:
            return pd.DataFrame(columns=RESULT_COLUMNS)
        res = pd.read_csv(self.results_path)
        return res.drop_duplicates("run_id", keep="last").reset_index(drop=True)

    def compact_history(self) -> int:
        """Rewrite ``history.csv`` with one block per finished run; returns rows dropped.

        Blocks of runs without a result row (interrupted attempts) and all but
        the last block of a run (earlier attempts) go; the runner calls this
        under its lock before a resume.
        """
        if not self.history_path.exists() or self.history_path.stat().st_size == 0:
            return 0
        h = pd.read_csv(self.history_path, dtype={"run_id": str})
        kept = self._last_blocks(h)
        dropped = len(h) - len(kept)
        if dropped:
            buf = io.StringIO()
            kept.to_csv(buf, index=False, lineterminator="\n")
            atomic_write(self.history_path, buf.getvalue())
        return dropped

    def _last_blocks(self, h: pd.DataFrame) -> pd.DataFrame:
        ids = self.done_ids()
        h = h[h["run_id"].isin(ids)]
        # an attempt interrupted after its history was written and then re-run leaves two
        # blocks for one id: keep the last block (iterations restart at 0)
        block = (h["iter"] == 0).groupby(h["run_id"]).cumsum()
        last = block.groupby(h["run_id"]).transform("max")
        return h[block == last].reset_index(drop=True)

    def history(self) -> pd.DataFrame:
        """Iterate rows of the runs that have a result row (latest attempt only)."""
        if not self.history_path.exists() or self.history_path.stat().st_size == 0:
            return pd.DataFrame(columns=HISTORY_STORE_COLUMNS)
        return self._last_blocks(pd.read_csv(self.history_path, dtype={"run_id": str}))
