"""Writing stored sets: :class:`SetWriter`, resumable and atomic per instance."""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Optional, Union

import h5py
import numpy as np

from lcpbench.core.clock import utc_now
from lcpbench.core.operator import Operator, dense_uncounted
from lcpbench.core.reference import Reference
from lcpbench.sets.common import (
    _ID_RE,
    _INCOMPLETE,
    _INSTANCES,
    _SHA,
    COST_CONVENTION,
    FORMAT,
    VERSION,
    PathLike,
    StoredSetError,
    _digest,
)
from lcpbench.sets.read import _check_root

__all__ = ["SetWriter"]


def _attr_value(key: str, value: Any) -> Any:
    """Convert a Python value into something h5py stores as an attribute."""
    if value is None:
        raise TypeError(f"attribute {key!r} is None; HDF5 attributes cannot be None, "
                        "omit the key instead")
    if isinstance(value, (str, bool, int, float, np.generic)):
        return value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Mapping):
        return json.dumps(value, sort_keys=True, default=float)
    seq = list(value) if isinstance(value, (list, tuple, np.ndarray)) else None
    if seq is None:
        raise TypeError(f"attribute {key!r}: cannot store a {type(value).__name__}; use a "
                        "str, a number, a bool, a dict (stored as JSON) or a sequence of them")
    if all(isinstance(v, str) for v in seq):
        return np.array(seq, dtype=h5py.string_dtype())
    arr = np.asarray(seq)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number)
                                   or arr.dtype == bool):
        raise TypeError(f"attribute {key!r}: a sequence must hold only numbers or only "
                        "strings")
    return arr



def _as_reference_dict(ref: Union[Reference, Mapping[str, Any]]) -> dict:
    d = ref.as_dict() if isinstance(ref, Reference) else dict(ref)
    missing = [k for k in ("x", "w") if k not in d]
    if missing:
        raise ValueError(f"reference: missing {', '.join(missing)}; pass a "
                         "lcpbench.Reference or a dict with x, w, solvers, kkt_abs, "
                         "disagreement")
    return d


def _vector(name: str, v, n: int) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (n,):
        raise ValueError(f"{name}: length {a.shape[0]} does not match n = {n}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: non-finite entries; store finite values only")
    return a


def _matrix(name: str, M, n: int) -> np.ndarray:
    if isinstance(M, Operator):
        M = dense_uncounted(M)
    elif hasattr(M, "toarray"):
        M = M.toarray()
    a = np.asarray(M, dtype=np.float64)
    if a.shape != (n, n):
        raise ValueError(f"{name}: shape {a.shape} does not match (n, n) = {(n, n)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: non-finite entries; store finite values only")
    return a


