"""The fidelity registry: named mobility models, parsed once into a typed description.

A fidelity name (``rpy``, ``self``, ``bim``, ``p4``, ``p4e6``, ``p8f6e3``, ``p8f6r3e3``) is
parsed once by :func:`parse_fidelity` into a :class:`Fidelity`: the model, the
spherical-harmonic order ``p`` and GMRES tolerance ``eps_gmres`` (validated here and
nowhere else in the fidelity path), and the extra knobs of its kind.  Each kind of name is
one registered :class:`FidelityKind`: a pattern, a function that reads a match into a
:class:`Fidelity`, and a builder that makes the mobility of a configuration.

Adding a low fidelity: write its mobility (a ``LinearOperator`` of shape ``(6M, 6M)``; a
new module, or nothing when it combines existing ones) and register its kind with
:func:`register_fidelity` (here, or in the module that defines it).  Nothing else changes:
scenes, ``lcpbench generate --low`` and the contact problem find it by name
(``tests/test_scene.py::test_a_new_low_fidelity_is_one_registration`` is the worked example).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Optional, cast

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, aslinearoperator

from .geometry import check_configuration, check_order, check_tolerance, check_viscosity

__all__ = ["Fidelity", "FidelityKind", "Configuration", "register_fidelity",
           "unregister_fidelity", "fidelity_kinds", "parse_fidelity", "build_mobility",
           "self_mobility"]


@dataclass(frozen=True)
class Fidelity:
    """A parsed fidelity name.

    Attributes
    ----------
    name : str
        The name as given (stripped).
    kind : str
        The registered kind that parsed it (:func:`fidelity_kinds`).
    model : str
        The mobility model: ``rpy``, ``self``, ``bim`` or a registered kind's own.
    p : int
        Spherical-harmonic order (>= 1; recorded for every model).
    eps_gmres : float
        GMRES tolerance in (0, 1) (recorded for every model).
    extra : dict
        The kind's further knobs (``far_degree``, ``rank_tol`` of a distance-split low).
    """

    name: str
    kind: str
    model: str
    p: int
    eps_gmres: float
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "p", check_order(self.p))
        object.__setattr__(self, "eps_gmres", check_tolerance(self.eps_gmres))

    def knobs(self) -> dict:
        """``{"model": ..., "p": ..., "eps_gmres": ...}`` and the kind's extra knobs: what a
        stored set records per low fidelity."""
        return {"model": self.model, "p": self.p, "eps_gmres": self.eps_gmres, **self.extra}

    def product_rtol(self) -> float:
        """The relative accuracy of a product: ``eps_gmres`` for an iterative kind, else 0
        (what the contact operator declares as ``Operator(rtol=...)``)."""
        return self.eps_gmres if _KINDS[self.kind].iterative else 0.0

    def symmetrized(self, request: Optional[bool] = None) -> bool:
        """Whether the contact operator of this fidelity is symmetrised (with the adjoint
        solve: :mod:`.operators`): its kind's default, or ``request`` when given and the
        kind allows it."""
        kind = _KINDS[self.kind]
        if not kind.symmetrizable:
            return False
        return kind.symmetrize if request is None else bool(request)


@dataclass(frozen=True)
class Configuration:
    """What a fidelity's builder gets: the spheres and the high fidelity already built.

    Attributes
    ----------
    centers, radii : ndarray
        Checked configuration, (M, 3) and (M,).
    mu : float
        Viscosity.
    high : LinearOperator or None
        The high-fidelity mobility of the same configuration (None while the high itself
        is built); a low may share its set-up (``BimMobility.at_tolerance``).
    high_fidelity : Fidelity or None
        The high's description (None for a user callable or while it is built).
    krylov : KrylovBudget or None
        The memory budget of kept Krylov directions that every boundary-integral
        mobility of this configuration shares (:class:`.bim.recycle.KrylovBudget`; None:
        each builds its own default one).
    far : {"auto", "direct", "fmm"}
        Far-field engine of the boundary-integral mobilities (:func:`.bim.fmm.resolve_far`).
    """

    centers: np.ndarray
    radii: np.ndarray
    mu: float = 1.0
    high: Optional[LinearOperator] = None
    high_fidelity: Optional[Fidelity] = None
    krylov: Any = None
    far: str = "direct"

    def same_order_bim(self, fid: Fidelity) -> bool:
        """The high is a boundary-integral mobility of ``fid``'s order (its set-up serves)."""
        h = self.high_fidelity
        return (h is not None and h.model == "bim" and h.p == fid.p
                and hasattr(self.high, "at_tolerance"))


