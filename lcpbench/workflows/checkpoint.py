"""Checkpoints of online simulations: the state after the last finished step, written atomically.

``lcpbench simulate`` writes one checkpoint per simulation (scene, solver, warm start) into
``DIR/checkpoints/`` after every step, *before* the step's row goes to ``results.csv``. The
checkpoint holds the scene's state after the step (positions, orientations, the previous
step's contact pairs and forces, the step index), the step's result row and its history. A
rerun of the same command then resumes exactly once per step:

* killed while the checkpoint was being written: the previous checkpoint stands and the step
  is simulated again (its row was never written);
* killed between the checkpoint and the row: the rerun writes the row from the checkpoint;
* killed after the row: the rerun continues with the next step.

The file is an ``.npz`` (numpy arrays only, no pickles): the scene's arrays under
``scene/<name>``, the history's columns under ``history/<column>``, and the step, the
simulation's configuration and the row as JSON under ``meta``. It is written to a temporary
file ``.tmp-*.npz`` in the same folder, locked (``flock``) while it is written, flushed to disk
and moved into place (``os.replace``), so a reader sees the old checkpoint or the new one,
never a half-written file. A write that fails (disk full) raises an ``OSError`` naming the
checkpoint and keeps the previous one. Temporary files that no writer holds and that are older
than this process (left by a killed writer) are removed whenever a checkpoint of the folder is
read or written.

A checkpoint is read as an untrusted file: before anything is decompressed, every member's
``.npy`` header (shape, dtype) is checked against the bytes the member holds and against the
read budget of :func:`lcpbench.sets.read_budget` (2 GiB, or ``$LCPBENCH_READ_BUDGET``), and
only numbers, booleans and text are accepted.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import math
import os
import tempfile
import time
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pandas as pd

from lcpbench.sets.common import READ_BUDGET_ENV, human_bytes, read_budget

__all__ = ["Checkpoint", "checkpoint_path", "save_checkpoint", "load_checkpoint"]

_FORMAT = "lcpbench.simulation-checkpoint"
_VERSION = 1
_TMP_PREFIX = ".tmp-"
#: When this process started writing: temporary files older than it, unlocked, are orphans.
_STARTED = time.time()
#: Kinds of array a checkpoint may hold: booleans, integers, floats and text.
_KINDS = "biufU"


@dataclass
class Checkpoint:
    """The state of one simulation after its last finished step.

    Attributes
    ----------
    step : int
        The last finished step (0-based).
    config : dict
        The simulation's settings (scene, solver, stop rule, budget, ...); a rerun with other
        settings is refused.
    scene_state : dict of str to numpy.ndarray
        What the scene's ``get_state`` returned after the step.
    row : dict
        The step's result row, as written to ``results.csv``.
    history : pandas.DataFrame or None
        The step's iterates, as written to ``history.csv``.
    finished : bool
        True when the simulation stopped for good at ``step`` (a failed step).
    """

    step: int
    config: dict
    scene_state: dict
    row: dict
    history: Optional[pd.DataFrame] = None
    finished: bool = False


def checkpoint_path(store_dir: Path, key: str) -> Path:
    """The checkpoint file of the simulation named ``key`` in the run store ``store_dir``."""
    digest = hashlib.sha256(key.encode()).hexdigest()[:20]
    return Path(store_dir) / "checkpoints" / f"{digest}.npz"


def _plain(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot store a {type(value).__name__} in a checkpoint")


def _clean_orphans(folder: Path) -> None:
    """Remove the ``.tmp-*.npz`` files of writers killed mid-write in ``folder``.

    A temporary file is an orphan when no writer holds its lock and it is older than this
    process; a live writer's file is locked from its creation on, so it is left alone.
    """
    for tmp in folder.glob(f"{_TMP_PREFIX}*.npz"):
        try:
            fd = os.open(tmp, os.O_RDONLY)
        except FileNotFoundError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if os.fstat(fd).st_mtime < _STARTED:
                tmp.unlink()
        except BlockingIOError:
            continue                        # a writer at work
        except FileNotFoundError:
            continue                        # removed meanwhile
        except OSError as exc:
            warnings.warn(f"{tmp}: cannot remove this temporary file of an interrupted "
                          f"checkpoint writer ({exc.strerror}); delete it by hand",
                          RuntimeWarning, stacklevel=3)
        finally:
            os.close(fd)


def save_checkpoint(path: Path, ckpt: Checkpoint) -> None:
    """Write ``ckpt`` to ``path`` atomically (temporary file, fsync, rename).

    Raises
    ------
    OSError
        The file could not be written (disk full, I/O error); ``filename`` is ``path``, the
        previous checkpoint is kept and no temporary file is left.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _clean_orphans(path.parent)
    arrays: dict[str, np.ndarray] = {}
    for name, value in ckpt.scene_state.items():
        arrays[f"scene/{name}"] = np.asarray(value)
    if ckpt.history is not None:
        for col in ckpt.history.columns:
            values = ckpt.history[col].to_numpy()
            if values.dtype == object:
                values = values.astype(str)
            arrays[f"history/{col}"] = values
    meta = {"format": _FORMAT, "version": _VERSION, "step": int(ckpt.step),
            "config": ckpt.config, "row": ckpt.row, "finished": bool(ckpt.finished),
            "history": ckpt.history is not None,
            "history_columns": list(ckpt.history.columns) if ckpt.history is not None else []}
    arrays["meta"] = np.array(json.dumps(meta, default=_plain, sort_keys=True))
    try:
        _write(path, arrays)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write the simulation checkpoint "
                      f"({exc.strerror or exc}); the previous checkpoint is kept. Free space "
                      "(or fix the disk) and rerun the same command to resume",
                      str(path)) from exc


