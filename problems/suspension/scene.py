"""The lattice scene: Janus-like spheres packing into a cluster, one LCP per time step.

Initialisation (appendix "Initialization Procedure" of the method paper): the
``m x m x m`` sphere centres are put on a lattice centred at the origin,
``spacing`` radii apart, moved by uniform jitter of width ``jitter`` radii, and
the whole configuration is scaled by the factor ``gamma`` found by bisection so
that about ``m^3 / 2`` pairs are candidate contacts (gap ``<= delta``), within
``m^3 / 10``. The number of candidate pairs is non-increasing in ``gamma``;
the search is kept above the scale at which two spheres would touch, so the
initial configuration never overlaps. (The paper's algorithm listing moves
``gamma`` the wrong way on one branch; this is the bisection it describes.)
With strong polydispersity the window may need overlapping spheres; the scale
then stops just above touching, with fewer pairs than desired
(``LatticeScene.initial_pairs`` says how many).

Driving model (the least that reproduces the paper's workload of ``n >= M``
contacts as Janus particles cluster to hide their hydrophobic sides): every
sphere ``i`` carries a unit orientation ``o_i`` (its hydrophobic pole),
initially pointing at the centroid ``c_bar`` of the configuration. With
``t_i = -(c_i - c_bar) / max(|c_i - c_bar|, a_i)`` (a pull direction that
fades inside one radius of the centroid) and its unit vector ``t^_i``:

* force  ``F_i = 6 pi mu a_i * force * (1 + o_i . t^_i) / 2 * t_i``: a pull
  towards the centroid, strongest when the hydrophobic pole faces inwards;
  ``force`` is the free-sphere drift speed in length per unit time;
* torque ``T_i = 8 pi mu a_i^3 * torque * (o_i x t^_i)``: turns the pole
  towards the centroid at rate ``torque`` (1 / time) for a free sphere.

Orientations follow the rotational velocity, ``o <- o + dt Omega x o``
(renormalised). The cluster that forms is dense, so after a few dozen steps the
LCPs have more contacts than spheres, as in the paper's time steps 201-250.

Time stepping is forward Euler: each step builds the contact LCP of
:mod:`.problem`, solves it with the given solver, and moves the spheres with
``U = U_nc + M D x``; the product ``M D x`` is the one the framework made
when verifying the solve, so the update needs no extra mobility solve.  With the
boundary-integral model the non-collisional solve ``U_nc`` starts from the previous
step's density when no sphere moved more than :data:`NC_GUESS_MOVE` radii since,
extrapolated linearly from the two previous steps' densities when both are at hand
(:meth:`LatticeScene.nc_guess`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Literal, Optional

import numpy as np
from scipy.spatial.distance import pdist

from lcpbench.core.guards import Estimate
from lcpbench.core.registry import register_scene
from lcpbench.core.scene import FidelityAxes, StepRecord, step_scene
from lcpbench.core.specs import Bounds, CheckedParams
from lcpbench.toolkit.quasinewton import SecantMemory

from .contacts import max_overlap
from .fidelity import parse_fidelity
from .geometry import pair_gaps
from .problem import ContactOptions, ContactProblem, build_contact_problem

__all__ = ["LatticeParams", "LatticeScene", "lattice_configuration", "bisect_scale",
           "lattice", "PaperLatticeParams", "paper_lattice", "LATTICE_AXES", "NC_GUESS_MOVE"]

#: The previous step's density is the initial guess of the non-collisional solve when no
#: sphere moved more than this many (smallest) radii since that density was solved for
#: (docs/mobility.md, "Warm-started non-collisional solve").
NC_GUESS_MOVE = 0.5

#: The fidelity knobs the lattice scenes declare (read by the fidelity study): the
#: boundary-integral order and GMRES tolerance span the grid; ``m`` sets the size.
LATTICE_AXES = FidelityAxes(rows="p", columns="eps_gmres", model_knob="model",
                            grid_models=("", "bim"), size_param="m")


@dataclass(frozen=True)
class LatticeParams(CheckedParams):
    """Parameters of the lattice scene (CLI: ``lattice:m=3,model=rpy,dt=0.1``).

    Parameters
    ----------
    m : int
        Lattice side: ``M = m^3`` spheres (>= 1).
    p : int
        Spherical-harmonic order of the boundary-integral mobility (model bim).
    model : str
        High-fidelity mobility: ``rpy``, ``bim`` or ``self`` (no interactions).
    eps_gmres : float
        GMRES tolerance of the boundary-integral mobility.
    radius : float
        Mean sphere radius.
    polydisperse : float
        Radii uniform in ``radius * [1 - polydisperse, 1 + polydisperse]`` (0 <= . < 1).
    dt : float
        Time step (> 0).
    delta : float
        Candidate-contact gap threshold (>= 0); keep it above the largest
        relative displacement per step (about ``2 * force * dt``).
    seed : int
        Seed of the jitter, radii and the centre sphere's orientation.
    mu : float
        Viscosity.
    low : list of str
        Low-fidelity operators per LCP (``rpy``, ``self``, ``p4``, ``p4e6``, the
        distance-split ``p8f6e3`` and its compressed ``p8f6r3e3``, ...;
        :func:`.fidelity.parse_fidelity`).
    force : float
        Free-sphere drift speed of the centroid pull (length / time).
    torque : float
        Free-sphere alignment rate of the hydrophobic pole (1 / time).
    spacing : float
        Lattice spacing before scaling, in radii.
    jitter : float
        Width of the uniform jitter of each coordinate before scaling, in radii.
    target : float
        Desired candidate pairs per sphere at the start (paper: 1/2).
    separation : float
        Minimum gap the LCP keeps between spheres, in length units: the gap
        function is ``Phi - separation`` (default 0.1, a tenth of the default
        radius), so that a correct solve never makes spheres touch, the
        boundary-integral model (which refuses overlapping spheres) can be
        evaluated at every step, and the active contacts sit where that model
        still means something (docs/mobility.md, "Measured choices behind the
        defaults").
    krylov_mb : float
        Memory budget (MB) of the Krylov directions the boundary-integral operators of
        one step keep and reuse across products (:class:`.bim.recycle.KrylovBudget`;
        default 256); 0 switches recycling off, as in the method paper
        (``lcpbench simulate --regime paper`` sets it).  Results agree to the GMRES
        tolerance either way; the cost of a product does not.
    """

    m: Annotated[int, Bounds(ge=1)] = 3
    p: Annotated[int, Bounds(ge=1)] = 8
    model: Literal["rpy", "bim", "self"] = "rpy"
    eps_gmres: Annotated[float, Bounds(gt=0, lt=1)] = 1e-8
    radius: Annotated[float, Bounds(gt=0)] = 1.0
    polydisperse: Annotated[float, Bounds(ge=0, lt=1)] = 0.0
    dt: Annotated[float, Bounds(gt=0)] = 0.1
    delta: Annotated[float, Bounds(ge=0)] = 0.3
    seed: int = 0
    mu: Annotated[float, Bounds(gt=0)] = 1.0
    low: tuple[str, ...] = ()
    force: Annotated[float, Bounds(ge=0)] = 1.0
    torque: Annotated[float, Bounds(ge=0)] = 1.0
    spacing: Annotated[float, Bounds(gt=0)] = 3.0
    jitter: Annotated[float, Bounds(ge=0)] = 0.5
    target: Annotated[float, Bounds(ge=0)] = 0.5
    separation: Annotated[float, Bounds(ge=0)] = 0.1
    krylov_mb: Annotated[float, Bounds(ge=0)] = ContactOptions.krylov_mb

    def __post_init__(self) -> None:
        super().__post_init__()              # the declared bounds
        for name in self.low:
            parse_fidelity(name, self.p, self.eps_gmres)


@dataclass(frozen=True)
class PaperLatticeParams(LatticeParams):
    """The lattice scene as the method paper's authors ran it (CLI: ``paper-lattice:m=3``).

    The same scene and parameters as :class:`LatticeParams`, with the defaults of the
    authors' released simulation code: unit radius, lattice ``spacing`` 2.5 radii,
    time step 0.1, a kept minimum ``separation`` of 0.3 (three tenths of the radius)
    and candidate contacts within 1.1 x 0.3 radii of that separation (``delta = 0.3 +
    0.33``).  At a 0.3a gap the squeeze traction between two spheres spreads over about
    sqrt(0.3) radii, 1.7 times wider than at the 0.1a of the default lattice scene, so
    low spherical-harmonic orders resolve it far better (docs/mobility.md has every
    low fidelity's error on both scenes).  The default ``lattice`` scene, packed to
    0.1a, stays as the hard case.
    """

    spacing: Annotated[float, Bounds(gt=0)] = 2.5
    separation: Annotated[float, Bounds(ge=0)] = 0.3
    delta: Annotated[float, Bounds(ge=0)] = 0.63


def lattice_configuration(m: int, spacing: float, jitter: float,
                          rng: np.random.Generator) -> np.ndarray:
    """``m^3`` lattice points ``spacing`` apart, centred at the origin, plus uniform jitter.

    The jitter of each coordinate is uniform in ``[-jitter / 2, jitter / 2]``.
    """
    ax = (np.arange(m) - (m - 1) / 2.0) * spacing
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    P = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    return P + rng.uniform(-jitter / 2.0, jitter / 2.0, size=P.shape)


def bisect_scale(points: np.ndarray, radii: np.ndarray, delta: float, n_desired: float,
                 n_window: float, max_iter: int = 200) -> tuple[float, int]:
    """Scale ``gamma`` with ``|pairs(gamma * points)|`` in ``n_desired +- n_window``.

    Parameters
    ----------
    points : ndarray, shape (M, 3)
        Unscaled centres (centred at the origin).
    radii : ndarray, shape (M,)
    delta : float
        Candidate-pair gap threshold.
    n_desired, n_window : float
        Target count and half-width of the accepted window.

    Returns
    -------
    gamma : float
        The scale; never below the touching scale (no two spheres overlap or touch).
    count : int
        Candidate pairs at ``gamma``. When no scale hits the window (e.g. a jump
        of the count across it, or the window needs overlapping spheres) the
        closest count found is returned.
    """
    M = len(points)
    if M < 2:
        return 1.0, 0

    def count(g: float) -> int:
        return int(len(pair_gaps(g * points, radii, delta)[0]))

    iu = np.triu_indices(M, 1)
    touch = float(np.max((radii[iu[0]] + radii[iu[1]]) / pdist(points)))
    lo = touch * (1.0 + 1e-9)
    hi = max(1.0, 2.0 * lo)
    while count(hi) > 0:
        hi *= 2.0
    lo_n, hi_n = n_desired - n_window, n_desired + n_window
    best = (abs(count(lo) - n_desired), -lo, lo, count(lo))
    if count(lo) < lo_n:          # fewer pairs than desired even at touching distance
        return lo, count(lo)
    for _ in range(max_iter):
        mid = 0.5 * (lo + hi)
        c = count(mid)
        best = min(best, (abs(c - n_desired), -mid, mid, c))
        if lo_n <= c <= hi_n:
            return mid, c
        if c > hi_n:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * hi:
            break
    return best[2], best[3]


class LatticeScene:
    """A lattice of Janus-like spheres packing into a cluster (see the module docs).

    The reference implementation of :class:`lcpbench.core.scene.Scene`.

    Parameters
    ----------
    m : int
        Lattice side (``M = m^3`` spheres).
    params : LatticeParams, optional
        All parameters at once (then ``m`` and keywords are not used).
    **kwargs
        Any other field of :class:`LatticeParams` (``p``, ``model``,
        ``eps_gmres``, ``radius``, ``polydisperse``, ``dt``, ``delta``, ``seed``,
        ``mu``, ``low``, ``force``, ``torque``, ...).

    Attributes
    ----------
    centers, orientations : ndarray, shape (M, 3)
        Current state.
    radii : ndarray, shape (M,)
    gamma : float
        Scale found by the initial bisection.
    initial_pairs : int
        Candidate pairs of the initial configuration.
    step_index : int
        Steps taken so far.
    far : str
        Far-field engine of the boundary-integral mobility: ``"auto"`` (default: the FMM
        from :data:`.bim.fmm.FAR_CROSSOVER_M` spheres on when fmm3dpy is importable),
        ``"direct"`` or ``"fmm"``.  An attribute, not a parameter, so that stored sets
        and simulations keep their recorded parameters; the results agree to the
        tolerance either way.
    """

    fidelity_axes = LATTICE_AXES
    far: str = "auto"
    nc_extrapolate: bool = True
    """Start the non-collisional solve from the two previous densities extrapolated
    (:meth:`nc_guess`); False: from the previous density."""

    def __init__(self, m: int = 3, *, params: Optional[LatticeParams] = None, **kwargs):
        if params is not None and kwargs:
            raise TypeError(f"LatticeScene: pass either params= or keyword parameters, not "
                            f"both (got params and {sorted(kwargs)})")
        self.params = params if params is not None else LatticeParams(m=m, **kwargs)
        P = self.params
        rng = np.random.default_rng(P.seed)
        M = P.m ** 3
        self.radii = P.radius * (1.0 + P.polydisperse * rng.uniform(-1.0, 1.0, M))
        pts = lattice_configuration(P.m, P.spacing * P.radius, P.jitter * P.radius, rng)
        pts -= pts.mean(axis=0)
        self.gamma, self.initial_pairs = bisect_scale(pts, self.radii, P.delta,
                                                      P.target * M, M / 10.0)
        self.centers = self.gamma * pts
        rel = self.centers - self.centers.mean(axis=0)
        dist = np.linalg.norm(rel, axis=1)
        o = np.empty_like(rel)
        inner = dist < 1e-12 * P.radius
        o[~inner] = -rel[~inner] / dist[~inner, None]
        if inner.any():
            r = rng.normal(size=(int(inner.sum()), 3))
            o[inner] = r / np.linalg.norm(r, axis=1, keepdims=True)
        self.orientations = o
        self.step_index = 0
        self._prev_pairs = np.empty((0, 2), dtype=np.intp)
        self._prev_x = np.empty(0)
        self._prev_memory: Optional[SecantMemory] = None
        self._nc_centers = np.empty((0, 3))       # where the kept density was solved for
        self._nc_density = np.empty(0)
        self._nc_step = -1                        # the step it was solved at
        self._nc_before = np.empty(0)             # the density of the step before that
        self._nc_cold = 0.0                       # applications of its solve from zero

    def get_state(self) -> dict:
        """The state that evolves from step to step, as arrays (for simulation checkpoints).

        Everything else (radii, parameters) follows from ``params``, so
        ``set_state(get_state())`` on a scene made from the same parameters continues the
        same trajectory. ``memory_S`` and ``memory_Y`` hold the previous solve's
        secant pairs (``qn_memory=True``; no columns otherwise), ``nc_centers`` and
        ``nc_density`` the non-collisional solve's density and where it was solved for
        (the next guess; empty without one), ``nc_step`` the step it was solved at and
        ``nc_before`` the density of the step before (empty without one), ``nc_cold``
        the inner applications of that solve from zero.
        """
        mem = self._prev_memory
        empty = np.zeros((len(self._prev_pairs), 0))
        return {"centers": self.centers.copy(), "orientations": self.orientations.copy(),
                "step_index": np.array(self.step_index), "prev_pairs": self._prev_pairs.copy(),
                "prev_x": self._prev_x.copy(),
                "memory_S": empty if mem is None else mem.S.copy(),
                "memory_Y": empty if mem is None else mem.Y.copy(),
                "nc_centers": self._nc_centers.copy(), "nc_density": self._nc_density.copy(),
                "nc_step": np.array(self._nc_step), "nc_before": self._nc_before.copy(),
                "nc_cold": np.array(self._nc_cold)}

    def set_state(self, state: dict) -> None:
        """Restore what :meth:`get_state` returned (a ``ValueError`` names a mismatch)."""
        centers = np.asarray(state["centers"], dtype=np.float64)
        if centers.shape != self.centers.shape:
            raise ValueError(f"scene state has {centers.shape[0]} spheres, this scene "
                             f"{self.M}: it was saved by a scene with other parameters")
        self.centers = centers
        self.orientations = np.asarray(state["orientations"], dtype=np.float64)
        self.step_index = int(state["step_index"])
        self._prev_pairs = np.asarray(state["prev_pairs"], dtype=np.intp).reshape(-1, 2)
        self._prev_x = np.asarray(state["prev_x"], dtype=np.float64)
        S = np.asarray(state.get("memory_S", np.zeros((0, 0))), dtype=np.float64)
        Y = np.asarray(state.get("memory_Y", np.zeros((0, 0))), dtype=np.float64)
        self._prev_memory = SecantMemory(S, Y) if S.ndim == 2 and S.shape[1] else None
        self._nc_centers = np.asarray(state.get("nc_centers", np.empty((0, 3))),
                                      dtype=np.float64).reshape(-1, 3)
        self._nc_density = np.asarray(state.get("nc_density", np.empty(0)),
                                      dtype=np.float64).reshape(-1)
        self._nc_step = int(state.get("nc_step", -1))
        self._nc_before = np.asarray(state.get("nc_before", np.empty(0)),
                                     dtype=np.float64).reshape(-1)
        self._nc_cold = float(state.get("nc_cold", 0.0))

    def fidelity_knobs(self, name: str) -> dict:
        """The knobs of low-fidelity ``name`` at this scene's order and tolerance.

        ``{"model": "bim", "p": 4, "eps_gmres": 1e-6}`` for ``p4e6``; ``rpy`` and
        ``self`` name the analytic models. Raises ``ValueError`` for an unknown name.
        """
        return parse_fidelity(name, self.params.p, self.params.eps_gmres).knobs()

    @property
    def M(self) -> int:
        """Number of spheres."""
        return int(len(self.centers))

    # ------------------------------------------------------------------ physics
    def loads(self) -> tuple[np.ndarray, np.ndarray]:
        """External forces and torques ``(F, T)``, each ``(M, 3)``, of the Janus model."""
        P = self.params
        a = self.radii
        rel = self.centers - self.centers.mean(axis=0)
        dist = np.linalg.norm(rel, axis=1)
        t = -rel / np.maximum(dist, a)[:, None]
        that = np.zeros_like(t)
        nz = dist > 0
        that[nz] = -rel[nz] / dist[nz, None]
        align = 0.5 * (1.0 + np.sum(self.orientations * that, axis=1))
        F = (6.0 * np.pi * P.mu * a * P.force * align)[:, None] * t
        T = (8.0 * np.pi * P.mu * a ** 3 * P.torque)[:, None] * np.cross(self.orientations, that)
        return F, T

    def warm_start(self, problem: ContactProblem) -> np.ndarray:
        """The previous step's forces carried to ``problem``'s contacts by pair identity."""
        return problem.contacts.carry(self._prev_pairs, self._prev_x)

    def carry_memory(self, problem: ContactProblem) -> Optional[SecantMemory]:
        """The previous solve's secant pairs mapped onto ``problem``'s contacts by pair identity.

        Rows of contacts that persist move to their new position, new contacts
        get zero rows, and pairs that lost too much to vanished contacts or
        lost their positive curvature are dropped (:meth:`SecantMemory.remap`,
        which says why ``y`` is then only approximately ``A s``). None when
        the previous solve left no memory or no pair survived.
        """
        if self._prev_memory is None or not problem.contacts.n:
            return None
        index = problem.contacts.index_of(self._prev_pairs)
        memory = self._prev_memory.remap(index)
        return memory if memory.rank else None

    def keep_memory(self, memory) -> None:
        """Keep a solve's secant pairs for the next step (anything but a
        :class:`SecantMemory`, None included, forgets them)."""
        self._prev_memory = memory if isinstance(memory, SecantMemory) else None

    def nc_guess(self) -> Optional[np.ndarray]:
        """The start of the non-collisional solve: None when no density is kept or a sphere
        moved more than :data:`NC_GUESS_MOVE` radii since it was solved for; else, when
        it was solved at the previous step and the density of the step before is kept too
        (and ``nc_extrapolate``), the two extrapolated linearly to this step, ``2 s_1 -
        s_0``; else the kept density.

        The density is a smooth function of the configuration, which moves by one time
        step per step: the extrapolation removes the change that continues at the same
        rate.  In the packed phase the motion changes from step to step (contacts), and
        it saves little: 166 inner applications over 10 steps against 175 from the kept
        density and 210 from zero (docs/benchmarks.md, "Set-up, memory and the split low
        in rotated form")."""
        if self._nc_density.size == 0 or self._nc_centers.shape != self.centers.shape:
            return None
        moved = float(np.max(np.linalg.norm(self.centers - self._nc_centers, axis=1)))
        if moved > NC_GUESS_MOVE * float(np.min(self.radii)):
            return None
        if (self.nc_extrapolate and self._nc_step == self.step_index - 1
                and self._nc_before.shape == self._nc_density.shape):
            return 2.0 * self._nc_density - self._nc_before
        return self._nc_density

    def build(self, warm_start: bool = True, symmetrize: Optional[bool] = None,
              lows: Optional[Sequence[str]] = None) -> ContactProblem:
        """The current step's contact problem (contacts, mobility, ``U_nc``, LCP).

        ``lows`` names the scene's low fidelities to build (default: all of ``params.low``);
        a single-fidelity solver needs none, and each one costs a mobility set-up per
        step.  ``symmetrize`` is the option of :class:`.problem.ContactOptions` (default:
        one forward solve per product; True symmetrises the boundary-integral operators
        with the adjoint solve).  The non-collisional solve starts from :meth:`nc_guess`
        (with ``warm_start``), and its density is kept for the next step."""
        P = self.params
        F, T = self.loads()
        options = ContactOptions(dt=P.dt, delta=P.delta, separation=P.separation,
                                 model=P.model, p=P.p, eps_gmres=P.eps_gmres, mu=P.mu,
                                 low=P.low if lows is None else tuple(lows),
                                 symmetrize=symmetrize, far=self.far,
                                 krylov_mb=P.krylov_mb)
        problem = build_contact_problem(
            self.centers, self.radii, F, T, options=options,
            name=f"lattice-m{P.m}-step{self.step_index}",
            meta={"family": "lattice", "step": self.step_index, "m": P.m, "seed": P.seed},
            nc_guess=self.nc_guess() if warm_start else None, nc_cold=self._nc_cold or None)
        if problem.nc_density is not None:
            if self._nc_step != self.step_index:   # a new step: the kept one moves back
                consecutive = (self._nc_step == self.step_index - 1
                               and self._nc_density.shape == problem.nc_density.shape)
                self._nc_before = self._nc_density if consecutive else np.empty(0)
            self._nc_centers, self._nc_density = self.centers.copy(), problem.nc_density
            self._nc_step = self.step_index
            self._nc_cold = float(problem.nc_cold_applications or 0.0)
        if warm_start and problem.contacts.n:
            x0 = self.warm_start(problem)
            if np.any(x0):
                problem.lcp.x0 = x0
        return problem

    def advance(self, problem: ContactProblem, x: np.ndarray) -> tuple[float, int]:
        """Move the spheres one forward Euler step with contact forces ``x``.

        Returns
        -------
        max_overlap : float
            Largest overlap of two spheres after the step.
        solves : int
            Mobility solves the update needed (0 when ``M D x`` was cached).

        Raises
        ------
        ValueError
            ``x`` is not finite or has the wrong length (the state is unchanged).
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        if not np.all(np.isfinite(x)):
            raise ValueError(f"step {self.step_index}: the contact forces are not finite; "
                             "the simulation cannot continue from a diverged solve")
        before = problem.extra_solves
        U = problem.velocities(np.maximum(x, 0.0)).reshape(self.M, 6)
        dt = self.params.dt
        self.centers = self.centers + dt * U[:, :3]
        o = self.orientations + dt * np.cross(U[:, 3:], self.orientations)
        self.orientations = o / np.linalg.norm(o, axis=1, keepdims=True)
        self._prev_pairs = problem.contacts.pairs.copy()
        self._prev_x = np.maximum(x, 0.0)
        self.step_index += 1
        return max_overlap(self.centers, self.radii), problem.extra_solves - before

    def step(self, solver: str = "bb-pgd", *, tol: float = 1e-8, stop: str = "paper",
             budget=None, warm_start: bool = True, qn_memory: bool = False,
             params: Optional[dict] = None, lows: Optional[Sequence[str]] = None
             ) -> StepRecord:
        """Build, solve and advance one step.

        Parameters
        ----------
        solver : str
            Registered solver spec, e.g. ``bi-pqn:low=rpy``.
        tol, stop : stop rule of the solve.
        budget : lcpbench.core.context.Budget, optional
        warm_start : bool
            Start from the previous step's forces matched by pair identity.
        qn_memory : bool
            Start the solver's quasi-Newton model from the previous step's
            secant pairs (:meth:`carry_memory`; the PQN solvers use it, others
            ignore it) and keep this solve's pairs for the next step. Off by
            default so that a stepped scene follows the trajectory ``lcpbench
            generate`` stores; ``lcpbench simulate`` turns it on (what it saves:
            docs/benchmarks.md, "Quasi-Newton memory across time steps").
        params : dict, optional
            Extra solver parameters.
        lows : list of str, optional
            The low fidelities to build (:meth:`build`; default all of the scene's).

        Returns
        -------
        lcpbench.core.scene.StepRecord
        """
        return step_scene(self, solver, tol=tol, stop=stop, budget=budget,
                          warm_start=warm_start, qn_memory=qn_memory, params=params, lows=lows)

    def __repr__(self) -> str:
        P = self.params
        return (f"<LatticeScene m={P.m} M={self.M} model={P.model!r} step={self.step_index} "
                f"gamma={self.gamma:.4g} initial_pairs={self.initial_pairs}>")


def _lattice_estimate(params: LatticeParams) -> Estimate:
    """Memory of making the lattice scene and one step's LCP, before making anything.

    The configuration checks and the pair search hold arrays over all M^2 sphere pairs
    (8 bytes a pair, with three such temporaries), and the RPY mobility is a dense 6M x 6M
    matrix; a step's LCP has at most 3M contacts (n).
    """
    M = float(params.m) ** 3
    held = 3 * 8.0 * M * M + (8.0 * (6 * M) ** 2 if params.model == "rpy" else 0.0)
    return Estimate(instances=1, n=int(min(3 * M, 2 ** 62)), bytes=held)


@register_scene("lattice", LatticeParams, estimate=_lattice_estimate)
def lattice(params: LatticeParams) -> LatticeScene:
    """Spheres on an m x m x m lattice packed by an inward pull (the paper's appendix scene)."""
    return LatticeScene(params=params)


@register_scene("paper-lattice", PaperLatticeParams, estimate=_lattice_estimate)
def paper_lattice(params: PaperLatticeParams) -> LatticeScene:
    """The lattice scene with the paper authors' gaps: 0.3a kept separation, spacing 2.5."""
    return LatticeScene(params=params)
