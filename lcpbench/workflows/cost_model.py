"""A deterministic price for low-fidelity products online: inner applications times a cost.

A solve's E-MVPs weigh each low product by the cost ratio its step timed, so the same
step priced the same low at very different ratios from one run to the next and two
identical simulations disagreed. The model here prices a low by its **inner
applications** (the Krylov applications its products made, ``SolveResult.lofi_applications``;
one per product for a model without them) times a **cost per application**, in high
products:

    model E-MVPs = high MVPs + sum over lows of applications_low * c_low

``c_low = (seconds per inner application of the low) / (seconds of one cold high product)``
is calibrated once: on the first step in which the low and the high both made counted
products, from that step's own products after each operator's first call (their seconds and
applications; :attr:`lcpbench.Operator.steady_application_seconds`), and
never again in the run (a resumed run takes it from ``meta.json``). The calibration is
kept in the user cache directory, keyed by the scene, the low, the lcpbench version and
the machine (processor, cores, thread settings), so a second identical run on the same
machine uses the same constants and gives the same E-MVPs at every step; the store's
``meta.json`` records every constant and where it came from (``cost_model``). The
per-step timed E-MVPs stay in the ``emvps`` column; the model's are ``model_emvps``.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

__all__ = ["CostModel", "calibrate", "cache_key", "COST_CACHE"]

#: Sub-folder of the user cache directory holding the calibrations.
COST_CACHE = "cost-model"

#: How a calibration is taken (part of its cache key, so that a calibration taken the
#: earlier way, from every call including the first, is never reused).
METHOD = 2


def cache_key(scene_spec: str, low: str, machine: Mapping[str, Any]) -> str:
    """The cache key of one low's calibration: scene, low, lcpbench version, machine."""
    from lcpbench import __version__

    what = {"scene": scene_spec, "low": low, "lcpbench": __version__, "method": METHOD,
            "cpu": machine.get("cpu"), "cpu_count": machine.get("cpu_count"),
            "threads": machine.get("threads")}
    return hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode()).hexdigest()[:24]


def _positive(v: Any) -> bool:
    return isinstance(v, (int, float)) and bool(np.isfinite(v)) and v > 0


def calibrate(result) -> dict[str, float]:
    """Cost per inner application of each low that made counted products in the solve
    ``result``, in high products: ``(seconds per application of the low) / (seconds of one
    cold high product)``, from the solve's ``info``.

    Each operator's seconds per application are taken over its calls after the first
    (``operator_steady_seconds``): the first call of a step's operator can pay the first
    compilation of its kernels or a table built on first use, which priced a split low at
    fifty times its steady cost. An operator with a single call is priced by all its
    seconds (``operator_seconds``; the high by ``operator_cost``, its measured cold cost).
    Empty when the high made no counted product (no unit to price in).
    """
    info = result.info or {}
    seconds, cost = info.get("operator_seconds") or {}, info.get("operator_cost") or {}
    steady = info.get("operator_steady_seconds") or {}
    cold = info.get("operator_cold_applications") or {}
    high = cost.get("high")
    if _positive(steady.get("high")) and _positive(cold.get("high")):
        high = steady["high"] * cold["high"]
    if not _positive(high):
        return {}
    out = {}
    for name, apps in dict(result.lofi_applications or {}).items():
        per = steady.get(name)
        if not _positive(per):
            s = seconds.get(name)
            per = s / apps if apps and apps > 0 and _positive(s) else None
        if per is not None:
            out[str(name)] = float(per / high)
    return out


@dataclass
class CostModel:
    """The run's cost per inner application of each low, calibrated once per low.

    Parameters
    ----------
    scene_spec : str
        The scene the costs belong to.
    entries : dict
        ``{low: {"per_application": c, "source": text}}``: from an earlier ``meta.json``
        when the run resumes, else empty.
    machine : dict
        The machine description the cache is keyed by (``cpu``, ``cpu_count``, ``threads``).
    cache_dir : Path, optional
        Where calibrations are kept (default: the user cache directory's ``cost-model``).
    persist : callable, optional
        Called with :attr:`entries` after every new calibration (writes ``meta.json``).
    """

    scene_spec: str
    entries: dict = field(default_factory=dict)
    machine: dict = field(default_factory=dict)
    cache_dir: Optional[Path] = None
    persist: Optional[Callable[[dict], None]] = None

    def _cache(self) -> Path:
        if self.cache_dir is not None:
            return Path(self.cache_dir)
        from lcpbench.workflows.fidelity import user_cache_dir

        return user_cache_dir() / COST_CACHE

    def _cached(self, low: str) -> Optional[dict]:
        path = self._cache() / f"{cache_key(self.scene_spec, low, self.machine)}.json"
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        c = data.get("per_application") if isinstance(data, dict) else None
        if not isinstance(c, (int, float)) or not np.isfinite(c) or c <= 0:
            return None
        return {"per_application": float(c),
                "source": f"cached calibration {path} ({data.get('source', '-')})"}

    def _store(self, low: str, entry: dict) -> None:
        folder = self._cache()
        try:
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{cache_key(self.scene_spec, low, self.machine)}.json"
            tmp = path.with_suffix(f".tmp{os.getpid()}")
            tmp.write_text(json.dumps(entry, sort_keys=True), encoding="utf-8")
            os.replace(tmp, path)
        except OSError:
            pass            # an unwritable cache only means the next run calibrates again

    def observe(self, result, where: str) -> None:
        """Calibrate every low that made products in the solve ``result`` and is not
        calibrated yet (cache first, then this solve's products); ``where`` names the
        step in the record."""
        fresh = calibrate(result)
        used = {k for k, v in dict(result.lofi_applications or {}).items() if v}
        changed = False
        for low in sorted(used - set(self.entries)):
            entry = self._cached(low)
            if entry is None and low in fresh:
                entry = {"per_application": fresh[low], "source": f"calibrated on {where}"}
                self._store(low, entry)
            if entry is not None:
                self.entries[low] = entry
                changed = True
        if changed and self.persist is not None:
            self.persist(self.entries)

    def emvps(self, result) -> float:
        """The model E-MVPs of a solve: its high MVPs plus each low's inner applications
        times its cost per application (NaN when a low with applications is not
        calibrated)."""
        total = float(result.mvps)
        for low, apps in dict(result.lofi_applications or {}).items():
            if not apps:
                continue
            entry = self.entries.get(str(low))
            if entry is None:
                return float("nan")
            total += float(apps) * float(entry["per_application"])
        return total