def _write(path: Path, arrays: dict) -> None:
    fd, tmp = tempfile.mkstemp(prefix=_TMP_PREFIX, suffix=".npz", dir=path.parent)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)          # the file is live: cleaners leave it alone
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _check_members(path: Path) -> None:
    """Check every member's ``.npy`` header against its size and the read budget.

    Raises ValueError before any member is decompressed beyond its header.
    """
    limit = read_budget()
    total = 0
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            with zf.open(info) as fh:
                version = np.lib.format.read_magic(fh)
                if version == (1, 0):
                    shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
                elif version == (2, 0):
                    shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
                else:
                    raise ValueError(f"member {name!r}: .npy format {version} is not one "
                                     "lcpbench writes")
                header = fh.tell()
            if dtype.hasobject or dtype.kind not in _KINDS or dtype.fields:
                raise ValueError(f"member {name!r} has dtype {dtype}; a checkpoint holds "
                                 "numbers, booleans and text only")
            nbytes = math.prod(shape) * dtype.itemsize
            if header + nbytes > info.file_size:
                raise ValueError(f"member {name!r} declares {human_bytes(nbytes)} of data "
                                 f"but holds {human_bytes(max(info.file_size - header, 0))}")
            total += nbytes
            if total > limit:
                raise ValueError(f"member {name!r} inflates to {human_bytes(nbytes)}, over "
                                 f"the read budget of {human_bytes(limit)} (if the file is "
                                 f"trusted, raise it with {READ_BUDGET_ENV}, e.g. 16G)")


def load_checkpoint(path: Path) -> Checkpoint:
    """Read a checkpoint written by :func:`save_checkpoint`, checked as an untrusted file.

    Raises
    ------
    ValueError
        The file is not a readable checkpoint of this format, or a member would take more
        than the read budget or more than it holds (the message names the file and the
        member and says how to start over).
    """
    path = Path(path)
    _clean_orphans(path.parent)
    try:
        _check_members(path)
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            if not isinstance(meta, dict) or meta.get("format") != _FORMAT \
                    or int(meta.get("version", 0)) > _VERSION:
                raise ValueError("not a checkpoint of this lcpbench version")
            scene = {k.split("/", 1)[1]: data[k] for k in data.files if k.startswith("scene/")}
            history = None
            if meta.get("history"):
                history = pd.DataFrame({c: data[f"history/{c}"]
                                        for c in meta["history_columns"]})
        ckpt = Checkpoint(step=int(meta["step"]), config=dict(meta["config"]),
                          scene_state=scene, row=dict(meta["row"]), history=history,
                          finished=bool(meta["finished"]))
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: unreadable simulation checkpoint ({exc}); delete it and the "
                         "simulation's rows, or choose another --out, to start that simulation "
                         "again") from None
    return ckpt
