"""The collision-resolution LCP of one time step: contacts, mobility, ``U_nc`` and operators.

With the contacts of :mod:`.contacts` (``D``, gaps ``Phi``), the mobility ``M`` of the
high fidelity and the non-contact loads, one forward Euler step of ``dt`` keeps every
candidate pair apart to first order when the contact forces ``x`` solve the LCP of
eq. (defAandb) of the method paper::

    A = D' M D,      b = (Phi - s + dt D' U_nc) / dt,      U_nc = M [F_ext; T_ext],

with ``s`` the kept separation.  ``A`` is never formed: it is a counted matrix-free
operator (:mod:`.operators`), one forward solve per product (symmetrised with the adjoint
solve on request: ``ContactOptions(symmetrize=True)``).  Low fidelities are named
(:mod:`.fidelity`) and built on the high's set-up where they can share it.  All options are one :class:`ContactOptions`.

Cost ratio.  No operator of the step declares a cost, and no product is made to time one:
every operator is priced by the counted products the solve makes with it anyway
(:attr:`lcpbench.Operator.measured_cost`).  A boundary-integral operator reports its inner
applications (GCR/GMRES products of the traction operator), so its cost is its seconds per
application times its cold applications: the cost of a first product, as the paper's cost
ratio counts it, estimated from all of the solve's products.  The high's cold applications
are those of the non-collisional solve (the high mobility's first product, made anyway);
a low's are those of its first counted product (its own recycled spaces start empty).  So
the ratio is ``(s_low / a_low) c_low / ((s_high / a_high) c_high)`` with ``s`` the seconds
and ``a`` the applications of the solve's products and ``c`` the cold applications; the
analytic models (no applications) are priced by their mean product time.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np
from scipy.sparse.linalg import LinearOperator, aslinearoperator

from lcpbench.core.lcp import LCP
from lcpbench.core.operator import Operator

from .contacts import Contacts
from .fidelity import Configuration, Fidelity, build_mobility, parse_fidelity
from .geometry import check_configuration, check_viscosity
from .operators import ContactOperator, contact_product

__all__ = ["ContactOptions", "ContactProblem", "build_contact_problem", "contact_lcp",
           "resolve_mobility", "MobilityModel"]

#: A mobility model: a fidelity name (``"rpy"``, ``"bim"``, ``"self"``, ``"p4e6"``, ...) or a
#: callable ``f(centers, radii) -> LinearOperator (6M, 6M)``.
MobilityModel = Union[str, Callable[[np.ndarray, np.ndarray], LinearOperator]]


@dataclass(frozen=True)
class ContactOptions:
    """Everything but the configuration and the loads that sets one step's contact LCP.

    Parameters
    ----------
    dt : float
        Time step (> 0).
    delta : float
        Candidate-contact gap threshold (>= 0).
    separation : float
        Minimum gap to keep (``>= 0``, normally below ``delta``): the gap function is
        ``Phi - separation``, so a solved step leaves every candidate pair at least
        ``separation`` apart to first order (default 0).
    model : str or callable
        High-fidelity mobility (:func:`resolve_mobility`).
    p, eps_gmres : int, float
        Boundary-integral order and GMRES tolerance (model "bim", and the defaults of the
        fidelity names that leave them open).
    mu : float
        Viscosity.
    low : list of str or mapping
        Low-fidelity operators ``D' M_low D`` by fidelity name (:func:`.fidelity.parse_fidelity`:
        ``rpy``, ``self``, ``p4``, ``p4e6``, ``p8f6r3e3``, ...) or a mapping name -> model.
    symmetrize : bool, optional
        Use ``A = D' (M + M') D / 2``, symmetrised explicitly with the adjoint mobility solve
        (every MVP then costs two mobility solves; the position update still uses
        ``M D x``).  Default: each fidelity's own, off for every built-in model: the
        boundary-integral ``D' M D`` (one forward solve per MVP) is symmetric only to its
        discretisation error, which moves the answer less than that error
        (docs/mobility.md); RPY and ``self`` are exactly symmetric; the distance-split lows
        are never symmetrised.
    krylov_mb : float
        Memory budget (MB) of the kept Krylov directions that every boundary-integral
        operator of the step shares (the high's forward and transposed recycled spaces,
        its twins at other tolerances, the distance-split lows and the lows of other
        orders): :class:`.bim.recycle.KrylovBudget`, default
        :data:`.bim.recycle.DEFAULT_KRYLOV_MB`; 0 turns recycling off.
    far : {"direct", "fmm", "auto"}
        Far-field engine of the boundary-integral mobilities: compiled direct sums,
        fmm3dpy's Stokes FMM, or ``auto`` (the FMM from the measured crossover
        :data:`.bim.fmm.FAR_CROSSOVER_M` spheres on when fmm3dpy is importable;
        :func:`.bim.fmm.resolve_far`).
    """

    dt: float = 0.1
    delta: float = 0.3
    separation: float = 0.0
    model: MobilityModel = "rpy"
    p: int = 8
    eps_gmres: float = 1e-8
    mu: float = 1.0
    low: Union[Sequence[str], Mapping[str, MobilityModel], str] = ()
    symmetrize: Optional[bool] = None
    krylov_mb: float = 256.0
    far: str = "direct"

    def __post_init__(self) -> None:
        dt = float(self.dt)
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt = {dt} must be a finite positive time step")
        separation = float(self.separation)
        if not (np.isfinite(separation) and separation >= 0):
            raise ValueError(f"separation = {separation} must be a finite number >= 0 (the "
                             "minimum gap the LCP keeps)")
        mb = float(self.krylov_mb)
        if not (np.isfinite(mb) and mb >= 0):
            raise ValueError(f"krylov_mb = {self.krylov_mb!r} must be a finite number of MB >= 0 "
                             "(memory of the kept Krylov directions of one step, e.g. 256)")
        if self.far not in ("auto", "direct", "fmm"):
            raise ValueError(f"far = {self.far!r}; use 'direct', 'fmm' or 'auto' (the far-field "
                             "engine of the boundary-integral mobility)")
        object.__setattr__(self, "krylov_mb", mb)
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "separation", separation)
        object.__setattr__(self, "mu", check_viscosity(self.mu))


@dataclass
class ContactProblem:
    """One step's contacts, mobility, non-contact velocities and LCP.

    Attributes
    ----------
    contacts : Contacts
    mobility : LinearOperator
        High-fidelity mobility ``M`` of the configuration.
    U_nc : ndarray, shape (6M,)
        ``M [F_ext; T_ext]``: velocities without contact forces.
    lcp : LCP
        ``A = D' M D`` (counted, matrix-free; symmetrised with the adjoint solve on
        request), ``b = (Phi - s + dt D' U_nc) / dt``, low-fidelity operators with
        per-instance costs.
    setup_solves : int
        Mobility solves spent building the problem outside the LCP's counters
        (``U_nc``, and cost timing when there was no ``U_nc`` to time).
    nc_density : ndarray or None
        The solution of the non-collisional solve's traction equation (boundary-integral
        high), the next step's ``nc_guess``.
    nc_applications : float or None
        Inner applications of the non-collisional solve (None without a work hook).
    nc_cold_applications : float or None
        The applications it takes from zero: ``nc_applications`` when it started from
        zero, else the ``nc_cold`` it was given (the next step's ``nc_cold``).
    """

    contacts: Contacts
    mobility: LinearOperator
    U_nc: np.ndarray
    lcp: LCP
    _dmd: ContactOperator = field(repr=False)
    setup_solves: int = 0
    nc_density: Optional[np.ndarray] = field(default=None, repr=False)
    nc_applications: Optional[float] = None
    nc_cold_applications: Optional[float] = None

    def velocities(self, x: np.ndarray) -> np.ndarray:
        """``U = U_nc + M D x`` (reuses a product of ``A`` at exactly ``x`` if one was made).

        The framework's verification of a solve applies ``A`` at the returned
        ``x``, so after :func:`lcpbench.core.api.run_solver` this costs no new solve.
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1)
        if x.shape != (self.contacts.n,):
            raise ValueError(f"x has shape {x.shape}; expected ({self.contacts.n},), one force "
                             "per contact")
        return self.U_nc + self._dmd.velocity(x)

    @property
    def pairs(self) -> np.ndarray:
        """Pair identities ``(i, j)`` of the contacts, one row per unknown of the LCP."""
        return self.contacts.pairs

    @property
    def min_gap(self) -> float:
        """Smallest gap among the contacts (nan when there are none)."""
        return float(self.contacts.gaps.min()) if self.contacts.n else float("nan")

    @property
    def extra_solves(self) -> int:
        """Mobility solves of ``M D v`` so far (counted MVPs, verification, update)."""
        return self._dmd.solves


