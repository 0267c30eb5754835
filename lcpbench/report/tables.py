"""Summary tables computed from a run store (pure pandas, no plotting).

Every function takes the ``results.csv`` (and ``history.csv``) frames and
returns a DataFrame sorted deterministically, so two reports diff cleanly.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER

__all__ = ["offline_table", "paper_tables", "failures_table", "work_precision",
           "performance_profile", "online_table", "convergence_curves", "LEVELS",
           "solved_mask", "offline_runs", "work_precision_display"]

#: Residual levels of the work-precision table (absolute ``||min(x, Ax+b)||``).
LEVELS = (1e-2, 1e-4, 1e-6, 1e-8)


def _truthy(series: pd.Series) -> pd.Series:
    return series.astype(str).str.lower().isin(("true", "1", "1.0"))


def solved_mask(results: pd.DataFrame) -> pd.Series:
    """Runs whose verified residual met the tolerance (the only "success")."""
    return _truthy(results["solved"])


def offline_runs(results: pd.DataFrame) -> pd.DataFrame:
    """The offline rows of a results frame (``kind`` empty counts as offline)."""
    return results[results["kind"].fillna("offline") == "offline"]


def offline_table(results: pd.DataFrame) -> pd.DataFrame:
    """Long form of the offline comparison: one row per problem set and solver.

    Per problem set and solver: min / median / mean / max E-MVPs over the
    verified-solved runs, with high-fidelity MVPs in parentheses for
    multi-fidelity solvers; the share of runs solved (verified); median seconds;
    median error of ``w`` against the reference. Written as ``tables/offline.csv``;
    the page shows :func:`paper_tables` instead.
    """
    off = offline_runs(results).copy()
    if off.empty:
        return pd.DataFrame()
    off["ok"] = solved_mask(off)
    rows = []
    for (problem, solver), g in off.groupby(["problem", "solver"], sort=True):
        ok = g[g["ok"]]
        multi = _truthy(g["multifidelity"]).any()
        stats = _emvp_stats(ok, multi)
        rows.append({
            "problem": problem, "solver": solver, "runs": len(g),
            "solved": f"{len(ok)}/{len(g)}",
            "success_rate": round(len(ok) / len(g), 3),
            "emvps_min": stats["min"], "emvps_median": stats["median"],
            "emvps_mean": stats["mean"], "emvps_max": stats["max"],
            "median_seconds": float(np.round(g["time_s"].astype(float).median(), 6)),
            "median_ref_err_w": _median_sci(g.get("ref_err_w")),
            "false_converged": int(_truthy(g["false_convergence"]).sum()),
        })
    return pd.DataFrame(rows)


def _emvp_stats(ok: pd.DataFrame, multi: bool) -> dict[str, str]:
    """``min``/``median``/``mean``/``max`` E-MVPs as text; high MVPs in parentheses if ``multi``."""
    out = {}
    for key, fn in (("min", np.min), ("median", np.median), ("mean", np.mean), ("max", np.max)):
        if ok.empty:
            out[key] = "-"
            continue
        e = f"{fn(ok['emvps'].astype(float)):.3g}"
        out[key] = f"{e} ({fn(ok['mvps'].astype(float)):.3g})" if multi else e
    return out


def _solver_order(g: pd.DataFrame) -> tuple:
    """Baselines first, then the multi-fidelity solvers, each alphabetical."""
    multi = bool(_truthy(g["multifidelity"]).any())
    return (multi, str(g["solver"].iloc[0]))


def paper_tables(results: pd.DataFrame, baseline: str = BASELINE_SOLVER) -> dict[str, pd.DataFrame]:
    """The paper's offline table, one per problem set: solver rows, E-MVP statistics.

    Only MVP-only solvers appear (the reference QP solvers work on the dense
    matrix and count no MVPs). Columns: ``solver``; ``solved`` (verified, out of
    the runs the solver was given); ``min``, ``median``, ``mean``, ``max`` E-MVPs
    over the solved runs, with the high-fidelity MVPs in parentheses for
    multi-fidelity solvers; ``median / <baseline>``, the solver's median E-MVPs
    divided by the baseline's on the same set (``-`` without a baseline run).

    Returns
    -------
    dict
        ``{problem: DataFrame}``, problems sorted by name.
    """
    off = offline_runs(results)
    off = off[_truthy(off["mvp_only"])].copy()
    if off.empty:
        return {}
    off["ok"] = solved_mask(off)
    out = {}
    for problem, p in off.groupby("problem", sort=True):
        base = p[(p["solver"] == baseline) & p["ok"]]["emvps"].astype(float)
        base_med = float(base.median()) if len(base) else np.nan
        groups = sorted((g for _, g in p.groupby("solver", sort=True)), key=_solver_order)
        rows = []
        for g in groups:
            ok = g[g["ok"]]
            multi = bool(_truthy(g["multifidelity"]).any())
            row = {"solver": str(g["solver"].iloc[0]), "solved": f"{len(ok)}/{len(g)}"}
            row.update(_emvp_stats(ok, multi))
            med = float(ok["emvps"].astype(float).median()) if len(ok) else np.nan
            ratio = med / base_med if np.isfinite(med) and np.isfinite(base_med) and base_med > 0 \
                else np.nan
            row[f"median / {baseline}"] = f"{ratio:.2f}" if np.isfinite(ratio) else "-"
            rows.append(row)
        out[str(problem)] = pd.DataFrame(rows)
    return out


def _median_sci(col) -> str:
    if col is None:
        return "-"
    v = pd.to_numeric(col, errors="coerce").dropna()
    return f"{v.median():.2e}" if len(v) else "-"


def failures_table(results: pd.DataFrame) -> pd.DataFrame:
    """Every run that was not verified-solved: status, message, instance."""
    bad = results[~solved_mask(results)]
    cols = ["problem", "instance", "solver", "status", "message", "verified_kkt_abs", "threshold"]
    return bad.reindex(columns=cols).sort_values(["problem", "instance", "solver"]) \
        .reset_index(drop=True)


def _residual(history: pd.DataFrame) -> pd.Series:
    """Verified residual per iterate where recorded, else the solver's own."""
    v = pd.to_numeric(history["kkt_abs_verified"], errors="coerce")
    return v.fillna(pd.to_numeric(history["kkt_abs"], errors="coerce"))


