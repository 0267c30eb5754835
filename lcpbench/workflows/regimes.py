"""Regimes of an online run: the settings outside any one solver that decide what a step costs.

Two settings of a simulation change which solver is fastest without being part of any
solver: Krylov recycling in the boundary-integral mobility (later products of a step reuse
the directions of earlier ones, so a product of a converging input costs few new
directions) and quasi-Newton memory across time steps (a PQN solve starts from the previous
step's secant pairs).  A regime names one choice of both, plus the PQN product rule and the
online low fidelity that go with it, so a user picks a whole, recorded configuration:

``paper``
    The method paper's online experiment (its section "Online Comparison"): no Krylov
    recycling, no quasi-Newton memory across steps, the paper's products (``A`` applied to
    the search direction), and the paper's online low fidelity, BIM p = 4 at eps 1e-8
    (fidelity name ``p4`` on a p = 8, eps 1e-8 scene).
``default``
    lcpbench's defaults: recycling with the scene's budget, memory across steps, any
    product rule; the low fidelity is the scene's.

:func:`apply_regime` turns a regime and a user's scene spec, solver specs and memory choice
into the settings a simulation runs with, refusing a choice that contradicts the regime
(recycling on, memory on, or other products under ``paper``) instead of silently running
something else under its name.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Optional

from lcpbench.core.registry import get_solver
from lcpbench.core.specs import make_params, parse_spec

__all__ = ["Regime", "REGIMES", "DEFAULT_REGIME", "PAPER_ONLINE_LOW", "get_regime",
           "apply_regime", "RegimeSettings"]

#: The paper's online low fidelity (BIM p = 4 at eps_gmres 1e-8, on a p = 8, eps 1e-8 scene).
PAPER_ONLINE_LOW = "p4"


@dataclasses.dataclass(frozen=True)
class Regime:
    """One regime of an online run.

    Attributes
    ----------
    name : str
        ``paper`` or ``default``.
    krylov_mb : float or None
        The Krylov recycling budget it imposes on the scene (0: no recycling); ``None``
        leaves the scene's own.
    qn_memory : bool
        Whether PQN solves start from the previous step's secant pairs.
    products : str or None
        The PQN product rule it imposes; ``None`` allows any.
    low : str or None
        Its online low fidelity; ``None`` leaves the scene's.
    summary : str
        One line for help texts and reports.
    """

    name: str
    krylov_mb: Optional[float]
    qn_memory: bool
    products: Optional[str]
    low: Optional[str]
    summary: str


REGIMES: dict[str, Regime] = {
    "default": Regime("default", None, True, None, None,
                      "lcpbench's defaults: Krylov recycling on, quasi-Newton memory "
                      "across steps"),
    "paper": Regime("paper", 0.0, False, "paper", PAPER_ONLINE_LOW,
                    "the method paper's: no Krylov recycling, no quasi-Newton memory "
                    f"across steps, the paper's products, low fidelity {PAPER_ONLINE_LOW}"),
}
"""The regimes by name."""

DEFAULT_REGIME = "default"


def get_regime(name: str) -> Regime:
    """The regime called ``name``; a clear error names the known ones."""
    try:
        return REGIMES[str(name)]
    except KeyError:
        raise ValueError(f"unknown regime {name!r}; choose one of "
                         f"{', '.join(sorted(REGIMES))}") from None


@dataclasses.dataclass(frozen=True)
class RegimeSettings:
    """What :func:`apply_regime` returns: the settings a simulation runs with."""

    regime: str
    scene_spec: str
    qn_memory: bool


def _with_recycling(scene_spec: str, regime: Regime) -> str:
    """``scene_spec`` with the regime's recycling budget (refused when the spec sets
    another)."""
    from lcpbench.core.registry import make_scene

    if regime.krylov_mb is None:
        return scene_spec
    name, raw = parse_spec(scene_spec)
    if "krylov_mb" in raw:
        given = float(raw["krylov_mb"])
        if given != regime.krylov_mb:
            raise ValueError(f"scene {scene_spec!r} sets krylov_mb={raw['krylov_mb']}, but "
                             f"regime {regime.name!r} runs with krylov_mb="
                             f"{regime.krylov_mb:g}; drop krylov_mb from the scene or use "
                             "--regime default")
        return scene_spec
    probe = make_scene(scene_spec)
    if not hasattr(probe.params, "krylov_mb"):
        return scene_spec          # a scene without a recycled mobility has nothing to switch
    sep = "," if ":" in scene_spec else ":"
    return f"{scene_spec}{sep}krylov_mb={regime.krylov_mb:g}"


def _check_products(solver_specs: Sequence[str], regime: Regime) -> None:
    """Refuses a solver whose product rule is not the regime's."""
    if regime.products is None:
        return
    for spec in solver_specs:
        name, raw = parse_spec(spec)
        params = make_params(name, get_solver(name).params, raw)
        products = getattr(params, "products", None)
        if products is not None and products != regime.products:
            raise ValueError(f"solver {spec!r} uses products={products}, but regime "
                             f"{regime.name!r} runs the paper's products "
                             f"(products={regime.products}); drop products= or use "
                             "--regime default")


def apply_regime(regime_name: str, scene_spec: str, solver_specs: Sequence[str],
                 qn_memory: Optional[bool]) -> RegimeSettings:
    """The settings of a simulation in regime ``regime_name``.

    Parameters
    ----------
    regime_name : str
        A key of :data:`REGIMES`.
    scene_spec : str
        The user's scene spec; the regime's recycling budget is added when it sets none.
    solver_specs : list of str
        The solvers; under a regime that fixes the product rule, a solver with another is
        refused.
    qn_memory : bool or None
        The user's memory choice; ``None`` takes the regime's.  A choice that contradicts
        the regime is refused.

    Returns
    -------
    RegimeSettings

    Raises
    ------
    ValueError
        Unknown regime, or a scene, solver or memory choice that contradicts it.
    """
    regime = get_regime(regime_name)
    if qn_memory is not None and regime.name != DEFAULT_REGIME and \
            bool(qn_memory) != regime.qn_memory:
        raise ValueError(f"--qn-memory={'on' if qn_memory else 'off'} contradicts regime "
                         f"{regime.name!r} (memory across steps "
                         f"{'on' if regime.qn_memory else 'off'}); drop the option or use "
                         "--regime default")
    _check_products(solver_specs, regime)
    memory = regime.qn_memory if qn_memory is None else bool(qn_memory)
    return RegimeSettings(regime.name, _with_recycling(str(scene_spec).strip(), regime),
                          memory)
