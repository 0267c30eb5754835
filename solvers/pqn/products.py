"""PQN's product rules: what the iteration's one product with ``Q`` is applied to.

Algorithm 1 and Algorithm 3 of the method paper make one product per iteration, ``Q p``
for the direction ``p``, and move the gradient by the recurrence ``G + eta Q p`` (Remark 2).
A :class:`ProductRule` makes that product for the loop:

* :class:`DirectionProducts`: ``Q p``, as in the paper (``products=paper``);
* :class:`IterateProducts`: ``Q (x + p) - Q x``, the product of the new point, optionally
  made to a looser accuracy (``products=iterate``, ``relax``). Its accuracy argument is in
  its docstring.

The loops call :meth:`ProductRule.product` once per iteration, :meth:`ProductRule.stepped`
after the step and :meth:`ProductRule.restart` after an exact gradient, and never ask
which rule they hold.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional, Protocol

import numpy as np

from lcpbench.core.residuals import kkt_abs

__all__ = ["ProductRule", "DirectionProducts", "IterateProducts", "LowPoints"]


class ProductRule(Protocol):
    """How a PQN loop gets ``Q p`` for its step from ``z`` (gradient ``G``) along ``p``."""

    def product(self, z: np.ndarray, G: np.ndarray, p: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """``(Q p, G)``: the product and the gradient to step from (``G`` itself, or
        ``G`` recomputed when the rule had to refresh it)."""

    def stepped(self, eta: float) -> None:
        """The step ``z + eta p`` was taken."""

    def restart(self) -> None:
        """The gradient was recomputed exactly by the loop."""

    def model_error(self, rho: Optional[float]) -> None:
        """Bi-PQN measured its model's relative error ``rho`` along a step."""

    def as_dict(self) -> dict:
        """Counters for ``SolveResult.info``."""