def work_precision(results: pd.DataFrame, history: pd.DataFrame,
                   levels=LEVELS) -> pd.DataFrame:
    """Median E-MVPs and seconds to first reach each residual level, per solver.

    Only the runs a solver was given count (a multi-fidelity solver is not run
    on instances without a low fidelity): ``reached@level`` is ``k/m`` over those
    ``m`` runs. Also the median final error of ``w`` against the reference.
    """
    if history.empty or results.empty:
        return pd.DataFrame()
    h = history.copy()
    h["res"] = _residual(h)
    meta = results.set_index("run_id")[["solver", "problem"]]
    h = h.join(meta, on="run_id", how="inner")
    rows = []
    for solver, g in h.groupby("solver", sort=True):
        row = {"solver": solver}
        runs = g["run_id"].nunique()
        for lv in levels:
            hit = g[g["res"] <= lv].groupby("run_id").first()
            row[f"emvps@{lv:.0e}"] = float(np.round(hit["emvps"].median(), 2)) if len(hit) else None
            row[f"s@{lv:.0e}"] = float(np.round(hit["time_s"].median(), 6)) if len(hit) else None
            row[f"reached@{lv:.0e}"] = f"{len(hit)}/{runs}"
        r = results[results["solver"] == solver]
        row["median_ref_err_w"] = _median_sci(r.get("ref_err_w"))
        rows.append(row)
    return pd.DataFrame(rows)


def work_precision_display(wp: pd.DataFrame) -> pd.DataFrame:
    """:func:`work_precision` folded for the page: one cell per level, ``E-MVPs · s · k/m``."""
    if wp is None or wp.empty:
        return pd.DataFrame()
    levels = [c.split("@", 1)[1] for c in wp.columns if c.startswith("emvps@")]
    rows = []
    for _, r in wp.iterrows():
        row = {"solver": r["solver"]}
        for lv in levels:
            e, s = r[f"emvps@{lv}"], r[f"s@{lv}"]
            if e is None or not np.isfinite(float(e)):
                row[f"to {lv}"] = f"never ({r[f'reached@{lv}']})"
            else:
                row[f"to {lv}"] = f"{float(e):.3g} E-MVPs, {float(s):.2g} s ({r[f'reached@{lv}']})"
        row["median error of w"] = r["median_ref_err_w"]
        rows.append(row)
    return pd.DataFrame(rows)


