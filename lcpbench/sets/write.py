"""Writing stored sets: :class:`SetWriter`, resumable and atomic per instance.

The HDF5 library never writes to the disk here: :class:`SetWriter` holds the set as an HDF5
image in memory (h5py on a :class:`io.BytesIO`), adds each instance to the image and then
replaces the file with the whole image, written by Python to a temporary file beside it,
flushed to the disk (fsync) and renamed over the set. A full disk or an I/O error is then an
ordinary ``OSError`` of that write, never an HDF5 library error mid-write that leaves the
file's metadata inconsistent (or crashes the process); the file on disk is always the image
after the last finished instance. What rewriting the image costs per instance is measured in
docs/benchmarks.md ("Writing stored sets: the cost of an atomic replace per instance").
"""

from __future__ import annotations

import contextlib
import fcntl
import glob
import io
import json
import os
import secrets
import stat
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
from lcpbench.sets.read import _check_root, read_set
from lcpbench.sets.seal import USERBLOCK, check_seal, seal_image

__all__ = ["SetWriter", "seal_set"]


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


# ---------------------------------------------------------------------- the file on disk
class _SetLock:
    """An exclusive ``flock`` on ``.NAME.h5.lock`` beside the set while one writer writes it.

    The kernel drops the lock when its holder exits, however it exits, so a killed writer
    never blocks a resume; the file is removed when the lock is released. Children forked
    while the lock is held close their copy of the descriptor.
    """

    _held: list = []

    def __init__(self, target: Path):
        self.target = target
        self.path = target.with_name(f".{target.name}.lock")
        self.fd: Optional[int] = None

    def acquire(self) -> None:
        """Take the lock, or raise StoredSetError naming the holder's pid."""
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 32).decode(errors="replace").strip() or "unknown"
                os.close(fd)
                raise StoredSetError(
                    f"{self.target}: the set is being written by another lcpbench process "
                    f"(pid {holder}); wait for it to finish, or choose another --out",
                    path=self.target) from None
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)        # its holder removed the file as we opened it: take a new one
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self.fd = fd
        _SetLock._held.append(fd)

    def release(self) -> None:
        """Remove the lock file and drop the lock (in that order, so no one takes a stale one)."""
        if self.fd is None:
            return
        _SetLock._held.remove(self.fd)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)
        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)
        self.fd = None


def _close_held_locks_in_child() -> None:
    for fd in _SetLock._held:
        with contextlib.suppress(OSError):       # closed already in this child
            os.close(fd)
    _SetLock._held.clear()


os.register_at_fork(after_in_child=_close_held_locks_in_child)


def _write_all(fh, data) -> None:
    """Write every byte of ``data`` to the unbuffered binary file ``fh``."""
    view = memoryview(data).cast("B")
    while len(view):
        view = view[fh.write(view):]


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno != 22:             # EINVAL: the file system cannot sync folders
            raise
    finally:
        os.close(fd)


