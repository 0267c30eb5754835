"""``zero-sr1``: the zero-memory SR1 proximal quasi-Newton method of Becker & Fadili.

Becker & Fadili, "A quasi-Newton proximal splitting method", NeurIPS 2012, and
Becker, Fadili & Ochs, "On quasi-Newton forward-backward splitting: proximal
calculus and convergence", SIAM J. Optim. 29 (2019) (arXiv:1801.08691, the
method paper's citation); baseline "zeroSR1" of the method paper's section
"Comparison Methods" (first order, step 1, over-relaxation 1), run by the paper
authors through ``ZERO_SR1_matfree.m`` on the reference implementation
``stephenbeckr/zeroSR1``.

Each iteration builds the inverse-Hessian model ``H = t I + sigma v v'`` from
the last secant pair ``(s, y)``: ``t = diag_weight * t_bb`` with the BB2 step
``t_bb = s'y / y'y`` (the source's default ``BB_type = 2``, ``SR1_diagWeight =
0.8``; a full BB step would satisfy the secant equation and leave no rank-1
term), ``v = (s - t y) / sqrt(|v'y|)`` and ``sigma = sign((s - t y)'y)``, so that
``H y = s``. The step is the weighted prox

    x+ = argmin_{z >= 0} 1/2 || z - (x - H w) ||^2_{H^-1},

which for the nonnegativity constraint is a one-dimensional monotone piecewise
linear root problem solved exactly in O(n log n) by sorting its breakpoints
(:func:`prox_rank1_nonneg`). One counted MVP per iteration (``A x+``).

Choices the source leaves open or makes differently (lcpbench's, documented):

* first iteration: the source uses ``t = 1/L`` with ``L = 1`` unless told; here,
  with a nonzero warm start ``x0``, the first model is built from the free
  secant pair ``(x0, A x0)`` (``A x0`` is known from the first gradient and
  ``A 0 = 0``), otherwise the first step is the Cauchy step ``w'w / w'Aw``
  (one counted product, as for ``bb-pgd``); ``first_step > 0`` forces a plain
  first step of that length;
* when ``s'y <= 0`` or ``y = 0`` (no curvature: singular PSD ``A`` or no move)
  the source flags a failure and stops; here the previous ``t`` is kept and
  the rank-1 term dropped for that iteration (``info['skipped_rank1']``);
* the source stops on relative objective change; here lcpbench's stop rule
  decides.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from lcpbench import register_solver
from lcpbench.core.context import SolverContext
from lcpbench.core.result import SolveResult
from lcpbench.core.specs import Bounds, CheckedParams
from lcpbench.toolkit.quasinewton import free_secant_pair
from lcpbench.toolkit.steps import cauchy_step

__all__ = ["ZeroSR1Params", "zero_sr1", "prox_rank1_nonneg"]


def prox_rank1_nonneg(x: np.ndarray, d: np.ndarray, u: np.ndarray, sigma: float = 1.0) -> np.ndarray:
    """``argmin_{z >= 0} 1/2 ||z - x||_B^2`` for ``B = diag(d) + sigma u u'``, in O(n log n).

    The optimality conditions give ``z = max(x - alpha d^-1 u, 0)`` for the
    scalar ``alpha = sigma u'(z - x)``. ``phi(alpha) = sigma u'(z(alpha) - x) -
    alpha`` is piecewise linear with breakpoints ``x_i d_i / u_i`` and strictly
    decreasing whenever ``B`` is positive definite (for ``sigma = -1`` that is
    ``u' d^-1 u < 1``), so its root is found by sorting the breakpoints,
    evaluating ``phi`` at all of them with cumulative sums and solving the
    linear piece that brackets the root.

    Parameters
    ----------
    x : ndarray, shape (n,)
        Point to project.
    d : ndarray, shape (n,)
        Positive diagonal of ``B``.
    u : ndarray, shape (n,)
        Rank-1 vector.
    sigma : float
        +1 or -1, the sign of the rank-1 term.

    Returns
    -------
    ndarray
        The projection in the ``B``-norm.

    Raises
    ------
    ValueError
        If ``d`` is not positive, ``sigma`` is not +-1, or ``B`` is not positive
        definite.
    """
    x = np.asarray(x, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    if sigma not in (1, -1, 1.0, -1.0):
        raise ValueError(f"sigma must be +1 or -1, got {sigma!r}")
    if not (x.shape == d.shape == u.shape and x.ndim == 1):
        raise ValueError(f"x, d, u must be vectors of one length; got shapes "
                         f"{x.shape}, {d.shape}, {u.shape}")
    if x.size and not np.all(d > 0):
        raise ValueError("d must be positive (the diagonal of a positive definite B)")
    c = u / d
    if sigma < 0 and float(u @ c) >= 1.0:
        raise ValueError("B = diag(d) - u u' is not positive definite (u' d^-1 u >= 1)")
    nz = u != 0.0
    if not np.any(nz):
        return np.maximum(x, 0.0)
    uy_all = float(u @ x)

    # phi on a set of active indices: sigma * (S1 - alpha S2 - uy_all) - alpha, where
    # S1 = sum u_i x_i and S2 = sum u_i c_i over i with x_i - alpha c_i > 0 (u_i != 0),
    # plus the constant sum over u_i == 0 (their z_i does not depend on alpha).
    const = float(u[~nz] @ np.maximum(x[~nz], 0.0)) if np.any(~nz) else 0.0
    uu, xx, cc = u[nz], x[nz], c[nz]
    t = xx / cc                                  # breakpoints
    pos, neg = cc > 0, cc < 0                    # active when alpha < t (pos), alpha > t (neg)
    tp, tn = t[pos], t[neg]
    op, on = np.argsort(tp), np.argsort(tn)
    tp, tn = tp[op], tn[on]
    a1p = np.concatenate(([0.0], np.cumsum((uu[pos] * xx[pos])[op])))
    a2p = np.concatenate(([0.0], np.cumsum((uu[pos] * cc[pos])[op])))
    a1n = np.concatenate(([0.0], np.cumsum((uu[neg] * xx[neg])[on])))
    a2n = np.concatenate(([0.0], np.cumsum((uu[neg] * cc[neg])[on])))

    def sums(alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # pos: active if t > alpha (strict); at a breakpoint either side gives the same phi
        kp = np.searchsorted(tp, alpha, side="right")
        kn = np.searchsorted(tn, alpha, side="left")
        s1 = (a1p[-1] - a1p[kp]) + a1n[kn]
        s2 = (a2p[-1] - a2p[kp]) + a2n[kn]
        return s1, s2

    def phi(alpha: np.ndarray) -> np.ndarray:
        s1, s2 = sums(alpha)
        return sigma * (s1 - alpha * s2 + const - uy_all) - alpha

    brk = np.unique(t)
    vals = phi(brk)
    k = int(np.searchsorted(-vals, 0.0, side="left"))   # vals decreasing: first index with phi <= 0
    if k < brk.size and vals[k] == 0.0:
        alpha = float(brk[k])
    else:
        lo = brk[k - 1] if k > 0 else brk[0] - 1.0
        hi = brk[k] if k < brk.size else brk[-1] + 1.0
        mid = np.array([0.5 * (lo + hi)])
        s1, s2 = sums(mid)
        alpha = float(sigma * (s1[0] + const - uy_all) / (1.0 + sigma * s2[0]))
    return np.maximum(x - alpha * c, 0.0)


@dataclass(frozen=True)
class ZeroSR1Params(CheckedParams):
    """Parameters of zero-sr1.

    Parameters
    ----------
    diag_weight : float
        Scale ``gamma`` of the BB2 step in the diagonal ``t = gamma s'y / y'y``
        (the source's ``SR1_diagWeight``, default 0.8; must be in (0, 1) so that
        the rank-1 term is positive and ``H`` stays positive definite on a
        convex problem).
    first_step : float
        Step of the first (plain projected gradient) iteration; 0 (default):
        the model of the free secant pair ``(x0, A x0)`` when ``x0`` is not
        zero, else the Cauchy step ``w'w / w'Aw``, one counted product.
    """

    diag_weight: Annotated[float, Bounds(gt=0, lt=1)] = 0.8
    first_step: Annotated[float, Bounds(ge=0)] = 0.0


@register_solver("zero-sr1", ZeroSR1Params)
def zero_sr1(ctx: SolverContext, p: ZeroSR1Params) -> SolveResult:
    """Zero-memory SR1 proximal quasi-Newton (Becker & Fadili 2012) for the LCP's QP.

    See the module docstring for the model, the rank-1 prox and lcpbench's
    choices. ``info``: ``skipped_rank1`` (iterations without a rank-1 term),
    ``last_t``.
    """
    b, n = ctx.b, ctx.n
    x = np.maximum(ctx.x0, 0.0)
    w = ctx.A @ x + b
    ctx.info.update(skipped_rank1=0)
    if ctx.report(x, w):
        return ctx.finish(x, w)
    pair = free_secant_pair(x, w, b) if p.first_step == 0.0 else None
    if pair is None:
        if p.first_step > 0.0:
            t = p.first_step
        else:
            t = cauchy_step(w, ctx.A @ w)
        # first iteration: projected gradient step with the scalar t
        xn = np.maximum(x - t * w, 0.0)
        wn = ctx.A @ xn + b
    while True:
        if pair is not None:
            (s, y), pair = pair, None
        else:
            s, y = xn - x, wn - w
            x, w = xn, wn
            if ctx.report(x, w):
                return ctx.finish(x, w)
        sy, yy = float(s @ y), float(y @ y)
        v = None
        if sy > 0.0 and yy > 0.0:
            t = p.diag_weight * sy / yy
            r = s - t * y
            ry = float(r @ y)
            if ry > 0.0:
                v = r / np.sqrt(ry)
        if v is None:
            ctx.info["skipped_rank1"] += 1
            xn = np.maximum(x - t * w, 0.0)
        else:
            # H = t I + v v'; B = H^-1 = I/t - q q' with q = v / (t sqrt(1 + v'v / t))
            step = t * w + v * float(v @ w)
            q = v / (t * np.sqrt(1.0 + float(v @ v) / t))
            d = np.full(n, 1.0 / t)
            # B = diag(d) - q q' positive definite also in floating point: the very test the
            # prox makes (q' d^-1 q < 1), so a B the prox would refuse is never handed to it
            if float(q @ (q / d)) < 1.0:
                xn = prox_rank1_nonneg(x - step, d, q, -1.0)
            else:                               # v'v >> t: rounding lost definiteness
                ctx.info["skipped_rank1"] += 1
                xn = np.maximum(x - t * w, 0.0)
        ctx.info["last_t"] = t
        wn = ctx.A @ xn + b