@dataclass(frozen=True)
class FidelityKind:
    """One registered kind of fidelity name.

    Attributes
    ----------
    name : str
        Registry key.
    pattern : str
        Regular expression the lower-cased name must match in full.
    describe : callable
        ``describe(match, p, eps_gmres) -> Fidelity``: the typed description (``p`` and
        ``eps_gmres`` are the defaults for what the name leaves open).
    build : callable
        ``build(fidelity, configuration) -> LinearOperator`` of shape (6M, 6M).
    example : str
        A valid name, for error messages.
    symmetrize : bool
        Symmetrise the contact operator by default (the model is symmetric only to its
        discretisation error).
    symmetrizable : bool
        False for a kind whose contact operator is never symmetrised, even on request.
    iterative : bool
        True for a kind whose products are iterative solves at ``eps_gmres``: its contact
        operator declares that relative accuracy (``Operator(rtol=eps_gmres)``), so the
        framework holds the stop test no tighter than the products resolve and trusts a
        drift bound without measuring the operator; False for an analytic model, whose
        products are exact to rounding (``rtol=0``).
    """

    name: str
    pattern: str
    describe: Callable[[re.Match, int, float], Fidelity]
    build: Callable[[Fidelity, Configuration], LinearOperator]
    example: str
    symmetrize: bool = False
    symmetrizable: bool = True
    iterative: bool = False


_KINDS: dict[str, FidelityKind] = {}


def register_fidelity(kind: FidelityKind) -> FidelityKind:
    """Add a kind of fidelity name to the registry (a kind of the same name is replaced)."""
    re.compile(kind.pattern)
    _KINDS[kind.name] = kind
    return kind


def unregister_fidelity(name: str) -> None:
    """Remove a registered kind (nothing happens for an unknown name)."""
    _KINDS.pop(name, None)


def fidelity_kinds() -> dict[str, FidelityKind]:
    """The registered kinds, in registration order (the first whose pattern matches wins)."""
    return dict(_KINDS)


def parse_fidelity(name: str, p: int, eps_gmres: float) -> Fidelity:
    """The typed description of a fidelity name.

    Parameters
    ----------
    name : str
        ``"rpy"``, ``"self"`` (no interactions), ``"bim"`` (boundary integral at the given
        ``p`` and ``eps_gmres``), ``"p<k>"`` (order ``k``), ``"p<k>e<j>"`` (order ``k``,
        GMRES tolerance ``1e-j``), e.g. ``p4e6``, ``"p<k>f<q>e<j>"``: order ``k`` near
        contact with the far field truncated at degree ``q`` (:mod:`.bim.split`), e.g.
        ``p8f4e3``, and ``"p<k>f<q>r<i>e<j>"`` with its blocks compressed to the singular
        values above ``1e-i`` of each block's largest, e.g. ``p8f6r3e3``; or the name of a
        registered kind.
    p, eps_gmres
        The defaults for the parts the name leaves open.

    Raises
    ------
    ValueError
        An unknown name, or knobs out of range (the message names the rule and an example).
    """
    key = str(name).strip().lower()
    for kind in _KINDS.values():
        m = re.fullmatch(kind.pattern, key)
        if m:
            try:
                return kind.describe(m, p, eps_gmres)
            except ValueError as exc:
                if str(exc).startswith("fidelity "):
                    raise
                raise ValueError(f"fidelity {name!r}: {exc}") from None
    examples = ", ".join(k.example for k in _KINDS.values())
    raise ValueError(f"unknown fidelity {name!r}; use rpy, self, bim, p<k> (boundary integral "
                     "at order k), p<k>e<j> (order k, GMRES tolerance 1e-j), p<k>f<q>e<j> (far "
                     "field truncated at degree q) or p<k>f<q>r<i>e<j> (its blocks compressed "
                     f"at 1e-i); e.g. {examples}")


def build_mobility(fid: Fidelity, config: Configuration) -> LinearOperator:
    """The mobility of ``config`` at fidelity ``fid`` (its kind's builder), shape checked.

    Raises
    ------
    ValueError
        The builder returned another shape than (6M, 6M).
    """
    op = _KINDS[fid.kind].build(fid, config)
    M6 = 6 * len(config.centers)
    if op.shape != (M6, M6):
        raise ValueError(f"fidelity {fid.name!r} returned shape {op.shape}; expected "
                         f"({M6}, {M6}) (6 rows per sphere: force then torque)")
    return op


