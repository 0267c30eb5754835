"""The stored-set file format: one HDF5 file per set, written resumably and read with verification.

Layout (inspired by FCLIB's HDF5 problem files)::

    /                              attrs: format="lcpbench.set", version, title, description,
                                   created, generator, lcpbench_version, cost_convention
    /instances/<id>/A              (n, n) float64, high fidelity
    /instances/<id>/b              (n,)
    /instances/<id>/x0             optional warm start
    /instances/<id>/low/<name>/A   (n, n); attrs: cost_ratio and the fidelity knobs
    /instances/<id>/reference/x,w  attrs: solvers, kkt_abs, disagreement (objective, accepted)
    instance attrs:                n, the caller's attrs (step, M, t_mvp_high, ...) and
                                   "sha256:<dataset>" for every dataset of the instance

Integrity
    Every dataset has a SHA-256 (of its dtype, shape and little-endian bytes) in the
    instance attrs; the set of ``sha256:*`` attrs is also the instance's manifest, so a
    deleted dataset is found as well as a changed one. :func:`read_set` and
    :func:`read_instance` check the file's ``format`` and ``version``, every dataset's
    presence, shape and checksum, and raise :class:`StoredSetError` naming the file,
    the instance, the dataset and the command that regenerates the file.

Atomicity and resuming
    :class:`SetWriter` writes each instance into ``/_incomplete/<id>`` and moves the
    finished group to ``/instances/<id>`` (a link move, cheap and atomic for HDF5
    readers), then flushes. An interrupted run leaves at most one group under
    ``/_incomplete``; the next :class:`SetWriter` on the file deletes it with a
    warning, and keeps every finished instance (:meth:`SetWriter.has`).

Cost convention (E-MVPs)
    ``low/<name>.attrs["cost_ratio"]`` is ``t_low / t_high``: the cost of one
    low-fidelity MVP in units of one high-fidelity MVP (0.1 means ten times cheaper),
    the same convention as ``bifidelity:cost_ratio``. Reading gives the high operator
    the declared cost 1.0 and each low operator the declared cost ``cost_ratio``, so the
    E-MVPs of a solve on a stored instance are those measured when the set was generated,
    whatever machine reads it. The seconds, when known, are kept as instance attr
    ``t_mvp_high`` and low attr ``t_mvp``.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path
from typing import Optional, Union

import numpy as np

from lcpbench.core.ranges import parse_ranges

__all__ = ["FORMAT", "VERSION", "COST_CONVENTION", "StoredSetError", "PathLike",
           "parse_instances", "set_problem_name"]

FORMAT = "lcpbench.set"
#: Layout version written by this module; files with a newer version are refused.
VERSION = 1
#: Root attribute documenting the meaning of ``cost_ratio``.
COST_CONVENTION = "cost_ratio = t_low / t_high (seconds per low MVP / seconds per high MVP)"

_INSTANCES = "instances"
_INCOMPLETE = "_incomplete"
_SHA = "sha256:"
_ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+=-]*$")

PathLike = Union[str, Path]


class StoredSetError(RuntimeError):
    """A stored set is unreadable, truncated, corrupted or incomplete.

    Attributes
    ----------
    path : str
        The file.
    instance : str or None
        The instance concerned, if any.
    dataset : str or None
        The dataset concerned (relative to the instance group), if any.
    """

    def __init__(self, message: str, *, path: PathLike, instance: Optional[str] = None,
                 dataset: Optional[str] = None):
        super().__init__(message)
        self.path = str(path)
        self.instance = instance
        self.dataset = dataset


def _digest(arr: np.ndarray) -> str:
    """SHA-256 of a dataset's dtype, shape and little-endian bytes."""
    a = np.ascontiguousarray(arr)
    if a.dtype.byteorder not in ("|", "<"):
        a = a.astype(a.dtype.newbyteorder("<"))
    h = hashlib.sha256()
    h.update(f"{a.dtype.str}:{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()



def _natural_key(s: str):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", s)]



def parse_instances(spec: str, count: int) -> list[int]:
    """Positions selected by ``"0-9"``, ``"0,3,5-7"`` or ``""`` (all) among ``count``.

    Ranges are inclusive; positions refer to the written order of the set.
    """
    if not spec.strip():
        return list(range(count))
    out = parse_ranges(spec, "instances", "'0-9' or '0,3,5-7'")
    if out and max(out) >= count:
        raise ValueError(f"instances: position {max(out)} is out of range, the set has "
                         f"{count} instance(s) (positions 0-{count - 1})")
    return out


def set_problem_name(stem: str) -> str:
    """The problem family name of the stored set ``stem``: ``set-<stem>``."""
    return "set-" + re.sub(r"[^a-z0-9]+", "-", stem.lower()).strip("-")
