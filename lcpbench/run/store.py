"""The run store: a folder of ``results.csv``, ``history.csv`` and ``meta.json``.

Rows are appended and flushed one run at a time, so an interrupted sweep loses
at most the runs in flight. Every result row is one line ending in ``row_crc``,
the CRC-32 of the rest of the line.

Locking. A runner (``lcpbench run``, ``simulate``) holds an exclusive ``flock`` on
``DIR/.lock`` while it writes (:meth:`RunStore.lock`). Files are rewritten
(repaired, compacted) only under that lock: a reader (``lcpbench report``, a
second runner that is then refused) never changes a file while a runner holds
it, and reads what is complete, in memory (a half-written last line is ignored,
not deleted). Opening a store whose lock is free repairs it under the lock.

Repair. A line whose checksum does not match (a half row, a stray quote, an
edit) is moved to ``results.csv.corrupt``, reported with its file and line
(:attr:`RunStore.corrupt`), and its run is run again on resume. A last line
without its newline is kept when its checksum is valid (a file saved without
the final newline) and set aside like any bad line otherwise; the last line of
``history.csv`` (no checksum) is kept only when it has every field and its run
has a result row (the history is written before its result), else set aside.
Nothing is deleted without being set aside with its file and line.

A run whose worker process was killed from outside is run once more on resume.
``meta.json`` is written atomically (temporary file, then rename).
``pandas.read_csv`` loads both CSV files without options.
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import io
import json
import os
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Optional

import numpy as np
import pandas as pd

from lcpbench.core.result import HISTORY_COLUMNS

__all__ = ["RunStore", "RunLock", "StoreLocked", "RESULT_COLUMNS", "HISTORY_STORE_COLUMNS",
           "atomic_write", "DIED_PREFIX"]

#: Columns of ``results.csv``, in order.
RESULT_COLUMNS = [
    "run_id", "kind", "problem", "problem_params", "family", "instance", "instance_index", "n",
    "solver", "solver_name", "solver_params", "mvp_only", "multifidelity", "reference_solver",
    "tol", "stop", "repeat", "status", "message", "solved", "false_convergence",
    "float64_floor",
    "claimed_kkt_abs", "verified_kkt_abs", "verified_kkt_inf", "verified_comp_gap",
    "verified_infeas_x", "verified_infeas_w", "threshold", "ref_err_w", "ref_err_objective",
    "ref_err_w_others",
    "ref_solvers", "mvps", "lofi_mvps", "lofi_mvps_total", "emvps", "iterations", "time_s",
    "mvp_time_s", "info", "step", "sim_total_s", "max_overlap", "started", "finished",
    "applications", "lofi_applications_total", "app_cost", "model_emvps", "framework_mvps",
    "row_crc",
]
#: How a row of a run whose worker process died starts its message (retried once on resume).
DIED_PREFIX = "worker process died"
#: Columns of ``history.csv``, in order.
HISTORY_STORE_COLUMNS = ["run_id"] + HISTORY_COLUMNS


def refuse_link(path: Path) -> None:
    """Raise OSError when ``path`` or its folder is a symbolic link.

    A run store writes only inside its own folder: a link planted in it (``.lock``,
    ``tables/``, ``results.csv``) is refused rather than followed to a file elsewhere.
    """
    for p in (Path(path), Path(path).parent):
        if p.is_symlink():
            raise OSError(f"{p} is a symbolic link; lcpbench writes a run store's files only "
                          "inside its folder and never follows links: remove the link")


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename (no link followed)."""
    refuse_link(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)              # a leftover (or a planted link): never written through
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
    with open(fd, "w", encoding="utf-8") as fh:
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

    Parameters
    ----------
    path : Path
        The lock file (``DIR/.lock``).
    repair : bool
        A short hold by a reader that repairs the files (written into the lock
        file as ``PID repair``): it is refused at once when anyone holds the
        lock, while a runner that meets it waits for it (up to
        :attr:`REPAIR_WAIT_S`) instead of being refused.
    """

    _held: list = []
    #: Seconds a runner waits for a reader's repair to finish before it gives up.
    REPAIR_WAIT_S = 60.0

    def __init__(self, path: Path, *, repair: bool = False):
        self.path = Path(path)
        self.repair = repair
        self.fd: Optional[int] = None

    def __enter__(self) -> RunLock:
        refuse_link(self.path)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
        deadline = time.monotonic() + self.REPAIR_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
                if self.repair or not holder.endswith(" repair") or \
                        time.monotonic() > deadline:
                    os.close(fd)
                    raise StoreLocked(
                        f"{self.path.parent} is being written by another lcpbench run (pid "
                        f"{holder.split()[0]}); wait for it to finish, or choose another "
                        "--out") from None
                time.sleep(0.02)            # a reader's repair: over in moments
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}{' repair' if self.repair else ''}\n".encode(), 0)
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


def _crc(text: str) -> str:
    return f"{zlib.crc32(text.encode('utf-8')):08x}"


def _one_line(value):
    """A value as it goes into a CSV cell: no line breaks (one row, one line)."""
    if value is None:
        return ""
    if isinstance(value, str) and ("\n" in value or "\r" in value):
        return value.replace("\r", " ").replace("\n", " | ")
    return value


def _fields(line: str, count: int) -> bool:
    """Whether ``line`` parses to ``count`` CSV fields."""
    try:
        return len(next(csv.reader([line]))) == count
    except (csv.Error, StopIteration):
        return False


def _check_header(path: Path, header: list[str]) -> None:
    """Refuse a results.csv header of lcpbench (``run_id`` first) whose columns are
    unknown, repeated or out of order: the row checksums cover the rows, not the header,
    so an edited header would give every value another column's meaning. A header of
    another program (no ``run_id`` first) is left to :meth:`RunStore.results`."""
    if header[:1] != ["run_id"]:
        return
    unknown = [c for c in header if c not in RESULT_COLUMNS]
    repeated = sorted({c for c in header if header.count(c) > 1})
    order = [RESULT_COLUMNS.index(c) for c in header if c in RESULT_COLUMNS]
    swapped = next(((header[i], header[i + 1]) for i in range(len(order) - 1)
                    if order[i] > order[i + 1]), None)
    what = (f"unknown column {unknown[0]!r}" if unknown else
            f"column {repeated[0]!r} appears twice" if repeated else
            f"columns {swapped[0]!r} and {swapped[1]!r} are out of order" if swapped else None)
    if what:
        raise ValueError(f"{path}: its header was edited or corrupted ({what}), so its rows "
                         "cannot be read by column; restore the header line "
                         f"({','.join(RESULT_COLUMNS[:4])},...) or rerun into a new --out")


class _Scan:
    """The lines of one CSV file of the store, sorted into good and bad.

    With ``checksum_column`` (the header's last column) a line is good when its
    last field is the CRC-32 of the rest; without it (``history.csv``, result
    files written before the checksum), when it has as many fields as the header
    (counted for all lines at once; a line with quotes goes through the CSV parser).
    A last line without its newline is good only when it passes the checksum, or,
    without one, when ``keep_tail`` accepts it.

    Attributes
    ----------
    bad : list of (int, str, str)
        ``(line number, reason, text)`` of every bad line.
    dirty : bool
        Whether the file differs from :meth:`text` (a bad line, or a last line
        without newline): a repair rewrites it.
    """

    def __init__(self, path: Path, checksum_column: Optional[str],
                 keep_tail: Optional[Callable[[str], bool]] = None):
        self.data = path.read_bytes()
        self.terminated = self.data.endswith(b"\n")
        arr = np.frombuffer(self.data, dtype=np.uint8)
        newlines = np.flatnonzero(arr == ord("\n"))
        self.starts = np.concatenate(([0], newlines + 1))
        self.ends = np.concatenate((newlines, [arr.size]))
        if self.terminated or not self.data:
            self.starts, self.ends = self.starts[:-1], self.ends[:-1]
        self.bad: list[tuple[int, str, str]] = []
        self.ok = np.ones(self.starts.size, dtype=bool)
        if self.starts.size == 1 and not self.terminated:
            self._mark(0, "the header was cut short (no newline)")
        elif self.starts.size:
            header = next(csv.reader([self.line(0)]))
            if checksum_column is not None and header[-1:] == [checksum_column]:
                self._check_sums()
            else:
                self._count_fields(arr, len(header), keep_tail)
        self.bad.sort()
        self.dirty = bool(self.bad) or (bool(self.data) and not self.terminated)

    def line(self, i: int) -> str:
        """Line ``i`` (0-based, the header is 0) without its newline."""
        return self.data[self.starts[i]:self.ends[i]].decode("utf-8", errors="replace")

    def _mark(self, i: int, reason: str) -> None:
        self.ok[i] = False
        self.bad.append((i + 1, reason, self.line(int(i))))

    def _tail(self, i: int) -> bool:
        return i == self.starts.size - 1 and not self.terminated

    def _check_sums(self) -> None:
        for i in range(1, self.starts.size):
            body, _, mark = self.line(int(i)).rpartition(",")
            if not (body and mark == _crc(body)):
                why = "checksum mismatch (a cut, merged or edited row)"
                self._mark(int(i), f"last line cut short (no newline; {why})" if self._tail(int(i))
                           else why)

    def _count_fields(self, arr: np.ndarray, count: int,
                      keep_tail: Optional[Callable[[str], bool]]) -> None:
        def per_line(char: str) -> np.ndarray:
            at = np.flatnonzero(arr == ord(char))
            return np.searchsorted(at, self.ends) - np.searchsorted(at, self.starts)

        ok = per_line(",") + 1 == count
        quoted = per_line('"') > 0
        for i in np.flatnonzero(quoted):
            ok[i] = _fields(self.line(int(i)), count)
        last = self.starts.size - 1
        tail_ok = bool(ok[last]) and keep_tail is not None and keep_tail(self.line(last))
        for i in np.flatnonzero(~ok[1:]) + 1:
            if not self._tail(int(i)):
                self._mark(int(i), f"not {count} fields")
        if last > 0 and not self.terminated and not tail_ok:
            self._mark(last, "last line cut short (no newline, and no checksum to show it "
                             "is whole)")

    def good_lines(self) -> list[str]:
        """The header and the good lines, in file order, without newlines."""
        return [self.line(int(i)) for i in np.flatnonzero(self.ok)]

    def text(self) -> str:
        """The good lines as a file (each with its newline)."""
        if not self.bad:
            text = self.data.decode("utf-8")
            return text if self.terminated or not text else text + "\n"
        return "".join(line + "\n" for line in self.good_lines())

    def frame(self, **read_csv) -> Optional[pd.DataFrame]:
        """The good lines through ``pandas.read_csv`` (None when there is no header)."""
        if not self.ok.any():
            return None
        return pd.read_csv(io.StringIO(self.text()), **read_csv)


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
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot create the run store folder ({exc.strerror}); "
                          "choose another --out", str(self.path)) from None
        self.results_path = self.path / "results.csv"
        self.history_path = self.path / "history.csv"
        self.meta_path = self.path / "meta.json"
        #: Lines set aside under the lock: ``(file, line number, reason)``.
        self.corrupt: list[tuple[str, int, str]] = []
        self._writing = False
        if self._needs_repair():
            try:
                with RunLock(self.path / ".lock", repair=True):
                    self._repair()
            except (StoreLocked, OSError):
                # a runner holds the lock (it repairs what it finds when it takes it), or the
                # folder is read-only: change nothing, read what is complete
                pass

    # ------------------------------------------------------------------ scans and repair
    def _scan_results(self) -> Optional[_Scan]:
        if not self.results_path.exists() or self.results_path.stat().st_size == 0:
            return None
        scan = _Scan(self.results_path, "row_crc")
        if scan.starts.size and (scan.terminated or scan.starts.size > 1):
            _check_header(self.results_path, next(csv.reader([scan.line(0)])))
        return scan

    def _scan_history(self, results: Optional[_Scan]) -> Optional[_Scan]:
        """``history.csv``; its last line without newline is kept only when whole and when
        its run has a result row (the history is written before its result row)."""
        if not self.history_path.exists() or self.history_path.stat().st_size == 0:
            return None

        def finished(line: str) -> bool:
            ids = {next(csv.reader([r]))[0] for r in results.good_lines()[1:]} \
                if results else set()
            return next(csv.reader([line]))[0] in ids

        return _Scan(self.history_path, None, keep_tail=finished)

    def _needs_repair(self) -> bool:
        results = self._scan_results()
        history = self._scan_history(results)
        return any(scan is not None and scan.dirty for scan in (results, history))

    def _repair(self) -> None:
        """Set aside the bad lines of both files and end every kept line with its newline.

        Call with the exclusive lock held: it rewrites the files.
        """
        results = self._scan_results()
        self._rewrite(self.results_path, results)
        self._rewrite(self.history_path, self._scan_history(results))

    def _rewrite(self, path: Path, scan: Optional[_Scan]) -> None:
        """Move the bad lines of ``path`` to ``path.corrupt`` and write it without them."""
        if scan is None or not scan.dirty:
            return
        if scan.bad:
            corrupt = Path(str(path) + ".corrupt")
            refuse_link(corrupt)
            fd = os.open(corrupt, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, 0o644)
            with open(fd, "a", encoding="utf-8", newline="") as fh:
                fh.write("".join(text + "\n" for _, _, text in scan.bad))
                fh.flush()
                os.fsync(fh.fileno())
        atomic_write(path, scan.text())
        self.corrupt += [(str(path), i, reason) for i, reason, _ in scan.bad]

    # ------------------------------------------------------------------ lock
    @contextlib.contextmanager
    def lock(self) -> Iterator[RunLock]:
        """Exclusive writer lock on this folder (see :class:`RunLock`).

        Taking it repairs the files (see the module docstring); while it is held,
        this store's rewrites (:meth:`compact_history`) need no other lock.

        Raises
        ------
        StoreLocked
            If another runner holds the lock.
        """
        with RunLock(self.path / ".lock") as held:
            self._writing = True
            try:
                self._repair()
                yield held
            finally:
                self._writing = False

    def _exclusive(self) -> contextlib.AbstractContextManager:
        """The lock for one rewrite: none when this store holds the runner's lock."""
        return contextlib.nullcontext() if self._writing else \
            RunLock(self.path / ".lock", repair=True)

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
        scan = self._scan_results()
        rows = scan.frame(usecols=["run_id", "status", "message"], dtype=str) if scan else None
        if rows is None or rows.empty:
            return set()
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
        size = path.stat().st_size if path.exists() else 0
        if size == 0:
            csv.writer(buf, lineterminator="\n").writerow(columns)
        else:
            with open(path, "rb") as fh:
                fh.seek(size - 1)
                if fh.read(1) != b"\n":
                    # never glue a row onto a line cut short: the cut line stays a line of its
                    # own, set aside (or kept, if whole) by the next repair
                    buf.write("\n")
        for r in rows:
            line = io.StringIO()
            csv.writer(line, lineterminator="").writerow([_one_line(v) for v in r])
            text = line.getvalue()
            buf.write(f"{text},{_crc(text)}\n" if checksum else text + "\n")
        refuse_link(path)
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW, 0o644)
        with open(fd, "a", encoding="utf-8", newline="") as fh:
            fh.write(buf.getvalue())
            fh.flush()
            os.fsync(fh.fileno())

    def results(self) -> pd.DataFrame:
        """The latest row of every run (empty frame with the columns if none).

        Only complete rows are read (see the module docstring); the file is not changed.
        """
        scan = self._scan_results()
        res = scan.frame() if scan else None
        if res is None:
            return pd.DataFrame(columns=RESULT_COLUMNS)
        if "run_id" not in res.columns:
            raise ValueError(f"{self.results_path} is not a results.csv of lcpbench (no run_id "
                             f"column; it has {', '.join(map(str, res.columns[:5]))}); give the "
                             "DIR that lcpbench run or simulate wrote")
        return res.drop_duplicates("run_id", keep="last").reset_index(drop=True)

    def _history_frame(self) -> Optional[pd.DataFrame]:
        scan = self._scan_history(self._scan_results())
        return scan.frame(dtype={"run_id": str}) if scan else None

    def compact_history(self) -> int:
        """Rewrite ``history.csv`` with one block per finished run; returns rows dropped.

        Blocks of runs without a result row (interrupted attempts) and all but
        the last block of a run (earlier attempts) go; the runner calls this
        under its lock before a resume. Called without that lock, it takes the
        lock for the rewrite.

        Raises
        ------
        StoreLocked
            If a runner holds the lock (and it is not this store's).
        """
        with self._exclusive():
            h = self._history_frame()
            if h is None:
                return 0
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
        """Iterate rows of the runs that have a result row (latest attempt only).

        Only complete lines are read; the file is not changed.
        """
        h = self._history_frame()
        if h is None:
            return pd.DataFrame(columns=HISTORY_STORE_COLUMNS)
        return self._last_blocks(h)
