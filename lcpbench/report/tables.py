"""Summary tables computed from a run store (pure pandas, no plotting).

Every function takes the ``results.csv`` (and ``history.csv``) frames and
returns a DataFrame sorted deterministically, so two reports diff cleanly.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd

from lcpbench.core.defaults import BASELINE_SOLVER

__all__ = ["offline_table", "paper_tables", "failures_table", "work_precision",
           "performance_profile", "online_table", "convergence_curves", "LEVELS",
           "solved_mask", "offline_runs", "work_precision_display", "online_runs",
           "online_common_steps", "online_paper_table", "online_step_rows", "lattice_side",
           "online_paper_display"]

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
    out: dict[str, object] = {"tau": taus}
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


def online_runs(results: pd.DataFrame) -> pd.DataFrame:
    """The finished online steps of a results frame.

    A step counts as finished when it has both its collision-resolution seconds
    (``time_s``) and its whole-step seconds (``sim_total_s``); the row of a step
    that stopped a simulation (diverged forces, a rejected configuration) has
    neither and is left out.
    """
    if results.empty or "kind" not in results.columns:
        return results.iloc[0:0]
    on = results[results["kind"] == "online"]
    if on.empty:
        return on
    t = pd.to_numeric(on["time_s"], errors="coerce")
    tot = pd.to_numeric(on.get("sim_total_s", pd.Series(np.nan, index=on.index)),
                        errors="coerce")
    return on[np.isfinite(t) & np.isfinite(tot)]


def lattice_side(problem_params) -> int | None:
    """The lattice side ``m`` of a scene (``M = m^3`` particles) from its stored parameters.

    ``problem_params`` is the JSON text that ``lcpbench simulate`` stores per row;
    ``None`` when it is missing, unreadable or has no integer ``m``.
    """
    if not isinstance(problem_params, str):
        return None
    try:
        m = json.loads(problem_params).get("m")
    except (ValueError, AttributeError):
        return None
    return int(m) if isinstance(m, (int, np.integer)) and not isinstance(m, bool) else None


def _online_solver_order(on: pd.DataFrame, baseline: str) -> list[str]:
    """Solvers of the online rows: the baseline first, then the others as in the offline tables."""
    groups = sorted((g for _, g in on.groupby("solver", sort=True)), key=_solver_order)
    names = [str(g["solver"].iloc[0]) for g in groups]
    return sorted(names, key=lambda s: s != baseline)


def _scene_order(on: pd.DataFrame) -> list[str]:
    """Scenes sorted by lattice side (scenes without one last), then by name."""
    side = {str(p): lattice_side(g["problem_params"].iloc[0]) if "problem_params" in g else None
            for p, g in on.groupby("problem", sort=True)}
    return sorted(side, key=lambda p: (side[p] is None, side[p] or 0, p))


def online_common_steps(results: pd.DataFrame) -> dict[str, dict]:
    """Per scene, the steps every one of its simulations finished.

    Simulations are resumable and may be unfinished, so solvers of one scene are
    compared over the steps they all finished, never over unequal step ranges.

    Returns
    -------
    dict
        ``{scene: {"steps": sorted list of common step indices,
        "stored": {solver: finished steps stored}}}``.
    """
    on = online_runs(results)
    out = {}
    for scene, part in on.groupby("problem", sort=True):
        per = {str(s): set(pd.to_numeric(g["step"]).astype(int))
               for s, g in part.groupby("solver", sort=True)}
        common = set.intersection(*per.values()) if per else set()
        out[str(scene)] = {"steps": sorted(common),
                           "stored": {s: len(v) for s, v in per.items()}}
    return out


def online_step_rows(results: pd.DataFrame) -> pd.DataFrame:
    """The finished online steps cut to each scene's common steps, with a ``size`` label.

    ``size`` is ``"3x3x3"`` for a lattice of side 3 (the scene's name when it
    has no lattice side); ``M`` the number of particles (``m^3``, NaN without a
    side). Rows are ordered by lattice side, scene, solver and step.
    """
    on = online_runs(results)
    if on.empty:
        return on
    common = online_common_steps(on)
    keep = [int(r_step) in common[str(scene)]["steps"] for scene, r_step in
            zip(on["problem"], on["step"])]
    cut = on[np.asarray(keep, dtype=bool)].copy()
    sides = {p: lattice_side(g["problem_params"].iloc[0]) if "problem_params" in g else None
             for p, g in cut.groupby("problem", sort=True)}
    labels = {p: f"{m}x{m}x{m}" if m is not None else str(p) for p, m in sides.items()}
    if len(set(labels.values())) < len(labels):      # two scenes of one size: keep them apart
        labels = {p: f"{lab} ({p})" if sides[p] is not None else lab for p, lab in labels.items()}
    cut["size"] = cut["problem"].map(labels)
    cubes = {p: float(m ** 3) if m is not None else np.nan for p, m in sides.items()}
    cut["M"] = cut["problem"].map(cubes)
    order = {p: i for i, p in enumerate(_scene_order(cut))}
    cut["_o"] = cut["problem"].map(order)
    return cut.sort_values(["_o", "problem", "solver", "step"]).drop(columns="_o") \
        .reset_index(drop=True)


def online_paper_table(results: pd.DataFrame, baseline: str = BASELINE_SOLVER) -> pd.DataFrame:
    """The paper's online table: one row per scene, over the steps all its solvers finished.

    Columns: ``scene``, ``lattice size`` (``3x3x3``), ``M`` (particles), ``steps``
    (the common steps compared); the baseline's summed total and
    collision-resolution seconds; for every other solver its total and
    collision-resolution speedup against the baseline (the baseline's summed
    seconds divided by the solver's, NaN without a baseline run on the scene);
    then the median E-MVPs and median high-fidelity MVPs per step of every
    solver. Total seconds are the whole step (``sim_total_s``), collision
    resolution the LCP solve (``time_s``).

    ``attrs["stored"]`` maps each scene to ``{solver: finished steps stored}``
    so a caption can say where a simulation was cut; ``attrs["solvers"]`` is
    the solver order of the columns (the baseline first).
    """
    rows_in = online_step_rows(results)
    if rows_in.empty:
        return pd.DataFrame()
    solvers = _online_solver_order(rows_in, baseline)
    stored = {k: v["stored"] for k, v in online_common_steps(results).items()}
    rows = []
    for scene in _scene_order(rows_in):
        part = rows_in[rows_in["problem"] == scene]
        m = lattice_side(part["problem_params"].iloc[0]) if "problem_params" in part else None
        row = {"scene": scene, "lattice size": f"{m}x{m}x{m}" if m is not None else "-",
               "M": m ** 3 if m is not None else np.nan,
               "steps": int(part["step"].nunique())}
        sums = {s: (float(pd.to_numeric(g["sim_total_s"]).sum()),
                    float(pd.to_numeric(g["time_s"]).sum()))
                for s, g in part.groupby("solver", sort=True)}
        base = sums.get(baseline)
        row[f"{baseline} total s"] = base[0] if base else np.nan
        row[f"{baseline} collision s"] = base[1] if base else np.nan
        for s in solvers:
            if s == baseline:
                continue
            mine = sums.get(s)
            for j, what in ((0, "total"), (1, "collision")):
                row[f"{s} {what} speedup"] = (base[j] / mine[j] if base is not None
                                              and mine is not None and mine[j] > 0 else np.nan)
        for s in solvers:
            g = part[part["solver"] == s]
            for col, what in (("emvps", "median E-MVPs"), ("mvps", "median MVPs")):
                v = pd.to_numeric(g[col], errors="coerce").dropna()
                row[f"{s} {what}"] = float(v.median()) if len(v) else np.nan
        rows.append(row)
    out = pd.DataFrame(rows)
    out.attrs["stored"] = stored
    out.attrs["solvers"] = solvers
    return out


def online_paper_display(paper: pd.DataFrame) -> pd.DataFrame:
    """:func:`online_paper_table` as text for the page: seconds to 4 digits, speedups as ``1.70x``.

    Missing values (no baseline run on a scene, no lattice side) become ``-``.
    """
    if paper is None or paper.empty:
        return pd.DataFrame()

    def fmt(col: str, v) -> str:
        if v is None or (isinstance(v, float) and not np.isfinite(v)):
            return "-"
        if col.endswith(" speedup"):
            return f"{float(v):.2f}x"
        if col.endswith(" s"):
            return f"{float(v):.0f}" if abs(float(v)) >= 1000 else f"{float(v):.4g}"
        if col.startswith("median") or " median " in col:
            return f"{float(v):.3g}"
        if col == "M":
            return str(int(v))
        return str(v)

    return pd.DataFrame({c: [fmt(c, v) for v in paper[c]] for c in paper.columns})


def online_table(results: pd.DataFrame, baseline: str = BASELINE_SOLVER) -> pd.DataFrame:
    """Every online simulation in detail: one row per scene and solver, over all its steps.

    Per scene (sorted by lattice side) and solver (the baseline first): the
    finished steps stored, summed total and collision-resolution seconds, median
    E-MVPs and high-fidelity MVPs per step, the largest overlap and the steps
    solved (verified). Simulations of one scene may have different step counts
    here; :func:`online_paper_table` compares them over their common steps.
    """
    on = online_runs(results)
    if on.empty:
        return pd.DataFrame()
    solvers = _online_solver_order(on, baseline)
    rows = []
    for scene in _scene_order(on):
        part = on[on["problem"] == scene]
        for s in solvers:
            g = part[part["solver"] == s]
            if g.empty:
                continue
            rows.append({
                "problem": scene, "solver": s, "steps": int(len(g)),
                "total_s": float(pd.to_numeric(g["sim_total_s"]).sum()),
                "collision_s": float(pd.to_numeric(g["time_s"]).sum()),
                "median_emvps": float(pd.to_numeric(g["emvps"], errors="coerce").median()),
                "median_mvps": float(pd.to_numeric(g["mvps"], errors="coerce").median()),
                "max_overlap": float(pd.to_numeric(g["max_overlap"], errors="coerce").max()),
                "solved": int(_truthy(g["solved"]).sum())})
    return pd.DataFrame(rows)
