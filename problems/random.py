"""Random SPD problem families: a stand-in for the suspension LCPs, and bi-fidelity pairs.

``random-spd`` was the default set of ``lcpbench run`` until the stored sets of
suspension LCPs landed (now ``set-lattice-bim-m3``): SPD matrices with condition numbers
10..100 and n = 150..300, the sizes and the benign conditioning of the collision LCPs of
the method paper (section "Numerical Results": kappa = O(10), N_c of the order of the
particle count).
``bifidelity`` pairs a high-fidelity matrix with a perturbed low-fidelity one,
the setting of the paper's Bi-PQN (section "Multifidelity" -> "A Bifidelity
Proximal Quasi-Newton Method").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import numpy as np

from lcpbench import LCP, Operator, register_problem
from lcpbench.core.specs import Bounds

from .synthetic import (
    Cond,
    Count,
    InstanceSize,
    SeededParams,
    Size,
    meta,
    random_spd_matrix,
    seeded,
    spd_estimate,
)

__all__ = ["random_spd", "bifidelity", "symmetric_perturbation", "with_perturbed_lows",
           "PERTURBED_LOWS"]


@dataclass(frozen=True)
class RandomSpdParams(SeededParams):
    """Parameters of random-spd.

    Parameters
    ----------
    n_min, n_max : int
        Range of sizes, drawn uniformly per instance (defaults 150 and 300).
    cond_min, cond_max : float
        Range of condition numbers, drawn log-uniformly per instance
        (defaults 10 and 100).
    """

    n_min: Size = 150
    n_max: Size = 300
    cond_min: Cond = 10.0
    cond_max: Cond = 100.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.n_max < self.n_min:
            raise ValueError(f"need n_min <= n_max, got n_min = {self.n_min}, "
                             f"n_max = {self.n_max}")
        if self.cond_max < self.cond_min:
            raise ValueError(f"need cond_min <= cond_max, got cond_min = {self.cond_min:g}, "
                             f"cond_max = {self.cond_max:g}")


@register_problem("random-spd", RandomSpdParams,
                  estimate=lambda p: spd_estimate(p.count, p.n_max))
def random_spd(p: RandomSpdParams) -> list[LCP]:
    """Random SPD LCPs, n 150..300 and condition number 10..100 (synthetic stand-in).

    ``A = Q diag(lam) Q'`` with Haar-random ``Q`` and eigenvalues from 1 to
    ``cond`` (:func:`lcpbench.problems.synthetic.random_spd_matrix`), scaled so that
    ``||A||_2 = 1``; ``b ~ N(0, 1)``. With mixed signs in b the unconstrained
    minimiser ``-A^{-1} b`` has entries of both signs, so the solution has a
    mix of active (x_i > 0) and inactive (x_i = 0) indices: about half each.
    """
    def one(i: int, rng: np.random.Generator) -> LCP:
        n = int(rng.integers(p.n_min, p.n_max + 1))
        cond = float(10.0 ** rng.uniform(np.log10(p.cond_min), np.log10(p.cond_max)))
        A = random_spd_matrix(rng, n, cond) / cond
        b = rng.standard_normal(n)
        return LCP(A, b, name=f"random-spd-{i}",
                   meta=meta("random-spd", p.seed, n, instance=i, cond=cond))

    return seeded(p.count, p.seed, one)


@dataclass(frozen=True)
class BifidelityParams(SeededParams):
    """Parameters of bifidelity.

    Parameters
    ----------
    cond : float
        Condition number of the high-fidelity A (default 50).
    rel_error : float
        ``||A_low - A||_2 / ||A||_2`` of the random symmetric perturbation
        (default 1e-3).
    indefinite : bool
        Make A_low indefinite while A stays SPD (default False): the perturbation
        also subtracts ``((1 + rel_error) lam_min(A) + rel_error) v v'`` with v
        A's lowest eigenvector, which makes ``v' A_low v < 0``; the actual
        relative error grows to about ``1/cond + 2 rel_error`` (recorded in meta
        as ``rel_error_actual``, the smallest eigenvalue as ``lam_min_low``).
    cost_ratio : float
        Declared cost of a low-fidelity MVP in high-fidelity units (high costs
        1.0; default 0.1), used for E-MVPs.
    """

    count: Count = 3
    n: InstanceSize = 150
    cond: Cond = 50.0
    rel_error: Annotated[float, Bounds(ge=0)] = 1e-3
    indefinite: bool = False
    cost_ratio: Annotated[float, Bounds(gt=0)] = 0.1


def symmetric_perturbation(rng: np.random.Generator, A: np.ndarray, rel: float) -> np.ndarray:
    """A symmetric Gaussian matrix ``E`` with ``||E||_2 = rel ||A||_2``."""
    G = rng.standard_normal(A.shape)
    E = (G + G.T) / 2
    nrm = np.linalg.norm(E, 2) if A.size else 0.0
    return E * (rel * np.linalg.norm(A, 2) / nrm) if nrm > 0 else E


#: Low-fidelity levels added by :func:`with_perturbed_lows`: (name, relative error, cost).
PERTURBED_LOWS = (("low", 1e-3, 0.1), ("lower", 1e-2, 0.01))


def with_perturbed_lows(lcp: LCP, seed: int, levels=PERTURBED_LOWS) -> LCP:
    """``lcp`` with low-fidelity operators ``A + E`` of the given relative errors and costs.

    An explicit high-fidelity matrix is used as it is. A matrix-free one (for
    instance an inexact operator whose products are iterative solves) stays the
    high-fidelity operator unchanged, with its declared accuracy; only the lows
    are built from its dense form (``n`` uncounted products, so for small
    ``n``). That dense form is symmetric only to the accuracy of the products,
    so it is symmetrised first and its asymmetry ``max|A - A'| / max|A|`` is
    recorded in ``meta['low_base_asymmetry']``: far below the relative errors
    of the lows, it changes nothing they model.

    Parameters
    ----------
    lcp : LCP
        An instance with an explicit (or small) high-fidelity matrix.
    seed : int
        Seed of the perturbations.
    levels : sequence of (str, float, float)
        ``(name, ||E||_2 / ||A||_2, declared cost)``; the high operator gets cost 1.

    Returns
    -------
    LCP
        Same ``b``, name and meta, with the low operators attached.
    """
    A = lcp.dense()
    meta = dict(lcp.meta)
    if lcp.A.explicit:
        high = Operator(A, cost=1.0)
    else:
        high = Operator(lcp.A, cost=1.0)              # keeps the operator and its accuracy
        scale = float(np.max(np.abs(A))) if A.size else 0.0
        meta["low_base_asymmetry"] = (float(np.max(np.abs(A - A.T))) / scale
                                      if scale > 0 else 0.0)
        A = (A + A.T) / 2
    rng = np.random.default_rng(seed)
    low = {name: Operator(A + symmetric_perturbation(rng, A, rel), cost=cost, name=name)
           for name, rel, cost in levels}
    return LCP(high, lcp.b, low=low, name=lcp.name, meta=meta, psd_check=False)


def _bifidelity_estimate(p: BifidelityParams):
    """A and A_low per instance; two 2-norms (SVDs) and eigenvalue solves besides A's build."""
    return spd_estimate(p.count, p.n, matrices=2, extra_flops=60.0 * float(p.n) ** 3)


