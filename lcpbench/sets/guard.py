"""Checks that make reading an untrusted stored set safe: links, storage, types, sizes.

Everything here runs before the reader reads a dataset: a hostile or damaged file is a
:class:`~lcpbench.sets.common.StoredSetError` naming the file, the instance and the dataset,
never a huge allocation, an opened file outside the set, a cast or a raw ``ValueError``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

import h5py
import numpy as np

from lcpbench.sets.common import READ_BUDGET_ENV, PathLike, StoredSetError, _err, human_bytes

__all__ = ["Where", "ReadBudget", "check_links", "hard_child", "dataset_bytes", "read_attrs",
           "want_int", "want_float", "want_bool", "want_str", "want_str_list", "want_sha"]

_F64 = np.dtype(np.float64)


@dataclass(frozen=True)
class Where:
    """The place an error is about: the file, the instance and the regenerating command."""

    path: PathLike
    instance: Optional[str] = None
    generator: Optional[str] = None

    def err(self, msg: str, dataset: Optional[str] = None, *,
            fix: Optional[str] = None) -> StoredSetError:
        """A StoredSetError naming the file, the instance and ``dataset``."""
        return _err(self.path, msg, self.instance, dataset, self.generator, fix=fix)


@dataclass
class ReadBudget:
    """Bytes one read call may still allocate (see :func:`lcpbench.sets.read_budget`)."""

    limit: int
    used: int = field(default=0)

    def take(self, nbytes: int, where: Where, dataset: str) -> None:
        """Count ``nbytes`` for ``dataset``; StoredSetError when the budget is exceeded."""
        if self.used + nbytes > self.limit:
            before = (f", {human_bytes(self.used)} already read by this call"
                      if self.used else "")
            raise where.err(
                f"reading it needs {human_bytes(nbytes)}{before}, over the read budget of "
                f"{human_bytes(self.limit)}", dataset,
                fix=f"If the file is trusted, raise the budget with {READ_BUDGET_ENV} (e.g. "
                    f"{READ_BUDGET_ENV}=16G) or budget=; otherwise do not use it")
        self.used += nbytes


def _link_kind(link: Any) -> Optional[str]:
    if isinstance(link, h5py.ExternalLink):
        return f"an external link to {link.filename}:{link.path}"
    if isinstance(link, h5py.SoftLink):
        return f"a soft link to {link.path}"
    if not isinstance(link, h5py.HardLink):
        return f"a link of unknown kind ({type(link).__name__})"
    return None


def hard_child(parent: h5py.Group, name: str, where: Where, dataset: Optional[str] = None):
    """``parent[name]`` when it is a hard link in the file; None when there is no such link.

    The link is inspected without being followed, so an external link never opens
    another file.
    """
    try:
        link = parent.get(name, getlink=True)
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        raise where.err(f"cannot read the link {name!r} ({exc})", dataset) from None
    if link is None:
        return None
    kind = _link_kind(link)
    if kind:
        raise where.err(f"{name!r} is {kind}; a stored set holds its data itself and is "
                        "read only through hard links", dataset)
    try:
        return parent[name]
    except (OSError, KeyError, RuntimeError, ValueError) as exc:
        raise where.err(f"cannot open {name!r}, the file is truncated or corrupted ({exc})",
                        dataset) from None


def check_links(group: h5py.Group, where: Where, *, depth: int = 3) -> None:
    """Every link below ``group`` must be a hard link (external and soft links are refused),
    and no group may lie deeper than ``depth`` levels (the layout's ``low/<name>/A`` is 3),
    which also stops hard-link cycles. Links are inspected without being followed."""
    stack = [("", group, 1)]
    while stack:
        prefix, g, level = stack.pop()
        try:
            names = list(g.keys())
        except (OSError, RuntimeError, ValueError) as exc:
            raise where.err(f"cannot list the instance's contents, the file is truncated or "
                            f"corrupted ({exc})", prefix.rstrip("/") or None) from None
        for name in names:
            rel = prefix + name
            obj = hard_child(g, name, where, rel)
            if not isinstance(obj, h5py.Group):
                continue
            if level >= depth:
                raise where.err("a group nested deeper than the stored-set layout (A, b, x0, "
                                "low/<name>/A, reference/x, reference/w)", rel)
            stack.append((rel + "/", obj, level + 1))


def dataset_bytes(ds: h5py.Dataset, rel: str, file_size: int, where: Where) -> int:
    """Bytes that reading ``ds`` allocates, after checking that it can be read safely.

    Refused: virtual datasets and external raw storage (data in other files), complex and
    non-numeric data, and uncompressed data that is not all stored in the file (a small
    file declaring a huge dataset). Compressed data is bounded by the caller's budget.
    """
    try:
        dcpl = ds.id.get_create_plist()
        virtual = ds.is_virtual
        external = ds.external
        nfilters = dcpl.get_nfilters()
        dtype = ds.dtype
    except (OSError, RuntimeError, ValueError, TypeError) as exc:
        raise where.err(f"cannot read the dataset's layout ({exc})", rel) from None
    if virtual:
        raise where.err("a virtual dataset (it maps data of other files); a stored set holds "
                        "its data itself", rel)
    if external:
        files = ", ".join(str(e[0]) for e in external)
        raise where.err(f"its data is stored outside the file, in {files} (HDF5 external "
                        "storage); a stored set holds its data itself", rel)
    if dtype.kind == "c":
        raise where.err(f"complex data ({dtype}); stored matrices and vectors are real", rel)
    if dtype.kind not in "fiu" or dtype.itemsize > 16:
        raise where.err(f"data of type {dtype}; stored matrices and vectors are real numbers "
                        "(float64)", rel)
    count = math.prod(int(s) for s in ds.shape)
    raw = count * dtype.itemsize
    if nfilters == 0:
        try:
            layout = dcpl.get_layout()
            stored = int(ds.id.get_storage_size())
            offset = ds.id.get_offset() if layout == h5py.h5d.CONTIGUOUS else 0
        except (OSError, RuntimeError, ValueError) as exc:
            raise where.err(f"cannot read the dataset's storage ({exc})", rel) from None
        if stored < raw or raw > file_size:
            raise where.err(f"{human_bytes(raw)} of data declared, not stored in the file "
                            f"({human_bytes(stored)} stored, the file has "
                            f"{human_bytes(file_size)})", rel)
        if raw and (offset is None or offset + raw > file_size):   # empty data: no storage
            raise where.err(f"its {human_bytes(raw)} of data lie beyond the end of the file "
                            f"({human_bytes(file_size)}); the file is truncated or corrupted",
                            rel)
    return count * _F64.itemsize + (0 if dtype == _F64 else raw)


# ----------------------------------------------------------------------------- attributes


def _py(value: Any) -> Any:
    """An attribute read back as a plain Python value (text decoded as UTF-8)."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return [_py(v) for v in value.tolist()] if value.dtype == object else value.tolist()
    if isinstance(value, np.generic):
        return _py(value.item())
    return value


def read_attrs(obj, where: Where, dataset: Optional[str] = None) -> dict:
    """All attributes of ``obj`` as plain Python values; StoredSetError for an unreadable one."""
    out = {}
    try:
        names = list(obj.attrs.keys())
    except (OSError, RuntimeError, ValueError, TypeError) as exc:
        raise where.err(f"cannot list the attributes ({exc})", dataset) from None
    for name in names:
        try:
            out[name] = _py(obj.attrs[name])
        except UnicodeDecodeError:
            raise where.err(f"attribute {name!r} is not UTF-8 text", dataset) from None
        except (OSError, RuntimeError, ValueError, TypeError, KeyError) as exc:
            raise where.err(f"cannot read attribute {name!r} ({exc})", dataset) from None
    return out


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _bad(where: Where, key: str, want: str, value: Any, dataset: Optional[str]):
    return where.err(f"attribute {key!r} must be {want}, got {_shown(value)}", dataset)


def want_int(attrs: dict, key: str, where: Where, dataset: Optional[str] = None, *,
             minimum: int = 0) -> int:
    """``attrs[key]`` as an int >= ``minimum`` (bools, floats and lists are refused)."""
    value = attrs.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise _bad(where, key, f"an integer >= {minimum}", value, dataset)
    return value


def want_float(attrs: dict, key: str, where: Where, dataset: Optional[str] = None, *,
               positive: bool = False) -> float:
    """``attrs[key]`` as a float (a finite positive one when ``positive``)."""
    value = attrs.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (positive and not (math.isfinite(value) and value > 0)):
        raise _bad(where, key, "a positive finite number" if positive else "a number", value,
                   dataset)
    return float(value)


def want_bool(attrs: dict, key: str, where: Where, dataset: Optional[str] = None) -> bool:
    """``attrs[key]`` as a bool (HDF5's boolean, or the integers 0 and 1)."""
    value = attrs.get(key)
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    raise _bad(where, key, "a boolean", value, dataset)


def want_str(attrs: dict, key: str, where: Where, dataset: Optional[str] = None) -> str:
    """``attrs[key]`` as text."""
    value = attrs.get(key)
    if not isinstance(value, str):
        raise _bad(where, key, "text", value, dataset)
    return value


def want_str_list(attrs: dict, key: str, where: Where,
                  dataset: Optional[str] = None) -> list[str]:
    """``attrs[key]`` as a list of text (one text is a list of one)."""
    value = attrs.get(key)
    if isinstance(value, str):
        return [value]
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return list(value)
    raise _bad(where, key, "a list of text", value, dataset)


def want_sha(attrs: dict, key: str, where: Where) -> str:
    """``attrs[key]`` as a SHA-256 in hexadecimal."""
    value = attrs.get(key)
    if not (isinstance(value, str) and len(value) == 64
            and all(c in "0123456789abcdef" for c in value)):
        raise _bad(where, key, "a SHA-256 in hexadecimal (64 characters)", value,
                   key.split(":", 1)[1])
    return value
