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
from lcpbench.report.online_cost import with_model_emvps
from lcpbench.report.ranking import common_ground, emvp_stats, ranked_runs, ranking_table

__all__ = ["reach_table", "offline_table", "paper_tables", "failures_table", "work_precision",
           "performance_profile", "online_table", "convergence_curves", "LEVELS",
           "solved_mask", "offline_runs", "work_precision_display", "online_runs",
           "online_common_steps", "online_paper_table", "online_step_rows", "lattice_side",
           "online_paper_display", "online_left_out"]

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
        stats = emvp_stats(ok, multi)
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



def _solver_order(g: pd.DataFrame) -> tuple:
    """Baselines first, then the multi-fidelity solvers, each alphabetical."""
    multi = bool(_truthy(g["multifidelity"]).any())
    return (multi, str(g["solver"].iloc[0]))


def paper_tables(results: pd.DataFrame, baseline: str = BASELINE_SOLVER,
                 meta: dict | None = None) -> dict[str, pd.DataFrame]:
    """The paper's offline table per problem set, on common ground.

    Per problem set, the MVP-only, non-reference solvers over the instances every one of
    them was given (:func:`lcpbench.report.ranking.common_ground`); the table is
    :func:`lcpbench.report.ranking.ranking_table`, whose ``attrs`` carry the compared
    instance count (``instances``, ``total``) and the failure penalty.

    Returns
    -------
    dict
        ``{problem: DataFrame}``, problems sorted by name.
    """

    off = ranked_runs(results, "emvps")
    out: dict = {}
    if off.empty:
        return out
    for problem, part in off.groupby("problem", sort=True):
        cut, info = common_ground(part)
        table = ranking_table(cut, baseline, meta)
        table.attrs.update(info)
        out[str(problem)] = table
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


def reach_table(results: pd.DataFrame, history: pd.DataFrame, levels=LEVELS) -> pd.DataFrame:
    """Per run: the E-MVPs and seconds at which it first reached each residual level.

    One row per run of ``results`` (runs without history never reached any level):
    ``run_id``, ``solver``, ``instance``, ``repeat`` and ``emvps@L`` / ``s@L`` per level
    (NaN where the run never reached it).
    """
    cols = ["run_id", "solver", "instance", "repeat"]
    out = results.reindex(columns=cols).copy().reset_index(drop=True)
    h = history[history["run_id"].isin(out["run_id"])].copy() if not history.empty \
        else history
    if not h.empty:
        h["res"] = _residual(h)
    for lv in levels:
        key = f"{lv:.0e}"
        if h.empty:
            out[f"emvps@{key}"] = np.nan
            out[f"s@{key}"] = np.nan
            continue
        hit = h[h["res"] <= lv].groupby("run_id").first()
        out[f"emvps@{key}"] = out["run_id"].map(pd.to_numeric(hit["emvps"], errors="coerce"))
        out[f"s@{key}"] = out["run_id"].map(pd.to_numeric(hit["time_s"], errors="coerce"))
    return out


