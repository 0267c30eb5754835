"""The fidelity study of stored sets: error and cost of each low fidelity against c(A).

For any stored set (:mod:`lcpbench.sets`) this computes the numbers behind the paper's
figure of low-fidelity errors and costs: per low fidelity, the log10 of the largest
``||A_low - A||_inf`` over the instances, how many low-fidelity MVPs cost as much as one
high-fidelity MVP, and the share of instances whose low fidelity lies within ``c(A)``
of ``A`` (Cottle's lemma: there the solution map is locally Lipschitz; ``c(A)`` from
:mod:`lcpbench.workflows.cottle`). The figures are drawn by :mod:`lcpbench.report.fidelity`.

Norms
    ``||E||_inf`` is the matrix norm induced by the vector infinity norm (the largest
    absolute row sum), the norm of Cottle's lemma, whose ``c(A)`` is defined over the
    unit sphere of the vector infinity norm.

Knobs
    Which knobs span the study's grid is the scene's word, not the framework's: a set
    generated from a scene records the scene's spec (root attribute ``scene``), and the
    registered scene declares its :class:`~lcpbench.core.scene.FidelityAxes` (rows,
    columns, the knob naming the model, the models the two knobs set). A set whose scene
    is unknown, and LCPs given directly, get a table without knob columns.

Costs
    Stored sets keep ``cost_ratio = t_low / t_high`` per low fidelity and instance; the
    table reports its reciprocal ``t_high / t_low`` (low MVPs per high MVP), the median
    over instances.

Cache
    Estimating ``c(A)`` takes seconds per instance, so :func:`cached_fidelity_table`
    keeps each table in the user cache directory (:func:`user_cache_dir`:
    ``$XDG_CACHE_HOME/lcpbench``, by default ``~/.cache/lcpbench``), keyed by the sha256
    of the set file, the instances used and the study's parameters: it is computed once
    per set and machine, whatever the output folder, and an edited or regenerated set
    is computed again. The instances are spread over worker processes (one per core).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from lcpbench.core.scene import FidelityAxes
from lcpbench.workflows.cottle import cottle_c

__all__ = ["METRIC_COLUMNS", "cached_fidelity_table", "fidelity_table", "set_axes",
           "stored_set_specs", "table_columns", "user_cache_dir"]

#: The measured columns of :func:`fidelity_table`, after the name and the knobs.
METRIC_COLUMNS = ["instances", "log10_max_err", "median_low_per_high", "share_err_below_c",
                  "share_err_below_lower"]


def table_columns(axes: FidelityAxes | None) -> list[str]:
    """Columns of :func:`fidelity_table`: the name, the scene's knobs (model, rows,
    columns of :class:`~lcpbench.core.scene.FidelityAxes`; none without axes), the metrics."""
    knobs = [axes.model_knob, axes.rows, axes.columns] if axes is not None else []
    return ["fidelity", *knobs, *METRIC_COLUMNS]


def set_axes(path) -> FidelityAxes | None:
    """The fidelity axes the scene of a stored set declares, or None.

    Read from the set's root attribute ``scene`` (the spec it was generated from, e.g.
    ``lattice:m=3,model=bim``) through the scene registry; None for a set without one,
    or whose scene is not registered here.
    """
    from lcpbench.core.registry import get_scene
    from lcpbench.sets import StoredSetError, set_info

    try:
        spec = set_info(path).get("scene")     # the file checksum verified first
    except (OSError, StoredSetError):
        return None
    if not isinstance(spec, str) or not spec.strip():
        return None
    try:
        return get_scene(spec.split(":", 1)[0].strip()).fidelity_axes()
    except (KeyError, AttributeError, TypeError, ValueError):
        return None



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


def _c_values(matrices: list[np.ndarray], jobs: int,
              progress: Callable[[str], None] | None) -> list[float]:
    """:func:`cottle_c` of each matrix, over ``jobs`` worker processes, with progress."""
    say = progress or (lambda text: None)
    total = len(matrices)
    if jobs <= 1 or total <= 1:
        out = []
        for k, A in enumerate(matrices):
            out.append(cottle_c(A))
            say(f"c(A) of instance {k + 1}/{total}")
        return out
    with ProcessPoolExecutor(max_workers=min(jobs, total)) as pool:
        futures = [pool.submit(cottle_c, A) for A in matrices]
        out = []
        for k, fut in enumerate(futures):
            out.append(fut.result())
            say(f"c(A) of instance {k + 1}/{total}")
    return out


def fidelity_table(path_or_lcps, *, instances: Sequence[str] | None = None,
                   c_values: Sequence[float] | None = None, jobs: int = 1,
                   progress: Callable[[str], None] | None = None,
                   axes: FidelityAxes | None = None) -> pd.DataFrame:
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
    jobs : int
        Worker processes for the ``c(A)`` estimates (1: in this process).
    progress : callable, optional
        Called with a line of text after each instance's ``c(A)``.
    axes : FidelityAxes, optional
        The knobs to tabulate; default the set's scene's (:func:`set_axes`), none for LCPs.

    Returns
    -------
    DataFrame
        Columns :func:`table_columns` of the axes: ``fidelity`` (name), the scene's model
        knob and its two grid knobs (the low attrs; NaN when absent), ``instances`` (how many instances
        have this fidelity), ``log10_max_err`` (log10 of the max over instances of
        ``||A_low - A||_inf``, the induced infinity norm), ``median_low_per_high``
        (median over instances of ``t_high / t_low = 1 / cost_ratio``) and
        ``share_err_below_c`` (share of instances with ``||A_low - A||_inf < c(A)``, the
        condition of Cottle's lemma; ``c(A)`` is an upper-bound estimate, so the share
        may count an instance whose true ``c(A)`` is slightly smaller) and
        ``share_err_below_lower`` (the same with the rigorous lower bound
        ``lambda_min(sym A) / n`` of ``c(A)``: instances certainly inside the lemma's
        neighbourhood). Sorted by model, row knob, column knob (largest first), name.
        ``table.attrs["axes"]`` holds the axes (None without).
    """
    if axes is None and isinstance(path_or_lcps, (str, Path)):
        axes = set_axes(path_or_lcps)
    rows: dict[str, dict] = {}
    pairs = list(_iter_instances(path_or_lcps, instances))
    if not pairs:
        raise ValueError("fidelity_table: the set has no instances")
    if c_values is not None:
        c_list = [float(c) for c in c_values]
        if len(c_list) < len(pairs):
            raise ValueError(f"c_values has {len(c_list)} entries but the set has more "
                             "instances; pass one c(A) per instance")
    else:
        with_low = [k for k, (_, lows) in enumerate(pairs) if lows]
        found = _c_values([pairs[k][0] for k in with_low], jobs, progress)
        c_list = [math.nan] * len(pairs)
        for k, c in zip(with_low, found):
            c_list[k] = c
    for k, (A, lows) in enumerate(pairs):
        if not lows:
            continue
        lower = float(np.linalg.eigvalsh(0.5 * (A + A.T))[0]) / A.shape[0]
        c = c_list[k]
        for name, (A_low, ratio, la) in lows.items():
            r = rows.setdefault(name, {"errs": [], "ratios": [], "below": [], "sure": [],
                                       "attrs": la})
            err = _inf_norm(A_low - A)
            r["errs"].append(err)
            r["ratios"].append(ratio)
            r["below"].append(err < c)
            r["sure"].append(err < lower)
    out = []
    for name, r in rows.items():
        la = r["attrs"]
        max_err = max(r["errs"])
        with np.errstate(divide="ignore"):
            log_err = float(np.log10(max_err)) if max_err > 0 else -math.inf
        ratios = np.asarray(r["ratios"], dtype=float)
        knobs = ({axes.model_knob: str(la.get(axes.model_knob, "")),
                  axes.rows: _knob(la.get(axes.rows)),
                  axes.columns: _knob(la.get(axes.columns))} if axes is not None else {})
        out.append({"fidelity": name, **knobs,
                    "instances": len(r["errs"]), "log10_max_err": log_err,
                    "median_low_per_high": float(np.median(1.0 / ratios)),
                    "share_err_below_c": float(np.mean(r["below"])),
                    "share_err_below_lower": float(np.mean(r["sure"]))})
    df = pd.DataFrame(out, columns=table_columns(axes))
    if not df.empty:
        df = _sorted(df, axes)
    df.attrs["axes"] = axes
    return df


