"""The fidelity study of stored sets: error and cost of each low fidelity, and Cottle's c(A).

This reproduces, for any stored set (:mod:`lcpbench.sets`), the paper's figure
"lofiMVPs" (heatmaps over the fidelity knobs ``(p, eps_gmres)`` of the log10 of the
largest ``||A_low - A||_inf`` over the instances, and of how many low-fidelity MVPs
cost as much as one high-fidelity MVP) and its appendix "Computing c(A)" (the share of
instances whose low fidelity lies in the neighbourhood ``||A_low - A||_inf < c(A)`` where
lemma cottleLemma guarantees a locally Lipschitz solution map).

Norms
    ``||E||_inf`` is the matrix norm induced by the vector infinity norm (the largest
    absolute row sum), the norm of lemma cottleLemma, whose ``c(A)`` is defined over the
    unit sphere of the vector infinity norm.

Costs
    Stored sets keep ``cost_ratio = t_low / t_high`` per low fidelity and instance; the
    table reports its reciprocal ``t_high / t_low`` (low MVPs per high MVP, the right
    heatmap of the paper), the median over instances.
"""

from __future__ import annotations

import contextlib
import html
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from lcpbench.report import plots

__all__ = [
    "GRID_MODELS",
    "TABLE_COLUMNS",
    "CottleBounds",
    "cottle_bounds",
    "cottle_c",
    "cottle_heatmap_svg",
    "fidelity_section",
    "fidelity_table",
    "heatmap_svg",
    "heatmaps",
    "stored_set_specs",
]

#: Columns of :func:`fidelity_table`, in order.
TABLE_COLUMNS = ["fidelity", "model", "p", "eps_gmres", "instances", "log10_max_err",
                 "median_low_per_high", "share_err_below_c", "share_err_below_lower"]



# ---------------------------------------------------------------------- c(A)
@dataclass(frozen=True)
class CottleBounds:
    """Bounds on Cottle's fundamental quantity ``c(A)``.

    Attributes
    ----------
    estimate : float
        ``h(z)`` at the best feasible ``z`` found: an upper bound of ``c(A)``.
    z : ndarray
        That ``z`` (``||z||_inf = 1``).
    lower : float
        ``lambda_min((A + A') / 2) / n``, a lower bound of ``c(A)`` (valid for any
        square ``A``; informative when the symmetric part is positive definite).
    lambda_min : float
        Smallest eigenvalue of the symmetric part of ``A``. For symmetric ``A`` it is an
        upper bound of ``c(A)``, so ``lower <= c(A) <= estimate <= lambda_min``.
    starts : int
        Number of local optimisations run.
    """

    estimate: float
    z: np.ndarray
    lower: float
    lambda_min: float
    starts: int


