"""Reading stored sets, verified: format, version, presence, shape and checksum of every dataset."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any, Optional

import h5py
import numpy as np

from lcpbench.core.lcp import LCP
from lcpbench.core.operator import Operator
from lcpbench.core.registry import stored_sets
from lcpbench.sets.common import (
    _INCOMPLETE,
    _INSTANCES,
    _SHA,
    FORMAT,
    VERSION,
    PathLike,
    StoredSetError,
    _digest,
)

__all__ = ["read_set", "read_instance", "set_info", "instance_ids"]


def _py(value: Any) -> Any:
    """An attribute read back as a plain Python value."""
    if isinstance(value, bytes):
        return value.decode()
    if isinstance(value, np.ndarray):
        return [_py(v) for v in value.tolist()] if value.dtype == object else value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value



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
                             f"{', '.join(stored_sets()) or 'none'})", path=p)
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