def resolve_mobility(centers, radii, model: MobilityModel = "rpy", p: int = 8,
                     eps_gmres: float = 1e-8, mu: float = 1.0) -> LinearOperator:
    """The ``(6M, 6M)`` mobility operator of a configuration.

    Parameters
    ----------
    model : str or callable
        A fidelity name (``"self"``, ``"rpy"``, ``"bim"``, ``"p4e6"``, ...;
        :mod:`.fidelity`), or a callable ``f(centers, radii) -> LinearOperator`` for a
        user model.
    p, eps_gmres, mu
        Fidelity knobs of the boundary-integral model and the viscosity.
    """
    c, r = check_configuration(centers, radii)
    return _high(c, r, model, p, eps_gmres, check_viscosity(mu))[0]


def _high(c: np.ndarray, r: np.ndarray, model: MobilityModel, p: int, eps_gmres: float,
          mu: float, *, krylov=None, far: str = "direct"
          ) -> tuple[LinearOperator, Optional[Fidelity]]:
    """The high mobility and its description (None for a user callable); a
    boundary-integral one gets the Krylov budget ``krylov`` and the far field ``far``."""
    if callable(model):
        op = model(c, r)
        op = op if isinstance(op, LinearOperator) else aslinearoperator(op)
        M6 = 6 * len(c)
        if op.shape != (M6, M6):
            raise ValueError(f"mobility model {model!r} returned shape {op.shape}; expected "
                             f"({M6}, {M6}) (6 rows per sphere: force then torque)")
        return op, None
    try:
        fid = parse_fidelity(model, p, eps_gmres)
    except ValueError as exc:
        raise ValueError(f"unknown mobility model {model!r}: {exc}; or pass a callable "
                         "(centers, radii) -> LinearOperator") from None
    return build_mobility(fid, Configuration(c, r, mu, krylov=krylov, far=far)), fid


