"""The typed state and outcomes the PQN loops hand each other and the solver."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Optional, Union

import numpy as np

from lcpbench.toolkit.quasinewton import OperatorBFGS, Pairs

__all__ = ["Outcome", "Decision", "Counters", "LevelResult", "BiCarry"]


class Outcome(enum.Enum):
    """How a PQN loop ended."""

    #: its stop test held
    STOP = "stop"
    #: its iteration cap was reached
    MAX_ITER = "max_iter"
    #: negative curvature with no blocking constraint: the quadratic is not bounded below
    #: along ``p``, so the answer is the last point
    UNBOUNDED = "unbounded"
    #: no descent direction exists: the projected gradient vanishes
    STATIONARY = "stationary"


class Decision(enum.Enum):
    """What a Bi-PQN step was (``info['decisions']`` lists their values)."""

    #: the low-fidelity start answered (the first line of Algorithm 3)
    START_LOW = "start:low"
    #: the low-fidelity start broke down: the outer iteration starts at ``x0``
    START_X0 = "start:x0"
    #: a step along the subproblem's answer
    MODEL = "model"
    #: a Mono-PQN step on the high pairs (the subproblem's answer did not descend)
    FALLBACK = "fallback"
    #: the model check judged the low fidelity useless: Mono-PQN from here on
    MONO_MODEL = "mono:model"
    #: ``max_fallbacks`` fallbacks in a row: Mono-PQN from here on
    MONO_SUBPROBLEM = "mono:subproblem"


@dataclass
class Counters:
    """Per-solve counters, copied into ``SolveResult.info``."""

    prox_newton_iters: int = 0
    prox_damped: int = 0
    prox_fallbacks: int = 0
    gradient_fallbacks: int = 0
    mono_fallbacks: int = 0
    recomputes: int = 0
    inner_iterations: int = 0
    low_iterate_products: int = 0     # products=iterate: low products of points
    low_loose_products: int = 0       # relax > 0: low products made to a looser accuracy
    skipped_pairs: int = 0
    abandoned_low: bool = False
    model_errors: list[float] = field(default_factory=list)
    forcing: list[float] = field(default_factory=list)
    decisions: list[Decision] = field(default_factory=list)

    def as_dict(self) -> dict:
        out: dict = {k: (list(v) if isinstance(v, list) else v) for k, v in self.__dict__.items()}
        out["decisions"] = [d.value for d in self.decisions]
        return out


@dataclass
class LevelResult:
    """The end of a PQN loop: the point, its gradient, why it ended, and its pairs."""

    z: np.ndarray
    G: np.ndarray
    outcome: Outcome
    iterations: int
    pairs: Pairs
    #: For :attr:`Outcome.UNBOUNDED`: the direction ``p`` and its product ``Q p`` (the
    #: evidence a solver offers the framework, which checks every ``infeasible`` claim).
    ray: Optional[tuple[np.ndarray, np.ndarray]] = None


@dataclass
class BiCarry:
    """What a Bi-PQN level hands to its next call (or its low-fidelity start to it).

    Parameters
    ----------
    pairs : Pairs
        The high-fidelity pairs ``(S, Q S, A_low S)`` of the model ``B``.
    inner : Pairs or BiCarry or None
        The subproblem level's carried state: its pairs (Mono-PQN) or, down a
        multi-fidelity chain, its own carry.
    model : OperatorBFGS or None
        The ``B`` the inner pairs were made with (the next level corrects them for
        its change).
    low_x : ndarray, optional
        ``products=iterate``: ``A_low x`` at the outer iterate, known from the start.
    low_x_error : float
        The error bound of ``low_x``.
    """

    pairs: Pairs
    inner: Union[Pairs, BiCarry, None] = None
    model: Optional[OperatorBFGS] = None
    low_x: Optional[np.ndarray] = None
    low_x_error: float = 0.0
