"""Random SPD problem families: a synthetic stand-in for the suspension LCPs, and bi-fidelity pairs.

``random-spd`` was the default set of ``lcpbench run`` until the stored sets of
suspension LCPs landed (now ``set-lattice-bim-m3``): SPD matrices with condition numbers 10..100 and n = 150..300, the sizes
and the benign conditioning of the collision LCPs of the method paper (section
"Numerical Results": kappa = O(10), N_c of the order of the particle count).
``bifidelity`` pairs a high-fidelity matrix with a perturbed low-fidelity one,
the setting of the paper's Bi-PQN (section "Multifidelity" -> "A Bifidelity
Proximal Quasi-Newton Method").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lcpbench import LCP, Operator, register_problem

from .hard import random_spd_matrix

__all__ = ["random_spd", "bifidelity", "symmetric_perturbation", "with_perturbed_lows",
           "PERTURBED_LOWS"]


def _sizes(rng: np.random.Generator, count: int, lo: int, hi: int) -> np.ndarray:
    return rng.integers(lo, hi + 1, count)


@dataclass(frozen=True)
class RandomSpdParams:
    """Parameters of random-spd.

    Parameters
    ----------
    count : int
        Number of instances (default 5).
    seed : int
        Random seed; instance i uses ``default_rng([seed, i])`` (default 0).
    n_min, n_max : int
        Range of sizes, drawn uniformly per instance (defaults 150 and 300).
    cond_min, cond_max : float
        Range of condition numbers, drawn log-uniformly per instance
        (defaults 10 and 100).
    """

    count: int = 5
    seed: int = 0
    n_min: int = 150
    n_max: int = 300
    cond_min: float = 10.0
    cond_max: float = 100.0

    def __post_init__(self) -> None:
        if not (isinstance(self.count, int) and self.count >= 1):
            raise ValueError(f"count must be an integer >= 1, got {self.count!r}")
        if not 1 <= self.n_min <= self.n_max:
            raise ValueError(f"need 1 <= n_min <= n_max, got {self.n_min}, {self.n_max}")
        if not 1 <= self.cond_min <= self.cond_max or not np.isfinite(self.cond_max):
            raise ValueError("need 1 <= cond_min <= cond_max < inf")


@register_problem("random-spd", RandomSpdParams)
def random_spd(p: RandomSpdParams) -> list[LCP]:
    """Random SPD LCPs, n 150..300 and condition number 10..100 (synthetic stand-in).

    ``A = Q diag(lam) Q'`` with Haar-random ``Q`` and eigenvalues from 1 to
    ``cond`` (:func:`lcpbench.problems.hard.random_spd_matrix`), scaled so that
    ``||A||_2 = 1``; ``b ~ N(0, 1)``. With mixed signs in b the unconstrained
    minimiser ``-A^{-1} b`` has entries of both signs, so the solution has a
    mix of active (x_i > 0) and inactive (x_i = 0) indices: about half each.
    """
    out = []
    for i in range(p.count):
        rng = np.random.default_rng([p.seed, i])
        n = int(rng.integers(p.n_min, p.n_max + 1))
        cond = float(10.0 ** rng.uniform(np.log10(p.cond_min), np.log10(p.cond_max)))
        A = random_spd_matrix(rng, n, cond) / cond
        b = rng.standard_normal(n)
        out.append(LCP(A, b, name=f"random-spd-{i}",
                       meta={"family": "random-spd", "seed": p.seed, "n": n,
                             "instance": i, "cond": cond}))
    return out


@dataclass(frozen=True)
class BifidelityParams:
    """Parameters of bifidelity.

    Parameters
    ----------
    count : int
        Number of instances (default 3).
    seed : int
        Random seed (default 0).
    n : int
        Size of every instance (default 150).
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

    count: int = 3
    seed: int = 0
    n: int = 150
    cond: float = 50.0
    rel_error: float = 1e-3
    indefinite: bool = False
    cost_ratio: float = 0.1

    def __post_init__(self) -> None:
        if not (isinstance(self.count, int) and self.count >= 1):
            raise ValueError(f"count must be an integer >= 1, got {self.count!r}")
        if self.n < 1:
            raise ValueError(f"n must be >= 1, got {self.n}")
        if not (np.isfinite(self.cond) and self.cond >= 1):
            raise ValueError(f"cond must be a finite number >= 1, got {self.cond}")
        if not (np.isfinite(self.rel_error) and self.rel_error >= 0):
            raise ValueError(f"rel_error must be >= 0, got {self.rel_error}")
        if not (np.isfinite(self.cost_ratio) and self.cost_ratio > 0):
            raise ValueError(f"cost_ratio must be > 0, got {self.cost_ratio}")


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
    rng = np.random.default_rng(seed)
    low = {name: Operator(A + symmetric_perturbation(rng, A, rel), cost=cost, name=name)
           for name, rel, cost in levels}
    return LCP(Operator(A, cost=1.0), lcp.b, low=low, name=lcp.name, meta=lcp.meta,
               psd_check=False)


@register_problem("bifidelity", BifidelityParams)
def bifidelity(p: BifidelityParams) -> list[LCP]:
    """SPD LCPs with a low-fidelity operator ``A_low = A + E`` named ``"low"``.

    ``A`` as in ``random-spd`` (``||A||_2 = 1``) at condition number ``cond``;
    ``E`` is a symmetric Gaussian matrix scaled to ``||E||_2 = rel_error``
    (plus, with ``indefinite``, a negative rank-one term that pushes the
    smallest eigenvalue of ``A_low`` below zero). Operators carry declared
    costs: ``A`` 1.0, ``A_low`` ``cost_ratio``; ``b ~ N(0, 1)``.
    """
    out = []
    for i in range(p.count):
        rng = np.random.default_rng([p.seed, i])
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
        out.append(LCP(Operator(A, cost=1.0), b, name=f"bifidelity-{i}",
                       low={"low": Operator(A_low, cost=p.cost_ratio, name="low")},
                       meta={"family": "bifidelity", "seed": p.seed, "n": p.n, "instance": i,
                             "cond": p.cond, "rel_error": p.rel_error,
                             "rel_error_actual": float(np.linalg.norm(A_low - A, 2)),
                             "indefinite": p.indefinite, "lam_min_low": lam_low,
                             "cost_ratio": p.cost_ratio}))
    return out