def _low_models(low, p: int, eps_gmres: float) -> dict:
    """Low-fidelity name -> :class:`Fidelity` (or the user's callable)."""
    if isinstance(low, str):
        low = [s for s in low.split(",") if s.strip()]
    if isinstance(low, Mapping):
        return {str(k): (v if callable(v) else parse_fidelity(v, p, eps_gmres))
                for k, v in low.items()}
    out: dict = {}
    for item in low:
        key = str(item).strip()
        if key in out:
            raise ValueError(f"low-fidelity {key!r} is listed twice; name each fidelity once")
        out[key] = parse_fidelity(key, p, eps_gmres)
    return out


def _check_forces(name: str, F, M: int) -> np.ndarray:
    if F is None:
        return np.zeros((M, 3))
    F = np.asarray(F, dtype=np.float64)
    if F.shape != (M, 3):
        raise ValueError(f"{name} must have shape ({M}, 3), one vector per sphere; got {F.shape}")
    if not np.all(np.isfinite(F)):
        raise ValueError(f"{name} has non-finite entries; external loads must be finite")
    return F


def _work(mob: LinearOperator):
    """The mobility's inner-application counter (:meth:`~.bim.BimMobility.work_counts`), the
    ``work`` hook of the counted operator, or None (RPY and the one-sphere model: a product
    is one application)."""
    return getattr(mob, "work_counts", None)


@dataclass(frozen=True)
class _LoadSolve:
    """The non-collisional solve ``U_nc = M [F; T]`` as it was made: velocities, seconds,
    inner applications (None without a work hook) and the preconditioned density ``y``
    (None unless the mobility offers :meth:`~.bim.BimMobility.solve_loads`)."""

    U: np.ndarray
    seconds: float = 0.0
    applications: Optional[float] = None
    density: Optional[np.ndarray] = None


