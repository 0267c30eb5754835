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
    The whole file (every byte after its 512-byte user block) has a SHA-256 in that user
    block, checked before HDF5 parses the file (:mod:`lcpbench.sets.seal`), so attributes
    and HDF5 headers are covered as well as data. Every dataset has a SHA-256 (of its dtype, shape and little-endian bytes) in the
    instance attrs; the set of ``sha256:*`` attrs is also the instance's manifest, so a
    deleted dataset is found as well as a changed one. :func:`read_set` and
    :func:`read_instance` check the file's ``format`` and ``version``, every dataset's
    presence, shape and checksum, and raise :class:`StoredSetError` naming the file,
    the instance, the dataset and the command that regenerates the file.

Untrusted files
    The reader treats every file as untrusted. Before it reads a dataset it checks that
    every link of the instance is a hard link inside the file (no external or soft links),
    that the data is stored in the file itself (no external raw storage, no virtual
    dataset), that it is real (complex data is refused, never cast), that the bytes an
    uncompressed dataset declares are stored in the file, and that everything one call
    returns fits the read budget (:data:`READ_BUDGET`, 2 GiB, or the environment variable
    ``LCPBENCH_READ_BUDGET``, or ``budget=``); this also bounds what a compressed dataset
    may inflate to. Every attribute the reader uses is type-checked. Each violation is a
    :class:`StoredSetError` naming the file, the instance and the dataset.

Atomicity and resuming
    :class:`SetWriter` never lets the HDF5 library write to the disk: it holds the set
    as an HDF5 image in memory, adds each instance to the image and then replaces the
    file with the new image atomically (a temporary file beside it, fsync, rename). A
    write that fails (disk full, I/O error, a killed process) leaves the file as it was
    before that instance, with every finished instance, and the same command resumes
    (:meth:`SetWriter.has`). One writer at a time: a second one on the same file is
    refused. Files written by earlier versions may hold a half-written group under
    ``/_incomplete``; the writer deletes it with a warning.

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
import os
import re
from pathlib import Path
from typing import Optional, Union

import numpy as np

from lcpbench.core.ranges import parse_ranges

__all__ = ["FORMAT", "VERSION", "COST_CONVENTION", "READ_BUDGET", "READ_BUDGET_ENV",
           "StoredSetError", "PathLike", "parse_instances", "set_problem_name", "read_budget",
           "human_bytes"]

FORMAT = "lcpbench.set"
#: Layout version written by this module; files with a newer version are refused.
VERSION = 1
#: Root attribute documenting the meaning of ``cost_ratio``.
COST_CONVENTION = "cost_ratio = t_low / t_high (seconds per low MVP / seconds per high MVP)"

_INSTANCES = "instances"
_INCOMPLETE = "_incomplete"
_SHA = "sha256:"
_ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+=-]*$")

#: The most bytes one read of untrusted data (a stored set's datasets, a checkpoint's
#: arrays) may allocate, unless the environment variable :data:`READ_BUDGET_ENV` says
#: otherwise: 2 GiB, room for a dense instance of n = 9000 contacts with two lows (three
#: matrices of 618 MiB); the shipped instances take under 1 MiB each.
READ_BUDGET = 2 << 30
#: Environment variable overriding :data:`READ_BUDGET`: bytes, or with K, M, G or T.
READ_BUDGET_ENV = "LCPBENCH_READ_BUDGET"
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
_BUDGET_RE = re.compile(r"^\s*(\d+(?:\.\d*)?)\s*([KMGT]?)(?:I?B)?\s*$", re.IGNORECASE)

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


def read_budget(budget: Optional[int] = None) -> int:
    """The read budget in bytes: ``budget`` if given, else ``$LCPBENCH_READ_BUDGET``, else
    :data:`READ_BUDGET`.

    Raises
    ------
    ValueError
        ``budget`` is not a positive integer, or the environment variable is malformed.
    """
    if budget is not None:
        if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) \
                or budget <= 0:
            raise ValueError(f"budget={budget!r}: give the read budget as a positive number "
                             "of bytes")
        return int(budget)
    raw = os.environ.get(READ_BUDGET_ENV, "")
    if not raw.strip():
        return READ_BUDGET
    m = _BUDGET_RE.match(raw)
    value = float(m.group(1)) * _UNITS[m.group(2).upper()] if m else 0.0
    if value < 1:
        raise ValueError(f"{READ_BUDGET_ENV}={raw!r}: give a number of bytes, optionally "
                         "with K, M, G or T (powers of 1024), e.g. 4G")
    return int(value)


def human_bytes(n: int) -> str:
    """``28800000000`` -> ``"26.8 GiB"``: bytes in powers of 1024, one decimal."""
    n = int(n)
    for unit, size in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20),
                       ("KiB", 1 << 10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n} B"


def _err(path, msg, instance=None, dataset=None, generator=None, *,
         fix: Optional[str] = None) -> StoredSetError:
    """A StoredSetError ``"FILE, instance 'I', dataset 'D': MSG. FIX"``.

    ``fix`` defaults to the command that regenerates the file (``generator``).
    """
    where = f"{path}"
    if instance is not None:
        where += f", instance {instance!r}"
    if dataset is not None:
        where += f", dataset {dataset!r}"
    if fix is None:
        fix = (f"Regenerate the file with: {generator}" if generator else
               "Regenerate the file with the command that made it")
    return StoredSetError(f"{where}: {msg}. {fix}", path=path, instance=instance,
                          dataset=dataset)


def _digest(arr: np.ndarray) -> str:
    """SHA-256 of a dataset's dtype, shape and little-endian bytes (hashed in place, without
    a copy, when the data is contiguous and little-endian already)."""
    a = np.ascontiguousarray(arr)
    if a.dtype.byteorder == ">" or (a.dtype.byteorder == "=" and not np.little_endian):
        a = a.astype(a.dtype.newbyteorder("<"))
    h = hashlib.sha256()
    h.update(f"{a.dtype.str}:{a.shape}".encode())
    h.update(a.data)
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