def _sorted(df: pd.DataFrame, axes: FidelityAxes | None) -> pd.DataFrame:
    """Rows by model, row knob, column knob (largest first) and name."""
    if axes is None:
        return df.sort_values("fidelity", kind="stable").reset_index(drop=True)
    df = df.assign(_col=-df[axes.columns])
    df = df.sort_values([axes.model_knob, axes.rows, "_col", "fidelity"], na_position="last",
                        kind="stable")
    return df.drop(columns="_col").reset_index(drop=True)


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
        try:
            params = json.loads(row.get("problem_params") or "{}")
        except (TypeError, ValueError):
            params = {}
        if not isinstance(params, dict):
            params = {}
        if not params and ":" in problem:
            params = dict(kv.split("=", 1) for kv in problem.split(":", 1)[1].split(",")
                          if "=" in kv)
        names_a_set = any(str(v).endswith(".h5") or str(v) in shipped for v in params.values())
        if kind not in by_problem and not names_a_set:
            continue
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


#: Bump when the table's computation changes, so old cache entries are not reused.
CACHE_VERSION = 3
#: The study's parameters, part of the cache key (those of :func:`cottle_c`).
STUDY_PARAMS = {"starts": 32, "random_starts": 8, "seed": 0, "norm": "inf"}


def user_cache_dir() -> Path:
    """The user cache directory of lcpbench: ``$XDG_CACHE_HOME/lcpbench``.

    ``XDG_CACHE_HOME`` defaults to ``~/.cache`` (the XDG base-directory rule); the
    folder is created when something is first written to it.
    """
    base = os.environ.get("XDG_CACHE_HOME") or ""
    root = Path(base) if base.strip() and Path(base).is_absolute() else Path.home() / ".cache"
    return root / "lcpbench"


