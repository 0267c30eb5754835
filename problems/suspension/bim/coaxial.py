"""The coaxial pair table: near-field blocks of equal spheres on the z axis, by distance.

For two spheres of equal radius whose centres are joined along +z (source sphere j at the
origin, target sphere i above it), the block that maps the density's real VSH coefficients
on j to the degree <= p traction coefficients on i depends only on ``rho = d/a - 1`` (the
pair plan's ``(d - a_i)/a_j``).  A pair along any direction ``u`` has the block
``D(Q) E(rho) D(Q)^T`` with ``Q`` taking +z to ``u`` (:mod:`.rotation`).

The tabulated block is the L2 projection of the traction onto the degree <= p VSH of the
target sphere, integrated accurately in the coaxial frame: there the traction of a source
harmonic of azimuthal order m has order m only, so ``2p + 2`` equispaced longitudes are
exact, and the polar integral is Gauss-Legendre in cos(theta) with far more nodes than the
lab-frame grids (converged to rounding even for touching spheres: the traction of a
band-limited density is analytic outside the source's centre).
This block is the same for every orientation; the direct build
(:meth:`.pairs.PairPlan._build_blocks`) approximates it on a finite grid fixed in the lab
frame (order 2p, or the native nodes), with an orientation-dependent error
(docs/mobility.md, "Coaxial pair table").

Only the couplings of equal azimuthal order ``m`` are nonzero in the coaxial block; the
table stores those entries (``mask``), as piecewise Chebyshev interpolants in ``rho`` on
panels whose ends grow geometrically from touching (rho = 1), so that each panel sees the
block's singularity (rho = 0) at the same relative distance.  Tables are cached on disk
(:func:`cache_dir`), keyed by their inputs, written atomically and checked on reading.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
import warnings
import zipfile
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

from .harmonics import vsh_at
from .kernels import real_block_columns, traction_response
from .sphere_vsh import RHO_GRID, expansion_factors, knm_table, quadrature_radius, vsh_basis

__all__ = ["TABLE_VERSION", "RHO_MIN", "PANEL_RATIO", "CHEB_NODES", "CoaxialTable",
           "basis_at", "coaxial_blocks", "coaxial_table", "cache_dir", "table_range", "order_mask"]

TABLE_VERSION = 1
"""Version of the table's definition and layout (part of the cache key)."""

RHO_MIN = 1.0
"""Touching spheres: the table starts here."""

PANEL_RATIO = 1.5
"""Ratio of the ends of successive interpolation panels in rho."""

CHEB_NODES = 16
"""Chebyshev nodes per panel (measured accuracy: docs/mobility.md, "Coaxial pair table")."""

def _theta_nodes(p: int) -> int:
    """Gauss-Legendre nodes in cos(theta) of the coaxial quadrature (measured: at p = 8 the
    block of touching spheres is converged to 1e-14 with 49 nodes)."""
    return 6 * p + 16


def basis_at(nodes: np.ndarray, p: int) -> np.ndarray:
    """The real orthonormal VSH of degree <= p (the columns of
    :func:`.sphere_vsh.vsh_basis`) at unit vectors ``nodes`` (K, 3): ``(K, 3, nv)``."""
    b = vsh_basis(p)
    K = knm_table(p)
    Y = np.empty((nodes.shape[0], p + 1, p + 1), dtype=np.complex128)
    V = np.empty((nodes.shape[0], p + 1, p + 1, 3), dtype=np.complex128)
    for k in range(nodes.shape[0]):
        vsh_at(np.ascontiguousarray(nodes[k], dtype=float), p, K, Y[k], V[k])
    out = np.empty((nodes.shape[0], 3, b.kind.size))
    for c, (t, n, m, sine) in enumerate(zip(b.kind, b.degree, b.order, b.sine)):
        Vc = V[:, n, m, :]
        if t == 0:
            F, norm = Vc, np.sqrt((n + 1) * (2 * n + 1))
        elif t == 1:
            F, norm = Vc + (2 * n + 1) * Y[:, n, m, None] * nodes, np.sqrt(n * (2 * n + 1))
        else:
            F, norm = np.cross(nodes, Vc), np.sqrt(n * (n + 1))
        part = F.imag if sine else F.real
        out[:, :, c] = part * ((np.sqrt(2.0) if m > 0 else 1.0) / norm)
    return out


