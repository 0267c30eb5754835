"""What a solver sees: the counted operators, the stop rule, the budget, the monitor.

A solver receives a :class:`SolverContext`. It applies ``ctx.A`` (and
``ctx.low[name]``) for every product, reports each iterate with
``ctx.report(x, w)`` and returns ``ctx.finish(x, w)``. The context

* records the history (:class:`Monitor`) without counting products and without
  charging the solver's clock for the bookkeeping,
* applies the stop rule and the iteration cap, and
* enforces the budget (max E-MVPs, max seconds) inside the operators: a product
  that would exceed it raises :class:`~lcpbench.core.operator.BudgetExhausted`, which
  the framework turns into a ``max_iter`` result at the last reported iterate.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np
import pandas as pd
from scipy.sparse.linalg import LinearOperator, eigsh

from lcpbench.core.lcp import LCP
from lcpbench.core.operator import BudgetExhausted, Operator, apply_uncounted
from lcpbench.core.residuals import StopRule, kkt_abs, kkt_rel, objective
from lcpbench.core.result import HISTORY_COLUMNS, SolveResult, Status

__all__ = ["Budget", "Monitor", "SolverContext", "StopSolver"]


class StopSolver(Exception):
    """Raised from inside a library callback to end a solve the context has closed."""


@dataclass(frozen=True)
class Budget:
    """Limits every solve honours.

    Parameters
    ----------
    max_emvps : float
        Effective MVPs (high-fidelity units) a solve may spend.
    max_seconds : float or None
        Solver wall-time limit (bookkeeping excluded).
    max_iter : int
        Iterates a solve may report.
    """

    max_emvps: float = 5000.0
    max_seconds: Optional[float] = None
    max_iter: int = 5000

    def __post_init__(self) -> None:
        if not (self.max_emvps > 0):
            raise ValueError(f"budget max_emvps must be > 0, got {self.max_emvps!r}")
        if self.max_seconds is not None and not (self.max_seconds > 0):
            raise ValueError(f"budget max_seconds must be > 0 or None, got {self.max_seconds!r}")
        if not (isinstance(self.max_iter, int) and self.max_iter >= 1):
            raise ValueError(f"budget max_iter must be an integer >= 1, got {self.max_iter!r}")


class Monitor:
    """Records one row per iterate (columns :data:`~lcpbench.core.result.HISTORY_COLUMNS`).

    Parameters
    ----------
    verify : bool
        Also record the verified residual of every iterate (one uncounted
        product each; on by default for explicit matrices, where it is cheap).
    callback : callable, optional
        ``callback(row: dict, x: ndarray)`` after each iterate.
    """

    def __init__(self, verify: bool = False, callback: Optional[Callable] = None):
        self.verify = verify
        self.callback = callback
        self.rows: list[dict] = []
        self.seconds = 0.0

    def frame(self) -> pd.DataFrame:
        return pd.DataFrame(self.rows, columns=HISTORY_COLUMNS)


class SolverContext:
    """The view of one solve handed to a solver function.

    Attributes
    ----------
    A : Operator
        High-fidelity counted operator.
    b : ndarray
    n : int
    low : dict of str to Operator
        Low-fidelity counted operators.
    x0 : ndarray
        Starting point (warm start, or zeros).
    stop : StopRule
    budget : Budget
    dense : ndarray or None
        The explicit matrix, only for solvers registered with ``needs_dense``.
    state : object
        Solver state carried over from a previous solve (e.g. quasi-Newton
        memory for time stepping), or None.
    info : dict
        Solver-specific counters copied into the result.
    """

    def __init__(self, lcp: LCP, stop: StopRule, budget: Budget, monitor: Monitor, *,
                 x0: Optional[np.ndarray] = None, dense: Optional[np.ndarray] = None,
                 state: Any = None):
        self.lcp = lcp
        self.A: Operator = lcp.A
        self.b = lcp.b
        self.n = lcp.n
        self.low: dict[str, Operator] = dict(lcp.low)
        start = x0 if x0 is not None else lcp.x0
        self.x0 = np.zeros(self.n) if start is None else np.array(start, dtype=np.float64)
        self.stop = stop
        self.budget = budget
        self.monitor = monitor
        self.dense = dense
        self.state = state
        self.info: dict = {}
        self.status: Optional[Status] = None
        self.message = ""
        self._prev_kkt: Optional[float] = None
        self._last: Optional[tuple[np.ndarray, np.ndarray]] = None
        self._t0: Optional[float] = None
        self._threshold = stop.threshold(lcp.b)
        for op in lcp.operators().values():
            op._guard = self._guard

    # ------------------------------------------------------------------ clock
    def start(self) -> None:
        self._t0 = time.perf_counter()

    def elapsed(self) -> float:
        """Solver seconds so far, excluding the monitor's bookkeeping."""
        if self._t0 is None:
            return 0.0
        return time.perf_counter() - self._t0 - self.monitor.seconds

    @property
    def threshold(self) -> float:
        """The absolute residual ``||min(x, w)||`` at which the stop rule declares convergence."""
        return self._threshold

    def emvps(self) -> float:
        return self.lcp.emvps()

    # ------------------------------------------------------------------ budget
    def _guard(self, op: Operator, k: int) -> None:
        if op.name == "high":
            extra = float(k)
        else:
            c = op.cost
            extra = k * (c / self.lcp.high_cost()) if c is not None else 0.0
        if self.lcp.emvps() + extra > self.budget.max_emvps + 1e-9:
            raise BudgetExhausted(f"budget of {self.budget.max_emvps:g} E-MVPs exhausted")
        if self.budget.max_seconds is not None and self.elapsed() > self.budget.max_seconds:
            raise BudgetExhausted(f"time budget of {self.budget.max_seconds:g} s exhausted")

    def detach(self) -> None:
        for op in self.lcp.operators().values():
            op._guard = None

    # ------------------------------------------------------------------ monitor
    def report(self, x: np.ndarray, w: np.ndarray, **extra: Any) -> bool:
        """Record iterate ``x`` with the solver's ``w = A x + b``; True means stop.

        Applies the stop rule (absolute test -> ``converged``; the paper's
        relative test alone -> ``stagnated``), the iteration cap and the time
        budget, and flags non-finite iterates as ``diverged``. The time spent
        here is not charged to the solver.
        """
        t0 = time.perf_counter()
        x = np.asarray(x, dtype=np.float64)
        w = np.asarray(w, dtype=np.float64)
        it = len(self.monitor.rows)
        finite = bool(np.all(np.isfinite(x)) and np.all(np.isfinite(w)))
        e_abs = kkt_abs(x, w) if finite else float("nan")
        e_rel = kkt_rel(e_abs, self._prev_kkt)
        verified = float("nan")
        if self.monitor.verify and finite:
            verified = kkt_abs(x, apply_uncounted(self.A, x) + self.b)
        lofi = sum(op.count for op in self.low.values())
        row = {"iter": it, "mvps": self.A.count, "lofi_mvps": lofi,
               "emvps": self.lcp.emvps(), "kkt_abs": e_abs, "kkt_rel": e_rel,
               "objective": objective(x, w, self.b) if finite else float("nan"),
               "time_s": self.elapsed(), "kkt_abs_verified": verified}
        self.monitor.rows.append(row)
        if finite:
            self._last = (x.copy(), w.copy())
        stop = False
        if not finite:
            self.status, self.message = Status.diverged, "non-finite iterate or residual"
            stop = True
        else:
            verdict = self.stop.check(e_abs, e_rel, self.b)
            if verdict == "converged":
                self.status = Status.converged
                self.message = f"||min(x,w)|| = {e_abs:.3g} <= {self._threshold:.3g}"
                stop = True
            elif verdict == "stagnated":
                self.status = Status.stagnated
                self.message = (f"relative KKT change {e_rel:.3g} < tol (paper's rule) with "
                                f"||min(x,w)|| = {e_abs:.3g}")
                stop = True
            elif self._prev_kkt is not None and len(self.monitor.rows) > 1 and \
                    e_abs > 1e12 * max(self.monitor.rows[0]["kkt_abs"], 1e-300):
                self.status, self.message = Status.diverged, f"residual grew to {e_abs:.3g}"
                stop = True
            elif it >= self.budget.max_iter:
                self.status = Status.max_iter
                self.message = f"iteration cap {self.budget.max_iter} reached"
                stop = True
            elif self.budget.max_seconds is not None and self.elapsed() > self.budget.max_seconds:
                self.status = Status.max_iter
                self.message = f"time budget of {self.budget.max_seconds:g} s exhausted"
                stop = True
        self._prev_kkt = e_abs if finite else self._prev_kkt
        if self.monitor.callback is not None:
            self.monitor.callback(dict(row), x)
        self.monitor.seconds += time.perf_counter() - t0
        return stop

    @property
    def iterations(self) -> int:
        return max(len(self.monitor.rows) - 1, 0)

    @property
    def last(self) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """The last finite reported ``(x, w)``, or None."""
        return self._last

    def oracle_spectrum(self) -> tuple[float, float]:
        """``(lambda_max, max(lambda_min, 0))`` of ``A`` from the framework's oracle.

        For solvers whose source grants the spectral constants as known (the
        paper's A-PGD). The products are uncounted -- the framework's, not the
        solver's -- so the solve is flagged with ``info['oracle_constants']``:
        its E-MVPs understate what it would cost without the oracle. Dense
        eigenvalues up to n = 1000, Lanczos (``eigsh``) beyond.
        """
        n = self.n
        self.info["oracle_constants"] = True
        if n <= 1000:
            D = apply_uncounted(self.A, np.eye(n))
            ev = np.linalg.eigvalsh((D + D.T) / 2)
            return float(ev[-1]), float(max(ev[0], 0.0))
        op = LinearOperator((n, n), matvec=lambda v: apply_uncounted(self.A, v),
                            dtype=np.float64)
        hi = float(eigsh(op, k=1, which="LA", tol=1e-8, return_eigenvectors=False)[0])
        lo = float(eigsh(op, k=1, which="SA", tol=1e-8, return_eigenvectors=False)[0])
        return hi, max(lo, 0.0)

    # ------------------------------------------------------------------ results
    def finish(self, x: np.ndarray, w: np.ndarray, status: Optional[Status] = None,
               message: str = "", state: Any = None) -> SolveResult:
        """Close the solve at ``(x, w)``.

        ``status`` defaults to what :meth:`report` decided; a solver that ends
        for its own reason (e.g. a breakdown) passes it explicitly with a message.
        The framework then verifies the answer and fills the counts.
        """
        st = status if status is not None else self.status
        if st is None:
            st = Status.max_iter
            message = message or "solver returned without meeting the stop rule"
        return SolveResult(x=np.asarray(x, dtype=np.float64), w=np.asarray(w, dtype=np.float64),
                           status=Status(st), message=message or self.message, state=state)
