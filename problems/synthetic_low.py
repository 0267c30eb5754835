"""Stored sets with synthetic low fidelities ``A + E`` of known relative error.

Problem family ``synthetic-low``: every instance of a stored set, with low-fidelity
operators ``A + E`` for each requested relative error ``||E||_2 / ||A||_2`` and
each shape of ``E``, beside the set's own low fidelities. ``lcpbench run`` then
runs a multi-fidelity solver once per low operator, and the report's section
"Fidelity advantage" plots its MVPs against the relative error of the low
(``lcpbench.report.fidelity_map``); ``benchmarks/fidelity_map.py`` adds the
oracle floor.

Low operators are named ``SHAPE~ERROR`` so that the run store keeps the error:
``random~1e-3`` (``E`` a random symmetric Gaussian matrix), ``like~1e-3`` (``E``
shaped like the set's own low-fidelity error ``A_like - A``) and, for the set's
real lows, ``NAME~ERROR`` with the measured relative error of that instance
(e.g. ``p4e6~0.21``). :func:`parse_low_name` reads the name back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from lcpbench import LCP, Operator, register_problem
from lcpbench.core.operator import dense_uncounted

from .stored import StoredParams, stored

__all__ = ["SyntheticLowParams", "synthetic_low", "low_error", "parse_low_name", "SHAPES"]

#: Shapes of the error ``E``.
SHAPES = ("random", "like")


@dataclass(frozen=True)
class SyntheticLowParams:
    """Parameters of synthetic-low.

    Parameters
    ----------
    path : str
        The stored set: a ``.h5`` file or the name of a shipped set (default
        ``lattice-bim-m3``).
    instances : str
        Positions to read, e.g. ``"0-9"`` (default all).
    errors : list of float
        Relative errors ``||E||_2 / ||A||_2`` of the synthetic lows (default
        1e-1 ... 1e-6).
    shapes : list of str
        ``random`` and/or ``like`` (see the module docstring).
    like : str
        The set's low whose error ``A_like - A`` shapes ``E`` for ``like``
        (default ``p4e6``, BIM p = 4 at GMRES tolerance 1e-6, the paper's
        candidate low fidelity).
    cost_ratio : float
        Declared cost of one synthetic low MVP in high MVPs (default 0.08,
        about a p = 4 BIM product against p = 8).
    real : bool
        Keep the set's own low fidelities (renamed ``NAME~ERROR``).
    seed : int
        Seed of the random ``E``.
    """

    path: str = "lattice-bim-m3"
    instances: str = ""
    errors: tuple[float, ...] = (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
    shapes: tuple[str, ...] = SHAPES
    like: str = "p4e6"
    cost_ratio: float = 0.08
    real: bool = True
    seed: int = 0

    def __post_init__(self) -> None:
        bad = [e for e in self.errors if not (np.isfinite(e) and 0 < e < 10)]
        if bad or not self.errors:
            raise ValueError(f"errors must be relative errors in (0, 10), got {list(self.errors)}")
        unknown = [s for s in self.shapes if s not in SHAPES]
        if unknown:
            raise ValueError(f"shapes: unknown {', '.join(unknown)}; use {' and/or '.join(SHAPES)}")
        if not (np.isfinite(self.cost_ratio) and self.cost_ratio >= 0):
            raise ValueError(f"cost_ratio must be >= 0, got {self.cost_ratio}")


def low_error(A: np.ndarray, A_low: np.ndarray) -> float:
    """Relative error ``||A_low - A||_2 / ||A||_2`` of a low fidelity."""
    return float(np.linalg.norm(A_low - A, 2) / np.linalg.norm(A, 2))


def _name(shape: str, err: float) -> str:
    return f"{shape}~{err:.2g}"


def parse_low_name(name: str) -> Optional[tuple[str, float]]:
    """``"like~0.001"`` -> ``("like", 0.001)``; None for a name without an error."""
    shape, sep, err = str(name).rpartition("~")
    if not sep:
        return None
    try:
        return shape, float(err)
    except ValueError:
        return None


def _scaled(D: np.ndarray, A_norm: float, err: float) -> np.ndarray:
    D = (D + D.T) / 2
    return D * (err * A_norm / np.linalg.norm(D, 2))


def _with_lows(lcp: LCP, p: SyntheticLowParams, rng: np.random.Generator) -> LCP:
    A = dense_uncounted(lcp.A)
    A_norm = float(np.linalg.norm(A, 2))
    low = {}
    like = p.like
    if "like" in p.shapes and like not in lcp.low:
        raise ValueError(f"synthetic-low: like={like!r} is not a low fidelity of {lcp.name} "
                         f"(it has {', '.join(lcp.low) or 'none'}); name one with like=NAME "
                         "or use shapes=[random]")
    G = rng.standard_normal(A.shape)
    for shape in p.shapes:
        D = G if shape == "random" else dense_uncounted(lcp.low[like]) - A
        for err in p.errors:
            name = _name(shape, err)
            low[name] = Operator(A + _scaled(D, A_norm, err), cost=p.cost_ratio, name=name)
    if p.real:
        for k, op in lcp.low.items():
            M = dense_uncounted(op)
            name = _name(k, low_error(A, M))
            low[name] = Operator(M, cost=op.cost, name=name)
    meta = dict(lcp.meta, family="synthetic-low", like=like)
    return LCP(lcp.A, lcp.b, x0=lcp.x0, low=low, name=lcp.name, meta=meta,
               reference=lcp.reference, psd_check=False)


@register_problem("synthetic-low", SyntheticLowParams)
def synthetic_low(p: SyntheticLowParams) -> list[LCP]:
    """A stored set with synthetic low fidelities A + E of known relative error, and its own."""
    rng = np.random.default_rng(p.seed)
    return [_with_lows(lcp, p, rng) for lcp in stored(StoredParams(path=p.path,
                                                                   instances=p.instances))]