def _load_solve(mob: LinearOperator, FT: np.ndarray, guess: Optional[np.ndarray]) -> _LoadSolve:
    """``U_nc = M [F; T]``, timed, with its inner applications, from ``guess`` when the
    mobility takes one (:meth:`~.bim.BimMobility.solve_loads`)."""
    if not np.any(FT):
        return _LoadSolve(np.zeros(FT.size))
    work = _work(mob)
    before = sum(work().values()) if work is not None else None
    solve = getattr(mob, "solve_loads", None)
    if guess is not None and solve is not None and np.size(guess) != mob.setup.unknowns:
        guess = None                               # another configuration's size
    t0 = time.perf_counter()
    if solve is not None:
        U, y = solve(FT, guess)
    else:
        U, y = mob.matvec(FT), None
    seconds = time.perf_counter() - t0
    apps = sum(work().values()) - before if work is not None and before is not None else None
    return _LoadSolve(np.asarray(U, dtype=np.float64).reshape(-1), seconds, apps, y)


def build_contact_problem(centers, radii, F_ext=None, T_ext=None, *,
                          options: Optional[ContactOptions] = None,
                          x0: Optional[np.ndarray] = None, name: str = "contact",
                          meta: Optional[dict] = None, nc_guess: Optional[np.ndarray] = None,
                          nc_cold: Optional[float] = None, **knobs) -> ContactProblem:
    """Everything one forward Euler step needs (the module docstring has the LCP).

    Parameters
    ----------
    centers : array_like, shape (M, 3)
        Sphere centres.
    radii : float or array_like, shape (M,)
    F_ext, T_ext : array_like, shape (M, 3), optional
        Non-contact forces and torques (zero if omitted).
    options : ContactOptions, optional
        Time step, gaps, mobility and fidelities (default ``ContactOptions()``).
    x0 : array_like, optional
        Warm start (projected to ``x0 >= 0``).
    name : str
        Instance name.
    meta : dict, optional
        Extra metadata (step, scene parameters) merged into ``lcp.meta``.
    nc_guess : ndarray, optional
        Initial guess of the non-collisional solve: the previous step's
        :attr:`ContactProblem.nc_density` (a boundary-integral high only; ignored when its
        size does not match).
    nc_cold : float, optional
        The inner applications the non-collisional solve takes from zero (the previous
        step's :attr:`ContactProblem.nc_cold_applications`): with a guess the solve takes
        fewer, and the high's ``cold_applications`` (the unit of its cost) is this number;
        None leaves them to the high's first counted product.
    **knobs
        Fields of :class:`ContactOptions` that replace those of ``options``
        (``dt=0.1, model="bim"``).

    Returns
    -------
    ContactProblem
        With ``.lcp`` and ``.velocities(x)`` for the position update.

    Raises
    ------
    ValueError
        A bad configuration, load, option or fidelity name.
    TypeError
        A keyword that is not a field of :class:`ContactOptions`.
    """
    opts = _options(options, knobs)
    c, r = check_configuration(centers, radii)
    M = len(c)
    F = _check_forces("F_ext", F_ext, M)
    T = _check_forces("T_ext", T_ext, M)
    contacts = Contacts.from_configuration(c, r, opts.delta)
    krylov = _krylov_budget(opts)
    mob, high_fid = _high(c, r, opts.model, opts.p, opts.eps_gmres, opts.mu, krylov=krylov,
                          far=opts.far)
    FT = np.concatenate([F, T], axis=1).ravel()
    nc = _load_solve(mob, FT, nc_guess)
    U_nc = nc.U
    setup = int(bool(np.any(FT)))
    b = (contacts.gaps - opts.separation) / opts.dt + contacts.D.T @ U_nc
    sym = (high_fid.symmetrized(opts.symmetrize) if high_fid is not None
           else bool(opts.symmetrize))
    dmd = ContactOperator(contacts.D, mob, symmetrize=sym)
    # an iterative model declares its products' accuracy (eps_gmres), an analytic one 0
    # the non-collisional solve is the high mobility's cold product (empty recycled
    # spaces): its inner applications are the high's cold_applications (two solves when
    # symmetrised: about twice as many)
    cold_nc = nc.applications if nc_guess is None else nc_cold
    cold = cold_nc * (2 if sym else 1) if cold_nc else None
    high = Operator(dmd.operator(), name="high", work=_work(mob), cold_applications=cold,
                    rtol=high_fid.product_rtol() if high_fid is not None else None)
    config = Configuration(c, r, opts.mu, mob, high_fid, krylov=krylov, far=opts.far)
    # no declared costs: the paper recomputes the cost ratio at every time step, and here it
    # is measured on the step's own counted products (module docstring, "Cost ratio")
    low_ops = {}
    for key, spec in _low_models(opts.low, opts.p, opts.eps_gmres).items():
        if callable(spec):
            lm, lsym = resolve_mobility(c, r, spec, mu=opts.mu), bool(opts.symmetrize)
            lrtol = None
        else:
            lm, lsym = build_mobility(spec, config), spec.symmetrized(opts.symmetrize)
            lrtol = spec.product_rtol()
        low_ops[key] = Operator(contact_product(lm, contacts.D, lsym), name=key, rtol=lrtol,
                                work=_work(lm))
    info = _meta(meta, opts, M=M, contacts=contacts, sym=sym)
    if x0 is not None:
        x0 = np.maximum(np.asarray(x0, dtype=np.float64).reshape(-1), 0.0)
    lcp = LCP(high, b, x0=x0, low=low_ops, name=name, meta=info)
    return ContactProblem(contacts, mob, U_nc, lcp, dmd, setup, nc_density=nc.density,
                          nc_applications=nc.applications, nc_cold_applications=cold_nc)


