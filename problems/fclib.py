"""FCLIB local frictional-contact problems (HDF5): reader of the normal-contact LCP, writer.

``/fclib_local`` of the Frictional Contact Library (``src/fclib.h``): ``spacedim``
(2 or 3), ``W`` in fclib's matrix storage (datasets ``nzmax, m, n, nz, p, i, x``;
``nz >= 0`` triplet with ``i`` rows and ``p`` columns as in CSparse, ``nz == -1`` CSC,
``nz == -2`` CSR; fclib has no dense storage), ``vectors/q``, ``vectors/mu`` and an
optional ``info`` group (``title``, ``description``, ``math_info`` strings). The
frictionless LCP is the normal-contact block: contact k has local coordinates
``d*k .. d*k + d - 1`` with the normal first, so ``A = W[N, N]`` and ``b = q[N]`` with
``N = {d*k}``. Problems with equality constraints (``V``, ``R``) are refused:
dropping the multipliers would change the problem.

Non-symmetric matrices follow the symmetry policy of :mod:`lcpbench.problems.formats`
(default here: symmetrise up to 1e-6 relative asymmetry, the round-off of exported W).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import h5py
import numpy as np
import scipy.sparse as sp

from lcpbench import LCP
from lcpbench.sets import StoredSetError, read_budget
from lcpbench.sets.guard import ReadBudget, Where, check_links, dataset_bytes, hard_child

from .formats import PathLike, UnsupportedProblem, symmetric_lcp

__all__ = ["read_fclib_local", "write_fclib_local", "FCLIB_DEFAULT_SYMMETRIZE_RTOL"]

#: Default ``symmetrize_rtol`` of :func:`read_fclib_local`.
FCLIB_DEFAULT_SYMMETRIZE_RTOL = 1e-6


class _Guard:
    """The stored-set reader's checks (:mod:`lcpbench.sets.guard`) for one FCLIB file: every
    dataset is checked (no external storage, real, declared bytes stored, within the read
    budget) before it is read, and each failure is a one-line ValueError."""

    def __init__(self, path: Path):
        self.where = Where(path)
        self.size = path.stat().st_size
        self.budget = ReadBudget(read_budget())

    def take(self, nbytes: float, what: str) -> None:
        """Count ``nbytes`` an allocation of ``what`` needs against the read budget."""
        try:
            self.budget.take(int(min(nbytes, 2 ** 62)), self.where, what)
        except StoredSetError as exc:
            raise ValueError(str(exc)) from None

    def read(self, g: h5py.Group, key: str, where: str) -> np.ndarray:
        """Dataset ``key`` of ``g``, checked before it is read."""
        try:
            ds = hard_child(g, key, self.where, f"{where}/{key}")
            if ds is None:
                raise ValueError(f"{where}: dataset {key!r} is missing")
            if not isinstance(ds, h5py.Dataset):
                raise ValueError(f"{where}/{key} is a group, not a dataset")
            self.budget.take(dataset_bytes(ds, key, self.size, self.where), self.where,
                             f"{where}/{key}")
            return np.asarray(ds[()])
        except StoredSetError as exc:
            raise ValueError(str(exc)) from None
        except (OSError, RuntimeError, TypeError) as exc:
            raise ValueError(f"{where}/{key}: cannot read it, the file is truncated or "
                             f"corrupted ({exc})") from None


def _h5_scalar_int(g: h5py.Group, key: str, where: str, guard: _Guard) -> int:
    v = guard.read(g, key, where).reshape(-1)
    if v.size != 1 or not np.isfinite(v[0]) or v[0] != np.round(v[0]):
        raise ValueError(f"{where}/{key} must hold one integer, got {v.size} value(s)"
                         + (f" ({v[0]})" if v.size else "") + "; the file is not a valid "
                         "FCLIB problem")
    return int(v[0])


def _read_fclib_matrix(g: h5py.Group, where: str, guard: _Guard) -> sp.spmatrix:
    nzmax = _h5_scalar_int(g, "nzmax", where, guard)
    m, n, nz = (_h5_scalar_int(g, k, where, guard) for k in ("m", "n", "nz"))
    if m < 0 or n < 0:
        raise ValueError(f"{where}: m = {m} and n = {n} must be >= 0")
    # the sparse matrix's index arrays hold m + 1 and n + 1 entries whatever the data
    guard.take(8.0 * (m + n + 2) * 3, f"{where} (index arrays of an {m} x {n} matrix)")
    P = guard.read(g, "p", where).astype(np.int64).reshape(-1)
    I = guard.read(g, "i", where).astype(np.int64).reshape(-1)
    X = guard.read(g, "x", where).astype(np.float64).reshape(-1)
    try:
        if nz >= 0:                     # triplet: i rows, p columns (CSparse convention)
            return sp.coo_matrix((X[:nz], (I[:nz], P[:nz])), shape=(m, n)).tocsr()
        if nz == -1:                    # compressed columns
            k = int(P[n])
            return sp.csc_matrix((X[:k], I[:k], P[:n + 1]), shape=(m, n)).tocsr()
        if nz == -2:                    # compressed rows
            k = int(P[m])
            return sp.csr_matrix((X[:k], I[:k], P[:m + 1]), shape=(m, n))
    except (ValueError, IndexError) as exc:
        raise ValueError(f"{where}: inconsistent sparse storage (nzmax {nzmax}, nz {nz}, "
                         f"m {m}, n {n}): {exc}") from None
    raise ValueError(f"{where}: unknown fclib storage nz = {nz} (>= 0 triplet, -1 CSC, -2 CSR)")


def _h5_string(g: h5py.Group, key: str) -> Optional[str]:
    if key not in g:
        return None
    v = g[key][()]
    if isinstance(v, np.ndarray):
        v = v.reshape(-1)[0] if v.size else b""
    return (v.decode(errors="replace") if isinstance(v, bytes) else str(v)).strip("\x00")


def read_fclib_local(path: PathLike, *,
                     symmetrize_rtol: float = FCLIB_DEFAULT_SYMMETRIZE_RTOL,
                     psd_check: bool = True) -> LCP:
    """The normal-contact LCP of an FCLIB local problem (``/fclib_local``).

    Parameters
    ----------
    path : str or Path
        The ``.hdf5`` file.
    symmetrize_rtol, psd_check
        The symmetry policy shared with the Siconos reader
        (:func:`lcpbench.problems.formats.symmetric_lcp`) applied to ``W_nn``; here
        ``symmetrize_rtol`` defaults to 1e-6 (module docstring).

    Returns
    -------
    LCP
        ``A = W[N, N]``, ``b = q[N]`` with ``N = {spacedim * k}`` (the normal of each
        contact); ``meta`` has ``family="fclib"``, ``spacedim``, ``contacts``, ``mu_min``,
        ``mu_max``, ``title``, ``description``, ``math_info`` and ``source``.

    Raises
    ------
    ValueError
        For a file that is not an FCLIB local problem, a missing dataset, or a problem
        with equality constraints (``V``, ``R``).
    """
    p = Path(path)
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise ValueError(f"{p}: cannot open as HDF5 ({exc}); is it an FCLIB file?") from None
    guard = _Guard(p)
    with f:
        try:            # no external or soft link is followed, none nested beyond the layout
            check_links(f, guard.where, depth=3)
        except StoredSetError as exc:
            raise ValueError(str(exc)) from None
        if "fclib_local" not in f:
            kind = ("a global problem (/fclib_global)" if "fclib_global" in f
                    else f"groups {sorted(f.keys())}")
            if "fclib_global" in f:
                raise UnsupportedProblem(f"{p}: not an FCLIB local problem (a global problem, "
                                         "/fclib_global); lcpbench imports local ones only",
                                         "FCLIB global problem")
            raise ValueError(f"{p}: not an FCLIB local problem (no /fclib_local; found {kind})")
        g = f["fclib_local"]
        where = f"{p}: /fclib_local"
        if "V" in g or "R" in g:
            raise UnsupportedProblem(f"{where} has equality constraints (V, R); its normal "
                                     "block is not a plain LCP, so lcpbench does not import it",
                                     "equality constraints")
        d = _h5_scalar_int(g, "spacedim", where, guard)
        if d not in (2, 3):
            raise ValueError(f"{where}/spacedim is {d}; FCLIB uses 2 or 3")
        if "W" not in g:
            raise ValueError(f"{where}/W is missing")
        W = _read_fclib_matrix(g["W"], f"{where}/W", guard)
        if W.shape[0] != W.shape[1] or W.shape[0] % d:
            raise ValueError(f"{where}/W has shape {W.shape}; it must be square with a size "
                             f"divisible by spacedim = {d}")
        vec = g.get("vectors")
        if vec is None or "q" not in vec or "mu" not in vec:
            raise ValueError(f"{where}/vectors must hold q and mu")
        q = guard.read(vec, "q", f"{where}/vectors").astype(np.float64).reshape(-1)
        mu = guard.read(vec, "mu", f"{where}/vectors").astype(np.float64).reshape(-1)
        nc = W.shape[0] // d
        if q.shape[0] != W.shape[0] or mu.shape[0] != nc:
            raise ValueError(f"{where}/vectors: q has {q.shape[0]} entries and mu {mu.shape[0]}; "
                             f"expected {W.shape[0]} and {nc}")
        info = g.get("info")
        texts = {k: (_h5_string(info, k) if info is not None else None)
                 for k in ("title", "description", "math_info")}
    N = np.arange(nc) * d
    Wnn = W[N][:, N]
    A = Wnn.toarray() if nc <= 2000 else Wnn.tocsr()
    meta = {"family": "fclib", "n": nc, "contacts": nc, "spacedim": d,
            "mu_min": float(mu.min()) if nc else 0.0, "mu_max": float(mu.max()) if nc else 0.0,
            "source": str(p), **{k: v for k, v in texts.items() if v is not None}}
    return symmetric_lcp(A, q[N], p, "FCLIB normal block W_nn", symmetrize_rtol,
                  name=f"fclib/{p.stem}", meta=meta, psd_check=psd_check)


def write_fclib_local(path: PathLike, W, q, mu, d: int, *, title: Optional[str] = None,
                      description: Optional[str] = None, math_info: Optional[str] = None,
                      storage: str = "csc") -> Path:
    """Write an FCLIB local problem (``/fclib_local``) as ``fclib_write_local`` lays it out.

    Parameters
    ----------
    path : str or Path
        Created if missing; an existing file must not hold ``/fclib_local`` yet.
    W : (m, m) array_like or sparse matrix
        The Delassus matrix, contact-major with the normal first in each contact.
    q : (m,) array_like
    mu : (m / d,) array_like
        Friction coefficients per contact.
    d : int
        Space dimension, 2 or 3.
    title, description, math_info : str, optional
        Written to ``/fclib_local/info`` when any is given.
    storage : {"csc", "csr", "triplet"}
        fclib matrix storage (``nz`` = -1, -2 or the number of entries).

    Returns
    -------
    Path
    """
    if d not in (2, 3):
        raise ValueError(f"d (spacedim) must be 2 or 3, got {d}")
    if storage not in ("csc", "csr", "triplet"):
        raise ValueError(f"storage {storage!r}: choose csc, csr or triplet")
    Ws = sp.csc_matrix(W, dtype=np.float64) if storage == "csc" else (
        sp.csr_matrix(W, dtype=np.float64) if storage == "csr" else
        sp.coo_matrix(W, dtype=np.float64))
    m, n = Ws.shape
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    mu = np.asarray(mu, dtype=np.float64).reshape(-1)
    if m != n or m % d:
        raise ValueError(f"W has shape {Ws.shape}; it must be square with a size divisible by "
                         f"d = {d}")
    if q.shape[0] != m or mu.shape[0] != m // d:
        raise ValueError(f"q has {q.shape[0]} entries and mu {mu.shape[0]}; expected {m} and "
                         f"{m // d}")
    p = Path(path)
    with h5py.File(p, "a") as f:
        if "fclib_local" in f:
            raise ValueError(f"{p}: a local problem has already been written to this file; "
                             "choose another path")
        g = f.create_group("fclib_local")
        def one(v: int) -> np.ndarray:          # H5LTmake_dataset_int with dims {1}
            return np.array([v], dtype=np.int32)

        g.create_dataset("spacedim", data=one(d))
        gw = g.create_group("W")
        if storage == "triplet":
            nnz = int(Ws.nnz)
            P, I, X, nz = Ws.col, Ws.row, Ws.data, nnz
        else:
            nnz = int(Ws.indptr[-1])
            P, I, X, nz = Ws.indptr, Ws.indices, Ws.data, (-1 if storage == "csc" else -2)
        for key, val in (("nzmax", nnz), ("m", m), ("n", n), ("nz", nz)):
            gw.create_dataset(key, data=one(val))
        gw.create_dataset("p", data=np.asarray(P, dtype=np.int32))
        gw.create_dataset("i", data=np.asarray(I, dtype=np.int32))
        gw.create_dataset("x", data=np.asarray(X, dtype=np.float64))
        gv = g.create_group("vectors")
        gv.create_dataset("q", data=q)
        gv.create_dataset("mu", data=mu)
        texts = {"title": title, "description": description, "math_info": math_info}
        if any(v is not None for v in texts.values()):
            gi = g.create_group("info")
            for key, val in texts.items():
                if val is not None:
                    raw = str(val).encode()
                    gi.create_dataset(key, data=np.array(raw, dtype=f"S{len(raw) + 1}"))
    return p
