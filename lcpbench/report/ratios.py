"""Per-instance ratios to the baseline: the magnitudes the first screen and the paper section show.

A solver's ratio on one instance is its E-MVPs divided by the baseline's on the same
instance (and repeat). Ratios are taken over the instances the baseline solved with a
positive cost; where the solver did not solve such an instance its ratio is infinite, so
a solver that fails often has a large median and never looks cheap by its successes
alone. The median, the quartiles (25 % and 75 %) and the solved count are computed once
here; the summary names as best the solver with the lowest median ratio, the statistic it
shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from lcpbench.report.ranking import truthy

__all__ = ["RatioStats", "instance_ratios", "ratio_stats", "best_by_ratio", "format_ratio",
           "ratio_matrix"]


@dataclass(frozen=True)
class RatioStats:
    """One solver's ratios to the baseline on one set.

    Attributes
    ----------
    solver : str
        The solver spec.
    median, q25, q75 : float
        Median and quartiles of the per-instance ratios (``inf`` where the solver did not
        solve; NaN when no instance has a ratio).
    ratios : int
        Instances with a ratio (the baseline solved them at a positive cost).
    solved, runs : int
        The solver's verified-solved runs and its runs, over the compared instances.
    """

    solver: str
    median: float
    q25: float
    q75: float
    ratios: int
    solved: int
    runs: int


#: Stands for an infinite ratio inside the quantile (which cannot interpolate infinities).
_HUGE = 1e300


def _keyed(g: pd.DataFrame) -> pd.DataFrame:
    rep = (pd.to_numeric(g["repeat"], errors="coerce").fillna(0).astype(int)
           if "repeat" in g else pd.Series(0, index=g.index))
    return pd.DataFrame({"key": list(zip(g["instance"].astype(str), rep)),
                         "emvps": pd.to_numeric(g["emvps"], errors="coerce").to_numpy(),
                         "solved": truthy(g["solved"]).to_numpy()})


def instance_ratios(cut: pd.DataFrame, solver: str, baseline: str) -> np.ndarray:
    """The per-instance ratios of ``solver`` to ``baseline`` in ``cut`` (one set's runs).

    Over the (instance, repeat) pairs the baseline solved at a positive E-MVP cost; the
    ratio is ``inf`` where ``solver`` did not solve the pair or has no run of it.
    """
    base = _keyed(cut[cut["solver"] == baseline])
    base = base[base["solved"] & (base["emvps"] > 0)].set_index("key")["emvps"]
    mine = _keyed(cut[cut["solver"] == solver])
    mine = mine[mine["solved"]].set_index("key")["emvps"]
    out = [float(mine[k]) / float(b) if k in mine.index else np.inf for k, b in base.items()]
    return np.asarray(out, dtype=float)


def _quantile(r: np.ndarray, q: float) -> float:
    if r.size == 0:
        return np.nan
    finite = r[np.isfinite(r)]
    v = float(np.quantile(np.where(np.isfinite(r), r, _HUGE), q))
    return np.inf if finite.size == 0 or v > float(finite.max()) else v


def ratio_stats(cut: pd.DataFrame, baseline: str) -> list[RatioStats]:
    """:class:`RatioStats` of every solver of ``cut`` (one set on common ground), sorted by
    median ratio, then name; empty when the baseline has no run in ``cut``."""
    if cut.empty or not (cut["solver"] == baseline).any():
        return []
    out = []
    for solver, g in cut.groupby("solver", sort=True):
        r = np.sort(instance_ratios(cut, str(solver), baseline))
        out.append(RatioStats(str(solver), _quantile(r, 0.5), _quantile(r, 0.25),
                              _quantile(r, 0.75), int(r.size),
                              int(truthy(g["solved"]).sum()), len(g)))
    return sorted(out, key=lambda s: (np.nan_to_num(s.median, nan=np.inf), s.solver))


def best_by_ratio(stats: list[RatioStats]) -> RatioStats | None:
    """The solver with the lowest finite median ratio (the first of :func:`ratio_stats`),
    or None when no solver has one."""
    finite = [s for s in stats if np.isfinite(s.median)]
    return finite[0] if finite else None


def _num(v: float) -> str:
    if np.isnan(v):
        return "-"
    return "unsolved" if np.isinf(v) else f"{v:.2f}"


def format_ratio(s: RatioStats) -> str:
    """``0.42 [0.38-0.47], 20/20 solved``: median [quartiles], solved count."""
    return f"{_num(s.median)} [{_num(s.q25)}-{_num(s.q75)}], {s.solved}/{s.runs} solved"


def ratio_matrix(per_set: dict[str, list[RatioStats]], max_sets: int = 3
                 ) -> list[pd.DataFrame]:
    """Solvers down, sets across, :func:`format_ratio` in each cell: one table per group
    of at most ``max_sets`` sets (so each stays narrow), its last row the best of each set."""
    names = list(per_set)
    tables = []
    for start in range(0, len(names), max_sets):
        group = names[start:start + max_sets]
        solvers = sorted({s.solver for n in group for s in per_set[n]})
        rows = []
        for solver in solvers:
            row = {"solver": solver}
            for n in group:
                hit = [s for s in per_set[n] if s.solver == solver]
                row[n] = format_ratio(hit[0]) if hit else "-"
            rows.append(row)
        best = {"solver": "best (lowest median ratio)"}
        for n in group:
            b = best_by_ratio(per_set[n])
            best[n] = b.solver if b is not None else "-"
        rows.append(best)
        tables.append(pd.DataFrame(rows, columns=["solver", *group]))
    return tables
