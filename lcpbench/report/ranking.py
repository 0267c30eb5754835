"""Comparisons on common ground: per problem set, over the instances every solver was given.

Every ranking of the report (tables, ratios, work-precision, performance profiles, box
plots, convergence curves, the summary) is built from :func:`common_ground`: the offline
runs of one problem set, cut to the (instance, repeat) pairs that every compared solver
was run on. Reference QP solvers are never ranked (:func:`ranked_runs`); they have
their own table (:func:`references_table`).

Conventions (also stated on the page):

* success is the framework's verified residual meeting the tolerance;
* the ratio to the baseline is the median E-MVPs of the solver divided by the
  baseline's, both over the instances **both** solved, shown with that count;
* the shifted geometric mean counts every run, a failure at a penalty, as
  qpbenchmark does: ``exp(mean(log(v + shift))) - shift`` with ``v`` the run's
  E-MVPs (seconds) when solved and the penalty otherwise. The penalty is the sweep's
  E-MVP budget (per-run time limit) when the run store records one, else ten times the
  largest value any run of the set reached.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

__all__ = ["SHIFT", "common_ground", "ranked_runs", "shifted_geomean", "penalty",
           "ranking_table", "references_table", "truthy"]

#: Shift of the shifted geometric mean per metric (E-MVPs, seconds).
SHIFT = {"emvps": 10.0, "time_s": 0.01}


def truthy(series: pd.Series) -> pd.Series:
    """``True`` where a CSV column holds a true value (``True``, ``true``, ``1``)."""
    return series.astype(str).str.lower().isin(("true", "1", "1.0"))


def _offline(results: pd.DataFrame) -> pd.DataFrame:
    if results.empty:
        return results
    return results[results["kind"].fillna("offline") == "offline"]


def _is_reference(frame: pd.DataFrame) -> pd.Series:
    if "reference_solver" not in frame:
        return pd.Series(False, index=frame.index)
    return truthy(frame["reference_solver"])


def ranked_runs(results: pd.DataFrame, metric: str = "emvps") -> pd.DataFrame:
    """Offline runs of the solvers that are ranked: no reference QP solver, ever.

    With ``metric="emvps"`` only MVP-only solvers (a dense solver's E-MVPs mean
    nothing); with ``"time_s"`` every non-reference solver.
    """
    off = _offline(results)
    if off.empty:
        return off
    off = off[~_is_reference(off)]
    if metric == "emvps":
        off = off[truthy(off["mvp_only"])]
    return off


def common_ground(part: pd.DataFrame) -> tuple[pd.DataFrame, dict]:
    """The runs of one problem set cut to the instances every solver in it was given.

    Parameters
    ----------
    part : DataFrame
        Offline runs of one problem set (one ``problem``), already filtered to the
        solvers to compare.

    Returns
    -------
    (DataFrame, dict)
        The cut runs and ``{"instances": compared instances, "total": instances of the
        set among these runs, "solvers": sorted solver labels, "left_out": {solver:
        runs dropped}}``.
    """
    if part.empty:
        return part, {"instances": 0, "total": 0, "solvers": [], "left_out": {}}
    if "repeat" not in part:
        part = part.assign(repeat=0)
    keys = list(zip(part["instance"].astype(str),
                    pd.to_numeric(part["repeat"], errors="coerce").fillna(0).astype(int)))
    part = part.assign(_key=keys)
    per = {str(s): set(g["_key"]) for s, g in part.groupby("solver", sort=True)}
    common = set.intersection(*per.values())
    cut = part[part["_key"].isin(common)]
    info = {"instances": len({k[0] for k in common}), "runs": len(common),
            "total": part["instance"].astype(str).nunique(), "solvers": sorted(per),
            "left_out": {s: len(v - common) for s, v in per.items() if v - common}}
    return cut.drop(columns="_key"), info


def _by_instance(g: pd.DataFrame) -> pd.Series:
    """E-MVPs of the solved runs of ``g`` indexed by (instance, repeat)."""
    ok = g[truthy(g["solved"])]
    rep = pd.to_numeric(ok["repeat"], errors="coerce").fillna(0).astype(int) \
        if "repeat" in ok else pd.Series(0, index=ok.index)
    index = pd.MultiIndex.from_arrays([ok["instance"].astype(str), rep])
    return pd.Series(ok["emvps"].astype(float).to_numpy(), index=index)


def penalty(part: pd.DataFrame, metric: str, meta: dict | None = None) -> float:
    """The value a failed run counts as in :func:`shifted_geomean` (see the module doc)."""
    meta = meta or {}
    if metric == "emvps":
        budget = (meta.get("config") or {}).get("max_emvps")
    else:
        budget = meta.get("timeout")
    try:
        budget = float(budget)  # type: ignore[arg-type]   # None or text: no budget
    except (TypeError, ValueError):
        budget = np.nan
    if np.isfinite(budget) and budget > 0:
        return budget
    vals = pd.to_numeric(part[metric], errors="coerce")
    top = float(vals[np.isfinite(vals)].max()) if np.isfinite(vals).any() else 1.0
    return 10.0 * max(top, SHIFT[metric])


def shifted_geomean(values, solved, pen: float, shift: float) -> float:
    """``exp(mean(log(v + shift))) - shift`` with failed runs at ``pen``; NaN if no run."""
    v = np.asarray(values, dtype=float)
    ok = np.asarray(solved, dtype=bool) & np.isfinite(v)
    if v.size == 0:
        return np.nan
    v = np.where(ok, np.maximum(v, 0.0), pen)
    return max(0.0, round(float(np.exp(np.mean(np.log(v + shift))) - shift), 9))


def emvp_stats(ok: pd.DataFrame, multi: bool) -> dict[str, str]:
    """``min``/``median``/``mean``/``max`` E-MVPs as text; high MVPs in parentheses if ``multi``."""
    out = {}
    for key, fn in (("min", np.min), ("median", np.median), ("mean", np.mean), ("max", np.max)):
        if ok.empty:
            out[key] = "-"
            continue
        e = f"{fn(ok['emvps'].astype(float)):.3g}"
        out[key] = f"{e} ({fn(ok['mvps'].astype(float)):.3g})" if multi else e
    return out


def app_cost_median(ok: pd.DataFrame) -> str:
    """Median application-weighted cost of the solved runs as text (``app_cost``: inner
    applications weighted by their cost, in high products at their cold applications);
    ``-`` for stores written before the column existed or without solved runs."""
    if "app_cost" not in ok.columns:
        return "-"
    v = pd.to_numeric(ok["app_cost"], errors="coerce").dropna()
    return f"{float(v.median()):.3g}" if len(v) else "-"


def framework_median(g: pd.DataFrame) -> str:
    """Median products the framework made per run beside the solver's (``framework_mvps``:
    verification, probes, confirmations) as text; ``-`` for stores written before the column."""
    if "framework_mvps" not in g.columns:
        return "-"
    v = pd.to_numeric(g["framework_mvps"], errors="coerce").dropna()
    return f"{float(v.median()):.3g}" if len(v) else "-"


def _both_solved_ratio(g: pd.DataFrame, base: pd.DataFrame) -> str:
    """``median(solver) / median(baseline)`` over the instances both solved, with the count."""
    mine, theirs = _by_instance(g), _by_instance(base)
    both = mine.index.intersection(theirs.index)
    if len(both) == 0:
        return f"- (0 of {len(g)} both solved)"
    den = float(theirs.loc[both].median())
    if den <= 0:
        return f"- (baseline median 0; {len(both)} of {len(g)} both solved)"
    return f"{float(mine.loc[both].median()) / den:.2f} ({len(both)} of {len(g)} both solved)"


def ranking_table(cut: pd.DataFrame, baseline: str, meta: dict | None = None) -> pd.DataFrame:
    """The offline table of one set on common ground, one row per solver.

    Columns: ``solver``; ``solved`` (``k/m``) and ``success`` (%), over the compared
    instances; ``min``, ``median``, ``mean``, ``max`` E-MVPs over the solved runs (high
    MVPs in parentheses for multi-fidelity solvers); ``median / <baseline>`` over the
    instances both solved with the count; ``shifted GM`` (every run, failures at the
    penalty) and ``shifted GM / best``; ``median app. cost`` (the median
    application-weighted cost of the solved runs, :func:`app_cost_median`); ``median
    framework products`` (the framework's own products per run, every run,
    :func:`framework_median`). Rows: the baseline first, then single- and
    multi-fidelity solvers, each alphabetical.
    """
    if cut.empty:
        return pd.DataFrame()
    pen = penalty(cut, "emvps", meta)
    base = cut[cut["solver"] == baseline]
    rows = []
    for solver, g in cut.groupby("solver", sort=True):
        ok_mask = truthy(g["solved"])
        multi = bool(truthy(g["multifidelity"]).any())
        row: dict[str, Any] = {"solver": str(solver),
                               "solved": f"{int(ok_mask.sum())}/{len(g)}",
               "success": f"{100.0 * ok_mask.mean():.0f} %"}
        row.update(emvp_stats(g[ok_mask], multi))
        row["median app. cost"] = app_cost_median(g[ok_mask])
        row["median framework products"] = framework_median(g)
        row[f"median / {baseline}"] = (_both_solved_ratio(g, base) if len(base)
                                       else "- (baseline not run)")
        row["shifted GM"] = shifted_geomean(pd.to_numeric(g["emvps"], errors="coerce"),
                                            ok_mask, pen, SHIFT["emvps"])
        row["_multi"] = multi
        rows.append(row)
    out = pd.DataFrame(rows)
    best = out["shifted GM"].min()
    out["shifted GM / best"] = [f"{v / best:.2f}" if best > 0 else "-" for v in out["shifted GM"]]
    out["shifted GM"] = [f"{v:.3g}" for v in out["shifted GM"]]
    order = sorted(range(len(out)), key=lambda i: (out["solver"].iloc[i] != baseline,
                                                   bool(out["_multi"].iloc[i]),
                                                   out["solver"].iloc[i]))
    out = out.iloc[order].drop(columns="_multi")
    out.attrs["penalty"] = pen
    return out.reset_index(drop=True)


def references_table(results: pd.DataFrame) -> pd.DataFrame:
    """The reference QP solvers apart: wall time and accuracy, per problem set and solver.

    Columns: ``problem``, ``solver``, ``solved`` (verified, ``k/m``), ``median s``,
    ``median residual`` (the framework's verified ``||min(x, Ax+b)||``, which needs no
    reference), ``reference made of`` (the most frequent source of the set's reference:
    the consensus members, or a stored or planted solution), ``in consensus`` (on how
    many instances the solver was one of the consensus that defines the reference) and
    ``error of w vs the others`` (median relative error of ``w`` against a reference that
    excludes this solver: the set's reference where it was not a member, else the best
    answer of the other backends (leave one out); ``-`` when no other answer exists).
    """
    off = _offline(results)
    if off.empty:
        return pd.DataFrame()
    ref = off[_is_reference(off)]
    rows = []
    for (problem, solver), g in ref.groupby(["problem", "solver"], sort=True):
        name = str(g["solver_name"].iloc[0]) if "solver_name" in g else str(solver)
        members = g.get("ref_solvers", pd.Series("", index=g.index)).fillna("").astype(str)
        inside = members.map(lambda s, name=name: name in [x.strip() for x in s.split(",")])
        err = pd.to_numeric(g["ref_err_w"], errors="coerce") if "ref_err_w" in g \
            else pd.Series(np.nan, index=g.index)
        if "ref_err_w_others" in g:          # leave one out: against the other backends
            err = err.where(~inside, pd.to_numeric(g["ref_err_w_others"], errors="coerce"))
        else:
            err = err.where(~inside)
        outside = err.dropna()
        res = pd.to_numeric(g.get("verified_kkt_abs"), errors="coerce").dropna()
        rows.append({"problem": str(problem), "solver": str(solver),
                     "solved": f"{int(truthy(g['solved']).sum())}/{len(g)}",
                     "median s": f"{pd.to_numeric(g['time_s'], errors='coerce').median():.3g}",
                     "median residual": f"{res.median():.2e}" if len(res) else "-",
                     "reference made of": (members[members != ""].mode().iloc[0]
                                           if (members != "").any() else "-"),
                     "in consensus": f"{int(inside.sum())}/{len(g)}",
                     "error of w vs the others": (f"{outside.median():.2e} ({len(outside)})"
                                                  if len(outside) else "-")})
    return pd.DataFrame(rows)
