"""Summary tables computed from a run store (pure pandas, no plotting).

Every function takes the ``results.csv`` (and ``history.csv``) frames and
returns a DataFrame sorted deterministically, so two reports diff cleanly.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER

__all__ = ["offline_table", "failures_table", "work_precision", "performance_profile",
           "online_table", "convergence_curves", "LEVELS", "solved_mask"]

#: Residual levels of the work-precision table (absolute ``||min(x, Ax+b)||``).
LEVELS = (1e-2, 1e-4, 1e-6, 1e-8)


def _truthy(series: pd.Series) -> pd.Series:
    return series.astype(str).str.lower().isin(("true", "1", "1.0"))


def solved_mask(results: pd.DataFrame) -> pd.Series:
    """Runs whose verified residual met the tolerance (the only "success")."""
    return _truthy(results["solved"])


def offline_table(results: pd.DataFrame) -> pd.DataFrame:
    """The paper's offline table (section "Offline Comparison") plus accuracy columns.

    Per problem set and solver: min / median / mean / max E-MVPs over the
    verified-solved runs, with high-fidelity MVPs in parentheses for
    multi-fidelity solvers; the share of runs solved (verified); median seconds;
    median error of ``w`` against the reference.
    """
    off = results[results["kind"].fillna("offline") == "offline"].copy()
    if off.empty:
        return pd.DataFrame()
    off["ok"] = solved_mask(off)
    rows = []
    for (problem, solver), g in off.groupby(["problem", "solver"], sort=True):
        ok = g[g["ok"]]
        multi = _truthy(g["multifidelity"]).any()

        def fmt(fn):
            if ok.empty:
                return "-"
            e = f"{fn(ok['emvps'].astype(float)):.1f}"
            return f"{e} ({fn(ok['mvps'].astype(float)):.1f})" if multi else e

        rows.append({
            "problem": problem, "solver": solver, "runs": len(g),
            "solved": f"{len(ok)}/{len(g)}",
            "success_rate": round(len(ok) / len(g), 3),
            "emvps_min": fmt(np.min), "emvps_median": fmt(np.median),
            "emvps_mean": fmt(np.mean), "emvps_max": fmt(np.max),
            "median_seconds": float(np.round(g["time_s"].astype(float).median(), 6)),
            "median_ref_err_w": _median_sci(g.get("ref_err_w")),
            "false_converged": int(_truthy(g["false_convergence"]).sum()),
        })
    return pd.DataFrame(rows)


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

    Also the share of runs that reached the level and the median final
    error of ``w`` against the reference (speed against error).
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


def performance_profile(results: pd.DataFrame, metric: str = "emvps",
                        taus: np.ndarray | None = None) -> pd.DataFrame:
    """Dolan-More performance profile: share of problems within ``tau`` of the best.

    A problem is one (problem, instance, repeat); an unsolved run counts as
    infinitely slow. Reference (dense) solvers are left out of the E-MVP profile.
    """
    r = results[results["kind"].fillna("offline") == "offline"].copy()
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
    for s in sorted(piv.columns):
        vals = ratio[s].to_numpy()
        out[s] = [float(np.mean(vals <= t)) for t in taus]
    return pd.DataFrame(out)


def convergence_curves(results: pd.DataFrame, history: pd.DataFrame, x: str = "emvps",
                       points: int = 60) -> dict:
    """Median and 25-75 % band of log10 residual against ``x`` (emvps or time_s), per solver."""
    if history.empty:
        return {}
    h = history.copy()
    h["res"] = _residual(h).clip(lower=1e-20)   # an exact 0 would plot at -inf
    h = h.join(results.set_index("run_id")[["solver"]], on="run_id", how="inner")
    curves = {}
    for solver, g in h.groupby("solver", sort=True):
        xmax = float(g[x].max())
        if not np.isfinite(xmax) or xmax <= 0:
            continue
        grid = np.linspace(0, xmax, points)
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
                              "hi": np.nanquantile(arr, 0.75, axis=0)}
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
