"""Contacts between spheres and the collision-resolution LCP of one time step.

Given sphere centres ``c`` and radii ``a``, a pair ``(i, j)``, ``i < j``, is a
candidate contact when its surface gap ``Phi = |c_j - c_i| - a_i - a_j`` is at
most ``delta`` (eq. collisional-set of the method paper). Contact ``l`` has the
unit normal ``n_l = (c_j - c_i) / |c_j - c_i|`` (from ``i`` to ``j``) and the
column ``D[:, l]`` of the sparse ``(6M, n)`` contact matrix carries ``-n_l`` on
the force rows of sphere ``i`` and ``+n_l`` on those of sphere ``j``; the
torque rows are zero because a frictionless normal force on a sphere passes
through its centre.

Sign convention (checked in the tests): a force magnitude ``x_l >= 0`` pushes
``j`` along ``+n_l`` and ``i`` along ``-n_l``, i.e. apart; the rate of change
of the gap is ``d Phi_l / dt = n_l . (U_j - U_i) = (D' U)_l``, so
``Phi + dt D' U >= 0`` is non-penetration after a forward Euler step to first
order, and with ``U = U_nc + M D x`` it gives the LCP of eq. (defAandb)::

    A = D' M D,      b = (Phi + dt D' U_nc) / dt.

Vectors of forces and velocities are ordered per sphere: ``(F_i, T_i)`` on
rows ``6 i .. 6 i + 5`` map to ``(U_i, Omega_i)`` on the same rows.

``A`` is never formed: it is a counted matrix-free operator. For ``rpy`` and
``self`` (exactly symmetric mobilities) a product is one mobility solve,
``v -> D' (M (D v))``. The discrete boundary-integral mobility is symmetric only
to its discretisation error (about 1e-3 near contact at p = 6, see
docs/mobility.md), so its contact operator is symmetrised explicitly,
``v -> D' (M + M') D v / 2``, with the exact adjoint of the discrete mobility
(``BimMobility.rmatvec``, GMRES on the transposed equation): one forward and one
adjoint solve per MVP, both inside the counted product, and the per-instance
cost measurement includes both (``symmetrize=False`` gives the one-solve,
slightly asymmetric operator; ``lcp.meta["symmetrized"]`` says which).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, aslinearoperator

from lcpbench.core.lcp import LCP
from lcpbench.core.operator import Operator, measure_cost

from .geometry import check_configuration, check_viscosity, pair_gaps

__all__ = ["Contacts", "ContactProblem", "build_contact_problem", "contact_lcp",
           "resolve_mobility", "self_mobility", "parse_fidelity", "max_overlap",
]

#: A mobility model: a name (``"rpy"``, ``"bim"``, ``"self"``) or a callable
#: ``f(centers, radii) -> LinearOperator (6M, 6M)``.
MobilityModel = Union[str, Callable[[np.ndarray, np.ndarray], LinearOperator]]


# ----------------------------------------------------------------------------- contacts


@dataclass(frozen=True)
class Contacts:
    """Candidate contacts of a sphere configuration.

    Build with :meth:`from_configuration`.

    Attributes
    ----------
    pairs : ndarray, shape (n, 2), int
        Sphere indices ``(i, j)``, ``i < j``, sorted lexicographically: the pair
        identity of each column (used to carry forces across time steps).
    normals : ndarray, shape (n, 3)
        Unit normals from sphere ``i`` to sphere ``j``.
    gaps : ndarray, shape (n,)
        Surface gaps ``Phi`` (negative when the pair overlaps).
    D : scipy.sparse.csc_matrix, shape (6M, n)
        Contact matrix: ``F_c = D x`` are the forces and torques of the contact
        force magnitudes ``x``.
    M : int
        Number of spheres.
    delta : float
        Gap threshold the pairs were selected with.
    """

    pairs: np.ndarray
    normals: np.ndarray
    gaps: np.ndarray
    D: sp.csc_matrix
    M: int
    delta: float

    @classmethod
    def from_configuration(cls, centers, radii, delta: float) -> Contacts:
        """Candidate pairs with gap ``<= delta``, their normals, gaps and ``D``.

        Parameters
        ----------
        centers : array_like, shape (M, 3)
        radii : float or array_like, shape (M,)
        delta : float
            Gap threshold (finite, non-negative), in the units of the centres.

        Raises
        ------
        ValueError
            Invalid configuration (see :func:`check_configuration`) or ``delta``.
        """
        c, r = check_configuration(centers, radii)
        delta = float(delta)
        if not (np.isfinite(delta) and delta >= 0):
            raise ValueError(f"delta = {delta} must be a finite non-negative gap threshold "
                             "(e.g. a few times the largest displacement per step)")
        pairs, gaps = pair_gaps(c, r, delta)
        M, n = len(c), len(pairs)
        d = c[pairs[:, 1]] - c[pairs[:, 0]] if n else np.empty((0, 3))
        dist = np.linalg.norm(d, axis=1)
        normals = d / dist[:, None] if n else d
        rows = np.concatenate([6 * pairs[:, 0][:, None] + np.arange(3),
                               6 * pairs[:, 1][:, None] + np.arange(3)], axis=1).ravel()
        cols = np.repeat(np.arange(n), 6)
        vals = np.concatenate([-normals, normals], axis=1).ravel()
        D = sp.csc_matrix((vals, (rows, cols)), shape=(6 * M, n))
        return cls(pairs.astype(np.intp), normals, gaps, D, M, delta)

    @property
    def n(self) -> int:
        """Number of candidate contacts."""
        return int(len(self.pairs))

    def pair_ids(self) -> list[tuple[int, int]]:
        """``(i, j)`` per column, for matching forces across time steps."""
        return [(int(i), int(j)) for i, j in self.pairs]

    def index_of(self, old_pairs: np.ndarray) -> np.ndarray:
        """Where each of these contacts was among ``old_pairs`` (pair identity), -1 if new.

        Parameters
        ----------
        old_pairs : ndarray, shape (k, 2)
            Pair identities of a previous step's contacts.

        Returns
        -------
        ndarray of int, shape (n,)
            ``index[l] = k`` when contact ``l`` is the pair ``old_pairs[k]``, else ``-1``;
            ``old_vector[index]`` (where ``index >= 0``) moves a previous step's
            per-contact vector onto these contacts.
        """
        old_pairs = np.asarray(old_pairs, dtype=np.intp).reshape(-1, 2)
        out = np.full(self.n, -1, dtype=np.intp)
        if not self.n or not len(old_pairs):
            return out
        lookup = {(int(i), int(j)): k for k, (i, j) in enumerate(old_pairs)}
        for row, (i, j) in enumerate(self.pairs):
            out[row] = lookup.get((int(i), int(j)), -1)
        return out

    def carry(self, old_pairs: np.ndarray, old_x: np.ndarray) -> np.ndarray:
        """Forces of a previous step mapped onto these contacts by pair identity.

        Parameters
        ----------
        old_pairs : ndarray, shape (k, 2)
            Pair identities of the previous step's contacts.
        old_x : ndarray, shape (k,)
            Their force magnitudes.

        Returns
        -------
        ndarray, shape (n,)
            ``old_x`` of the same pair where it existed before, 0 for new pairs;
            negative or non-finite old values become 0.
        """
        old_pairs = np.asarray(old_pairs, dtype=np.intp).reshape(-1, 2)
        old_x = np.asarray(old_x, dtype=np.float64).reshape(-1)
        if len(old_pairs) != len(old_x):
            raise ValueError(f"carry: {len(old_pairs)} pairs but {len(old_x)} forces; pass "
                             "the pairs and forces of the same step")
        index = self.index_of(old_pairs)
        out = np.zeros(self.n)
        out[index >= 0] = old_x[index[index >= 0]]
        out[~np.isfinite(out)] = 0.0
        return np.maximum(out, 0.0)


def max_overlap(centers: np.ndarray, radii: np.ndarray) -> float:
    """Largest overlap ``max(0, -min gap)`` over all pairs of spheres."""
    _, gaps = pair_gaps(np.asarray(centers, float), np.asarray(radii, float), 0.0)
    return float(max(0.0, -gaps.min())) if len(gaps) else 0.0


# ----------------------------------------------------------------------------- mobility


def self_mobility(centers, radii, mu: float = 1.0) -> LinearOperator:
    """Block-diagonal one-sphere mobility (no hydrodynamic interactions).

    ``U_i = F_i / (6 pi mu a_i)``, ``Omega_i = T_i / (8 pi mu a_i^3)``: exact for
    one sphere and the cheapest low-fidelity model of any suspension mobility.
    """
    _, r = check_configuration(centers, radii)
    mu = check_viscosity(mu)
    t = 1.0 / (6.0 * np.pi * mu * r)
    w = 1.0 / (8.0 * np.pi * mu * r ** 3)
    diag = np.column_stack([t, t, t, w, w, w]).ravel()
    return aslinearoperator(sp.diags(diag))


_FIDELITY = re.compile(r"^p(\d+)(?:f(\d+))?(?:r(\d+))?(?:e(\d+))?$")


def parse_fidelity(name: str, p: int, eps_gmres: float) -> dict:
    """Mobility settings of a named fidelity.

    Parameters
    ----------
    name : str
        ``"rpy"``, ``"self"`` (no interactions), ``"bim"`` (boundary integral at
        the given ``p`` and ``eps_gmres``), ``"p<k>"`` (boundary integral at order
        ``k``), ``"p<k>e<j>"`` (order ``k``, GMRES tolerance ``1e-j``), e.g.
        ``p4e6`` for the paper's low fidelity ``p = 4, eps = 1e-6``, or
        ``"p<k>f<q>e<j>"``: order ``k`` near contact with the far field truncated at
        degree ``q`` (:mod:`.bim_split`), e.g. ``p8f4e3``, and ``"p<k>f<q>r<i>e<j>"``
        with its blocks compressed to the singular values above ``1e-i`` of each block's
        largest, e.g. ``p8f6r3e3``.
    p, eps_gmres
        The defaults for the parts the name leaves open.

    Returns
    -------
    dict
        ``{"model": ..., "p": ..., "eps_gmres": ...}``, and ``"far_degree"`` (and
        ``"rank_tol"`` when compressed) for a distance-split fidelity.
    """
    key = str(name).strip().lower()
    if key in ("rpy", "self", "bim"):
        return {"model": key, "p": int(p), "eps_gmres": float(eps_gmres)}
    m = _FIDELITY.match(key)
    if m:
        eps = float(f"1e-{m.group(4)}") if m.group(4) else float(eps_gmres)
        out = {"model": "bim", "p": int(m.group(1)), "eps_gmres": eps}
        if m.group(2) is not None:
            q = int(m.group(2))
            if not 1 <= q <= out["p"]:
                raise ValueError(f"fidelity {name!r}: the far-field degree {q} must be between "
                                 f"1 and the order {out['p']}, e.g. p8f4e3")
            out["far_degree"] = q
        if m.group(3) is not None:
            if m.group(2) is None:
                raise ValueError(f"fidelity {name!r}: block compression r<i> belongs to a "
                                 "distance-split fidelity; give its far-field degree too, "
                                 "e.g. p8f6r3e3")
            i = int(m.group(3))
            if i < 1:
                raise ValueError(f"fidelity {name!r}: the compression r{i} must cut at 1e-1 "
                                 "or below, e.g. r3 for 1e-3")
            out["rank_tol"] = float(f"1e-{i}")
        return out
    raise ValueError(f"unknown fidelity {name!r}; use rpy, self, bim, p<k> (boundary integral "
                     "at order k), p<k>e<j> (order k, GMRES tolerance 1e-j), e.g. p4e6, or "
                     "p<k>f<q>e<j> (far field truncated at degree q), e.g. p8f4e3, or "
                     "p<k>f<q>r<i>e<j> (its blocks compressed at 1e-i), e.g. p8f6r3e3")


def resolve_mobility(centers, radii, model: MobilityModel = "rpy", p: int = 8,
                     eps_gmres: float = 1e-8, mu: float = 1.0) -> LinearOperator:
    """The ``(6M, 6M)`` mobility operator of a configuration.

    Parameters
    ----------
    model : str or callable
        ``"self"`` (:func:`self_mobility`), ``"rpy"`` or ``"bim"`` (from
        ``lcpbench.problems.suspension.mobility``), or a callable
        ``f(centers, radii) -> LinearOperator`` for a user model.
    p, eps_gmres, mu
        Fidelity knobs of the boundary-integral model and the viscosity.
    """
    if callable(model):
        op = model(centers, radii)
        op = op if isinstance(op, LinearOperator) else aslinearoperator(op)
    elif model == "self":
        op = self_mobility(centers, radii, mu)
    elif model in ("rpy", "bim"):
        try:
            from lcpbench.problems.suspension import mobility

            op = mobility(centers, radii, model=model, p=p, eps_gmres=eps_gmres, mu=mu)
        except ImportError as exc:
            raise ValueError(f"mobility model {model!r} is not available ({exc}); the "
                             "suspension backend is incomplete: reinstall lcpbench or use "
                             "model='rpy' or 'self'") from None
    else:
        raise ValueError(f"unknown mobility model {model!r}; use 'rpy', 'bim', 'self' or a "
                         "callable (centers, radii) -> LinearOperator")
    M6 = 6 * len(np.asarray(centers).reshape(-1, 3))
    if op.shape != (M6, M6):
        raise ValueError(f"mobility model {model!r} returned shape {op.shape}; expected "
                         f"({M6}, {M6}) (6 rows per sphere: force then torque)")
    return op


def _apply(M: LinearOperator, v: np.ndarray) -> np.ndarray:
    return np.asarray(M.matvec(v), dtype=np.float64).reshape(-1)


def _apply_adjoint(M: LinearOperator, v: np.ndarray) -> np.ndarray:
    return np.asarray(M.rmatvec(v), dtype=np.float64).reshape(-1)


def _forward_and_adjoint(M: LinearOperator, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(M f, M' f)``, in one call when the operator makes both together
    (``BimMobility.matvec_rmatvec``: the two solves in lock step)."""
    both = getattr(M, "matvec_rmatvec", None)
    if both is None:
        return _apply(M, f), _apply_adjoint(M, f)
    u, ua = both(f, f)
    return (np.asarray(u, dtype=np.float64).reshape(-1),
            np.asarray(ua, dtype=np.float64).reshape(-1))


