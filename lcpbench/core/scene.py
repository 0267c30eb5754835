"""The scene contract as code, and the one stepping loop of online runs.

A scene (registered with :func:`lcpbench.core.registry.register_scene`) is a simulation
whose time step ``k`` defines an LCP: the solution moves the particles and so defines the
LCP of step ``k + 1``.  :class:`Scene` lists what ``lcpbench simulate`` and ``lcpbench
generate`` use of it, :class:`SceneProblem` what they use of one step's problem, and
:class:`FidelityAxes` the fidelity knobs the scene declares for the fidelity study.
:func:`step_scene` is the build-solve-advance loop body both workflows share;
``tests/test_layering.py`` checks the shipped scenes against the Protocols.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Optional, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from lcpbench.core.lcp import LCP

__all__ = ["Scene", "SceneProblem", "FidelityAxes", "StepRecord", "step_scene"]


@dataclass(frozen=True)
class FidelityAxes:
    """The fidelity knobs a scene declares: the two that span the fidelity study's grid.

    Attributes
    ----------
    rows, columns : str
        Knob names (keys of :meth:`Scene.fidelity_knobs`) of the grid's rows and columns,
        e.g. ``"p"`` and ``"eps_gmres"``.
    model_knob : str
        The knob that names the model (``"model"``).
    grid_models : tuple of str
        Values of ``model_knob`` whose fidelity the two knobs set ("" = not recorded); the
        other models are listed beside the grid.
    size_param : str
        The scene parameter that sets the problem size (``"m"``), or "" for none.
    """

    rows: str
    columns: str
    model_knob: str = "model"
    grid_models: tuple[str, ...] = ("",)
    size_param: str = ""


@runtime_checkable
class SceneProblem(Protocol):
    """One time step's problem, as :meth:`Scene.build` returns it."""

    lcp: LCP
    """The step's LCP (counted operator, ``b``, warm start, low fidelities)."""
    setup_solves: int
    """Operator solves spent building it outside the LCP's counters."""

    @property
    def pairs(self) -> np.ndarray:
        """Identities of the LCP's unknowns (one row each), to carry values across steps."""

    @property
    def min_gap(self) -> float:
        """Smallest gap among the step's contacts (nan when there are none)."""


@runtime_checkable
class Scene(Protocol):
    """What the online workflows use of a scene (``lattice`` is the reference)."""

    params: Any
    """The frozen parameter dataclass; ``params.low`` names the low fidelities."""
    radii: np.ndarray
    """Particle radii, (M,)."""
    step_index: int
    """Steps taken so far."""
    fidelity_axes: FidelityAxes
    """The fidelity knobs the scene declares."""

    @property
    def M(self) -> int:
        """Number of particles."""

    def build(self, warm_start: bool = True, symmetrize: Optional[bool] = None,
              lows: Optional[Sequence[str]] = None) -> SceneProblem:
        """The current step's problem (with the low fidelities ``lows``, default all)."""

    def advance(self, problem: Any, x: np.ndarray) -> tuple[float, int]:
        """Move the particles with the solution ``x``: ``(max_overlap, extra solves)``."""

    def carry_memory(self, problem: Any) -> Any:
        """The kept quasi-Newton memory mapped onto ``problem`` (None when there is none)."""

    def keep_memory(self, memory: Any) -> None:
        """Keep a solve's quasi-Newton memory for the next step (None forgets it)."""

    def fidelity_knobs(self, name: str) -> dict:
        """The knobs of a low-fidelity name (``ValueError`` for an unknown one)."""

    def get_state(self) -> dict:
        """The state that evolves from step to step, as arrays (for checkpoints)."""

    def set_state(self, state: dict) -> None:
        """Restore what :meth:`get_state` returned."""


@dataclass
class StepRecord:
    """What one time step did.

    Attributes
    ----------
    step : int
        0-based step index.
    n : int
        Unknowns (contacts) of the step's LCP.
    result : SolveResult
        The solve (counted MVPs, E-MVPs, verified residuals, time).
    x : ndarray
        The solution used for the update.
    pairs : ndarray
        Identities of the unknowns (:attr:`SceneProblem.pairs`).
    setup_s, update_s, total_s : float
        Seconds building the LCP, moving the particles, and the whole step.
    max_overlap : float
        Largest overlap of two particles after the step (0 if none).
    min_gap : float
        Smallest gap among the step's contacts before the step (nan if none).
    setup_solves, update_solves : int
        Operator solves outside the solver's counted MVPs.
    warm_entries : int
        Non-zero entries of the warm start carried from the previous step.
    qn_memory : bool
        The solve started from the previous step's secant pairs.
    qn_pairs : int
        Secant pairs that survived the mapping onto this step's unknowns.
    """

    step: int
    n: int
    result: Any
    x: np.ndarray
    pairs: np.ndarray
    setup_s: float
    update_s: float
    total_s: float
    max_overlap: float
    min_gap: float
    setup_solves: int
    update_solves: int
    warm_entries: int = 0
    qn_memory: bool = False
    qn_pairs: int = 0


def step_scene(scene: Scene, solver: str, *, tol: float = 1e-8, stop: str = "paper",
               budget=None, warm_start: bool = True, qn_memory: bool = False,
               params: Optional[dict] = None, lows: Optional[Sequence[str]] = None,
               symmetrize: Optional[bool] = None,
               before_solve: Optional[Callable[[Any], None]] = None) -> StepRecord:
    """Build, solve and advance one step of ``scene``: the loop body of ``simulate`` and
    ``generate``.

    Parameters
    ----------
    scene : Scene
    solver : str
        Registered solver spec, e.g. ``bi-pqn:low=rpy``.
    tol, stop : stop rule of the solve.
    budget : lcpbench.core.context.Budget, optional
    warm_start : bool
        Start from the previous step's solution matched by identity.
    qn_memory : bool
        Start the solver's quasi-Newton model from the previous step's secant pairs
        (:meth:`Scene.carry_memory`) and keep this solve's pairs for the next step.
    params : dict, optional
        Extra solver parameters.
    lows : list of str, optional
        The low fidelities to build (default: all of the scene's).
    symmetrize : bool, optional
        Passed to :meth:`Scene.build`.
    before_solve : callable, optional
        ``before_solve(problem)`` runs after the build and before the solve (``generate``
        stores the step's instance there).

    Returns
    -------
    StepRecord
    """
    from lcpbench.core.api import run_solver

    t0 = time.perf_counter()
    problem = scene.build(warm_start, symmetrize=symmetrize, lows=lows)
    t1 = time.perf_counter()
    if before_solve is not None:
        before_solve(problem)
    lcp = problem.lcp
    memory = scene.carry_memory(problem) if qn_memory else None
    res = run_solver(lcp, solver, stop=stop, tol=tol, budget=budget, state=memory,
                     params=params)
    t2 = time.perf_counter()
    step = scene.step_index
    overlap, solves = scene.advance(problem, res.x)
    scene.keep_memory(res.state if qn_memory else None)
    t3 = time.perf_counter()
    return StepRecord(step=step, n=lcp.n, result=res, x=np.asarray(res.x, float),
                      pairs=np.array(problem.pairs, copy=True), setup_s=t1 - t0,
                      update_s=t3 - t2, total_s=t3 - t0, max_overlap=overlap,
                      min_gap=problem.min_gap, setup_solves=problem.setup_solves,
                      update_solves=solves,
                      warm_entries=0 if lcp.x0 is None else int(np.count_nonzero(lcp.x0)),
                      qn_memory=bool(qn_memory), qn_pairs=0 if memory is None else memory.rank)
