"""What a solver sees: the counted operators, the stop rule, the budget, the monitor.

A solver receives a :class:`SolverContext`. It applies ``ctx.A`` (and
``ctx.low[name]``) for every product, reports each iterate with
``ctx.report(x, w)`` and returns ``ctx.finish(x, w)``. The context

* records the history (:class:`Monitor`) without counting products and without
  charging the solver's clock for the bookkeeping,
* applies the stop rule and the iteration cap, and
* enforces the budget (max E-MVPs, max seconds) inside the operators: a product
  that would exceed it raises :class:`~lcpbench.core.operator.BudgetExhausted`, which
  the framework turns into a ``budget`` (E-MVPs) or ``timeout`` (seconds)
  result at the last reported iterate.

After the solver returns, the framework confirms a ``converged`` claim with a
fresh counted product and looks for evidence of infeasibility
(:mod:`lcpbench.core.claims`).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
import pandas as pd
from scipy.sparse.linalg import LinearOperator, eigsh

from lcpbench.core.lcp import LCP
from lcpbench.core.operator import BudgetExhausted, Operator, all_finite, apply_uncounted
from lcpbench.core.probes import Accuracy, measure_accuracy, safe_column_norms
from lcpbench.core.residuals import StopRule, kkt_abs, kkt_rel, objective
from lcpbench.core.result import HISTORY_COLUMNS, SolveResult, Status

__all__ = ["Budget", "Monitor", "SolverContext", "StopSolver", "accuracy_floor"]


#: Reported iterates ``(x, w)`` the context keeps for the evidence of infeasibility
#: (:mod:`lcpbench.core.claims`): their differences and the differences of their ``w``
#: span directions whose products are known without a further product.
RECENT_ITERATES = 50
#: Directions with known products a solver may offer (:meth:`SolverContext.offer_direction`).
OFFERED_DIRECTIONS = 50
#: Each of the two windows keeps at most this many floats (``entries * n``, 32 MB of
#: vectors and as much of products), so a large ``n`` keeps fewer entries (at least 3).
WINDOW_FLOATS = 2_000_000

#: The accuracy floor of an operator with declared ``rtol``: ``ACCURACY_FACTOR rtol ||b||``.
ACCURACY_FACTOR = 10.0


def accuracy_floor(lcp: LCP) -> float:
    """The smallest residual a solver can resolve with the high operator's declared accuracy.

    A product with relative accuracy ``rtol`` gives ``w = A x + b`` up to about
    ``rtol ||A x||``, and near a solution ``||A x||`` is of the order of ``||b||``;
    :data:`ACCURACY_FACTOR` times ``rtol ||b||`` is the floor. 0 for an operator
    exact to rounding (no ``rtol``).
    """
    rtol = lcp.A.rtol
    if not rtol or lcp.n == 0:
        return 0.0
    return ACCURACY_FACTOR * rtol * float(np.linalg.norm(lcp.b))


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
        ``callback(row: dict, x: ndarray)`` after each iterate. Raising
        ``StopIteration`` in it ends the solve at that iterate (status ``stopped``).
    """

    def __init__(self, verify: bool = False, callback: Optional[Callable] = None):
        self.verify = verify
        self.callback = callback
        self.rows: list[dict] = []
        self.seconds = 0.0
        #: Columns a solver added with ``ctx.report(x, w, name=value)``, in order of appearance.
        self.extra_columns: list[str] = []

    def frame(self) -> pd.DataFrame:
        """The rows as a table: :data:`HISTORY_COLUMNS`, then the solver's own columns."""
        return pd.DataFrame(self.rows, columns=HISTORY_COLUMNS + self.extra_columns)

    def record_extra(self, row: dict, extra: dict) -> None:
        """Add a solver's own values to ``row`` as history columns, or refuse them.

        Raises
        ------
        TypeError
            A value that is not a real number, or a name of a framework column.
        """
        for key, value in extra.items():
            if key in HISTORY_COLUMNS:
                raise TypeError(f"ctx.report(..., {key}=...): {key!r} is a column the framework "
                                "records itself; give the solver's own value another name")
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float,
                                                                             np.integer,
                                                                             np.floating)):
                raise TypeError(f"ctx.report(..., {key}={value!r}): extra values are recorded "
                                "as history columns and must be real numbers; put other "
                                "records in ctx.info")
            row[key] = float(value)
            if key not in self.extra_columns:
                self.extra_columns.append(key)


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
        self.callback_stopped = False    # the callback raised StopIteration
        self.message = ""
        self._prev_kkt: Optional[float] = None
        self._last: Optional[tuple[np.ndarray, np.ndarray]] = None
        self._prev: Optional[tuple[np.ndarray, np.ndarray]] = None
        room = WINDOW_FLOATS // max(self.n, 1)
        self._recent: deque = deque(maxlen=max(3, min(RECENT_ITERATES, room)))
        self._offered: deque = deque(maxlen=max(3, min(OFFERED_DIRECTIONS, room)))
        self._certified: Optional[tuple[np.ndarray, float]] = None
        #: History rows whose verified residual is still to be computed, with their x.
        self._unverified: list[tuple[dict, np.ndarray]] = []
        self._accuracy: Optional[Accuracy] = None
        #: Largest ratio ||w - b|| / ||x|| and ||w_k - w_j|| / ||x_k - x_j|| over the
        #: reported iterates whose ratios were taken (:attr:`norm_A`), the iterates still
        #: to be taken, and the last one taken (for its difference with the next).
        self._norm_A = 0.0
        self._norm_pending: list[tuple[np.ndarray, np.ndarray]] = []
        self._norm_tail: Optional[tuple[np.ndarray, np.ndarray]] = None
        self._t0: Optional[float] = None
        self._threshold = stop.threshold(lcp.b)
        self.accuracy_floor = accuracy_floor(lcp)
        if self.accuracy_floor > self._threshold:
            self.info["accuracy_floor"] = self.accuracy_floor
            self._threshold = self.accuracy_floor
        for op in lcp.operators().values():
            op.install_guard(self._guard)

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
        """The absolute residual ``||min(x, w)||`` at which the stop rule declares convergence.

        The stop rule's bound, or the accuracy floor of the high-fidelity
        operator when it declares a relative accuracy ``rtol`` and the floor is
        larger (:func:`accuracy_floor`): no solver tightens its stop test below
        what its products can resolve.
        """
        return self._threshold

    def threshold_note(self) -> str:
        """A sentence for messages when the operator's accuracy loosened the stop test, else ''."""
        if "accuracy_floor" not in self.info:
            return ""
        return (f" (stop test loosened from {self.stop.threshold(self.b):.3g} to "
                f"{self._threshold:.3g}: the operator declares relative accuracy "
                f"rtol={self.A.rtol:g})")

    def emvps(self) -> float:
        return self.lcp.emvps()

    def operator_accuracy(self) -> Accuracy:
        """The high operator's accuracy: declared, explicit, or measured once per solve.

        Measured by :func:`~lcpbench.core.probes.measure_accuracy` on the
        framework's uncounted path the first time it is asked for (no counted
        product, and the probe's time is not charged to the solver); a float64
        matrix or a declared ``rtol`` costs nothing. Recorded in ``info``
        (``operator_accuracy``, ``operator_accuracy_source`` and, for an inexact
        undeclared operator, ``operator_accuracy_note``).
        """
        if self._accuracy is None:
            t0 = time.perf_counter()
            acc = measure_accuracy(self.A)
            if acc.source == "measured" and self.A.output_eps > max(acc.rtol, 0.0):
                acc = Accuracy(self.A.output_eps, "measured", acc.detail)
            self._accuracy = acc
            self.monitor.seconds += time.perf_counter() - t0
            self.info["operator_accuracy"] = acc.rtol
            self.info["operator_accuracy_source"] = acc.source
            if not acc.known:
                self.info["operator_accuracy_note"] = acc.detail
        elif self._accuracy.source == "measured" and self.A.output_eps > self._accuracy.rtol:
            # a later product came back narrower than the probe's
            self._accuracy = Accuracy(self.A.output_eps, "measured",
                                      "products returned in a dtype narrower than float64")
            self.info["operator_accuracy"] = self._accuracy.rtol
            self.info["operator_accuracy_note"] = self._accuracy.detail
        return self._accuracy

    def measured_exact(self) -> bool:
        """True when the operator is a float64 matrix, declares itself exact (``rtol=0``) or
        was already measured exact (no probe)."""
        if (self.A.explicit and self.A.rtol is None) or self.A.rtol == 0.0:
            return True
        return self._accuracy is not None and self._accuracy.exact

    def accuracy_advice(self) -> str:
        """A sentence for messages when the products are inexact and undeclared, else ''."""
        acc = self.operator_accuracy()
        if acc.known:
            return ""
        about = "of unknown accuracy" if not np.isfinite(acc.rtol) else \
            f"accurate to about {acc.rtol:.0e}"
        return (f"; the operator is {about} ({acc.detail}): declare Operator(..., rtol=...) "
                "so that the stop test is held at what its products can resolve")

    # ------------------------------------------------------------------ budget
    def _guard(self, op: Operator, k: int) -> None:
        if self.lcp.A.cost is None:
            # no unit yet (undeclared costs, no high product so far): low products are
            # priced once the first high product has been timed, rather than by a counted
            # high product made only to set the unit (LCP.high_cost)
            spent, extra = float(self.lcp.A.count), float(k) if op.name == "high" else 0.0
        elif op.name == "high":
            spent, extra = self.lcp.emvps(), float(k)
        else:
            c = op.cost
            spent = self.lcp.emvps()
            extra = k * (c / self.lcp.high_cost()) if c is not None else 0.0
        if spent + extra > self.budget.max_emvps + 1e-9:
            raise BudgetExhausted(f"budget of {self.budget.max_emvps:g} E-MVPs exhausted")
        if self.budget.max_seconds is not None and self.elapsed() > self.budget.max_seconds:
            raise BudgetExhausted(f"time budget of {self.budget.max_seconds:g} s exhausted",
                                  kind="time")

    def detach(self) -> None:
        for op in self.lcp.operators().values():
            op.install_guard(None)

    # ------------------------------------------------------------------ monitor
    def report(self, x: np.ndarray, w: np.ndarray, **extra: Any) -> bool:
        """Record iterate ``x`` with the solver's ``w = A x + b``; True means stop.

        Keyword arguments are the solver's own numbers for this iterate (a step
        length, an inner iteration count): each is recorded as a history column of
        its name; anything else is refused with a ``TypeError``
        (:meth:`Monitor.record_extra`). Applies the stop rule (absolute test -> ``converged``; the paper's
        relative test alone -> ``stagnated``), the iteration cap and the time
        budget, and flags non-finite iterates as ``diverged``. The time spent
        here is not charged to the solver.
        """
        if self.callback_stopped:   # a solver that reports on after being told to stop
            raise StopSolver(self.message)
        t0 = time.perf_counter()
        x = np.asarray(x, dtype=np.float64)
        w = np.asarray(w, dtype=np.float64)
        it = len(self.monitor.rows)
        finite = all_finite(x) and all_finite(w)
        e_abs = kkt_abs(x, w) if finite else float("nan")
        e_rel = kkt_rel(e_abs, self._prev_kkt)
        verified = float("nan")
        if self.monitor.verify and finite and self.monitor.callback is not None:
            verified = kkt_abs(x, apply_uncounted(self.A, x, history=True) + self.b)
        lofi = sum(op.count for op in self.low.values())
        row = {"iter": it, "mvps": self.A.count, "lofi_mvps": lofi,
               "emvps": self.lcp.emvps(), "kkt_abs": e_abs, "kkt_rel": e_rel,
               "objective": objective(x, w, self.b) if finite else float("nan"),
               "time_s": self.elapsed(), "kkt_abs_verified": verified}
        if extra:
            self.monitor.record_extra(row, extra)
        self.monitor.rows.append(row)
        if finite:
            self._prev, self._last = self._last, (x.copy(), w.copy())
            self._recent.append(self._last)
            self._norm_pending.append(self._last)       # its ratios are taken in a batch
            if len(self._norm_pending) * 2 * self.n >= WINDOW_FLOATS:
                self._take_norm_ratios()
            if self.monitor.verify and self.monitor.callback is None:
                self._unverified.append((row, self._last[0]))
                if len(self._unverified) * self.n >= WINDOW_FLOATS:
                    self.verify_history()
        stop = False
        if not finite:
            self.status, self.message = Status.diverged, "non-finite iterate or residual"
            stop = True
        else:
            verdict = "converged" if e_abs <= self._threshold else \
                self.stop.check(e_abs, e_rel, self.b)
            if verdict == "converged":
                self.status = Status.converged
                self.message = (f"||min(x,w)|| = {e_abs:.3g} <= {self._threshold:.3g}"
                                + self.threshold_note())
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
                self.status = Status.timeout
                self.message = f"time budget of {self.budget.max_seconds:g} s exhausted"
                stop = True
        self._prev_kkt = e_abs if finite else self._prev_kkt
        if self.monitor.callback is not None:
            stop = self._call_back(self.monitor.callback, row, x, stop)
        self.monitor.seconds += time.perf_counter() - t0
        return stop

    def _call_back(self, callback: Callable, row: dict, x: np.ndarray, stop: bool) -> bool:
        """The caller's callback on this iterate; its ``StopIteration`` ends the solve here.

        The status is then ``stopped`` (unless this iterate already ended the
        solve for its own reason); a solver that reports again after being told
        to stop is ended by :class:`StopSolver` (:meth:`report`) at the iterate
        the callback saw.
        """
        try:
            callback(dict(row), x)
        except StopIteration as exc:
            self.callback_stopped = True
            if not stop:
                self.status = Status.stopped
                self.message = (f"stopped by the callback at iterate {row['iter']}"
                                + (f": {exc}" if str(exc) else ""))
            return True
        return stop

    def verify_history(self) -> None:
        """Fill the verified residual of the iterates recorded since the last call.

        One uncounted block product over their ``x`` (a matrix-matrix product, several
        times cheaper per column than one product per iterate), made when the window
        of :data:`WINDOW_FLOATS` fills and when the solve ends; the time is not charged
        to the solver. An iterate reported to a ``callback`` is verified at once
        instead, so that the callback's row carries it.
        """
        if not self._unverified:
            return
        t0 = time.perf_counter()
        rows, xs = zip(*self._unverified)
        self._unverified = []
        X = np.column_stack(xs)
        W = apply_uncounted(self.A, X, history=True) + self.b[:, None]
        for row, e in zip(rows, np.linalg.norm(np.minimum(X, W), axis=0)):
            row["kkt_abs_verified"] = float(e)
        self.monitor.seconds += time.perf_counter() - t0

    @property
    def norm_A(self) -> float:
        """A lower bound on ``||A||`` for free: the largest ratio ``||w - b|| / ||x||`` and
        ``||w_k - w_j|| / ||x_k - x_j||`` (consecutive finite iterates) over the reported
        iterates, with the solvers' own ``w`` (0 before any ratio exists)."""
        self._take_norm_ratios()
        return self._norm_A

    def _take_norm_ratios(self) -> None:
        """Fold the ratios of the iterates reported since the last call into :attr:`norm_A`.

        One pass over the columns of the batch instead of four norms per iterate;
        overflow-safe (each column scaled by its largest entry), so a warm start of
        1e300 does not turn the estimate into inf or nan.
        """
        pending = self._norm_pending
        if not pending:
            return
        self._norm_pending = []
        X = np.column_stack([x for x, _ in pending])
        W = np.column_stack([w for _, w in pending])
        with np.errstate(all="ignore"):
            r = self._ratios(X, W)
        self._norm_tail = pending[-1]
        r = r[np.isfinite(r)]
        if r.size:
            self._norm_A = max(self._norm_A, float(r.max()))

    def _ratios(self, X: np.ndarray, W: np.ndarray) -> np.ndarray:
        """The ratios of the iterates ``X`` (columns, with their ``W``), and of their
        differences with the one before them."""
        ratios = [safe_column_norms(W - self.b[:, None]) / safe_column_norms(X)]
        first = (self._norm_tail,) if self._norm_tail is not None else ()
        if X.shape[1] + len(first) > 1:
            Xs = np.column_stack([x for x, _ in first] + [X]) if first else X
            Ws = np.column_stack([w for _, w in first] + [W]) if first else W
            ratios.append(safe_column_norms(np.diff(Ws, axis=1)) / safe_column_norms(np.diff(Xs, axis=1)))
        return np.concatenate(ratios)

    @property
    def iterations(self) -> int:
        return max(len(self.monitor.rows) - 1, 0)

    @property
    def last(self) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """The last finite reported ``(x, w)``, or None."""
        return self._last

    def certify(self, x: np.ndarray, bound: float) -> None:
        """Record that ``||min(x, A x + b)|| <= bound`` is proven for the iterate ``x``.

        For a solver's shared confirmation (:class:`lcpbench.toolkit.confirm.ConfirmedReport`),
        whose drift bound covers the rounding of its gradient recurrence: a
        ``converged`` claim at exactly this ``x`` with ``bound`` within the
        threshold is then accepted without a fresh product.
        """
        self._certified = (np.array(x, dtype=np.float64), float(bound))

    def certified(self, x: np.ndarray) -> Optional[float]:
        """The bound certified for exactly ``x`` (see :meth:`certify`), or None."""
        if self._certified is None or self._certified[0].shape != np.shape(x) \
                or not np.array_equal(self._certified[0], x):
            return None
        return self._certified[1]

    @property
    def recent(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The last finite reported ``(x, w)``, oldest first.

        At most :data:`RECENT_ITERATES` of them, fewer when ``n`` is large
        (:data:`WINDOW_FLOATS`).
        """
        return list(self._recent)

    def offer_direction(self, d: np.ndarray, Ad: np.ndarray) -> None:
        """Offer a direction ``d`` whose product ``A d`` the solver computed, as possible evidence.

        For directions along which the solver suspects the problem has no
        solution (a Newton step that blows up on a singular system, a search
        direction of zero curvature): after a solve that did not converge the
        framework looks for a non-negative combination of these directions and
        of the reported iterates' differences with ``A d ~ 0`` and ``b'd < 0``
        (:func:`lcpbench.core.claims.infeasibility_evidence`), and confirms it
        with one counted product. Offering costs no product and changes nothing
        else; the last :data:`OFFERED_DIRECTIONS` finite offers are kept (fewer
        when ``n`` is large, :data:`WINDOW_FLOATS`).
        """
        d = np.array(d, dtype=np.float64).reshape(-1)
        Ad = np.array(Ad, dtype=np.float64).reshape(-1)
        if d.shape == Ad.shape == (self.n,) and np.all(np.isfinite(d)) and \
                np.all(np.isfinite(Ad)) and np.any(d != 0.0):
            self._offered.append((d, Ad))

    @property
    def offered(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The directions offered by :meth:`offer_direction`, oldest first."""
        return list(self._offered)

    @property
    def previous(self) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """The finite reported ``(x, w)`` before :attr:`last`, or None."""
        return self._prev

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
        if self.callback_stopped and self.status == Status.stopped:
            st, message = Status.stopped, ""    # the caller's stop outranks the solver's reason
        if st is None:
            st = Status.max_iter
            message = message or "solver returned without meeting the stop rule"
        return SolveResult(x=np.asarray(x, dtype=np.float64), w=np.asarray(w, dtype=np.float64),
                           status=Status(st), message=message or self.message, state=state)
