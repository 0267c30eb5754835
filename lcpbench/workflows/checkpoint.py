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
file in the same folder, flushed to disk and moved into place (``os.replace``), so a reader
sees the old checkpoint or the new one, never a half-written file.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pandas as pd

__all__ = ["Checkpoint", "checkpoint_path", "save_checkpoint", "load_checkpoint"]

_FORMAT = "lcpbench.simulation-checkpoint"
_VERSION = 1


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


def save_checkpoint(path: Path, ckpt: Checkpoint) -> None:
    """Write ``ckpt`` to ``path`` atomically (temporary file, fsync, rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, Any] = {}   # Any: np.savez(**arrays) also takes keyword flags
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
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def load_checkpoint(path: Path) -> Checkpoint:
    """Read a checkpoint written by :func:`save_checkpoint`.

    Raises
    ------
    ValueError
        The file is not a readable checkpoint of this format (the message names the file and
        says how to start over).
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            if meta.get("format") != _FORMAT or int(meta.get("version", 0)) > _VERSION:
                raise ValueError("not a checkpoint of this lcpbench version")
            scene = {k.split("/", 1)[1]: data[k] for k in data.files if k.startswith("scene/")}
            history = None
            if meta.get("history"):
                history = pd.DataFrame({c: data[f"history/{c}"]
                                        for c in meta["history_columns"]})
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{path}: unreadable simulation checkpoint ({exc}); delete it and the "
                         "simulation's rows, or choose another --out, to start that simulation "
                         "again") from None
    return Checkpoint(step=int(meta["step"]), config=meta["config"], scene_state=scene,
                      row=meta["row"], history=history, finished=bool(meta["finished"]))
