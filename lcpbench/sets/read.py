"""Reading stored sets, verified: format, version, presence, shape and checksum of every dataset.

Every file is treated as untrusted (:mod:`lcpbench.sets.guard`): links, storage, types and
sizes are checked before any dataset is read, and the datasets one call returns never take
more than the read budget (:func:`lcpbench.sets.read_budget`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Optional

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
    _err,
    read_budget,
)
from lcpbench.sets.guard import (
    ReadBudget,
    Where,
    check_links,
    dataset_bytes,
    hard_child,
    read_attrs,
    want_bool,
    want_float,
    want_int,
    want_sha,
    want_str_list,
)
from lcpbench.sets.seal import check_seal, warn_unsealed

__all__ = ["read_set", "read_instance", "set_info", "instance_ids"]

#: The datasets an instance may hold (what SetWriter writes).
_LAYOUT = re.compile(r"^(A|b|x0|reference/[xw]|low/[A-Za-z0-9][A-Za-z0-9_.+=-]*/A)$")


def _open(path: PathLike) -> h5py.File:
    p = Path(path)
    if not p.exists():
        raise StoredSetError(f"{p}: no such stored set; check the path (shipped sets: "
                             f"{', '.join(stored_sets()) or 'none'})", path=p)
    if p.is_dir():
        raise StoredSetError(f"{p} is a folder, not a stored set; give the set's .h5 file, e.g. "
                             f"{p / 'NAME.h5'}", path=p)
    sealed = check_seal(p)
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        if not h5py.is_hdf5(p):     # no HDF5 signature at all: another kind of file
            raise StoredSetError(f"{p}: not an HDF5 file (a {p.suffix or 'suffix-less'} file); "
                                 "a stored set is the .h5 file lcpbench generate writes",
                                 path=p) from None
        raise _err(p, f"cannot open the HDF5 file, it is truncated or corrupted ({exc})") \
            from None
    if not sealed and f.attrs.get("format") == FORMAT:
        warn_unsealed(p)
    return f


def _check_root(f: h5py.File, path: PathLike) -> dict:
    """Check the root of a set (format, version, the instances group); its attributes."""
    attrs = read_attrs(f, Where(path))
    fmt = attrs.get("format")
    gen = attrs.get("generator")
    if fmt != FORMAT:
        raise StoredSetError(f"{path}: not an lcpbench stored set (format attribute "
                             f"{fmt!r}, expected {FORMAT!r})", path=path)
    if gen is not None and not isinstance(gen, str):
        raise _err(path, f"attribute 'generator' must be text, got {gen!r}")
    where = Where(path, generator=gen)
    ver = attrs.get("version")
    if isinstance(ver, bool) or not isinstance(ver, int) or ver < 1:
        raise where.err(f"invalid version attribute {ver!r}")
    if ver > VERSION:
        raise StoredSetError(f"{path}: layout version {ver} is newer than this lcpbench "
                             f"reads ({VERSION}); upgrade lcpbench", path=path)
    group = hard_child(f, _INSTANCES, where)
    if not isinstance(group, h5py.Group):
        raise where.err("the /instances group is missing")
    return attrs


def _ids(f: h5py.File, name: str, path: PathLike) -> list[str]:
    try:
        return list(f[name].keys())
    except (OSError, RuntimeError, KeyError) as exc:
        raise _err(path, f"cannot list the /{name} group ({exc})") from None


def set_info(path: PathLike) -> dict:
    """Root attributes of a stored set (format, version, title, generator, ...) and ``ids``."""
    with _open(path) as f:
        info = _check_root(f, path)
        info["ids"] = _ids(f, _INSTANCES, path)
        stale = hard_child(f, _INCOMPLETE, Where(path, generator=info.get("generator")))
        info["incomplete"] = _ids(f, _INCOMPLETE, path) if stale is not None else []
    return info


def instance_ids(path: PathLike) -> list[str]:
    """Finished instance ids of a stored set, in the order they were written."""
    return set_info(path)["ids"]


def _read_dataset(ds: h5py.Dataset, rel: str, sha: str, where: Where) -> np.ndarray:
    """The data of ``ds`` (checked by :func:`dataset_bytes` already), its checksum verified."""
    try:
        arr = ds[()]
    except (OSError, ValueError, RuntimeError, TypeError) as exc:
        raise where.err(f"cannot read the data, the file is truncated or corrupted ({exc})",
                        rel) from None
    got = _digest(arr)
    if got != sha:
        raise where.err(f"checksum mismatch (sha256 {got[:12]}..., stored {sha[:12]}...): "
                        "the data was changed or corrupted", rel)
    return np.asarray(arr, dtype=np.float64)


def _read_data(g: h5py.Group, attrs: dict, where: Where, budget: ReadBudget) -> dict:
    """Every dataset listed in the instance's checksums, each checked before it is read."""
    if "n" not in attrs:
        raise where.err("instance attribute 'n' is missing")
    n = want_int(attrs, "n", where)
    manifest = sorted(k[len(_SHA):] for k in attrs if k.startswith(_SHA))
    for req in ("A", "b"):
        if req not in manifest:
            raise where.err("no checksum recorded for a required dataset", req)
    file_size = os.path.getsize(where.path)
    checked = {}
    for rel in manifest:
        if not _LAYOUT.match(rel):
            raise where.err("a checksum names a dataset outside the stored-set layout (A, b, "
                            "x0, low/<name>/A, reference/x, reference/w)", rel)
        sha = want_sha(attrs, _SHA + rel, where)
        try:
            ds = g.get(rel)
        except (OSError, RuntimeError, KeyError, ValueError) as exc:
            raise where.err(f"cannot open the dataset ({exc})", rel) from None
        if ds is None:
            raise where.err("dataset is missing (listed in the instance's checksums)", rel)
        if not isinstance(ds, h5py.Dataset):
            raise where.err("expected a dataset, found a group", rel)
        shape = (n, n) if rel == "A" or rel.endswith("/A") else (n,)
        got = None if ds.shape is None else tuple(ds.shape)     # None: an empty dataspace
        if got != shape:
            raise where.err(f"shape {got}, expected {shape}", rel)
        budget.take(dataset_bytes(ds, rel, file_size, where), where, rel)
        checked[rel] = (ds, sha)
    # Datasets present but not in the manifest were not written by SetWriter.
    extra = []
    g.visititems(lambda name, obj: extra.append(name) if isinstance(obj, h5py.Dataset)
                 and name not in checked else None)
    if extra:
        raise where.err(f"datasets without a checksum: {', '.join(extra)}", extra[0])
    return {rel: _read_dataset(ds, rel, sha, where) for rel, (ds, sha) in checked.items()}