def _symmetrized(M: LinearOperator, D: sp.csc_matrix, Dt: sp.csr_matrix, v: np.ndarray,
                 forward: Optional[np.ndarray] = None) -> np.ndarray:
    """``D' (M + M') D v / 2``: the explicitly symmetrised contact operator (one forward
    and one adjoint mobility solve; ``forward`` = ``M D v`` when already known)."""
    Dv = D @ v
    if forward is None:
        u, ua = _forward_and_adjoint(M, Dv)
    else:
        u, ua = forward, _apply_adjoint(M, Dv)
    return Dt @ (0.5 * (u + ua))


def needs_symmetrizing(model: MobilityModel) -> bool:
    """Whether the contact operator of ``model`` is symmetrised by default: the
    boundary-integral mobility (and its named fidelities) is symmetric only to its
    discretisation error; RPY and the one-sphere model are exactly symmetric; a
    user callable is taken as it is."""
    return isinstance(model, str) and parse_fidelity(model, 1, 0.5)["model"] == "bim"


# ----------------------------------------------------------------------------- LCP


class _DMD:
    """``v -> D' M D v`` (or ``D' (M + M') D v / 2`` with ``symmetrize``) with a small
    cache of ``M D v`` for the position update."""

    def __init__(self, D: sp.csc_matrix, M: LinearOperator, cache: int = 8,
                 symmetrize: bool = False):
        self.D, self.Dt, self.M = D, D.T.tocsr(), M
        self._cache: list[tuple[np.ndarray, np.ndarray]] = []
        self._size = cache
        self.symmetrize = bool(symmetrize)
        self.solves = 0

    def _cached(self, v: np.ndarray) -> Optional[np.ndarray]:
        for key, u in reversed(self._cache):
            if key.shape == v.shape and np.array_equal(key, v):
                return u
        return None

    def _remember(self, v: np.ndarray, u: np.ndarray) -> None:
        self._cache.append((v.copy(), u))
        del self._cache[:-self._size]

    def velocity(self, v: np.ndarray) -> np.ndarray:
        """``M D v``: from the cache when ``v`` was applied before, else one solve."""
        v = np.asarray(v, dtype=np.float64).reshape(-1)
        if not np.any(v):
            return np.zeros(self.D.shape[0])
        u = self._cached(v)
        if u is None:
            u = _apply(self.M, self.D @ v)
            self.solves += 1
            self._remember(v, u)
        return u.copy()

    def matvec(self, v: np.ndarray) -> np.ndarray:
        if not self.symmetrize:
            return self.Dt @ self.velocity(v)
        v = np.asarray(v, dtype=np.float64).reshape(-1)
        if not np.any(v):
            return np.zeros(self.D.shape[1])
        u = self._cached(v)
        if u is not None:
            self.solves += 1                              # the adjoint solve
            return _symmetrized(self.M, self.D, self.Dt, v, forward=u)
        u, ua = _forward_and_adjoint(self.M, self.D @ v)  # both solves, together
        self.solves += 2
        self._remember(v, u)
        return self.Dt @ (0.5 * (u + ua))

    def operator(self) -> LinearOperator:
        n = self.D.shape[1]
        return LinearOperator((n, n), matvec=self.matvec, rmatvec=self.matvec, dtype=np.float64)


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
        ``A = D' M D`` (counted, matrix-free; symmetrised for the boundary-integral
        model, see :func:`contact_lcp`), ``b = (Phi - s + dt D' U_nc) / dt``,
        low-fidelity operators with per-instance costs.
    setup_solves : int
        Mobility solves spent building the problem outside the LCP's counters
        (``U_nc`` and cost timing).
    """

    contacts: Contacts
    mobility: LinearOperator
    U_nc: np.ndarray
    lcp: LCP
    _dmd: _DMD = field(repr=False)
    setup_solves: int = 0

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
    def extra_solves(self) -> int:
        """Mobility solves of ``M D v`` so far (counted MVPs, verification, update)."""
        return self._dmd.solves


def _check_forces(name: str, F, M: int) -> np.ndarray:
    if F is None:
        return np.zeros((M, 3))
    F = np.asarray(F, dtype=np.float64)
    if F.shape != (M, 3):
        raise ValueError(f"{name} must have shape ({M}, 3), one vector per sphere; got {F.shape}")
    if not np.all(np.isfinite(F)):
        raise ValueError(f"{name} has non-finite entries; external loads must be finite")
    return F


def build_contact_problem(centers, radii, F_ext=None, T_ext=None, dt: float = 0.1,
                          delta: float = 0.3, model: MobilityModel = "rpy", p: int = 8,
                          eps_gmres: float = 1e-8, mu: float = 1.0,
                          low: Union[Sequence[str], Mapping[str, MobilityModel]] = (),
                          x0: Optional[np.ndarray] = None, name: str = "contact",
                          meta: Optional[dict] = None,
                          separation: float = 0.0,
                          symmetrize: Optional[bool] = None) -> ContactProblem:
    """Everything one forward Euler step needs: see :func:`contact_lcp` for the parameters.

    Returns
    -------
    ContactProblem
        With ``.lcp`` and ``.velocities(x)`` for the position update.
    """
    c, r = check_configuration(centers, radii)
    mu = check_viscosity(mu)
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt = {dt} must be a finite positive time step")
    M = len(c)
    F = _check_forces("F_ext", F_ext, M)
    T = _check_forces("T_ext", T_ext, M)
    contacts = Contacts.from_configuration(c, r, delta)
    mob = resolve_mobility(c, r, model, p, eps_gmres, mu)
    FT = np.concatenate([F, T], axis=1).ravel()
    U_nc = _apply(mob, FT) if np.any(FT) else np.zeros(6 * M)
    setup = int(bool(np.any(FT)))
    separation = float(separation)
    if not (np.isfinite(separation) and separation >= 0):
        raise ValueError(f"separation = {separation} must be a finite number >= 0 (the "
                         "minimum gap the LCP keeps)")
    b = (contacts.gaps - separation) / dt + contacts.D.T @ U_nc
    sym = needs_symmetrizing(model) if symmetrize is None else bool(symmetrize)
    dmd = _DMD(contacts.D, mob, symmetrize=sym)
    lows = _low_models(low, p, eps_gmres)
    high = Operator(dmd.operator(), name="high")
    low_ops, low_mobs = {}, {}
    Dt = contacts.D.T.tocsr()
    for key, spec in lows.items():
        lm = _low_mobility(mob, spec, c, r, p if model == "bim" else None, mu)
        low_mobs[key] = lm
        lsym = needs_symmetrizing(spec["model"]) if symmetrize is None else sym
        if "far_degree" in spec:
            lsym = False               # one solve per product (bim_split: why that is enough)

        def mv(v, lm=lm, lsym=lsym):
            return _symmetrized(lm, contacts.D, Dt, v) if lsym else Dt @ _apply(lm, contacts.D @ v)

        low_ops[key] = Operator(LinearOperator((contacts.n, contacts.n), dtype=np.float64,
                                               matvec=mv), name=key)
    if low_ops and contacts.n:
        # the paper recomputes the cost ratio at every time step: time one product of each,
        # at the cost of a first product (measure_cost with cold: no recycled directions)
        high = Operator(high, cost=measure_cost(high, cold=_cold(mob)), name="high")
        setup += 1
        low_ops = {k: Operator(op, cost=measure_cost(op, cold=_cold(low_mobs[k])), name=k)
                   for k, op in low_ops.items()}
    info = dict(meta or {})
    info.update(M=M, n=contacts.n, dt=dt, delta=float(delta), separation=separation, mu=mu,
                model=model if isinstance(model, str) else getattr(model, "__name__", "custom"),
                p=int(p), eps_gmres=float(eps_gmres),
                symmetric=sym or model in ("rpy", "self"), symmetrized=sym,
                min_gap=float(contacts.gaps.min()) if contacts.n else None)
    if x0 is not None:
        x0 = np.maximum(np.asarray(x0, dtype=np.float64).reshape(-1), 0.0)
    lcp = LCP(high, b, x0=x0, low=low_ops, name=name, meta=info)
    return ContactProblem(contacts, mob, U_nc, lcp, dmd, setup)


def _cold(mob: LinearOperator):
    """The mobility's :meth:`~.bim.BimMobility.cold_products` when it keeps state between
    products (recycled Krylov directions), else None (RPY and the one-sphere model do not)."""
    return getattr(mob, "cold_products", None)


def _low_mobility(high: LinearOperator, spec: dict, c: np.ndarray, r: np.ndarray,
                  high_p: Optional[int], mu: float) -> LinearOperator:
    """The mobility of one low fidelity; a boundary-integral low of the high's own order is
    built on the high's set-up (:meth:`BimMobility.at_tolerance`, :mod:`.bim_split`)."""
    same = spec["model"] == "bim" and spec["p"] == high_p and hasattr(high, "at_tolerance")
    if "far_degree" in spec:
        from .bim_split import split_mobility

        base = high if same else resolve_mobility(c, r, "bim", spec["p"], spec["eps_gmres"], mu)
        return split_mobility(base, spec["far_degree"], spec["eps_gmres"],
                              rank_tol=spec.get("rank_tol"))
    if same:
        return high.at_tolerance(spec["eps_gmres"])
    return resolve_mobility(c, r, spec["model"], spec["p"], spec["eps_gmres"], mu)


def _low_models(low, p: int, eps_gmres: float) -> dict:
    if isinstance(low, str):
        low = [s for s in low.split(",") if s.strip()]
    if isinstance(low, Mapping):
        out = {}
        for k, v in low.items():
            out[str(k)] = ({"model": v, "p": p, "eps_gmres": eps_gmres} if callable(v)
                           else parse_fidelity(v, p, eps_gmres))
        return out
    out = {}
    for item in low:
        key = str(item).strip()
        if key in out:
            raise ValueError(f"low-fidelity {key!r} is listed twice; name each fidelity once")
        out[key] = parse_fidelity(key, p, eps_gmres)
    return out


def contact_lcp(centers, radii, F_ext=None, T_ext=None, dt: float = 0.1, delta: float = 0.3,
                model: MobilityModel = "rpy", p: int = 8, eps_gmres: float = 1e-8,
                mu: float = 1.0, low: Union[Sequence[str], Mapping[str, MobilityModel]] = (),
                x0: Optional[np.ndarray] = None, name: str = "contact",
                meta: Optional[dict] = None, separation: float = 0.0,
                symmetrize: Optional[bool] = None) -> LCP:
    """The collision-resolution LCP of one forward Euler step (eq. defAandb).

    Parameters
    ----------
    centers : array_like, shape (M, 3)
        Sphere centres.
    radii : float or array_like, shape (M,)
    F_ext, T_ext : array_like, shape (M, 3), optional
        Non-contact forces and torques (zero if omitted).
    dt : float
        Time step (> 0).
    delta : float
        Candidate-contact gap threshold (>= 0).
    model : {"rpy", "bim", "self"} or callable
        High-fidelity mobility (see :func:`resolve_mobility`).
    p, eps_gmres : int, float
        Boundary-integral order and GMRES tolerance (model "bim").
    mu : float
        Viscosity.
    low : list of str or mapping
        Low-fidelity operators ``D' M_low D`` by fidelity name (see
        :func:`parse_fidelity`: ``rpy``, ``self``, ``p4``, ``p4e6``, ...) or a
        mapping name -> model. Their cost, and the high-fidelity cost, are
        measured on this instance (one timed uncounted product each) and
        declared on the operators, so E-MVPs use this step's cost ratio.
    x0 : array_like, optional
        Warm start (projected to ``x0 >= 0``).
    name : str
        Instance name.
    meta : dict, optional
        Extra metadata (step, scene parameters) merged into ``lcp.meta``.
    separation : float
        Minimum gap to keep (``>= 0``, normally below ``delta``): the gap function
        is ``Phi - separation``, so a solved step leaves every candidate pair
        at least ``separation`` apart to first order (default 0).
    symmetrize : bool, optional
        Use ``A = D' (M + M') D / 2``, symmetrised explicitly with the adjoint
        mobility solve (``M.rmatvec``): every MVP then costs two mobility solves,
        and the position update still uses ``M D x``.  Default: on for the
        boundary-integral model and its fidelities (symmetric only to the
        discretisation error, about 1e-3 near contact at p = 6; docs/mobility.md),
        off for RPY and ``self`` (exactly symmetric) and for user callables.

    Returns
    -------
    LCP
        ``A = D' M D`` as a counted matrix-free operator (one mobility solve per
        MVP; nothing dense is formed), ``b = (Phi - s + dt D' U_nc) / dt`` with
        ``U_nc = M [F_ext; T_ext]``, and the low-fidelity operators.

    Examples
    --------
    >>> import numpy as np
    >>> lcp = contact_lcp([[0, 0, 0], [2.1, 0, 0]], 1.0, dt=0.1, delta=0.3, model="self")
    >>> lcp.n, round(float(lcp.b[0]), 12)   # gap 0.1 over dt 0.1, no external load
    (1, 1.0)
    """
    return build_contact_problem(centers, radii, F_ext, T_ext, dt, delta, model, p, eps_gmres,
                                 mu, low, x0, name, meta, separation, symmetrize).lcp