def _replace_atomically(target: Path, data) -> None:
    """Replace ``target`` by ``data``: a temporary file beside it, fsync, rename.

    On any failure the temporary file is removed and ``target`` is untouched.
    """
    tmp = target.with_name(f".{target.name}.tmp-{secrets.token_hex(6)}")
    mode = stat.S_IMODE(target.stat().st_mode) if target.exists() else None
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with open(fd, "wb", buffering=0) as fh:
            if mode is not None:
                os.fchmod(fd, mode)
            _write_all(fh, data)
            os.fsync(fd)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    _fsync_dir(target.parent)


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
        Ids of half-written instances (left by writers of earlier versions) found on open
        and deleted.

    Notes
    -----
    The set is held in memory while the writer is open (module docstring); each
    :meth:`write_instance` replaces the file atomically, so the file on disk is always a
    whole set. A write that fails raises :class:`StoredSetError` and leaves the file and
    the writer as they were before that instance. Changes made through :attr:`file`
    (root attributes) are written with the next instance or by :meth:`close`. One writer
    at a time: a second one on the same file raises :class:`StoredSetError`.

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
        self._buf: Optional[io.BytesIO] = None
        self._lock: Optional[_SetLock] = None
        self._target = self.path

    # -------------------------------------------------------------- context
    def __enter__(self) -> SetWriter:
        self.open()
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(save=exc_type is None)

    def open(self) -> SetWriter:
        """Lock the file, load (or create) it, check it and clean up what killed writers left."""
        if self._f is not None:
            return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._target = Path(os.path.realpath(self.path))
        lock = _SetLock(self._target)
        lock.acquire()
        try:
            self._remove_orphans()
            self._load()
            if self._prepare() or not self._target.exists():
                self._save("create the set" if not self._target.exists() else
                           "clean up the set", changed=True)
        except BaseException:
            self._drop()
            lock.release()
            raise
        self._lock = lock
        return self

    def close(self, *, save: bool = True) -> None:
        """Write what changed since the last instance (when ``save``), unlock and close."""
        try:
            if self._f is not None and save:
                self._save("save the set's attributes")
        finally:
            self._drop()
            if self._lock is not None:
                self._lock.release()
                self._lock = None

    @property
    def file(self) -> h5py.File:
        """The set's HDF5 image in memory (written to disk with the next instance)."""
        if self._f is None:
            raise RuntimeError("SetWriter is closed; use it as a context manager "
                               "(`with SetWriter(...) as w:`) or call open()")
        return self._f

    # -------------------------------------------------------------- the image
    def _remove_orphans(self) -> None:
        """Remove temporary images of writers killed mid-write (we hold the lock)."""
        pattern = f".{glob.escape(self._target.name)}.tmp-*"
        for orphan in self._target.parent.glob(pattern):
            try:
                orphan.unlink()
            except FileNotFoundError:
                continue
            except OSError as exc:
                warnings.warn(f"{orphan}: cannot remove this temporary file of an "
                              f"interrupted writer ({exc.strerror}); delete it by hand",
                              RuntimeWarning, stacklevel=4)

    def _load(self) -> None:
        """Read the file on disk into memory (or start an empty image)."""
        target = self._target
        if not (target.exists() and target.stat().st_size > 0):
            self._buf = io.BytesIO()
            self._f = h5py.File(self._buf, "w", userblock_size=USERBLOCK)
            return
        check_seal(target)
        self._buf = io.BytesIO(target.read_bytes())
        try:
            f = h5py.File(self._buf, "r+")
        except OSError as exc:
            raise StoredSetError(
                f"{self.path}: cannot open the stored set for writing ({exc}). If the file is "
                "truncated or corrupted, delete it and regenerate it", path=self.path) from None
        self._f = f
        if f.attrs.get("format") is not None:
            _check_root(f, self.path)
        elif len(f.keys()):
            raise StoredSetError(f"{self.path}: an HDF5 file that is not an lcpbench set "
                                 f"(no format={FORMAT!r} attribute); choose another path",
                                 path=self.path)
        if f.userblock_size < USERBLOCK:
            self._with_userblock()

    def _with_userblock(self) -> None:
        """Copy an image written before stored sets carried a file checksum into a new
        image with the user block that holds it (same attributes, groups and order)."""
        old = self.file
        buf = io.BytesIO()
        new = h5py.File(buf, "w", userblock_size=USERBLOCK)
        new.attrs.update({k: old.attrs[k] for k in old.attrs})
        for name in old:
            group = new.create_group(name, track_order=True)
            group.attrs.update({k: old[name].attrs[k] for k in old[name].attrs})
            for child in old[name]:
                old.copy(old[name][child], group, name=child)
        old.close()
        self._f, self._buf = new, buf

    def _prepare(self) -> bool:
        """Root attributes and groups of a new set, stale groups removed; True if changed."""
        f = self.file
        changed = "format" not in f.attrs or _INSTANCES not in f or _INCOMPLETE in f
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
                              "they will be written again", RuntimeWarning, stacklevel=4)
        return changed

    def _image(self) -> bytes:
        """The image as it stands (a copy: no view of the buffer outlives this call, so the
        HDF5 library can always go on writing to it)."""
        self.file.flush()
        assert self._buf is not None             # set with the file by open()
        return seal_image(self._buf.getvalue())

    def _save(self, what: str, instance: Optional[str] = None, *, changed: bool = False) -> None:
        """Replace the file by the image (unless ``changed`` is False and they are equal);
        StoredSetError if that fails.

        After a failure the image is reloaded from the file, so the writer holds what the
        file holds.
        """
        image = self._image()
        try:
            if changed or not self._on_disk(image):
                _replace_atomically(self._target, image)
        except OSError as exc:
            reason = exc.strerror or str(exc)
            self._reload()
            kept = len(self.ids()) if self._f is not None else 0
            raise StoredSetError(
                f"{self.path}: cannot {what} ({reason}); the file keeps its {kept} finished "
                "instance(s) and nothing half-written. Free space (or fix the disk) and "
                "rerun the same command to resume", path=self.path, instance=instance) \
                from exc

    def _on_disk(self, image: bytes) -> bool:
        """True when the file holds ``image`` already (compared a mebibyte at a time)."""
        target = self._target
        if not target.exists() or target.stat().st_size != len(image):
            return False
        view, step = memoryview(image), 1 << 20
        with open(target, "rb") as fh:
            for start in range(0, len(image), step):
                if fh.read(step) != view[start:start + step]:
                    return False
        return True

    def _drop(self) -> None:
        if self._f is not None:
            self._f.close()
        self._f, self._buf = None, None

    def _reload(self) -> None:
        """Forget the image in memory and load the file again (after a failed write)."""
        self._drop()
        if self._target.exists():
            self._load()

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
        StoredSetError
            The file could not be written (disk full, I/O error): the file and the writer
            are as they were before this instance, and a rerun resumes.
        """
        iid = str(instance_id)
        parts = self._collect(iid, A, b, low=low, x0=x0, reference=reference, attrs=attrs)
        try:
            self._add(iid, *parts)
        except BaseException:
            self._reload()              # the image may hold part of the instance: forget it
            raise
        self._save(f"write instance {iid!r}", iid, changed=True)

    def _collect(self, iid: str, A, b, *, low, x0, reference, attrs) -> tuple:
        """Check and convert the arguments of :meth:`write_instance` (nothing is written)."""
        _ = self.file                               # raises when closed
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
        return datasets, low_attrs, ref_attrs, inst_attrs, n

    def _add(self, iid: str, datasets: dict, low_attrs: dict, ref_attrs: dict,
             inst_attrs: dict, n: int) -> None:
        """Write the instance into the image (the caller reloads the image if this fails)."""
        g = self.file[_INSTANCES].create_group(iid)
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


def seal_set(path: PathLike) -> None:
    """Add the whole-file checksum to a stored set written before sets carried one.

    Every dataset is verified against its own checksum first (:func:`read_set`), then the
    set is rewritten atomically with the checksum in its user block
    (:mod:`lcpbench.sets.seal`); its instances, data and attributes are unchanged. A set
    that carries a checksum already is verified and left as it is.

    Raises
    ------
    StoredSetError
        The set fails a check of the reader; it is not rewritten.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        read_set(path, psd_check=False)
        with SetWriter(Path(path), title="", description="", generator="") as w:
            w._save("add the file checksum", changed=True)
