"""``lcpbench check``: regression checks of the MVP-only solvers on the shipped sets.

Every MVP-only solver (not the reference QP solvers, not those that need the
dense matrix) runs with its default parameters on every instance of every
shipped set (``problems/data/*.h5``, or the sets named with ``--set``). A
multi-fidelity solver runs once per low fidelity of the set (``bi-pqn:low=p4``)
when the set has several, with its plain defaults when it has one, and not at
all on a set without low fidelities. A (set, solver) pair *regresses* when

* a verified residual ``||min(x, Ax+b)||`` exceeds the paper stop rule's bound at
  ``--tol`` (the run is not solved);
* the verified ``w = A x + b`` differs from the stored reference ``w`` by more
  than ``W_RTOL`` relative, ``||w - w_ref|| / max(||w_ref||, ||b||)``;
* the median E-MVP count over the set exceeds the stored baseline by more than
  ``EMVP_SLACK`` (10 %).

E-MVPs on stored sets use the cost ratios stored with the set, so they are the
same on every machine and a baseline means what it meant when it was written.

Baselines live in a versioned JSON file (default ``problems/data/baselines.json``)::

    {"format": "lcpbench.baselines", "version": 1, "lcpbench_version": "0.1.0",
     "updated": "2024-...", "tol": 1e-08,
     "sets": {"<set>": {"<solver spec>": <median E-MVPs>, ...}, ...}}

``lcpbench check --update-baseline`` rewrites the entries of the sets it ran
(others are kept). A pair without a baseline entry is reported as ``new``, not
as a failure.

Importing this module also registers one problem family per shipped set,
``set-<stem>`` (e.g. ``--problem set-lattice-rpy-m3:instances=0-4``), so the
shipped sets appear in ``lcpbench list problems``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Optional, Union

import numpy as np

from lcpbench import __version__
from lcpbench.core.clock import utc_now
from lcpbench.core.context import Budget
from lcpbench.core.operator import apply_uncounted
from lcpbench.core.registry import get_solver, solvers, stored_sets
from lcpbench.core.residuals import make_stop_rule
from lcpbench.core.specs import make_params, parse_spec
from lcpbench.run.sweep import expand, per_low

__all__ = ["check", "CheckRow", "default_specs", "load_baselines", "write_baselines",
           "resolve_sets", "format_table", "default_baseline", "W_RTOL", "EMVP_SLACK", "BASELINE_FORMAT"]

#: Relative tolerance on ``w`` against the stored reference.
W_RTOL = 1e-6
#: Allowed relative increase of the median E-MVPs over the baseline.
EMVP_SLACK = 0.10
#: Value of the baseline file's ``format`` key.
BASELINE_FORMAT = "lcpbench.baselines"
_BASELINE_VERSION = 1


def default_baseline() -> Path:
    """The baseline file the shipped sets announce (see ``register_set``).

    Raises
    ------
    ValueError
        No registered set names a baseline file; pass ``--baseline FILE``.
    """
    for info in stored_sets().values():
        if info.baselines:
            return Path(info.baselines)
    raise ValueError("no shipped set names a baseline file; pass --baseline FILE")


# ----------------------------------------------------------------------------- baselines


def load_baselines(path: Union[str, Path]) -> dict:
    """The baseline file as a dict (an empty one when the file does not exist).

    Raises
    ------
    ValueError
        The file is not valid JSON or not an lcpbench baseline file.
    """
    path = Path(path)
    if not path.exists():
        return {"format": BASELINE_FORMAT, "version": _BASELINE_VERSION, "sets": {}}
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the baseline file ({exc}); fix it or rewrite it "
                         "with lcpbench check --update-baseline") from None
    if not isinstance(data, dict) or data.get("format") != BASELINE_FORMAT:
        raise ValueError(f"{path}: not an lcpbench baseline file (format "
                         f"{data.get('format') if isinstance(data, dict) else None!r}, expected "
                         f"{BASELINE_FORMAT!r}); rewrite it with lcpbench check --update-baseline")
    if int(data.get("version", 0)) > _BASELINE_VERSION:
        raise ValueError(f"{path}: baseline version {data.get('version')} is newer than this "
                         f"lcpbench reads ({_BASELINE_VERSION}); upgrade lcpbench")
    if not isinstance(data.get("sets", {}), dict):
        raise ValueError(f"{path}: 'sets' must map set -> solver -> median E-MVPs")
    data.setdefault("sets", {})
    return data


def write_baselines(path: Union[str, Path], data: dict) -> None:
    """Write the baseline file (sorted keys, one entry per line), atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    tmp.replace(path)