def _reference(g: h5py.Group, data: dict, where: Where) -> Optional[dict]:
    if "reference/x" not in data or "reference/w" not in data:
        return None
    ra = read_attrs(g["reference"], where, "reference")
    x, w = data["reference/x"], data["reference/w"]

    def number(key: str, default: float) -> float:
        return want_float(ra, key, where, "reference") if key in ra else default

    return {"x": x, "w": w,
            "objective": number("objective", float(0.5 * x @ (w + data["b"]))),
            "solvers": want_str_list(ra, "solvers", where, "reference")
            if "solvers" in ra else ["stored"],
            "kkt_abs": number("kkt_abs", np.nan),
            "disagreement": number("disagreement", np.nan),
            "accepted": want_bool(ra, "accepted", where, "reference")
            if "accepted" in ra else True}


def _load(f: h5py.File, path: Path, iid: str, gen: Optional[str], budget: ReadBudget,
          **lcp_kwargs) -> LCP:
    where = Where(path, iid, gen)
    g = hard_child(f[_INSTANCES], iid, where)
    if g is None:
        raise StoredSetError(f"{path}: no instance {iid!r}; the file holds "
                             f"{', '.join(_ids(f, _INSTANCES, path)[:20]) or 'none'}",
                             path=path, instance=iid)
    if not isinstance(g, h5py.Group):
        raise where.err("expected an instance group, found a dataset")
    check_links(g, where)
    attrs = read_attrs(g, where)
    data = _read_data(g, attrs, where, budget)
    n = attrs.pop("n")
    meta = {k: v for k, v in attrs.items() if not k.startswith(_SHA)}
    low = {}
    low_meta = {}
    for rel in data:
        if rel.startswith("low/"):
            name = rel.split("/")[1]
            la = read_attrs(g[f"low/{name}"], where, f"low/{name}")
            if "cost_ratio" not in la:
                raise where.err("attribute cost_ratio is missing", f"low/{name}")
            ratio = want_float(la, "cost_ratio", where, f"low/{name}", positive=True)
            low[name] = Operator(data[rel], cost=ratio, name=name)
            low_meta[name] = la
    reference = _reference(g, data, where)
    meta.update({"family": meta.get("family", "stored"), "n": n, "instance": iid,
                 "set": path.stem, "source": str(path)})
    if low_meta:
        meta["low"] = low_meta
    try:
        return LCP(Operator(data["A"], cost=1.0), data["b"], x0=data.get("x0"), low=low,
                   name=f"{path.stem}/{iid}", meta=meta, reference=reference, **lcp_kwargs)
    except (ValueError, TypeError) as exc:
        raise where.err(f"the stored data is not a valid LCP ({exc})") from None