def _h(A: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """``h(z) = max_j z_j (A z)_j`` for each column of ``Z``."""
    return np.max(Z * (A @ Z), axis=0)


def _smoothed(A: np.ndarray, Z: np.ndarray, mu: float):
    """Log-sum-exp smoothing of ``h`` with temperature ``mu`` and its gradient, per column."""
    AZ = A @ Z
    Q = Z * AZ
    qmax = Q.max(axis=0)
    E = np.exp((Q - qmax) / mu)
    S = E.sum(axis=0)
    P = E / S
    val = qmax + mu * np.log(S)
    grad = P * AZ + A.T @ (P * Z)
    return val, grad


def _project(Z: np.ndarray, idx: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Clip to the box ``[-1, 1]`` and fix ``z_i = sigma`` in each column."""
    Z = np.clip(Z, -1.0, 1.0)
    Z[idx, np.arange(Z.shape[1])] = sigma
    return Z


def _local_descent(A: np.ndarray, Z: np.ndarray, idx: np.ndarray, sigma: np.ndarray,
                   iters: int) -> tuple[np.ndarray, np.ndarray]:
    """Projected gradient with backtracking on the smoothed ``h``, all starts at once.

    Returns the best feasible iterate of each column and its true ``h``.
    """
    scale = max(float(np.abs(A).sum(axis=1).max()), np.finfo(float).tiny)
    S = Z.shape[1]
    best_Z = Z.copy()
    best_h = _h(A, Z)
    step = np.full(S, 1.0 / scale)
    stages = [1e-1, 1e-2, 1e-3, 1e-4, 1e-6]
    per_stage = max(iters // len(stages), 1)
    for rel_mu in stages:
        mu = rel_mu * scale
        val, grad = _smoothed(A, Z, mu)
        for _ in range(per_stage):
            active = np.ones(S, dtype=bool)
            new_Z = Z.copy()
            new_val = val.copy()
            t = np.minimum(step * 4.0, 10.0 / scale)
            for _bt in range(30):
                cols = np.flatnonzero(active)
                if cols.size == 0:
                    break
                trial = _project(Z[:, cols] - t[cols] * grad[:, cols], idx[cols], sigma[cols])
                tv, _ = _smoothed(A, trial, mu)
                d = trial - Z[:, cols]
                ok = tv <= val[cols] + 1e-4 * np.sum(grad[:, cols] * d, axis=0)
                good = cols[ok]
                new_Z[:, good] = trial[:, ok]
                new_val[good] = tv[ok]
                step[good] = t[good]
                active[good] = False
                t[cols[~ok]] *= 0.5
            moved = np.max(np.abs(new_Z - Z), axis=0)
            Z = new_Z
            val, grad = _smoothed(A, Z, mu)
            hz = _h(A, Z)
            better = hz < best_h
            best_h[better] = hz[better]
            best_Z[:, better] = Z[:, better]
            if np.all(moved <= 1e-12):
                break
    return best_Z, best_h


def _polish(A: np.ndarray, z: np.ndarray, i: int, sigma: float) -> np.ndarray:
    """SLSQP on the epigraph form ``min t s.t. z_j (A z)_j <= t, |z| <= 1, z_i = sigma``."""
    from scipy.optimize import minimize

    n = A.shape[0]

    def cons(v):
        zz = v[:n]
        return v[n] - zz * (A @ zz)

    def cons_jac(v):
        zz = v[:n]
        J = np.empty((n, n + 1))
        J[:, :n] = -(zz[:, None] * A)
        J[np.arange(n), np.arange(n)] -= A @ zz
        J[:, n] = 1.0
        return J

    bounds = [(-1.0, 1.0)] * n + [(None, None)]
    bounds[i] = (sigma, sigma)
    v0 = np.concatenate([z, [float(np.max(z * (A @ z)))]])
    res = minimize(lambda v: v[n], v0, jac=lambda v: np.eye(1, n + 1, n).ravel(),
                   method="SLSQP", bounds=bounds,
                   constraints=[{"type": "ineq", "fun": cons, "jac": cons_jac}],
                   options={"maxiter": 200, "ftol": 1e-14})
    out = np.clip(np.asarray(res.x[:n], dtype=float), -1.0, 1.0)
    out[i] = sigma
    return out


def cottle_bounds(A, *, starts: int | None = 32, random_starts: int = 8, seed: int = 0,
                  iters: int = 150, polish: int | None = None,
                  polish_max_n: int = 250) -> CottleBounds:
    """Estimate Cottle's fundamental quantity ``c(A)`` with bounds.

    ``c(A) = min_{||z||_inf = 1} max_i z_i (A z)_i`` (lemma cottleLemma). The problem is
    nonconvex and nonsmooth; following the paper's appendix "Computing c(A)", it is split
    into ``min over (i, sigma)`` of ``min h(z)`` subject to ``-1 <= z <= 1`` and
    ``z_i = sigma``, each solved by local optimisation started from the eigenvector of the
    smallest eigenvalue, scaled so that ``z_i = sigma`` and clipped to the box.

    Starts: ``h(-z) = h(z)``, so ``sigma = -1`` repeats ``sigma = +1`` and only ``sigma = +1``
    is run. ``starts`` indices ``i`` are used (the ``starts`` indices with the largest
    eigenvector entries; all ``n``, the appendix's full loop, when ``n <= starts`` or
    ``starts=None``; default 32), plus
    ``random_starts`` uniform random points of the box (seeded by ``seed``), each with a
    random fixed index: ``min(starts, n) + random_starts`` local optimisations in all.

    Local optimisation: projected gradient with Armijo backtracking (as the appendix) on a
    log-sum-exp smoothing of the max whose temperature decreases from ``0.1 ||A||_inf`` to
    ``1e-6 ||A||_inf`` (``iters`` iterations in all), keeping the iterate of smallest true
    ``h``; then the ``polish`` best candidates are refined by SLSQP on the epigraph form
    (for ``n <= polish_max_n``; by default all of them up to ``n = 60``, then fewer as
    ``40 (60 / n)^3``, at least 2, since the landscape has many local minima and the
    refinement is what finds the good ones). BLAS runs on one thread meanwhile.

    The estimate is ``h(z)`` at a feasible ``z`` (``||z||_inf = 1`` exactly), so it is an
    **upper bound** of the true ``c(A)``: any feasible ``z`` bounds the minimum from
    above; a local method may miss the global minimum. The rigorous lower bound
    ``lambda_min(sym A) / n`` (Cottle, Pang and Stone 2009) is returned beside it.

    Parameters
    ----------
    A : (n, n) array_like
    starts : int or None
        Number of eigenvector starts (fixed indices); None for all ``n``.
    random_starts : int
        Extra random starts.
    seed : int
        Seed of the random starts.
    iters : int
        Projected-gradient iterations per start.
    polish : int or None
        Number of best candidates refined by SLSQP (0 to skip; None: the default rule
        above).
    polish_max_n : int
        Skip SLSQP above this size (its dense QP subproblems cost ``O(n^3)`` each).

    Returns
    -------
    CottleBounds

    Raises
    ------
    ValueError
        If ``A`` is not a finite square matrix, or a count is negative.
    """
    A = np.asarray(A, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] == 0:
        raise ValueError(f"cottle_c: A must be a non-empty square matrix, got shape {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError("cottle_c: A has non-finite entries; c(A) needs a finite matrix")
    if (starts is not None and starts < 1) or random_starts < 0 or iters < 1 or (
            polish is not None and polish < 0):
        raise ValueError("cottle_c: starts must be >= 1 (or None for all n), random_starts, "
                         "polish >= 0 and iters >= 1")
    with _one_blas_thread():
        return _cottle_bounds(A, starts, random_starts, seed, iters, polish, polish_max_n)


_BLAS_SYMBOLS = (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
                 ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
                 ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
                 ("openblas_get_num_threads", "openblas_set_num_threads"))


@contextlib.contextmanager
def _one_blas_thread():
    """Run the block with one OpenBLAS thread, restoring the previous counts after.

    The many small dense products and SLSQP's small factorisations of :func:`cottle_bounds`
    run an order of magnitude faster without thread start-up and contention on a loaded
    machine. Uses threadpoolctl when installed, otherwise the ``*_set_num_threads``
    functions of the OpenBLAS libraries loaded in the process (numpy's and scipy's wheels
    each bring one); without either it changes nothing.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        threadpool_limits = None
    if threadpool_limits is not None:
        with threadpool_limits(limits=1, user_api="blas"):
            yield
        return
    restore = []
    for get, put in _openblas_controls():
        try:
            old = int(get())
            put(1)
        except (OSError, ValueError):
            continue
        restore.append((put, old))
    try:
        yield
    finally:
        for put, old in restore:
            put(old)


def _openblas_controls() -> list:
    """``(get_num_threads, set_num_threads)`` of each loaded OpenBLAS library (Linux)."""
    import ctypes

    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            libs = sorted({line.split()[-1] for line in fh if "openblas" in line.lower()
                           and line.split()[-1].startswith("/")})
    except OSError:
        return []
    out = []
    for lib in libs:
        try:
            handle = ctypes.CDLL(lib)
        except OSError:
            continue
        for get, put in _BLAS_SYMBOLS:
            if hasattr(handle, get) and hasattr(handle, put):
                g, s = getattr(handle, get), getattr(handle, put)
                g.restype, g.argtypes = ctypes.c_int, []
                s.restype, s.argtypes = None, [ctypes.c_int]
                out.append((g, s))
                break
    return out


def _cottle_bounds(A: np.ndarray, starts, random_starts, seed, iters, polish,
                   polish_max_n) -> CottleBounds:
    n = A.shape[0]
    sym = 0.5 * (A + A.T)
    lam, vecs = np.linalg.eigh(sym)
    lam_min = float(lam[0])
    lower = lam_min / n
    if n == 1:
        z = np.ones(1)
        return CottleBounds(float(A[0, 0]), z, lower, lam_min, 1)
    v = vecs[:, 0]
    order = np.argsort(-np.abs(v), kind="stable")
    k = n if starts is None else min(int(starts), n)
    idx = order[:k]
    Z0 = []
    for i in idx:
        if abs(v[i]) > 0:
            Z0.append(v * (np.sign(v[i]) / abs(v[i])))
        else:
            e = np.zeros(n)
            e[i] = 1.0
            Z0.append(e)
    rng = np.random.default_rng(seed)
    ridx = rng.integers(0, n, size=random_starts)
    for i in ridx:
        Z0.append(rng.uniform(-1.0, 1.0, size=n))
    all_idx = np.concatenate([idx, ridx]).astype(int)
    sigma = np.ones(all_idx.size)
    Z = _project(np.column_stack(Z0), all_idx, sigma)
    best_Z, best_h = _local_descent(A, Z, all_idx, sigma, iters)
    if polish is None:
        polish = max(2, int(40 * (60.0 / n) ** 3))
    if polish and n <= polish_max_n:
        for c in np.argsort(best_h, kind="stable")[:polish]:
            try:
                z = _polish(A, best_Z[:, c], int(all_idx[c]), 1.0)
            except (ValueError, np.linalg.LinAlgError):
                continue
            hz = float(np.max(z * (A @ z)))
            if hz < best_h[c]:
                best_h[c] = hz
                best_Z[:, c] = z
    c = int(np.argmin(best_h))
    return CottleBounds(float(best_h[c]), best_Z[:, c].copy(), lower, lam_min, int(all_idx.size))


def cottle_c(A, *, starts: int | None = 32, random_starts: int = 8, seed: int = 0) -> float:
    """An upper-bound estimate of Cottle's ``c(A) = min_{||z||_inf=1} max_i z_i (A z)_i``.

    Multi-start local optimisation as the paper's appendix "Computing c(A)": by default
    ``min(n, 32)`` eigenvector starts (one per fixed index ``z_i = 1``; ``z_i = -1`` is the
    same problem since ``h(-z) = h(z)``) plus ``random_starts = 8`` random ones, the best
    results refined by SLSQP (all 40 for ``n <= 60``, fewer above, none above ``n = 250``). Since every
    candidate is feasible, the value is an upper bound of the true minimum. See
    :func:`cottle_bounds` for the method, the lower bound ``lambda_min / n`` and the
    upper bound ``lambda_min`` (symmetric ``A``).

    Parameters
    ----------
    A : (n, n) array_like
    starts : int or None
        Eigenvector starts; None for all ``n``.
    random_starts : int
        Extra random starts.
    seed : int
        Seed of the random starts.

    Returns
    -------
    float
    """
    return cottle_bounds(A, starts=starts, random_starts=random_starts, seed=seed).estimate


# ---------------------------------------------------------------------- the table
def _inf_norm(E: np.ndarray) -> float:
    return float(np.abs(E).sum(axis=1).max()) if E.size else 0.0


def _knob(value) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return math.nan
    return out if math.isfinite(out) else math.nan


def _iter_instances(path_or_lcps, instances: Sequence[str] | None = None):
    """Yield ``(A, {name: (A_low, cost_ratio, attrs)})`` per instance."""
    from lcpbench.core.operator import dense_uncounted

    if isinstance(path_or_lcps, (str, Path)):
        from lcpbench.sets import instance_ids, read_instance

        path = Path(path_or_lcps)
        ids = list(instances) if instances is not None else instance_ids(path)
        for iid in ids:
            lcp = read_instance(path, iid, psd_check=False)
            yield _dense_pairs(lcp, dense_uncounted)
    else:
        for lcp in path_or_lcps:
            yield _dense_pairs(lcp, dense_uncounted)


def _dense_pairs(lcp, dense):
    A = dense(lcp.A)
    high_cost = lcp.A.cost or 1.0
    attrs = (lcp.meta or {}).get("low", {}) or {}
    lows = {}
    for name, op in dict(lcp.low or {}).items():
        la = dict(attrs.get(name, {}))
        ratio = _knob(la.get("cost_ratio"))
        if math.isnan(ratio):
            ratio = (op.cost / high_cost) if op.cost else math.nan
        lows[name] = (dense(op), ratio, la)
    return A, lows


def fidelity_table(path_or_lcps, *, instances: Sequence[str] | None = None,
                   c_values: Sequence[float] | None = None) -> pd.DataFrame:
    """One row per low fidelity of a stored set: error, cost and the Cottle condition.

    Parameters
    ----------
    path_or_lcps : str, Path or iterable of LCP
        A stored set (``.h5``) or LCPs with ``low`` operators (stored-set LCPs carry the
        low attrs ``cost_ratio``, ``p``, ``eps_gmres``, ``model`` in ``meta["low"]``;
        otherwise the cost ratio is ``low.cost / A.cost``).
    instances : sequence of str, optional
        Instance ids of the file to use; default all.
    c_values : sequence of float, optional
        ``c(A)`` per instance, if already known; default :func:`cottle_c` of each.

    Returns
    -------
    DataFrame
        Columns :data:`TABLE_COLUMNS`: ``fidelity`` (name), ``model``, ``p``,
        ``eps_gmres`` (knob attrs, NaN when absent), ``instances`` (how many instances
        have this fidelity), ``log10_max_err`` (log10 of the max over instances of
        ``||A_low - A||_inf``, the induced infinity norm), ``median_low_per_high``
        (median over instances of ``t_high / t_low = 1 / cost_ratio``) and
        ``share_err_below_c`` (share of instances with ``||A_low - A||_inf < c(A)``, the
        condition of lemma cottleLemma; ``c(A)`` is an upper-bound estimate, so the share
        may count an instance whose true ``c(A)`` is slightly smaller) and
        ``share_err_below_lower`` (the same with the rigorous lower bound
        ``lambda_min(sym A) / n`` of ``c(A)``: instances certainly inside the lemma's
        neighbourhood). Sorted by model, p, eps_gmres (largest first), name.
    """
    rows: dict[str, dict] = {}
    c_list = list(c_values) if c_values is not None else None
    count = 0
    for k, (A, lows) in enumerate(_iter_instances(path_or_lcps, instances)):
        count += 1
        if not lows:
            continue
        lower = float(np.linalg.eigvalsh(0.5 * (A + A.T))[0]) / A.shape[0]
        if c_list is not None:
            if k >= len(c_list):
                raise ValueError(f"c_values has {len(c_list)} entries but the set has more "
                                 "instances; pass one c(A) per instance")
            c = float(c_list[k])
        else:
            c = cottle_c(A)
        for name, (A_low, ratio, la) in lows.items():
            r = rows.setdefault(name, {"errs": [], "ratios": [], "below": [], "sure": [],
                                       "attrs": la})
            err = _inf_norm(A_low - A)
            r["errs"].append(err)
            r["ratios"].append(ratio)
            r["below"].append(err < c)
            r["sure"].append(err < lower)
    if count == 0:
        raise ValueError("fidelity_table: the set has no instances")
    out = []
    for name, r in rows.items():
        la = r["attrs"]
        max_err = max(r["errs"])
        with np.errstate(divide="ignore"):
            log_err = float(np.log10(max_err)) if max_err > 0 else -math.inf
        ratios = np.asarray(r["ratios"], dtype=float)
        out.append({"fidelity": name, "model": str(la.get("model", "")),
                    "p": _knob(la.get("p")), "eps_gmres": _knob(la.get("eps_gmres")),
                    "instances": len(r["errs"]), "log10_max_err": log_err,
                    "median_low_per_high": float(np.median(1.0 / ratios)),
                    "share_err_below_c": float(np.mean(r["below"])),
                    "share_err_below_lower": float(np.mean(r["sure"]))})
    df = pd.DataFrame(out, columns=TABLE_COLUMNS)
    if df.empty:
        return df
    df["_eps"] = -df["eps_gmres"]
    df = df.sort_values(["model", "p", "_eps", "fidelity"], na_position="last", kind="stable")
    return df.drop(columns="_eps").reset_index(drop=True)


# ---------------------------------------------------------------------- figures
#: Models whose fidelity is set by the knobs (p, eps_gmres); "" = not recorded.
GRID_MODELS = ("", "bim")


def _on_grid(table: pd.DataFrame) -> pd.Series:
    """Rows that get a heatmap cell: both knobs, a knob-driven model, first of its cell.

    ``lcpbench generate`` records the high fidelity's ``p`` and ``eps_gmres`` on other
    models too (``rpy``, ``self``); those knobs do not set their fidelity, so such rows
    are listed beside the heatmaps instead.
    """
    mask = (table["p"].notna() & table["eps_gmres"].notna()
            & table["model"].fillna("").astype(str).str.lower().isin(GRID_MODELS))
    dup = table["p"].astype(str) + "/" + table["eps_gmres"].astype(str)
    return mask & ~(dup.where(mask).duplicated() & mask)


def _grid(table: pd.DataFrame) -> pd.DataFrame:
    """Rows placed on the (p, eps_gmres) heatmaps (:func:`_on_grid`)."""
    if table is None or table.empty:
        return pd.DataFrame(columns=TABLE_COLUMNS)
    return table[_on_grid(table)]


def _fmt_eps(e: float) -> str:
    exp = math.log10(e)
    return f"1e{round(exp)}" if abs(exp - round(exp)) < 1e-9 else f"{e:.2g}"


def _fmt_p(p: float) -> str:
    return str(int(p)) if float(p).is_integer() else f"{p:g}"


def _heat(ax, grid: pd.DataFrame, column: str, title: str, cbar: str, fmt: str,
          cmap: str, fig) -> None:
    ps = sorted(grid["p"].unique())
    eps = sorted(grid["eps_gmres"].unique(), reverse=True)
    M = np.full((len(ps), len(eps)), np.nan)
    for _, r in grid.iterrows():
        M[ps.index(r["p"]), eps.index(r["eps_gmres"])] = r[column]
    shown = np.ma.masked_invalid(np.where(np.isfinite(M), M, np.nan))
    im = ax.imshow(shown, origin="lower", aspect="auto", cmap=cmap)
    fig.colorbar(im, ax=ax, label=cbar)
    ax.set_xticks(range(len(eps)))
    ax.set_xticklabels([_fmt_eps(e) for e in eps])
    ax.set_yticks(range(len(ps)))
    ax.set_yticklabels([_fmt_p(p) for p in ps])
    ax.set_xlabel("eps_gmres")
    ax.set_ylabel("p")
    ax.set_title(title)
    finite = M[np.isfinite(M)]
    mid = float(np.mean([finite.min(), finite.max()])) if finite.size else 0.0
    for a in range(len(ps)):
        for b in range(len(eps)):
            if np.isfinite(M[a, b]):
                ax.text(b, a, format(M[a, b], fmt), ha="center", va="center", fontsize=7,
                        color="white" if M[a, b] < mid else "black")


def _figure(ncols: int, width: float, height: float = 3.4):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update({"svg.hashsalt": "lcpbench", "font.size": 9})
    return plt.subplots(1, ncols, figsize=(width, height), squeeze=False)


def heatmap_svg(table: pd.DataFrame) -> str:
    """The paper's two heatmaps over ``(p, eps_gmres)`` as one SVG string.

    Left: log10 of the max ``||A_low - A||_inf``; right: median low MVPs per high MVP.
    Cells: fidelities with both knobs whose model is one of ``GRID_MODELS``. Returns
    ``""`` when there is none.
    """
    grid = _grid(table)
    if grid.empty:
        return ""
    ncol = grid["eps_gmres"].nunique()
    fig, axes = _figure(2, max(8.0, 2 * (2.5 + 0.7 * ncol)))
    _heat(axes[0, 0], grid, "log10_max_err", "log10 max ||A_low - A||_inf",
          "log10 error", ".2f", "viridis", fig)
    _heat(axes[0, 1], grid, "median_low_per_high", "low MVPs per high MVP (median)",
          "t_high / t_low", ".3g", "magma", fig)
    return plots.svg_of(fig)


def cottle_heatmap_svg(table: pd.DataFrame) -> str:
    """The appendix figure: share of instances with ``||A_low - A||_inf < c(A)``, in %."""
    grid = _grid(table).copy()
    if grid.empty:
        return ""
    grid["pct"] = 100.0 * grid["share_err_below_c"]
    ncol = grid["eps_gmres"].nunique()
    fig, axes = _figure(1, max(4.5, 2.5 + 0.7 * ncol))
    _heat(axes[0, 0], grid, "pct", "% instances with ||A_low - A||_inf < c(A)", "%",
          ".0f", "cividis", fig)
    return plots.svg_of(fig)


def _html_table(df: pd.DataFrame) -> str:
    if df is None or df.empty:
        return '<p class="note">(no rows)</p>'
    return df.to_html(index=False, escape=True, na_rep="-", border=0,
                      float_format=lambda v: f"{v:.4g}")


def heatmaps(table: pd.DataFrame, id_prefix: str = "fidhm_") -> str:
    """HTML: the two heatmaps (inline SVG) and a small table of the other fidelities.

    Fidelities off the ``(p, eps_gmres)`` grid (another model such as ``rpy``, or a knob
    missing; see ``GRID_MODELS``) have no cell in the heatmaps and are listed in the
    table instead. The SVG's ids get ``id_prefix`` so
    several figures can share one page.
    """
    from lcpbench.report.plots import prefix_ids

    parts = []
    svg = heatmap_svg(table)
    if svg:
        svg = prefix_ids(svg, id_prefix)
        parts.append(f'<div class="fig">{svg}</div>')
    if table is not None and not table.empty:
        others = table[~_on_grid(table)]
        if not others.empty:
            parts.append("<p class='note'>Fidelities not on the (p, eps_gmres) grid (other "
                         "models, or a knob missing):</p>")
            parts.append(_html_table(others))
    return "\n".join(parts)


# ---------------------------------------------------------------------- report section
def _names_a_set_file(row, shipped: dict) -> bool:
    """True when a result row's problem parameters name an ``.h5`` file or a shipped set."""
    try:
        params = json.loads(row.get("problem_params") or "{}")
    except (TypeError, ValueError):
        params = {}
    if not isinstance(params, dict):
        return False
    return any(str(v).endswith(".h5") or str(v) in shipped for v in params.values())


def stored_set_specs(results: pd.DataFrame) -> list[tuple[Path, list[str] | None]]:
    """The stored sets a run store's results used: ``[(path, instance ids or None)]``.

    Reads the ``problem`` and ``problem_params`` columns: rows of the ``stored`` plugin
    (``stored:path=...``, ``instances`` positions), of a ``set:name=...`` plugin whose
    name is a shipped set, and of the shipped-set families ``set-<stem>``. Files that no
    longer exist are skipped.
    """
    from lcpbench.core.registry import stored_sets
    from lcpbench.sets import instance_ids, parse_instances

    shipped = {name: Path(info.path) for name, info in stored_sets().items()}
    by_problem = {info.problem: name for name, info in stored_sets().items()}

    if results is None or results.empty or "problem" not in results:
        return []
    out: list[tuple[Path, list[str] | None]] = []
    seen = set()
    cols = ["problem", "problem_params"] if "problem_params" in results else ["problem"]
    for _, row in results[cols].drop_duplicates().iterrows():
        problem = str(row["problem"])
        kind = problem.split(":", 1)[0]
        if kind not in by_problem and not _names_a_set_file(row, shipped):
            continue
        try:
            params = json.loads(row.get("problem_params") or "{}")
        except (TypeError, ValueError):
            params = {}
        if not params and ":" in problem:
            params = dict(kv.split("=", 1) for kv in problem.split(":", 1)[1].split(",")
                          if "=" in kv)
        name = str(params.get("path") or params.get("name") or by_problem.get(kind, ""))
        if not name:
            continue
        path = Path(name)
        if not path.exists():
            path = shipped.get(name, path)
        if not path.exists():
            continue
        spec = str(params.get("instances") or "")
        key = (str(path.resolve()), spec)
        if key in seen:
            continue
        seen.add(key)
        ids = None
        if spec.strip():
            all_ids = instance_ids(path)
            ids = [all_ids[i] for i in parse_instances(spec, len(all_ids))]
        out.append((path, ids))
    return out


def fidelity_section(paths: Iterable) -> str:
    """HTML section of the report: per stored set, the table, heatmaps and Cottle figure.

    Parameters
    ----------
    paths : iterable
        Stored-set paths, or ``(path, instance ids or None)`` pairs as returned by
        :func:`stored_set_specs`.

    Returns
    -------
    str
        ``""`` when no set has a low fidelity.
    """
    from lcpbench.sets import StoredSetError

    from lcpbench.report.plots import prefix_ids

    parts = []
    for k, item in enumerate(paths):
        path, ids = (item if isinstance(item, tuple) else (item, None))
        path = Path(path)
        try:
            table = fidelity_table(path, instances=ids)
        except (StoredSetError, OSError, ValueError) as exc:
            parts.append(f"<h3>{html.escape(path.name)}</h3><p class='note'>fidelity study "
                         f"skipped: {html.escape(str(exc))}</p>")
            continue
        if table.empty:
            continue
        used = f"{len(ids)} selected instance(s)" if ids is not None else "all instances"
        parts.append(f"<h3>{html.escape(path.name)} ({used})</h3>")
        parts.append(_html_table(table))
        parts.append(heatmaps(table, id_prefix=f"fid{k}a_"))
        cottle = cottle_heatmap_svg(table)
        if cottle:
            parts.append(f'<div class="fig">{prefix_ids(cottle, f"fid{k}b_")}</div>')
    if not parts:
        return ""
    intro = ("<h2>Fidelity study of the stored sets</h2><p class='note'>Per low fidelity: "
             "log10 of the largest ||A_low - A||_inf over the instances (induced infinity "
             "norm), the median number of low-fidelity MVPs per high-fidelity MVP "
             "(1 / cost_ratio, as measured when the set was generated), and the share of "
             "instances with ||A_low - A||_inf &lt; c(A), the condition of the paper's "
             "lemma cottleLemma for a locally Lipschitz solution map. c(A) is estimated by "
             "multi-start local optimisation (appendix \"Computing c(A)\"); the estimate is "
             "an upper bound of c(A), so share_err_below_lower also gives the share "
             "certainly inside, with the lower bound lambda_min(A)/n of c(A).</p>")
    return intro + "\n".join(parts)