# ----------------------------------------------------------------------------- running


@dataclasses.dataclass
class CheckRow:
    """The outcome of one solver on one set.

    Attributes
    ----------
    set, solver : str
    runs, solved : int
        Instances run, and those whose verified residual met the bound.
    median_emvps : float
    baseline : float or None
        Stored median E-MVPs (None: no entry).
    max_w_err : float
        Largest ``||w - w_ref|| / max(||w_ref||, ||b||)`` over instances with a reference.
    problems : list of str
        What regressed (empty: none).
    """

    set: str
    solver: str
    runs: int
    solved: int
    median_emvps: float
    baseline: Optional[float]
    max_w_err: float
    problems: list = dataclasses.field(default_factory=list)

    @property
    def regressed(self) -> bool:
        return bool(self.problems)

    @property
    def verdict(self) -> str:
        if self.problems:
            return "REGRESSED: " + "; ".join(self.problems)
        return "new" if self.baseline is None else "ok"


def resolve_sets(names: Optional[Sequence[str]] = None) -> dict[str, Path]:
    """``{set name: path}`` of the shipped sets, or of the given names or ``.h5`` paths.

    Raises
    ------
    ValueError
        A name that is neither a shipped set nor an existing file, or a folder.
    """
    shipped = {name: Path(info.path) for name, info in stored_sets().items()}
    if not names:
        return dict(shipped)
    out = {}
    for n in names:
        p = Path(n)
        if n in shipped:
            out[n] = shipped[n]
        elif p.is_dir():
            raise ValueError(f"--set {n}: a folder, not a stored set; give a set's .h5 file "
                             f"(e.g. {p / 'NAME.h5'}) or a shipped set's name")
        elif p.suffix == ".h5" and p.exists():
            out[p.stem] = p
        else:
            raise ValueError(f"--set {n!r}: no shipped set of that name and no such .h5 file "
                             f"(shipped: {', '.join(shipped) or 'none'})")
    return out


def default_specs(low_names: Sequence[str]) -> list[str]:
    """Every MVP-only, non-reference solver with its defaults, for a set with ``low_names``."""
    specs: list[str] = []
    for name, info in solvers().items():
        if not info.listed or info.reference or not info.mvp_only:
            continue
        if info.multifidelity and not low_names:
            continue
        specs.extend(s.label for s in per_low(expand(name, "solver")[0], low_names))
    return specs


def _per_low(specs: Sequence[str], low_names: Sequence[str]) -> list[str]:
    """The given solver specs, a multi-fidelity one that names no low once per low of the
    set (as ``lcpbench run`` and the default list do: ``bi-pqn`` on a set with p4e6 and
    rpy is ``bi-pqn:low=p4e6`` and ``bi-pqn:low=rpy``)."""
    out: list[str] = []
    for spec in specs:
        for s in expand(spec, "solver"):
            out.extend(x.label for x in per_low(s, low_names))
    return out


def _w_err(lcp, x: np.ndarray) -> float:
    ref = lcp.reference
    if ref is None or ref.get("w") is None or not np.all(np.isfinite(x)):
        return float("nan") if ref is None else float("inf")
    w = apply_uncounted(lcp.A, x) + lcp.b
    w_ref = np.asarray(ref["w"], dtype=np.float64)
    scale = max(float(np.linalg.norm(w_ref)), float(np.linalg.norm(lcp.b)),
                np.finfo(float).tiny)
    return float(np.linalg.norm(w - w_ref) / scale)