def _krylov_budget(opts: ContactOptions):
    """One Krylov budget for the step's boundary-integral operators (None when no model of
    the step is a boundary-integral one, so that RPY steps never import it)."""
    low = opts.low
    names = [opts.model] + (list(low.values()) if isinstance(low, Mapping) else
                            low.split(",") if isinstance(low, str) else list(low))
    if not any(isinstance(m, str) and m.strip().lower() not in ("rpy", "self") for m in names):
        return None
    from .bim.recycle import KrylovBudget
    return KrylovBudget(opts.krylov_mb)


def _options(options: Optional[ContactOptions], knobs: dict) -> ContactOptions:
    """``options`` (default ``ContactOptions()``) with the fields in ``knobs`` replaced."""
    opts = options if options is not None else ContactOptions()
    if not knobs:
        return opts
    names = {f.name for f in dataclasses.fields(ContactOptions)}
    unknown = sorted(set(knobs) - names)
    if unknown:
        raise TypeError(f"unknown contact option(s) {', '.join(unknown)}; the options are "
                        + ", ".join(sorted(names)))
    return dataclasses.replace(opts, **knobs)


def _meta(meta: Optional[dict], opts: ContactOptions, *, M: int, contacts: Contacts,
          sym: bool) -> dict:
    """The LCP's ``meta``: the caller's, then the step's settings."""
    model = opts.model
    info = dict(meta or {})
    info.update(M=M, n=contacts.n, dt=opts.dt, delta=float(opts.delta),
                separation=opts.separation, mu=opts.mu,
                model=model if isinstance(model, str) else getattr(model, "__name__", "custom"),
                p=int(opts.p), eps_gmres=float(opts.eps_gmres),
                symmetric=sym or model in ("rpy", "self"), symmetrized=sym,
                min_gap=float(contacts.gaps.min()) if contacts.n else None)
    return info


def contact_lcp(centers, radii, F_ext=None, T_ext=None, **kwargs) -> LCP:
    """The collision-resolution LCP of one forward Euler step (eq. defAandb).

    Takes the arguments of :func:`build_contact_problem` and returns its ``.lcp``: ``A =
    D' M D`` as a counted matrix-free operator (one mobility solve per MVP, two when
    symmetrised; nothing dense is formed), ``b = (Phi - s + dt D' U_nc) / dt`` with ``U_nc
    = M [F_ext; T_ext]``, and the low-fidelity operators with this instance's costs.

    Examples
    --------
    >>> import numpy as np
    >>> lcp = contact_lcp([[0, 0, 0], [2.1, 0, 0]], 1.0, dt=0.1, delta=0.3, model="self")
    >>> lcp.n, round(float(lcp.b[0]), 12)   # gap 0.1 over dt 0.1, no external load
    (1, 1.0)
    """
    return build_contact_problem(centers, radii, F_ext, T_ext, **kwargs).lcp