def work_precision(results: pd.DataFrame, history: pd.DataFrame,
                   levels=LEVELS) -> pd.DataFrame:
    """Median E-MVPs and seconds to first reach each residual level, per solver.

    Pass the runs of one problem set on common ground (the report does): every
    solver's ``reached@level`` is then ``k/m`` over the same ``m`` runs, counted from
    ``results`` (a run that left no history never reached a level). The medians are
    over the runs that reached the level. Also the median final error of ``w`` against
    the reference.
    """
    if results.empty:
        return pd.DataFrame()
    reach = reach_table(results, history, levels)
    rows = []
    for solver, g in reach.groupby("solver", sort=True):
        row = {"solver": solver}
        for lv in levels:
            key = f"{lv:.0e}"
            e = g[f"emvps@{key}"].dropna()
            t = g[f"s@{key}"].dropna()
            row[f"emvps@{key}"] = float(np.round(e.median(), 2)) if len(e) else None
            row[f"s@{key}"] = float(np.round(t.median(), 6)) if len(t) else None
            row[f"reached@{key}"] = f"{len(e)}/{len(g)}"
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
    that solver's share instead of counting as a failure; the report passes the runs of
    one problem set on common ground, where every solver was given every problem.
    Reference QP solvers are never profiled.

    The default ``taus`` run from 1 to just past the largest finite ratio, so the
    curves end where the data do; a failure stays below 1 at every ``tau``.

    Returns
    -------
    DataFrame
        ``tau`` and one column per solver (share of its problems within ``tau``
        of the best); ``attrs["given"]`` maps each solver to how many of the
        problems it was run on and ``attrs["problems"]`` is their total.
    """

    r = ranked_runs(results, metric).copy()
    if r.empty:
        return pd.DataFrame()
    r["value"] = np.where(solved_mask(r), pd.to_numeric(r[metric], errors="coerce"), np.inf)
    r["value"] = r["value"].where(r["value"] > 0, 1e-12)
    piv = r.pivot_table(index=["problem", "instance", "repeat"], columns="solver",
                        values="value", aggfunc="min")
    best = piv.min(axis=1)
    ratio = piv.div(best.where(np.isfinite(best)), axis=0)
    if taus is None:
        finite = ratio.to_numpy()[np.isfinite(ratio.to_numpy())]
        top = max(2.0, 1.05 * float(finite.max())) if finite.size else 2.0
        taus = np.geomspace(1.0, top, 61)
    out: dict = {"tau": taus}
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
    all; each curve stops where its longest run stopped. A residual of exactly 0 is
    drawn a decade below the smallest positive residual of the runs (``floor`` in each
    curve), never at a fixed tiny value.
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
    h = history[history["run_id"].isin(results["run_id"])].copy()
    if h.empty:
        return {}
    res = _residual(h)
    positive = res[res > 0]
    # an exact 0 would plot at -inf: draw it a decade below the smallest positive residual
    # of these runs, so the axis starts at the data
    floor = float(positive.min()) / 10.0 if len(positive) else 1e-16
    h["res"] = res.clip(lower=floor)
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
                              "runs": len(runs), "floor": floor}
    return curves


def online_runs(results: pd.DataFrame) -> pd.DataFrame:
    """The finished online steps of a results frame.

    A step counts as finished when it has both its collision-resolution seconds
    (``time_s``) and its whole-step seconds (``sim_total_s``); the row of a step
    that stopped a simulation (diverged forces, a rejected configuration) has
    neither and is left out. ``emvps`` is the cost model's where recorded, the timed
    E-MVPs in ``timed_emvps`` (:func:`lcpbench.report.online_cost.with_model_emvps`).
    """
    if results.empty or "kind" not in results.columns:
        return results.iloc[0:0]
    on = results[results["kind"] == "online"]
    if on.empty:
        return on
    t = pd.to_numeric(on["time_s"], errors="coerce")
    tot = pd.to_numeric(on.get("sim_total_s", pd.Series(np.nan, index=on.index)),
                        errors="coerce")
    return with_model_emvps(on[np.isfinite(t) & np.isfinite(tot)])


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


def _left_out_steps(on: pd.DataFrame) -> dict[str, dict[str, set]]:
    """Per scene, the steps kept out of the comparison: warm-up, without contacts, and
    without products.

    Warm-up: the first step each simulation stored (it pays the one-off compilation of
    the numerical kernels, seconds that say nothing about the solver). Without
    contacts: a step where some simulation of the scene had no contact (``n == 0``):
    there is no LCP to solve, so its seconds measure everything but the solver. Without
    products: a step with contacts that no simulation of the scene needed a single
    product for (every contact apart, so the solution ``x = 0`` is read off ``b``): its
    E-MVPs are 0 for every solver, and counting it would pull every median to 0.
    """
    out = {}
    for scene, part in on.groupby("problem", sort=True):
        steps = pd.to_numeric(part["step"]).astype(int)
        warm = set(steps.groupby(part["solver"]).min())
        n = pd.to_numeric(part.get("n", pd.Series(np.nan, index=part.index)), errors="coerce")
        empty = set(steps[n == 0])
        products = pd.Series(0.0, index=part.index)
        for col in ("mvps", "lofi_mvps_total"):
            if col in part:
                products += pd.to_numeric(part[col], errors="coerce").fillna(0.0)
        if "mvps" in part:
            worked = set(steps[products > 0])
            idle = set(steps) - worked
        else:                                     # stores without the counts: none apart
            idle = set()
        out[str(scene)] = {"warm-up": warm, "no contacts": empty - warm,
                           "no products": idle - empty - warm}
    return out


def online_step_rows(results: pd.DataFrame) -> pd.DataFrame:
    """The compared online steps of each scene, with a ``size`` label.

    The steps every simulation of the scene finished (:func:`online_common_steps`),
    less the warm-up steps and the steps without contacts (:func:`online_left_out`
    lists them apart). ``size`` is ``"3x3x3"`` for a lattice of side 3 (the scene's
    name when it has no lattice side); ``M`` the number of particles (``m^3``, NaN
    without a side). Rows are ordered by lattice side, scene, solver and step. The
    online table and the E-MVP box plot are both built from these rows.
    """
    on = online_runs(results)
    if on.empty:
        return on
    common = online_common_steps(on)
    apart = _left_out_steps(on)
    keep = [int(r_step) in common[str(scene)]["steps"]
            and all(int(r_step) not in v for v in apart[str(scene)].values())
            for scene, r_step in zip(on["problem"], on["step"])]
    cut = on[np.asarray(keep, dtype=bool)].copy()
    sides = {p: lattice_side(g["problem_params"].iloc[0]) if "problem_params" in g else None
             for p, g in on.groupby("problem", sort=True)}
    labels = {p: f"{m}x{m}x{m}" if m is not None else str(p) for p, m in sides.items()}
    if len(set(labels.values())) < len(labels):      # two scenes of one size: keep them apart
        labels = {p: f"{lab} ({p})" if sides[p] is not None else lab for p, lab in labels.items()}
    cut["size"] = cut["problem"].map(labels)
    cut["M"] = cut["problem"].map(lambda p: float(m ** 3) if (m := sides[p]) is not None
                                  else np.nan)
    order = {p: i for i, p in enumerate(_scene_order(on))}
    cut["_o"] = cut["problem"].map(order)
    return cut.sort_values(["_o", "problem", "solver", "step"]).drop(columns="_o") \
        .reset_index(drop=True)


def online_left_out(results: pd.DataFrame) -> pd.DataFrame:
    """The online steps kept out of the speedups, reported apart.

    One row per scene, solver and reason (``warm-up``, ``no contacts``, ``no products``):
    the steps and
    their summed whole-step and collision-resolution seconds. Empty when none.
    """
    on = online_runs(results)
    if on.empty:
        return pd.DataFrame()
    rows = []
    for scene, reasons in _left_out_steps(on).items():
        part = on[on["problem"] == scene]
        for solver, g in part.groupby("solver", sort=True):
            steps = pd.to_numeric(g["step"]).astype(int)
            for reason, which in reasons.items():
                sel = g[steps.isin(which)]
                if sel.empty:
                    continue
                rows.append({"scene": scene, "solver": str(solver), "reason": reason,
                             "steps": ",".join(str(k) for k in sorted(
                                 pd.to_numeric(sel["step"]).astype(int))),
                             "total s": float(pd.to_numeric(sel["sim_total_s"]).sum()),
                             "collision s": float(pd.to_numeric(sel["time_s"]).sum()),
                             "E-MVPs": float(pd.to_numeric(sel["emvps"], errors="coerce").sum())})
    return pd.DataFrame(rows)


def online_paper_table(results: pd.DataFrame, baseline: str = BASELINE_SOLVER) -> pd.DataFrame:
    """The paper's online table: one row per scene, over its compared steps.

    The compared steps are :func:`online_step_rows`: finished by every solver of the
    scene, warm-up steps and steps without contacts left out (see
    :func:`online_left_out`).

    Columns: ``scene``, ``lattice size`` (``3x3x3``), ``M`` (particles), ``steps``
    (the common steps compared); the baseline's summed total and
    collision-resolution seconds; for every other solver its total and
    collision-resolution speedup against the baseline (the baseline's summed
    seconds divided by the solver's, NaN without a baseline run on the scene);
    then the median E-MVPs, median high-fidelity MVPs and median
    application-weighted cost (``app_cost``: products weighted by the inner
    applications they took, in cold high products; NaN for stores written before
    it) and median per-step timed E-MVPs per step of every solver. Total seconds are the whole step (``sim_total_s``), collision
    resolution the LCP solve (``time_s``).

    ``attrs["stored"]`` maps each scene to ``{solver: finished steps stored}``
    so a caption can say where a simulation was cut; ``attrs["solvers"]`` is
    the solver order of the columns (the baseline first).
    """
    rows_in = online_step_rows(results)
    if rows_in.empty:
        out = pd.DataFrame()
        out.attrs["stored"] = {k: v["stored"] for k, v in online_common_steps(results).items()}
        return out
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
            for col, what in (("emvps", "median E-MVPs"), ("mvps", "median MVPs"),
                              ("app_cost", "median app cost"),
                              ("timed_emvps", "median timed E-MVPs")):
                v = (pd.to_numeric(g[col], errors="coerce").dropna() if col in g
                     else pd.Series(dtype=float))
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
    E-MVPs and high-fidelity MVPs per step, the median application-weighted cost
    per step (``app_cost``; NaN for stores written before it), the median framework
    products per step (``framework_mvps``, the same), the largest overlap
    and the steps solved (verified). Simulations of one scene may have different step counts
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
                "median_app_cost": (float(pd.to_numeric(g["app_cost"], errors="coerce").median())
                                    if "app_cost" in g else np.nan),
                "median_framework_mvps": (
                    float(pd.to_numeric(g["framework_mvps"], errors="coerce").median())
                    if "framework_mvps" in g else np.nan),
                "max_overlap": float(pd.to_numeric(g["max_overlap"], errors="coerce").max()),
                "solved": int(_truthy(g["solved"]).sum())})
    return pd.DataFrame(rows)