def check(sets: Optional[Sequence[str]] = None, *, tol: float = 1e-8,
          baseline: Union[str, Path, None] = None, update_baseline: bool = False,
          solver_specs: Optional[Sequence[str]] = None, max_emvps: float = 5000.0,
          progress: bool = False) -> list[CheckRow]:
    """Run the regression checks; see the module docs.

    Parameters
    ----------
    sets : list of str, optional
        Shipped set names or ``.h5`` paths (default: every shipped set).
    tol : float
        Paper stop-rule tolerance of every run and of the verified-residual check.
    baseline : str or Path, optional
        Baseline file (default :func:`default_baseline`).
    update_baseline : bool
        Rewrite the baselines of the checked sets with this run's medians.
    solver_specs : list of str, optional
        Solvers to run instead of :func:`default_specs`; a multi-fidelity spec that names
        no low runs once per low of each set (``bi-pqn`` is ``bi-pqn:low=p4e6``, ...).
    max_emvps : float
        E-MVP budget of each run.
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    list of CheckRow
        One per (set, solver); ``row.regressed`` says whether it failed.

    Raises
    ------
    ValueError
        Unknown set, bad baseline file, bad solver spec, or a solver that is not
        MVP-only (a reference or dense solver has no E-MVP baseline to check).
    lcpbench.sets.StoredSetError
        A set is truncated or corrupted.
    """
    from tqdm.auto import tqdm

    from lcpbench.core.api import run_solver
    from lcpbench.sets import read_set

    path = Path(baseline) if baseline else default_baseline()
    make_stop_rule("paper", tol)                # bad values before any set is read
    Budget(max_emvps=max_emvps)
    for spec in solver_specs or ():
        name, raw = parse_spec(spec)
        info = get_solver(name)
        make_params(name, info.params, raw)
        if info.reference or not info.mvp_only:
            kind = "a reference QP solver" if info.reference else "a solver"
            raise ValueError(f"--solver {spec}: {name} is {kind} that needs the dense A, and "
                             "lcpbench check compares the E-MVPs of MVP-only solvers with their "
                             f"baselines; run it with lcpbench solve --problem "
                             f"set-NAME --solver {spec}")
    data = load_baselines(path)
    chosen = resolve_sets(sets)
    loaded = {name: read_set(p) for name, p in chosen.items()}
    plans = []
    for name, lcps in loaded.items():
        lows = sorted({k for lcp in lcps for k in lcp.low})
        for spec in (_per_low(solver_specs, lows) if solver_specs else default_specs(lows)):
            plans.append((name, spec))
    rows: list[CheckRow] = []
    total = sum(len(loaded[name]) for name, _ in plans)
    bar = tqdm(total=total, desc="lcpbench check", unit="run", disable=not progress,
               file=sys.stderr)
    try:
        for name, spec in plans:
            emvps, solved, errs, notes = [], 0, [], []
            failures: dict[str, int] = {}
            for lcp in loaded[name]:
                res = run_solver(lcp, spec, stop="paper", tol=tol,
                                 budget=Budget(max_emvps=max_emvps))
                solved += int(res.solved)
                if res.status == "failed":
                    why = " ".join(str(res.message or "no message").split())
                    failures[why] = failures.get(why, 0) + 1
                emvps.append(float(res.emvps))
                errs.append(_w_err(lcp, res.x))
                bar.update(1)
            runs = len(loaded[name])
            med = float(np.median(emvps)) if emvps else 0.0
            base = data["sets"].get(name, {}).get(spec)
            finite = [e for e in errs if not np.isnan(e)]
            max_err = max(finite) if finite else float("nan")
            for why, count in failures.items():      # the solver's own words first
                notes.append(f"{count} of {runs} run(s) failed: {why}")
            if solved < runs:
                notes.append(f"{runs - solved} of {runs} verified residual(s) above the "
                             f"tolerance {tol:g}")
            if finite and max_err > W_RTOL:
                notes.append(f"w differs from the reference by {max_err:.2g} relative "
                             f"(> {W_RTOL:g})")
            if base is not None and not update_baseline and med > (1 + EMVP_SLACK) * base:
                notes.append(f"median E-MVPs {med:.4g} > baseline {base:.4g} + "
                             f"{EMVP_SLACK:.0%}")
            rows.append(CheckRow(name, spec, runs, solved, med,
                                 None if base is None else float(base), max_err, notes))
    finally:
        bar.close()
    if update_baseline:
        for r in rows:
            data["sets"].setdefault(r.set, {})[r.solver] = round(r.median_emvps, 6)
        data.update({"format": BASELINE_FORMAT, "version": _BASELINE_VERSION,
                     "lcpbench_version": __version__, "tol": float(tol),
                     "updated": utc_now()})
        write_baselines(path, data)
    return rows


def format_table(rows: Sequence[CheckRow]) -> str:
    """The check table: set, solver, solved/runs, median E-MVPs, baseline, verdict."""
    from tabulate import tabulate

    body = [[r.set, r.solver, f"{r.solved}/{r.runs}", f"{r.median_emvps:.4g}",
             "-" if r.baseline is None else f"{r.baseline:.4g}",
             "-" if np.isnan(r.max_w_err) else f"{r.max_w_err:.1e}", r.verdict] for r in rows]
    return tabulate(body, headers=["set", "solver", "solved/runs", "median E-MVPs",
                                   "baseline", "max w err", "verdict"])