# ---------------------------------------------------------------------- writer
class SetWriter:
    """Write a stored set instance by instance; resumable and atomic per instance.

    Parameters
    ----------
    path : str or Path
        The ``.h5`` file. Created if missing; if it exists it must be an lcpbench set
        and its finished instances are kept (resume).
    title : str
        One-line title of the set (root attr ``title``).
    description : str
        What the set contains and how it was made.
    generator : str
        The command line that regenerates the file; quoted by every read error.
    compression : str, optional
        h5py compression filter for the matrices (e.g. ``"gzip"``); default none,
        which keeps datasets contiguous.

    Attributes
    ----------
    recovered : list of str
        Ids of half-written instances found on open and deleted.

    Examples
    --------
    >>> with SetWriter("set.h5", title="t", description="d", generator="cmd") as w:
    ...     if not w.has("0"):
    ...         w.write_instance("0", A, b, low={"p4": (A4, 0.1, {"p": 4})})
    """

    def __init__(self, path: PathLike, *, title: str, description: str, generator: str,
                 compression: Optional[str] = None):
        self.path = Path(path)
        self.title = str(title)
        self.description = str(description)
        self.generator = str(generator)
        self.compression = compression
        self.recovered: list[str] = []
        self._f: Optional[h5py.File] = None

    # -------------------------------------------------------------- context
    def __enter__(self) -> SetWriter:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> SetWriter:
        """Open (or create) the file, check it and clean up half-written instances."""
        if self._f is not None:
            return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        exists = self.path.exists() and self.path.stat().st_size > 0
        try:
            f = h5py.File(self.path, "a")
        except OSError as exc:
            raise StoredSetError(
                f"{self.path}: cannot open the stored set for writing ({exc}). If the file is "
                "truncated or corrupted, delete it and regenerate it", path=self.path) from None
        if exists and f.attrs.get("format") is not None:
            try:
                _check_root(f, self.path)
            except StoredSetError:
                f.close()
                raise
        elif exists and len(f.keys()):
            f.close()
            raise StoredSetError(f"{self.path}: an HDF5 file that is not an lcpbench set "
                                 f"(no format={FORMAT!r} attribute); choose another path",
                                 path=self.path)
        if "format" not in f.attrs:
            from lcpbench import __version__
            f.attrs.update({"format": FORMAT, "version": VERSION, "title": self.title,
                            "description": self.description, "generator": self.generator,
                            "created": utc_now(),
                            "lcpbench_version": __version__,
                            "cost_convention": COST_CONVENTION})
        if _INSTANCES not in f:
            f.create_group(_INSTANCES, track_order=True)
        if _INCOMPLETE in f:
            stale = list(f[_INCOMPLETE].keys())
            self.recovered.extend(str(k) for k in stale)
            del f[_INCOMPLETE]
            if stale:
                warnings.warn(f"{self.path}: deleted {len(stale)} half-written instance(s) "
                              f"left by an interrupted writer: {', '.join(self.recovered)}; "
                              "they will be written again", RuntimeWarning, stacklevel=3)
        f.flush()
        self._f = f
        return self

    def close(self) -> None:
        """Flush and close the file."""
        if self._f is not None:
            self._f.flush()
            self._f.close()
            self._f = None

    @property
    def file(self) -> h5py.File:
        if self._f is None:
            raise RuntimeError("SetWriter is closed; use it as a context manager "
                               "(`with SetWriter(...) as w:`) or call open()")
        return self._f

    # -------------------------------------------------------------- queries
    def has(self, instance_id: str) -> bool:
        """True when instance ``instance_id`` is already finished in the file."""
        return str(instance_id) in self.file[_INSTANCES]

    def ids(self) -> list[str]:
        """Finished instance ids, in the order they were written."""
        return list(self.file[_INSTANCES].keys())

    # -------------------------------------------------------------- writing
    def write_instance(self, instance_id: str, A, b, *,
                       low: Optional[Mapping[str, tuple]] = None, x0=None,
                       reference: Union[Reference, Mapping[str, Any], None] = None,
                       attrs: Optional[Mapping[str, Any]] = None) -> None:
        """Write one instance atomically.

        Parameters
        ----------
        instance_id : str
            Group name under ``/instances`` (letters, digits and ``_.+=-``).
        A : (n, n) array_like or sparse matrix
            High-fidelity matrix (stored dense, float64).
        b : (n,) array_like
        low : mapping, optional
            ``{name: (A_low, cost_ratio, attrs)}`` with ``cost_ratio = t_low / t_high``
            and ``attrs`` the fidelity knobs (``p``, ``eps_gmres``, ``t_mvp``, ...).
        x0 : (n,) array_like, optional
            Warm start.
        reference : Reference or dict, optional
            With ``x``, ``w`` and optionally ``solvers``, ``kkt_abs``, ``disagreement``,
            ``objective``, ``accepted``.
        attrs : dict, optional
            Instance attributes (``step``, ``M``, ``t_mvp_high``, scene parameters).

        Raises
        ------
        ValueError
            If the instance exists already, or a shape or value is wrong.
        """
        f = self.file
        iid = str(instance_id)
        if not _ID_RE.match(iid):
            raise ValueError(f"instance id {iid!r}: use letters, digits and _.+=- only "
                             "(it becomes an HDF5 group name)")
        if self.has(iid):
            raise ValueError(f"{self.path}: instance {iid!r} exists already; check "
                             "SetWriter.has(id) before writing to resume a set")
        b = np.asarray(b, dtype=np.float64).reshape(-1)
        n = int(b.shape[0])
        datasets: dict[str, tuple[np.ndarray, dict]] = {
            "A": (_matrix(f"instance {iid}: A", A, n), {}),
            "b": (_vector(f"instance {iid}: b", b, n), {}),
        }
        if x0 is not None:
            datasets["x0"] = (_vector(f"instance {iid}: x0", x0, n), {})
        low_attrs: dict[str, dict] = {}
        for name, spec in dict(low or {}).items():
            if not _ID_RE.match(str(name)):
                raise ValueError(f"instance {iid}: low-fidelity name {name!r}: use letters, "
                                 "digits and _.+=- only")
            if not isinstance(spec, (tuple, list)) or len(spec) not in (2, 3):
                raise ValueError(f"instance {iid}: low[{name!r}] must be (A_low, cost_ratio) "
                                 "or (A_low, cost_ratio, attrs)")
            A_low, ratio = spec[0], float(spec[1])
            if not (np.isfinite(ratio) and ratio > 0):
                raise ValueError(f"instance {iid}: low[{name!r}] cost_ratio must be a "
                                 f"positive number (t_low / t_high), got {spec[1]!r}")
            extra = dict(spec[2]) if len(spec) == 3 and spec[2] else {}
            datasets[f"low/{name}/A"] = (_matrix(f"instance {iid}: low[{name!r}]", A_low, n),
                                         {})
            low_attrs[str(name)] = {**{k: _attr_value(k, v) for k, v in extra.items()},
                                    "cost_ratio": ratio}
        ref_attrs: dict[str, Any] = {}
        if reference is not None:
            rd = _as_reference_dict(reference)
            datasets["reference/x"] = (_vector(f"instance {iid}: reference x", rd["x"], n), {})
            datasets["reference/w"] = (_vector(f"instance {iid}: reference w", rd["w"], n), {})
            for k in ("solvers", "kkt_abs", "disagreement", "objective", "accepted"):
                if rd.get(k) is not None:
                    ref_attrs[k] = _attr_value(k, list(rd[k]) if k == "solvers" else rd[k])
        inst_attrs = {k: _attr_value(k, v) for k, v in dict(attrs or {}).items()}
        if any(k.startswith(_SHA) for k in inst_attrs) or "n" in inst_attrs:
            raise ValueError(f"instance {iid}: attrs may not set 'n' or 'sha256:*' "
                             "(written by SetWriter)")

        tmp_name = f"{_INCOMPLETE}/{iid}"
        if tmp_name in f:
            del f[tmp_name]
        g = f.create_group(tmp_name)
        try:
            for rel, (arr, _) in datasets.items():
                kw = {"compression": self.compression} if self.compression and arr.ndim == 2 \
                    else {}
                g.create_dataset(rel, data=arr, **kw)
            for name, la in low_attrs.items():
                g[f"low/{name}"].attrs.update(la)
            if ref_attrs:
                g["reference"].attrs.update(ref_attrs)
            g.attrs.update(inst_attrs)
            g.attrs["n"] = n
            for rel, (arr, _) in datasets.items():
                g.attrs[_SHA + rel] = _digest(arr)
            f.move(tmp_name, f"{_INSTANCES}/{iid}")
            if not len(f[_INCOMPLETE]):
                del f[_INCOMPLETE]
        except BaseException:
            if tmp_name in f:
                del f[tmp_name]
            raise
        f.flush()