def read_instance(path: PathLike, instance_id: str, *, budget: Optional[int] = None,
                  **lcp_kwargs) -> LCP:
    """Read and verify one instance of a stored set.

    Parameters
    ----------
    path : str or Path
    instance_id : str
    budget : int, optional
        Most bytes the instance's data may take in memory; default the read budget
        (:func:`lcpbench.sets.read_budget`: ``$LCPBENCH_READ_BUDGET`` or 2 GiB).
    **lcp_kwargs
        Passed to :class:`~lcpbench.LCP` (e.g. ``psd_check=False``).

    Returns
    -------
    LCP
        High operator with declared cost 1.0, low operators with cost ``cost_ratio``
        (module docstring of :mod:`lcpbench.sets.common`), ``reference`` from the stored
        reference, ``meta`` from the instance attrs (plus ``instance``, ``set``,
        ``source`` and ``low`` attrs).

    Raises
    ------
    StoredSetError
        Naming the file, instance and dataset, for a truncated file, a checksum or
        shape mismatch, a missing dataset, an unknown instance, a link or storage outside
        the file, complex data, a bad attribute, or data over the budget.
    """
    p = Path(path)
    limit = ReadBudget(read_budget(budget))
    with _open(p) as f:
        gen = _check_root(f, p).get("generator")
        return _load(f, p, str(instance_id), gen, limit, **lcp_kwargs)


def read_set(path: PathLike, ids: Optional[Iterable[str]] = None, *,
             budget: Optional[int] = None, **lcp_kwargs) -> list[LCP]:
    """Read and verify every (or the given) instance of a stored set, in written order.

    Parameters
    ----------
    path : str or Path
    ids : iterable of str, optional
        Subset of instance ids; default all.
    budget : int, optional
        Most bytes the data of all the instances read may take in memory; default the
        read budget (:func:`lcpbench.sets.read_budget`).
    **lcp_kwargs
        Passed to :class:`~lcpbench.LCP`.

    Raises
    ------
    StoredSetError
        As :func:`read_instance`; nothing is dropped silently.
    """
    p = Path(path)
    limit = ReadBudget(read_budget(budget))
    with _open(p) as f:
        gen = _check_root(f, p).get("generator")
        chosen = _ids(f, _INSTANCES, p) if ids is None else [str(i) for i in ids]
        return [_load(f, p, iid, gen, limit, **lcp_kwargs) for iid in chosen]