class DirectionProducts:
    """The paper's product ``Q p`` of the direction (``products=paper``)."""

    def __init__(self, apply: Callable[[np.ndarray], np.ndarray]):
        self.apply = apply

    def product(self, z: np.ndarray, G: np.ndarray, p: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        return self.apply(p), G

    def stepped(self, eta: float) -> None:
        """Nothing to update: the product of the direction carries no known ``A x``."""

    def restart(self) -> None:
        """Nothing to restart: no product is kept from one iteration to the next."""

    def model_error(self, rho: Optional[float]) -> None:
        """Unused: the paper's products are made at full accuracy whatever the model's
        error."""

    def as_dict(self) -> dict:
        return {}


@dataclass(frozen=True)
class LowPoints:
    """Bi-PQN with ``products=iterate``: the low fidelity's products are of points too.

    Parameters
    ----------
    rtol : float
        The low operator's relative accuracy (declared, or 0 for a matrix).
    relax : float
        The solve's ``relax``.
    within : callable, optional
        ``within(v, rtol)``: the low's product to a looser accuracy (None: it has one).
    """

    rtol: float
    relax: float = 0.0
    within: Optional[Callable] = None


class IterateProducts:
    """``A p`` as ``A (x + p) - A x``: the product of the new point, not of the direction.

    PQN's product of an iteration is ``A p`` for the step ``p = x^ - x`` to the prox
    point ``x^``. An operator that is an iterative solve with Krylov recycling
    (the boundary-integral mobility) solves a product whose input is close to
    earlier inputs in few new directions; the directions ``p`` are new each
    iteration, the points ``x^`` converge. So the product is applied to ``x^``
    and ``A p = A x^ - A x``, ``A x`` being known (``G - b`` at the top level): one
    product per iteration as before.

    Accuracy. A product of an operator of relative accuracy ``rtol`` (its declared
    ``Operator(rtol=)``, or the framework's measurement; at least ``16 eps sqrt(n)``
    for rounding) is off by up to ``rtol ||A v||``. ``A x^`` carries such an error,
    and the known ``A x`` carries ``e_x``: after a step ``x+ = x + eta p``, ``A x+ =
    (1 - eta) A x + eta A x^``, so ``e_x+ = |1 - eta| e_x + eta rtol ||A x^||``
    (tracked, :meth:`stepped`; about one product's error while ``eta <= 2``). The
    difference is off by up to ``e = rtol ||A x^|| + e_x``, while a product of
    ``p`` is off by ``rtol ||A p||``: relative to ``||A p||`` the difference's
    error ``e / ||A p||`` grows as the iterates converge (``p -> 0`` while ``A x``
    does not). The step length and the secant pair ``(eta p, eta A p)`` tolerate a
    small relative error (the model only preconditions; each step is measured along
    ``p``; the gradient ``G + eta A p = (1 - eta) A x + eta A x^ + b`` is as accurate
    as a product of the iterate whatever the difference's error), so the difference is
    used while ``e <= difference_tol ||A p||``. Once it
    exceeds a tenth of that, the next step's would likely exceed it all: products of
    ``p`` are made from the next iteration on (``switched``: the products of points
    made until then). A difference already beyond ``difference_tol`` is replaced by
    a product of ``p`` (one extra product, counted in ``direct``). The solver
    confirms every convergence claim with a counted product.

    Loose products (``relax > 0``, an operator that offers them: ``within``). Far from
    the solution the gradient needs no product's full accuracy: an inexact proximal
    Newton method keeps its convergence while the gradient's error stays below a fixed
    fraction of the residual it drives to zero (the natural residual
    ``r(z) = ||z - max(z - G, 0)||``; Byrd, Nocedal and Oztoprak, Math. Program. 157
    (2016), for inexact subproblems; the same argument bounds an inexact gradient), and
    a Krylov solve stopped earlier costs fewer applications (Simoncini and Szyld, SIAM
    J. Sci. Comput. 25 (2003): relaxed inner accuracy where the outer iteration
    tolerates it). The error allowed at an iteration is ``T = min(relax r(z), cap ||A
    p||)``: the gradient's share, and the difference's (``cap`` a tenth of
    ``difference_tol``; for Bi-PQN at most a tenth of its model's measured error,
    :meth:`model_error`, or the model check would measure the product's error;
    ``||A p||`` predicted from the last step's ratio ``||A p|| / ||p||``, before the
    first step ``||A z|| / ||z||``). The known ``A x`` already carries ``e_x`` of it, and
    the new product's error stays in the next known ``A x`` while the next ``T`` is
    smaller by the residual's contraction ``q`` (observed from one iteration to the next),
    so the product is asked for ``e = min(T - e_x, T q^2 / 4)`` (relative to ``||A z||``,
    clipped to ``[rtol, 0.1]``; :meth:`_accuracy` says why): the errors shrink with the
    residual, and the next iteration can be loose again. Near the solution the request falls
    below ``rtol`` and products are made at full accuracy. When ``e_x`` alone would use
    half of ``difference_tol ||A p||`` (a contraction faster than predicted), the known
    ``A x`` is refreshed first by a full-accuracy product of the iterate (counted;
    with recycling a cheap one, its input being a combination of inputs already
    applied; ``refreshed``; top level only, where the gradient is ``A x + b``). With
    recycling the loose solves' directions are exact images, so the full-accuracy
    products after them lose nothing. The switch to products of ``p`` is judged on
    what full-accuracy products would give. Every convergence claim is confirmed by a
    full-accuracy product (the operator never reuses a loose one).

    Parameters
    ----------
    apply : callable
        The level's product ``Q v``.
    b : ndarray or None
        The linear term: the known ``A x`` is ``G - b`` (ignored with ``known``).
    rtol : float
        Relative accuracy of one product.
    tol : float
        ``difference_tol``.
    base : callable, optional
        The operator applied to the point (default: the level's product).
    known : callable, optional
        ``known(x, G)``: ``base x`` at the level's iterate (default ``G - b``).
    correction : callable, optional
        Added to the difference: the level's product is ``base + correction`` (the
        Bi-PQN subproblem's ``B = A_low + U U' - V V'``, whose low-rank part is exact).
    error : float, optional
        Error bound of the first ``known`` (default ``rtol ||A x||``).
    relax : float
        Loose products: the gradient's allowed error as a fraction of the natural
        residual (0: every product at full accuracy).
    within : callable, optional
        ``within(v, rtol)``: the product of ``v`` to relative accuracy ``rtol``
        (:meth:`lcpbench.core.operator.Operator.product_within`); without it
        ``relax`` has no effect.
    """

    #: The loosest accuracy a product of a point is asked for.
    LOOSEST = 0.1

    def __init__(self, apply: Callable[[np.ndarray], np.ndarray], b: Optional[np.ndarray],
                 rtol: float, tol: float, *,
                 base: Optional[Callable] = None, known: Optional[Callable] = None,
                 correction: Optional[Callable] = None, error: Optional[float] = None,
                 n: Optional[int] = None, relax: float = 0.0,
                 within: Optional[Callable] = None):
        size = n if n is not None else (b.shape[0] if b is not None else 1)
        self.apply = apply
        self.b, self.tol = b, tol
        self.rtol = max(float(rtol), 16 * np.finfo(float).eps * np.sqrt(max(size, 1)))
        self.base, self.known, self.correction = base, known, correction
        self.error = error            # bound on the error of the known A x (None: rtol ||A x||)
        self.on = True
        self.made = 0                 # products of points
        self.direct = 0               # differences replaced by a product of p
        self.switched: Optional[int] = None   # products of points made before the switch
        self.errors: list = []        # e / ||A p|| of each difference
        self._last: Optional[float] = None    # rtol ||A x^|| (or ||Q p||) of the last product
        self._point = False                   # the last product was of a point
        self.relax, self.within = float(relax), within
        self.loose: list = []         # accuracy asked of each loose product
        self.cap = 0.1 * tol          # a loose difference's error, relative to ||A p||
        self.refreshed = 0            # products of the iterate that refreshed A x
        self._ratio: Optional[float] = None   # ||A p|| / ||p|| of the last step
        self._res: Optional[float] = None     # the natural residual at the last product

    def product(self, z: np.ndarray, G: np.ndarray, p: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """``(Q p, G)`` for the step from ``z`` (gradient ``G``) along ``p``; ``G`` is
        recomputed when the known ``A x`` was refreshed."""
        if not self.on:
            return self._direct(p), G
        apply, G_step = self.apply, G
        Az = self.known(z, G) if self.known is not None else G - self.b
        if self.error is None:
            self.error = self.rtol * float(np.linalg.norm(Az))
        if self._stale(z, p, Az):
            Az = (self.base or apply)(z)
            G_step, self.error = Az + self.b, self.rtol * float(np.linalg.norm(Az))
            self.refreshed += 1
        rtol = self._accuracy(z, G, p, Az)
        if rtol > self.rtol:
            assert self.within is not None
            Ax_hat = self.within(z + p, rtol)
            self.loose.append(rtol)
        else:
            Ax_hat = (self.base or apply)(z + p)
        Ap = Ax_hat - Az
        self.made += 1
        self._last = rtol * float(np.linalg.norm(Ax_hat))
        size = float(np.linalg.norm(Ap))
        step = float(np.linalg.norm(p))
        if size > 0 and step > 0:
            self._ratio = size / step
        rel = (self._last + self.error) / size if size > 0 else float("inf")
        self.errors.append(rel)
        judged = rel
        if self.loose:
            # after loose products the switch asks what full-accuracy products would give:
            # a loose product's error is chosen, and the next request tightens it
            full = self.rtol * (float(np.linalg.norm(Ax_hat)) + float(np.linalg.norm(Az)))
            judged = full / size if size > 0 else float("inf")
        if not judged <= 0.1 * self.tol:
            self.on, self.switched = False, self.made
        if not rel <= self.tol:
            self.direct += 1
            return self._direct(p), G_step
        self._point = True
        return (Ap + self.correction(p) if self.correction is not None else Ap), G_step

    def _predicted(self, z: np.ndarray, p: np.ndarray, scale: float) -> float:
        """``||A p||`` predicted from the last step's ratio ``||A p|| / ||p||`` (before any
        step the secant ratio ``||A z|| / ||z||``, as BB's scaling)."""
        ratio = self._ratio
        if ratio is None:
            size = float(np.linalg.norm(z))
            ratio = scale / size if size > 0 else 0.0
        return ratio * float(np.linalg.norm(p))

    def _allowed(self, z: np.ndarray, p: np.ndarray, scale: float) -> float:
        """The error a loose product may carry: ``cap`` times the predicted ``||A p||``."""
        return self.cap * self._predicted(z, p, scale)

    def _stale(self, z: np.ndarray, p: np.ndarray, Az: np.ndarray) -> bool:
        """After loose products the known ``A x`` may carry more error than this difference
        affords (it decays only by ``|1 - eta|`` per step): when it alone would use half of
        ``difference_tol ||A p||``, it is refreshed by a full-accuracy product of the
        iterate (with recycling a cheap one, like a confirmation); at the top level only,
        where the gradient is ``A x + b``."""
        if not self.loose or self.known is not None or self.b is None or self.error is None:
            return False
        scale = float(np.linalg.norm(Az))
        return self.error > max(0.5 * self.tol * self._predicted(z, p, scale),
                                10 * self.rtol * scale)

    def _accuracy(self, z: np.ndarray, G: np.ndarray, p: np.ndarray, Az: np.ndarray) -> float:
        """The relative accuracy to ask of the product of ``z + p`` (``rtol``: full).

        The error allowed at this iteration is ``T = min(relax r(z), cap ||A p||)``; the
        known ``A x`` already carries ``e_x`` of it, and this product's error ``e`` stays in
        the next known ``A x`` (up to ``2 e`` for an over-relaxed step, ``eta <= 2``) while
        the next ``T`` is smaller by the residual's contraction, observed as ``q`` at this
        iteration and possibly faster (superlinear). So the product is asked for
        ``e = min(T - e_x, T q^2 / 4)``: room for one more contraction by ``q`` and a
        factor two of over-relaxation, so that the next iteration can again be loose
        instead of paying a full-accuracy product (against ``T q / (1 + q)``, which
        assumes the contraction stays ``q``: 93 against 104 Mono-PQN applications on a
        packed 27-sphere lattice; docs/benchmarks.md, "Loose products"). Each factor of
        ten tighter costs about 2.6 Krylov applications, a full-accuracy product 15-20."""
        if self.relax <= 0 or self.within is None:
            return self.rtol
        scale = float(np.linalg.norm(Az))
        res = kkt_abs(z, G)           # the natural residual ||z - max(z - G, 0)|| = ||min(z, G)||
        prev, self._res = self._res, res
        if scale == 0 or res == 0:
            return self.rtol
        q = min(max(res / prev, 0.01), 1.0) if prev else 0.5
        T = min(self.relax * res, self._allowed(z, p, scale))
        e = min(T - (self.error or 0.0), T * q * q / 4)
        return float(min(max(e / scale, self.rtol), self.LOOSEST))

    def model_error(self, rho: Optional[float]) -> None:
        """Bi-PQN measured its model's relative error ``rho`` along a step (its model check
        compares the difference ``A p`` with ``B p``): a loose difference must stay well
        below it, or the check would measure the product's error, not the model's."""
        if rho is not None and np.isfinite(rho):
            self.cap = min(0.1 * self.tol, 0.1 * float(rho))

    def _direct(self, p: np.ndarray) -> np.ndarray:
        """The paper's product ``Q p`` (its error ``rtol ||Q p||`` kept for :meth:`stepped`)."""
        Qp = self.apply(p)
        self._point, self._last = False, self.rtol * float(np.linalg.norm(Qp))
        return Qp

    def stepped(self, eta: float) -> None:
        """The step ``x + eta p`` was taken: the known ``A x``'s error bound follows."""
        if self.error is None or self._last is None:
            return
        if self._point:      # A x+ = (1 - eta) A x + eta A x^
            self.error = abs(1.0 - eta) * self.error + eta * self._last
        else:                # A x+ = A x + eta A p
            self.error += eta * self._last

    def restart(self) -> None:
        """The gradient was recomputed by a product of the iterate."""
        self.error = None

    def as_dict(self) -> dict:
        return {"iterate_products": self.made, "iterate_direct": self.direct,
                "iterate_switched": self.switched, "iterate_errors": list(self.errors),
                "loose_products": list(self.loose), "iterate_refreshed": self.refreshed}