@cache
def _coaxial_quadrature(p: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (K, 3) and weights (K,) on the unit sphere, exact in longitude for the
    azimuthal orders of a coaxial block, Gauss-Legendre in cos(theta)."""
    t, wt = np.polynomial.legendre.leggauss(_theta_nodes(p))
    nphi = 2 * p + 2
    phi = 2 * np.pi * np.arange(nphi) / nphi
    st = np.sqrt(np.clip(1.0 - t * t, 0.0, None))
    nodes = np.stack([np.outer(st, np.cos(phi)), np.outer(st, np.sin(phi)),
                      np.outer(t, np.ones(nphi))], axis=-1).reshape(-1, 3)
    weights = np.outer(wt, np.full(nphi, 2 * np.pi / nphi)).reshape(-1)
    nodes.setflags(write=False)
    weights.setflags(write=False)
    return nodes, weights


@cache
def _weighted_basis_T(p: int) -> np.ndarray:
    """``(nv, 3K)``: the quadrature weights times the basis at the coaxial nodes,
    transposed (the projection of nodal tractions onto the basis)."""
    nodes, weights = _coaxial_quadrature(p)
    Bq = basis_at(nodes, p) * weights[:, None, None]
    out = np.ascontiguousarray(Bq.reshape(-1, Bq.shape[2]).T)
    out.setflags(write=False)
    return out


def coaxial_blocks(rho: np.ndarray, p: int) -> np.ndarray:
    """Exact coaxial blocks ``(len(rho), nv, nv)`` at scaled distances ``rho`` (unit
    spheres, source at the origin, target centre at ``(0, 0, rho + 1)``)."""
    rho = np.atleast_1d(np.asarray(rho, dtype=float))
    b = vsh_basis(p)
    nv = b.kind.size
    flat = np.argmax(np.abs(b.to_complex), axis=0)
    cfac = b.to_complex[flat, np.arange(nv)]
    fac = np.ascontiguousarray(expansion_factors(p))
    nodes, _ = _coaxial_quadrature(p)
    proj = _weighted_basis_T(p)
    Nq = nodes.shape[0]
    out = np.empty((rho.size, nv, nv))
    chunk = max(1, int(64e6 // (Nq * 9 * (p + 1) ** 2 * 16)))        # ~64 MB of responses
    for k0 in range(0, rho.size, chunk):
        r = rho[k0:k0 + chunk]
        tgt = (nodes[None] + np.stack([0 * r, 0 * r, r + 1.0], axis=1)[:, None]).reshape(-1, 3)
        resp = np.empty((tgt.shape[0], 3, p + 1, p + 1, 3), dtype=np.complex128)
        traction_response(tgt, np.tile(nodes, (r.size, 1)), np.zeros((tgt.shape[0], 3)),
                          np.ones(tgt.shape[0]), p, fac, resp)
        Ep = np.empty((r.size, 3 * Nq, nv))
        real_block_columns(resp.reshape(tgt.shape[0], -1, 3), flat, cfac, Ep)
        out[k0:k0 + r.size] = np.matmul(proj, Ep)
    return out


def table_range(p: int) -> float:
    """The largest scaled distance a table of order p covers: the largest at which any
    pair can have a stored block (the native grid's quadrature radius at the smallest
    quadrature tolerance the defaults use, 1e-15)."""
    return float(min(quadrature_radius(p, p, 1e-15), RHO_GRID[-1]))


def order_mask(p: int) -> np.ndarray:
    """``(nv, nv)`` bool: the couplings of equal azimuthal order (the nonzero entries of a
    coaxial block)."""
    order = vsh_basis(p).order
    return order[:, None] == order[None, :]


def panel_edges(rho_max: float) -> np.ndarray:
    """Ends of the interpolation panels from :data:`RHO_MIN` past ``rho_max``."""
    k = int(np.ceil(np.log(rho_max / RHO_MIN) / np.log(PANEL_RATIO) - 1e-12))
    return RHO_MIN * PANEL_RATIO ** np.arange(max(k, 1) + 1)


def _cheb_nodes(n: int) -> np.ndarray:
    """Chebyshev points of the first kind on [-1, 1]."""
    return np.cos(np.pi * (np.arange(n) + 0.5) / n)


@dataclass(frozen=True)
class CoaxialTable:
    """Piecewise Chebyshev interpolant of the coaxial block in rho.

    Attributes
    ----------
    p : int
        Order of the blocks.
    edges : ndarray, shape (P + 1,)
        Panel ends in rho.
    coefs : ndarray, shape (P, CHEB_NODES, nnz)
        Chebyshev coefficients of the equal-order entries (``order_mask(p)``) per panel.
    """

    p: int
    edges: np.ndarray
    coefs: np.ndarray
    _ordered: dict = field(default_factory=dict, compare=False, repr=False)

    @property
    def rho_max(self) -> float:
        """Largest scaled distance covered."""
        return float(self.edges[-1])

    @property
    def nbytes(self) -> int:
        """Size of the stored coefficients."""
        return int(self.coefs.nbytes + self.edges.nbytes)

    def covers(self, rho: np.ndarray) -> np.ndarray:
        """Whether each ``rho`` lies in the table's range."""
        rho = np.asarray(rho, dtype=float)
        return (rho >= self.edges[0]) & (rho <= self.edges[-1])

    def values(self, rho: np.ndarray, columns: np.ndarray | None = None) -> np.ndarray:
        """Interpolated equal-order entries ``(len(rho), nnz)`` of the coaxial blocks, in
        the row-major order of ``order_mask(p)`` (``rho`` in the range), or with
        ``columns`` (distinct entries, e.g. a permutation) the entries ``columns``, in that order:
        written so directly, from coefficients permuted once per table and kept, so that
        no copy of the ``(len(rho), nnz)`` result is made to reorder it."""
        rho = np.atleast_1d(np.asarray(rho, dtype=float))
        if not self.covers(rho).all():
            raise ValueError(f"rho outside the table's range [{self.edges[0]}, {self.rho_max}]")
        coefs = self.coefs if columns is None else self._permuted(columns)
        k = np.clip(np.searchsorted(self.edges, rho, side="right") - 1, 0, self.edges.size - 2)
        order = np.argsort(k, kind="stable")
        bounds = np.searchsorted(k[order], np.arange(self.edges.size))
        out = np.empty((rho.size, coefs.shape[2]))
        for panel in range(self.edges.size - 1):          # one product per panel
            sel = order[bounds[panel]:bounds[panel + 1]]
            if not sel.size:
                continue
            a, b = self.edges[panel], self.edges[panel + 1]
            T = np.polynomial.chebyshev.chebvander((2 * rho[sel] - a - b) / (b - a),
                                                   coefs.shape[1] - 1)
            if sel.size == sel[-1] - sel[0] + 1:            # consecutive rows: in place
                np.matmul(T, coefs[panel], out=out[sel[0]:sel[-1] + 1])
            else:
                out[sel] = T @ coefs[panel]
        return out

    def _permuted(self, columns: np.ndarray) -> np.ndarray:
        """The coefficients of the entries ``columns`` (distinct), kept per table."""
        columns = np.asarray(columns, dtype=np.int64)
        key = columns.tobytes()
        if key not in self._ordered:
            n = self.coefs.shape[2]
            if columns.size and (columns.min() < 0 or columns.max() >= n
                                 or np.unique(columns).size != columns.size):
                raise ValueError(f"columns must be distinct entries of the table (0..{n - 1})")
            self._ordered[key] = np.ascontiguousarray(self.coefs[:, :, columns])
        return self._ordered[key]

    def blocks(self, rho: np.ndarray) -> np.ndarray:
        """Interpolated coaxial blocks ``(len(rho), nv, nv)`` (``rho`` in the range)."""
        vals = self.values(rho)
        mask = order_mask(self.p)
        out = np.zeros((vals.shape[0],) + mask.shape)
        out[:, mask] = vals
        return out


def build_table(p: int, rho_max: float, progress: bool = True) -> CoaxialTable:
    """Tabulates the coaxial block of order p on [RHO_MIN, >= rho_max] (see the module)."""
    edges = panel_edges(rho_max)
    mask = order_mask(p)
    xs = _cheb_nodes(CHEB_NODES)
    coefs = np.empty((edges.size - 1, CHEB_NODES, int(mask.sum())))
    start = time.perf_counter()
    bar = None
    for k, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        if progress and bar is None and time.perf_counter() - start > 2.0:
            from tqdm import tqdm
            bar = tqdm(total=edges.size - 1, initial=k, desc=f"coaxial pair table p={p}",
                       unit="panel", leave=False)
        vals = coaxial_blocks(0.5 * (a + b) + 0.5 * (b - a) * xs, p)[:, mask]
        coefs[k] = np.polynomial.chebyshev.chebfit(xs, vals, CHEB_NODES - 1)
        if bar is not None:
            bar.update(1)
    if bar is not None:
        bar.close()
    return CoaxialTable(p, edges, coefs)


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/lcpbench/pair-tables`` (``XDG_CACHE_HOME`` defaults to
    ``~/.cache``)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "lcpbench" / "pair-tables"


def _key(p: int, rho_max: float) -> dict:
    """The inputs a table depends on."""
    return {"version": TABLE_VERSION, "p": int(p), "panels": panel_edges(rho_max).size - 1,
            "panel_ratio": PANEL_RATIO, "cheb_nodes": CHEB_NODES, "rho_min": RHO_MIN,
            "theta_nodes": _theta_nodes(p)}


def _path(key: dict) -> Path:
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    return cache_dir() / f"coaxial-p{key['p']}-v{key['version']}-{digest}.npz"


def _read(path: Path, key: dict) -> CoaxialTable | None:
    """The table stored at ``path`` when it matches ``key`` and its shapes, else None."""
    try:
        with np.load(path, allow_pickle=False) as f:
            stored = json.loads(str(f["key"]))
            edges, coefs = np.array(f["edges"], dtype=float), np.array(f["coefs"], dtype=float)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    p = key["p"]
    want = (key["panels"], key["cheb_nodes"], int(order_mask(p).sum()))
    if (stored != key or coefs.shape != want or edges.shape != (want[0] + 1,)
            or not np.allclose(edges, panel_edges(edges[-1]))
            or not (np.isfinite(coefs).all() and np.isfinite(edges).all())):
        return None
    return CoaxialTable(p, edges, coefs)


def _write(path: Path, key: dict, table: CoaxialTable) -> None:
    """Writes the table atomically (a temporary file in the same directory, renamed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.stem, suffix=".tmp.npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, key=np.array(json.dumps(key, sort_keys=True)), edges=table.edges,
                     coefs=table.coefs)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


_MEMORY: dict[tuple, CoaxialTable] = {}


def coaxial_table(p: int, rho_max: float) -> CoaxialTable:
    """The coaxial table of order p covering ``[RHO_MIN, rho_max]``: from memory, from the
    disk cache, or built (and cached).  A cached file that does not match its key or its
    shapes is rebuilt with one warning."""
    key = _key(p, rho_max)
    mkey = tuple(sorted(key.items()))
    if mkey in _MEMORY:
        return _MEMORY[mkey]
    path = _path(key)
    table = _read(path, key) if path.exists() else None
    if table is None:
        if path.exists():
            warnings.warn(f"coaxial pair table {path} does not match its key or shapes; "
                          "rebuilding it", RuntimeWarning, stacklevel=2)
        table = build_table(p, rho_max)
        try:
            _write(path, key, table)
        except OSError as exc:
            warnings.warn(f"coaxial pair table not cached ({exc}); it is rebuilt next time",
                          RuntimeWarning, stacklevel=2)
    _MEMORY[mkey] = table
    return table