def _cache_key(path: Path, instances: Sequence[str] | None) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    digest.update(json.dumps([CACHE_VERSION, STUDY_PARAMS, list(instances)
                              if instances is not None else None], sort_keys=True).encode())
    return digest.hexdigest()[:24]


def cache_entry(path, instances: Sequence[str] | None = None, cache_dir=None) -> Path:
    """Where :func:`cached_fidelity_table` keeps the table of ``path`` (``instances``)."""
    path = Path(path)
    folder = Path(cache_dir) if cache_dir is not None else user_cache_dir()
    return folder / "fidelity" / f"{path.stem}-{_cache_key(path, instances)}.csv"


def cached_fidelity_table(path, instances: Sequence[str] | None = None,
                          cache_dir=None, *, jobs: int | None = None,
                          progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """:func:`fidelity_table` of a stored set, computed once and kept in a cache.

    Parameters
    ----------
    path : str or Path
        The stored set (``.h5``).
    instances : sequence of str, optional
        Instance ids to use; default all.
    cache_dir : str or Path, optional
        Folder of the cache (created when needed); default :func:`user_cache_dir`.
    jobs : int, optional
        Worker processes for a table not cached yet; default one per core.
    progress : callable, optional
        Called with a line of text per instance while the table is computed.

    Returns
    -------
    DataFrame
        As :func:`fidelity_table`. The entry is keyed by the sha256 of the file, the
        instance ids and :data:`STUDY_PARAMS`, so an edited or regenerated set is
        recomputed and an unchanged one never is.
    """
    from lcpbench.run.store import atomic_write

    path = Path(path)
    entry = cache_entry(path, instances, cache_dir)
    if entry.exists():
        axes = set_axes(path)
        table = pd.read_csv(entry, dtype=str, keep_default_na=False)
        text = {"fidelity", axes.model_knob if axes is not None else "fidelity"}
        for col in table.columns:
            if col not in text:
                table[col] = pd.to_numeric(table[col], errors="coerce")
        table["instances"] = table["instances"].astype(int)
        table = table.reindex(columns=table_columns(axes))
        table.attrs["axes"] = axes
        return table
    jobs = jobs if jobs is not None else (os.cpu_count() or 1)
    table = fidelity_table(path, instances=instances, jobs=jobs, progress=progress)
    entry.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(entry, table.to_csv(index=False))
    return table
