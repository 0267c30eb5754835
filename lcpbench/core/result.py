"""Results of a solve: the solver's claim beside the framework's verification."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

__all__ = ["Status", "SolveResult", "HISTORY_COLUMNS"]

#: Columns of :attr:`SolveResult.history` (one row per iterate).
HISTORY_COLUMNS = ["iter", "mvps", "lofi_mvps", "emvps", "kkt_abs", "kkt_rel", "objective",
                   "time_s", "kkt_abs_verified"]


class _History:
    """The ``history`` field of :class:`SolveResult`, built when first read.

    Set to a DataFrame, to a zero-argument callable that builds one (the framework's
    record of the iterates, turned into a table only when someone reads it: building
    a pandas frame costs milliseconds, as much as a small solve), or to None (an
    empty table). The built frame is kept.
    """

    def __set_name__(self, owner: type, name: str) -> None:
        self._key = "_" + name

    def __get__(self, obj: Any, objtype: Any = None) -> Any:
        if obj is None:
            return None                      # the dataclass default: an empty table
        value = obj.__dict__.get(self._key)
        if value is None or callable(value):
            value = value() if value is not None else pd.DataFrame(columns=HISTORY_COLUMNS)
            obj.__dict__[self._key] = value
        return value

    def __set__(self, obj: Any, value: Any) -> None:
        if not (value is None or callable(value) or isinstance(value, pd.DataFrame)):
            raise TypeError(f"SolveResult.history must be a DataFrame, a callable building "
                            f"one, or None; got {type(value).__name__}")
        obj.__dict__[self._key] = value


class Status(str, enum.Enum):
    """How a solve ended.

    ``converged``: the stop rule's absolute test held, and the framework
    confirmed it at the returned ``x`` with a fresh counted product (or the
    solver's last product was already at that ``x``).
    ``max_iter``: the iteration cap (the solver's own or the budget's) ran out.
    ``budget``: the E-MVP budget ran out (set by the framework).
    ``timeout``: the wall-time budget ``max_seconds`` ran out (set by the framework).
    ``stagnated``: the paper's relative stagnation measure fell below tol while
    the absolute residual did not, the method could make no more progress, or a
    fresh product refuted the solver's convergence claim.
    ``infeasible``: the iterates give evidence that the LCP has no solution: a
    direction ``d >= 0`` with ``A d ~ 0`` and ``b'd < 0`` (confirmed by a counted
    product; the message gives the bound it proves).
    ``diverged``: the iterate or residual became non-finite or blew up.
    ``failed``: the solver raised, an operator raised, or a backend reported failure.
    ``stopped``: the caller's callback raised ``StopIteration`` (as in
    ``scipy.optimize``); the solve ends at the iterate the callback was shown.
    """

    converged = "converged"
    max_iter = "max_iter"
    budget = "budget"
    timeout = "timeout"
    stagnated = "stagnated"
    infeasible = "infeasible"
    diverged = "diverged"
    failed = "failed"
    stopped = "stopped"

    def __str__(self) -> str:  # pragma: no cover - cosmetic
        return self.value


@dataclass
class SolveResult:
    """Outcome of one solve.

    Attributes
    ----------
    x, w : ndarray
        The solution and ``A x + b`` as the solver believes it.
    status : Status
        The solver's claim (see :class:`Status`).
    message : str
    mvps : int
        High-fidelity MVPs counted by the operator.
    lofi_mvps : dict
        MVPs per low-fidelity operator.
    emvps : float
        Effective MVPs: ``sum(count * cost) / cost_high``.
    applications : float
        Inner applications of the high-fidelity operator charged to its counted
        products (its ``work`` hook; equal to ``mvps`` without one).
    lofi_applications : dict
        The same per low-fidelity operator.
    app_cost : float
        Application-weighted cost: ``sum(applications_op * seconds_per_application_op)
        / cost_high``, in high products at their cold number of applications
        (:meth:`lcpbench.LCP.app_cost`).  Equals ``emvps`` when every product takes the
        same (cold) number of applications; smaller when recycling makes later
        products cheaper.  ``info["applications"]`` has the counts per operator and
        kind (e.g. ``forward`` and ``adjoint`` Krylov applications).
    framework_mvps : int
        Products the framework made at the operators beside the solver's: the
        verification, accuracy probes, cost timing and calibration, the
        confirmation of a claim, the evidence of infeasibility, a dense copy of a
        matrix-free operator (in columns). The counted ones among them (a
        confirmation, a calibration) are in ``mvps`` too
        (``info['confirmation_mvps']``, ``info['infeasibility_mvps']``). The
        verified history (one uncounted product per iterate, in block products;
        optional, ``verify_history``) is apart: ``info['history_mvps']``.
    iterations : int
        Iterates reported to the monitor, minus one (the initial point).
    time_s : float
        Solver wall time, excluding the monitor's bookkeeping.
    mvp_time_s : float
        Seconds spent inside counted products.
    history : pandas.DataFrame
        One row per iterate, columns :data:`HISTORY_COLUMNS` (built when first read).
    claimed_kkt_abs : float
        ``||min(x, w)||`` at the solver's own ``w``.
    verified : dict
        The framework's residuals at ``w = A x + b`` recomputed by one uncounted
        product (keys of :func:`lcpbench.core.residuals.all_residuals`).
    solved : bool
        True only if the verified residual meets the stop rule's absolute bound.
    solver, params : str, dict
        Solver name and its parameters.
    mvp_only : bool
        False for solvers that needed the dense matrix.
    info : dict
        Solver-specific counters (e.g. prox Newton fallbacks, model fallbacks).
    """

    x: np.ndarray
    w: np.ndarray
    status: Status
    message: str = ""
    mvps: int = 0
    lofi_mvps: dict = field(default_factory=dict)
    emvps: float = 0.0
    applications: float = 0.0
    lofi_applications: dict = field(default_factory=dict)
    app_cost: float = 0.0
    framework_mvps: int = 0
    iterations: int = 0
    time_s: float = 0.0
    mvp_time_s: float = 0.0
    history: _History = _History()
    claimed_kkt_abs: float = float("nan")
    verified: dict = field(default_factory=dict)
    solved: bool = False
    threshold: float = float("nan")
    solver: str = ""
    params: dict = field(default_factory=dict)
    mvp_only: bool = True
    info: dict = field(default_factory=dict)
    state: Any = None

    @property
    def verified_kkt_abs(self) -> float:
        """The framework's ``||min(x, Ax+b)||_2``."""
        return float(self.verified.get("kkt_abs", float("nan")))

    @property
    def false_convergence(self) -> bool:
        """A claimed convergence whose verified residual exceeds 10x the bound."""
        return (self.status == Status.converged
                and not (self.verified_kkt_abs <= 10 * self.threshold))

    def summary(self) -> str:
        """One line: solver, status, counts and residuals."""
        lo = ", ".join(f"{k}={v}" for k, v in self.lofi_mvps.items() if v)
        lo = f" (+ low {lo})" if lo else ""
        return (f"{self.solver}: {self.status.value} after {self.iterations} it, "
                f"{self.mvps} MVPs{lo}, {self.emvps:.2f} E-MVPs, "
                f"{self.applications:g} applications ({self.app_cost:.2f} weighted), "
                f"{self.framework_mvps} framework products, "
                f"claimed {self.claimed_kkt_abs:.2e}, verified {self.verified_kkt_abs:.2e}, "
                f"{'solved' if self.solved else 'NOT solved'}, {self.time_s:.3g} s")

    def __repr__(self) -> str:
        return f"<SolveResult {self.summary()}>"