@register_problem("bifidelity", BifidelityParams, estimate=_bifidelity_estimate)
def bifidelity(p: BifidelityParams) -> list[LCP]:
    """SPD LCPs with a low-fidelity operator ``A_low = A + E`` named ``"low"``.

    ``A`` as in ``random-spd`` (``||A||_2 = 1``) at condition number ``cond``;
    ``E`` is a symmetric Gaussian matrix scaled to ``||E||_2 = rel_error``
    (plus, with ``indefinite``, a negative rank-one term that pushes the
    smallest eigenvalue of ``A_low`` below zero). Operators carry declared
    costs: ``A`` 1.0, ``A_low`` ``cost_ratio``; ``b ~ N(0, 1)``.
    """
    def one(i: int, rng: np.random.Generator) -> LCP:
        A = random_spd_matrix(rng, p.n, p.cond) / p.cond
        b = rng.standard_normal(p.n)
        E = symmetric_perturbation(rng, A, p.rel_error)
        if p.indefinite:
            lam, V = np.linalg.eigh(A)
            v = V[:, 0]
            E = E - ((1.0 + p.rel_error) * lam[0] + p.rel_error) * np.outer(v, v)
        A_low = A + E
        A_low = (A_low + A_low.T) / 2
        lam_low = float(np.linalg.eigvalsh(A_low)[0])
        return LCP(Operator(A, cost=1.0), b, name=f"bifidelity-{i}",
                   low={"low": Operator(A_low, cost=p.cost_ratio, name="low")},
                   meta=meta("bifidelity", p.seed, p.n, instance=i, cond=p.cond,
                             rel_error=p.rel_error,
                             rel_error_actual=float(np.linalg.norm(A_low - A, 2)),
                             indefinite=p.indefinite, lam_min_low=lam_low,
                             cost_ratio=p.cost_ratio))

    return seeded(p.count, p.seed, one)
