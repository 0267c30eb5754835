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

Costs
    Stored sets keep ``cost_ratio = t_low / t_high`` per low fidelity and instance; the
    table reports its reciprocal ``t_high / t_low`` (low MVPs per high MVP), the median
    over instances.

Cache
    Estimating ``c(A)`` takes seconds per instance, so :func:`cached_fidelity_table`
    keeps each table in a folder (a run store's ``cache/``), keyed by the set file's
    content and the instances used: re-rendering a report does not recompute it.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from lcpbench.workflows.cottle import cottle_c

__all__ = ["TABLE_COLUMNS", "cached_fidelity_table", "fidelity_table", "stored_set_specs"]

#: Columns of :func:`fidelity_table`, in order.
TABLE_COLUMNS = ["fidelity", "model", "p", "eps_gmres", "instances", "log10_max_err",
                 "median_low_per_high", "share_err_below_c", "share_err_below_lower"]



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
        condition of Cottle's lemma; ``c(A)`` is an upper-bound estimate, so the share
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
CACHE_VERSION = 1


def _cache_key(path: Path, instances: Sequence[str] | None) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    digest.update(json.dumps([CACHE_VERSION, list(instances) if instances is not None
                              else None]).encode())
    return digest.hexdigest()[:20]


def cached_fidelity_table(path, instances: Sequence[str] | None = None,
                          cache_dir=None) -> pd.DataFrame:
    """:func:`fidelity_table` of a stored set, kept in ``cache_dir`` between calls.

    Parameters
    ----------
    path : str or Path
        The stored set (``.h5``).
    instances : sequence of str, optional
        Instance ids to use; default all.
    cache_dir : str or Path, optional
        Folder of the cache (created when needed); None computes without caching.

    Returns
    -------
    DataFrame
        As :func:`fidelity_table`. The entry is keyed by the file's content and the
        instance ids, so an edited or regenerated set is recomputed.
    """
    path = Path(path)
    if cache_dir is None:
        return fidelity_table(path, instances=instances)
    from lcpbench.run.store import atomic_write

    entry = Path(cache_dir) / f"fidelity-{path.stem}-{_cache_key(path, instances)}.csv"
    if entry.exists():
        table = pd.read_csv(entry, dtype=str, keep_default_na=False)
        for col in TABLE_COLUMNS[2:]:
            table[col] = pd.to_numeric(table[col], errors="coerce")
        table["instances"] = table["instances"].astype(int)
        return table.reindex(columns=TABLE_COLUMNS)
    table = fidelity_table(path, instances=instances)
    entry.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(entry, table.to_csv(index=False))
    return table
