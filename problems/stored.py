"""Stored LCP sets: one HDF5 file per set, written resumably and read with verification.

Layout (DESIGN.md, "Stored sets"; inspired by FCLIB)::

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
import json
import re
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional, Union

import h5py
import numpy as np

from lcpbench import LCP, Operator, Reference, register_problem
from lcpbench.core.operator import dense_uncounted
from lcpbench.core.ranges import parse_ranges

__all__ = ["SetWriter", "StoredSetError", "read_set", "read_instance", "set_info",
           "instance_ids", "shipped_sets", "parse_instances", "FORMAT", "VERSION",
           "COST_CONVENTION", "DATA_DIR", "ShippedSetParams", "register_shipped_sets", "set_problem_name",
           "DEFAULT_SETS"]

#: Value of the root attribute ``format``.
FORMAT = "lcpbench.set"
#: Layout version written by this module; files with a newer version are refused.
VERSION = 1
#: Root attribute documenting the meaning of ``cost_ratio``.
COST_CONVENTION = "cost_ratio = t_low / t_high (seconds per low MVP / seconds per high MVP)"
#: Folder of the sets shipped with lcpbench.
DATA_DIR = Path(__file__).resolve().parent / "data"

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


# ---------------------------------------------------------------------- helpers
def _digest(arr: np.ndarray) -> str:
    """SHA-256 of a dataset's dtype, shape and little-endian bytes."""
    a = np.ascontiguousarray(arr)
    if a.dtype.byteorder not in ("|", "<"):
        a = a.astype(a.dtype.newbyteorder("<"))
    h = hashlib.sha256()
    h.update(f"{a.dtype.str}:{a.shape}".encode())
    h.update(a.tobytes())
    return h.hexdigest()


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