def performance_profile(results: pd.DataFrame, metric: str = "emvps",
                        taus: np.ndarray | None = None) -> pd.DataFrame:
    """Dolan-More performance profile over the problems each solver was given.

    A problem is one (problem, instance, repeat). A run that was made and not
    solved counts as never solved; a problem a solver was not run on (a
    multi-fidelity solver on an instance without a low fidelity) is left out of
    that solver's share instead of counting as a failure. Reference (dense)
    solvers are left out of the E-MVP profile.

    Returns
    -------
    DataFrame
        ``tau`` and one column per solver (share of its problems within ``tau``
        of the best); ``attrs["given"]`` maps each solver to how many of the
        problems it was run on and ``attrs["problems"]`` is their total.
    """
    r = offline_runs(results).copy()
    if metric == "emvps":
        r = r[_truthy(r["mvp_only"])]
    if r.empty:
        return pd.DataFrame()
    r["value"] = np.where(solved_mask(r), pd.to_numeric(r[metric], errors="coerce"), np.inf)
    r["value"] = r["value"].where(r["value"] > 0, 1e-12)
    piv = r.pivot_table(index=["problem", "instance", "repeat"], columns="solver",
                        values="value", aggfunc="min")
    best = piv.min(axis=1)
    ratio = piv.div(best.where(np.isfinite(best)), axis=0)
    taus = np.logspace(0, 3, 61) if taus is None else taus
    out = {"tau": taus}
    given = {}
    for s in sorted(piv.columns):
        made = piv[s].notna().to_numpy()
        vals = ratio[s].to_numpy()[made]
        vals = np.where(np.isnan(vals), np.inf, vals)   # solved by nobody: never within tau
        given[s] = int(made.sum())
        out[s] = [float(np.mean(vals <= t)) if len(vals) else np.nan for t in taus]
    df = pd.DataFrame(out)
    df.attrs["given"] = given
    df.attrs["problems"] = int(len(piv))
    return df


def convergence_curves(results: pd.DataFrame, history: pd.DataFrame, x: str = "emvps",
                       points: int = 60, by: str | None = None) -> dict:
    """Median and 25-75 % band of log10 residual against ``x``, per solver.

    With ``by`` (a results column such as ``family``) the curves are computed per
    value of it: ``{value: {solver: curve}}``. The grid is logarithmic from the
    first positive ``x`` any run reached to the largest, so a log axis shows it
    all; each curve stops where its longest run stopped.
    """
    if history.empty:
        return {}
    if by is not None:
        out = {}
        for value, part in results.groupby(by, sort=True):
            c = convergence_curves(part, history[history["run_id"].isin(part["run_id"])], x,
                                   points)
            if c:
                out[str(value)] = c
        return out
    h = history.copy()
    h["res"] = _residual(h).clip(lower=1e-20)   # an exact 0 would plot at -inf
    h = h.join(results.set_index("run_id")[["solver"]], on="run_id", how="inner")
    xs_all = pd.to_numeric(h[x], errors="coerce")
    positive = xs_all[xs_all > 0]
    if positive.empty:
        return {}
    x0 = float(positive.min())
    curves = {}
    for solver, g in h.groupby("solver", sort=True):
        xmax = float(pd.to_numeric(g[x], errors="coerce").max())
        if not np.isfinite(xmax) or xmax <= x0:
            continue
        grid = np.geomspace(x0, xmax, points)
        runs = []
        for _, run in g.groupby("run_id"):
            xs = run[x].to_numpy(dtype=float)
            ys = np.log10(run["res"].to_numpy(dtype=float))
            idx = np.searchsorted(xs, grid, side="right") - 1
            val = np.where(idx >= 0, ys[np.clip(idx, 0, None)], np.nan)
            val[grid > xs[-1]] = ys[-1]   # a finished run stays at its final residual
            runs.append(val)
        arr = np.vstack(runs)
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            curves[solver] = {"x": grid, "median": np.nanmedian(arr, axis=0),
                              "lo": np.nanquantile(arr, 0.25, axis=0),
                              "hi": np.nanquantile(arr, 0.75, axis=0),
                              "runs": len(runs)}
    return curves


def online_table(results: pd.DataFrame, baseline: str = BASELINE_SOLVER) -> pd.DataFrame:
    """The paper's online table: total and collision-resolution seconds per scene and solver.

    Speedups are the baseline's times divided by the solver's (``-`` when
    the baseline did not run on the scene).
    """
    on = results[results["kind"] == "online"]
    if on.empty:
        return pd.DataFrame()
    agg = on.groupby(["problem", "solver"], sort=True).agg(
        steps=("step", "count"), total_s=("sim_total_s", "sum"), collision_s=("time_s", "sum"),
        median_emvps=("emvps", "median"), max_overlap=("max_overlap", "max"),
        solved=("solved", lambda s: int(_truthy(s).sum()))).reset_index()
    rows = []
    for _, r in agg.iterrows():
        base = agg[(agg["problem"] == r["problem"]) & (agg["solver"] == baseline)]
        sp_t = sp_c = "-"
        if len(base):
            sp_t = f"{float(base['total_s'].iloc[0]) / max(r['total_s'], 1e-12):.2f}"
            sp_c = f"{float(base['collision_s'].iloc[0]) / max(r['collision_s'], 1e-12):.2f}"
        rows.append({**r.to_dict(), "total_s": round(float(r["total_s"]), 3),
                     "collision_s": round(float(r["collision_s"]), 3),
                     f"speedup_total_vs_{baseline}": sp_t,
                     f"speedup_collision_vs_{baseline}": sp_c})
    return pd.DataFrame(rows)