# ----------------------------------------------------------------------------- the models


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


def _tolerance(group: Optional[str], eps_gmres: float) -> float:
    return float(f"1e-{group}") if group else float(eps_gmres)


def _build_analytic(fid: Fidelity, config: Configuration) -> LinearOperator:
    from . import mobility

    if fid.model == "self":
        return self_mobility(config.centers, config.radii, config.mu)
    return mobility(config.centers, config.radii, model="rpy", mu=config.mu)


def _build_bim(fid: Fidelity, config: Configuration) -> LinearOperator:
    """A boundary-integral low of the high's own order is built on the high's set-up
    (:meth:`.bim.BimMobility.at_tolerance`): it differs only by where GMRES stops."""
    if config.same_order_bim(fid):
        return config.high.at_tolerance(fid.eps_gmres)        # type: ignore[union-attr]
    from .bim import bim_mobility

    return bim_mobility(config.centers, config.radii, p=fid.p, eps_gmres=fid.eps_gmres,
                        mu=config.mu, krylov=config.krylov, far=config.far)


def _build_split(fid: Fidelity, config: Configuration) -> LinearOperator:
    """The distance-split low (:mod:`.bim.split`) on the high's set-up when the orders agree."""
    from .bim import BimMobility, bim_mobility, split_mobility

    base = (cast(BimMobility, config.high) if config.same_order_bim(fid)
            else bim_mobility(config.centers, config.radii, p=fid.p, eps_gmres=fid.eps_gmres,
                              mu=config.mu, krylov=config.krylov, far=config.far))
    return split_mobility(base, fid.extra["far_degree"], fid.eps_gmres,
                          rank_tol=fid.extra.get("rank_tol"))


def _describe_named(m: re.Match, p: int, eps_gmres: float) -> Fidelity:
    key = m.group(0)
    return Fidelity(key, "named", key, p, eps_gmres)


def _describe_bim(m: re.Match, p: int, eps_gmres: float) -> Fidelity:
    if m.group(0) == "bim":                        # the given order and tolerance
        return Fidelity("bim", "bim", "bim", p, eps_gmres)
    return Fidelity(m.group(0), "bim", "bim", int(m.group(1)), _tolerance(m.group(2), eps_gmres))


def _describe_split(m: re.Match, p: int, eps_gmres: float) -> Fidelity:
    name, order = m.group(0), int(m.group(1))
    if m.group(2) is None:
        raise ValueError(f"fidelity {name!r}: block compression r<i> belongs to a "
                         "distance-split fidelity; give its far-field degree too, e.g. p8f6r3e3")
    q = int(m.group(2))
    if not 1 <= q <= order:
        raise ValueError(f"fidelity {name!r}: the far-field degree {q} must be between "
                         f"1 and the order {order}, e.g. p8f4e3")
    extra: dict = {"far_degree": q}
    if m.group(3) is not None:
        i = int(m.group(3))
        if i < 1:
            raise ValueError(f"fidelity {name!r}: the compression r{i} must cut at 1e-1 "
                             "or below, e.g. r3 for 1e-3")
        extra["rank_tol"] = float(f"1e-{i}")
    return Fidelity(name, "split", "bim", order, _tolerance(m.group(4), eps_gmres), extra)


register_fidelity(FidelityKind("named", r"rpy|self", _describe_named, _build_analytic, "rpy"))
# one forward solve per product by default; symmetrize=True pairs it with the adjoint solve
# (docs/mobility.md, "One solve per product": the answer moves by half the asymmetry, less
# than its discretisation error, and the solvers need the same MVPs)
register_fidelity(FidelityKind("bim", r"bim|p(\d+)(?:e(\d+))?", _describe_bim, _build_bim, "p4e6",
                               iterative=True))
# one forward solve per product, never symmetrised (:mod:`.bim.split` says why that is enough)
register_fidelity(FidelityKind("split", r"p(\d+)(?:f(\d+))?(?:r(\d+))?(?:e(\d+))?",
                               _describe_split, _build_split, "p8f6r3e3", symmetrizable=False,
                               iterative=True))