def _py(value: Any) -> Any:
    """An attribute read back as a plain Python value."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return [_py(v) for v in value.tolist()] if value.dtype == object else value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _natural_key(s: str):
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", s)]


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
    def __enter__(self) -> "SetWriter":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> "SetWriter":
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
                            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
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


# ---------------------------------------------------------------------- reading
def _err(path, msg, instance=None, dataset=None, generator=None) -> StoredSetError:
    where = f"{path}"
    if instance is not None:
        where += f", instance {instance!r}"
    if dataset is not None:
        where += f", dataset {dataset!r}"
    fix = (f" Regenerate the file with: {generator}" if generator else
           " Regenerate the file with the command that made it")
    return StoredSetError(f"{where}: {msg}.{fix}", path=path, instance=instance,
                          dataset=dataset)


def _open(path: PathLike) -> h5py.File:
    p = Path(path)
    if not p.exists():
        raise StoredSetError(f"{p}: no such stored set; check the path (shipped sets: "
                             f"{', '.join(shipped_sets()) or 'none'})", path=p)
    try:
        return h5py.File(p, "r")
    except OSError as exc:
        raise _err(p, f"cannot open the HDF5 file, it is truncated or corrupted ({exc})") \
            from None


def _check_root(f: h5py.File, path: PathLike) -> None:
    fmt = _py(f.attrs.get("format"))
    gen = _py(f.attrs.get("generator"))
    if fmt != FORMAT:
        raise StoredSetError(f"{path}: not an lcpbench stored set (format attribute "
                             f"{fmt!r}, expected {FORMAT!r})", path=path)
    ver = _py(f.attrs.get("version"))
    if not isinstance(ver, int) or ver < 1:
        raise _err(path, f"invalid version attribute {ver!r}", generator=gen)
    if ver > VERSION:
        raise StoredSetError(f"{path}: layout version {ver} is newer than this lcpbench "
                             f"reads ({VERSION}); upgrade lcpbench", path=path)
    if _INSTANCES not in f:
        raise _err(path, "the /instances group is missing", generator=gen)


def set_info(path: PathLike) -> dict:
    """Root attributes of a stored set (format, version, title, generator, ...) and ``ids``."""
    with _open(path) as f:
        _check_root(f, path)
        info = {k: _py(v) for k, v in f.attrs.items()}
        info["ids"] = list(f[_INSTANCES].keys())
        info["incomplete"] = list(f[_INCOMPLETE].keys()) if _INCOMPLETE in f else []
    return info


def instance_ids(path: PathLike) -> list[str]:
    """Finished instance ids of a stored set, in the order they were written."""
    return set_info(path)["ids"]


def _read_dataset(g: h5py.Group, rel: str, shape: tuple, path, iid, gen) -> np.ndarray:
    if rel not in g:
        raise _err(path, "dataset is missing (listed in the instance's checksums)", iid, rel,
                   gen)
    ds = g[rel]
    if not isinstance(ds, h5py.Dataset):
        raise _err(path, "expected a dataset, found a group", iid, rel, gen)
    if tuple(ds.shape) != shape:
        raise _err(path, f"shape {tuple(ds.shape)}, expected {shape}", iid, rel, gen)
    try:
        arr = ds[()]
    except (OSError, ValueError, RuntimeError) as exc:
        raise _err(path, f"cannot read the data, the file is truncated or corrupted ({exc})",
                   iid, rel, gen) from None
    want = _py(g.attrs[_SHA + rel])
    got = _digest(arr)
    if got != want:
        raise _err(path, f"checksum mismatch (sha256 {got[:12]}..., stored {want[:12]}...): "
                   "the data was changed or corrupted", iid, rel, gen)
    return np.asarray(arr, dtype=np.float64)


def _load(f: h5py.File, path: Path, iid: str, **lcp_kwargs) -> LCP:
    gen = _py(f.attrs.get("generator"))
    if iid not in f[_INSTANCES]:
        raise StoredSetError(f"{path}: no instance {iid!r}; the file holds "
                             f"{', '.join(list(f[_INSTANCES].keys())[:20]) or 'none'}",
                             path=path, instance=iid)
    try:
        g = f[_INSTANCES][iid]
        attrs = {k: _py(v) for k, v in g.attrs.items()}
    except (OSError, KeyError, RuntimeError) as exc:
        raise _err(path, f"cannot read the instance group ({exc})", iid, None, gen) from None
    if "n" not in attrs:
        raise _err(path, "instance attribute 'n' is missing", iid, None, gen)
    n = int(attrs.pop("n"))
    manifest = sorted(k[len(_SHA):] for k in attrs if k.startswith(_SHA))
    for req in ("A", "b"):
        if req not in manifest:
            raise _err(path, "no checksum recorded for a required dataset", iid, req, gen)
    meta = {k: v for k, v in attrs.items() if not k.startswith(_SHA)}
    data = {}
    for rel in manifest:
        shape = (n, n) if rel == "A" or rel.endswith("/A") else (n,)
        data[rel] = _read_dataset(g, rel, shape, path, iid, gen)
    # Datasets present but not in the manifest were not written by SetWriter.
    extra = []
    g.visit(lambda name: extra.append(name) if isinstance(g[name], h5py.Dataset)
            and name not in data else None)
    if extra:
        raise _err(path, f"datasets without a checksum: {', '.join(extra)}", iid, extra[0], gen)
    low = {}
    low_meta = {}
    for rel in manifest:
        if rel.startswith("low/"):
            name = rel.split("/")[1]
            la = {k: _py(v) for k, v in g[f"low/{name}"].attrs.items()}
            if "cost_ratio" not in la:
                raise _err(path, "attribute cost_ratio is missing", iid, f"low/{name}", gen)
            ratio = float(la["cost_ratio"])
            low[name] = Operator(data[rel], cost=ratio * 1.0, name=name)
            low_meta[name] = la
    reference = None
    if "reference/x" in data and "reference/w" in data:
        ra = {k: _py(v) for k, v in g["reference"].attrs.items()}
        x, w = data["reference/x"], data["reference/w"]
        reference = {"x": x, "w": w,
                     "objective": float(ra.get("objective", 0.5 * x @ (w + data["b"]))),
                     "solvers": list(ra.get("solvers", ["stored"])) if not
                     isinstance(ra.get("solvers"), str) else [ra["solvers"]],
                     "kkt_abs": float(ra.get("kkt_abs", np.nan)),
                     "disagreement": float(ra.get("disagreement", np.nan)),
                     "accepted": bool(ra.get("accepted", True))}
    meta.update({"family": meta.get("family", "stored"), "n": n, "instance": iid,
                 "set": path.stem, "source": str(path)})
    if low_meta:
        meta["low"] = low_meta
    try:
        return LCP(Operator(data["A"], cost=1.0), data["b"], x0=data.get("x0"), low=low,
                   name=f"{path.stem}/{iid}", meta=meta, reference=reference, **lcp_kwargs)
    except (ValueError, TypeError) as exc:
        raise _err(path, f"the stored data is not a valid LCP ({exc})", iid, None, gen) \
            from None


def read_instance(path: PathLike, instance_id: str, **lcp_kwargs) -> LCP:
    """Read and verify one instance of a stored set.

    Parameters
    ----------
    path : str or Path
    instance_id : str
    **lcp_kwargs
        Passed to :class:`~lcpbench.LCP` (e.g. ``psd_check=False``).

    Returns
    -------
    LCP
        High operator with declared cost 1.0, low operators with cost ``cost_ratio``
        (module docstring), ``reference`` from the stored reference, ``meta`` from the
        instance attrs (plus ``instance``, ``set``, ``source`` and ``low`` attrs).

    Raises
    ------
    StoredSetError
        Naming the file, instance and dataset, for a truncated file, a checksum or
        shape mismatch, a missing dataset, or an unknown instance.
    """
    p = Path(path)
    with _open(p) as f:
        _check_root(f, p)
        return _load(f, p, str(instance_id), **lcp_kwargs)


def read_set(path: PathLike, ids: Optional[Iterable[str]] = None, **lcp_kwargs) -> list[LCP]:
    """Read and verify every (or the given) instance of a stored set, in written order.

    Parameters
    ----------
    path : str or Path
    ids : iterable of str, optional
        Subset of instance ids; default all.
    **lcp_kwargs
        Passed to :class:`~lcpbench.LCP`.

    Raises
    ------
    StoredSetError
        As :func:`read_instance`; nothing is dropped silently.
    """
    p = Path(path)
    with _open(p) as f:
        _check_root(f, p)
        try:
            all_ids = list(f[_INSTANCES].keys())
        except (OSError, RuntimeError) as exc:
            raise _err(p, f"cannot list instances ({exc})",
                       generator=_py(f.attrs.get("generator"))) from None
        chosen = all_ids if ids is None else [str(i) for i in ids]
        return [_load(f, p, iid, **lcp_kwargs) for iid in chosen]


def shipped_sets() -> dict[str, Path]:
    """The sets shipped with lcpbench: ``{stem: path}`` of ``problems/data/*.h5``."""
    if not DATA_DIR.is_dir():
        return {}
    return {p.stem: p for p in sorted(DATA_DIR.glob("*.h5"), key=lambda q: _natural_key(q.stem))}


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


@dataclass(frozen=True)
class StoredParams:
    """Parameters of stored.

    Parameters
    ----------
    path : str
        The ``.h5`` file, or the name of a shipped set (``shipped_sets()``).
    instances : str
        Positions to read, e.g. ``"0-9"`` or ``"0,3,5-7"`` (inclusive; default all).
    """

    path: str = ""
    instances: str = ""

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("path is required: stored:path=FILE.h5 (or a shipped set name: "
                             f"{', '.join(shipped_sets()) or 'none shipped'})")


@register_problem("stored", StoredParams)
def stored(p: StoredParams) -> list[LCP]:
    """A stored HDF5 set, verified on reading (checksums, shapes, format version)."""
    path = Path(p.path)
    if not path.exists() and p.path in shipped_sets():
        path = shipped_sets()[p.path]
    ids = instance_ids(path)
    chosen = [ids[i] for i in parse_instances(p.instances, len(ids))]
    return read_set(path, chosen)


# ----------------------------------------------------------------------------- shipped sets
# Every problems/data/*.h5 is a problem family ``set-<stem>`` wherever this plugin loads
# (CLI, library, dask workers), not only where the CLI imported it.


@dataclass(frozen=True)
class ShippedSetParams:
    """Parameters of a shipped stored set.

    Parameters
    ----------
    instances : str
        Positions to read, e.g. ``"0-9"`` or ``"0,3,5-7"`` (inclusive; default all).
    """

    instances: str = ""


def set_problem_name(stem: str) -> str:
    """The problem family name of the shipped set ``stem``: ``set-<stem>``."""
    return "set-" + re.sub(r"[^a-z0-9]+", "-", stem.lower()).strip("-")


#: Shipped sets in the default sweep of ``lcpbench run`` (with the hard-case families).
DEFAULT_SETS = ("lattice-bim-m3",)


def register_shipped_sets() -> list[str]:
    """Register problem ``set-<stem>`` for every shipped set; returns the names.

    Each reads its file with the ``stored`` plugin (verified on reading). Names
    already registered by the same function are left as they are. The sets in
    :data:`DEFAULT_SETS` join the default sweep of ``lcpbench run``.
    """
    names = []
    for stem, path in shipped_sets().items():
        pname = set_problem_name(stem)

        def load(p: ShippedSetParams, _path: Path = path):
            return stored(StoredParams(path=str(_path), instances=p.instances))

        load.__doc__ = f"Shipped stored set {stem} ({path.name}), verified on reading."
        load.__qualname__ = f"shipped_set_{pname}"
        try:
            register_problem(pname, ShippedSetParams, default=stem in DEFAULT_SETS)(load)
        except ValueError:
            continue                     # a plugin of that name exists: keep it
        names.append(pname)
    return names


register_shipped_sets()
