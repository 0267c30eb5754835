"""Counted linear operators: every product a solver asks for is recorded.

The cost that matters for the LCPs of collision resolution is the number of
matrix-vector products (MVPs), because every product is a Stokes mobility solve.
:class:`Operator` is the only way a solver touches a matrix: it subclasses
:class:`scipy.sparse.linalg.LinearOperator`, so it plugs into scipy's Krylov
solvers unchanged, and every public way of applying it (``matvec``, ``matmat``,
``rmatvec``, ``@``, ``dot``, ``__call__``, ``.T``/``.H``) goes through the same
counting path.  A block product with ``k`` columns counts ``k`` MVPs. A product
with an all-zero vector (column) is not counted: ``A 0 = 0`` needs no PDE
solve, so a cold start ``x0 = 0`` gets its gradient ``b`` for free, for every
solver alike.

The framework (never a solver) applies an operator without counting through
:func:`apply_uncounted`, to verify answers independently.

Work in inner applications.  An MVP is the paper's unit of cost, but an
operator that is itself an iterative solve (the boundary-integral mobility with Krylov
recycling) does not pay the same for every product.  ``Operator(..., work=callable)``
lets such an operator report its *inner applications* (e.g. GMRES/GCR products of the
traction operator, forward and adjoint): the counted operator reads the callable just
before and just after each counted product and charges the difference to that product,
so uncounted framework products are never charged.  Without the hook a product is one
application.  See :meth:`Operator.application_cost` for the application-weighted cost.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator, Mapping
from typing import Any, Optional, Union

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, aslinearoperator

#: What a ``work`` hook returns: cumulative inner applications so far, one number or one
#: number per kind (e.g. ``{"forward": 120, "adjoint": 97}``).
WorkCounts = Union[int, float, Mapping[str, Union[int, float]]]

__all__ = ["Operator", "WorkCounts", "BudgetExhausted", "OperatorError", "NonFiniteProduct", "apply_uncounted",
           "as_operator"]


class BudgetExhausted(RuntimeError):
    """Raised by a counted product that would exceed the solve's budget.

    The framework catches it and closes the solve with status ``budget`` (E-MVPs)
    or ``timeout`` (seconds, ``kind="time"``) and the last iterate the solver
    reported, so every solver honours the budget even when the product is
    requested deep inside a library (e.g. scipy's L-BFGS-B).
    """

    def __init__(self, message: str, kind: str = "emvps"):
        super().__init__(message)
        self.kind = kind


class OperatorError(RuntimeError):
    """An operator's own code raised, or returned an answer of the wrong shape.

    The message names the operator (``"high"`` or the low fidelity's name) and
    repeats the original error, which the framework records in a ``failed`` result.
    """


class NonFiniteProduct(ArithmeticError):
    """Raised when an operator returns NaN or Inf for a finite input.

    The framework closes the solve with status ``failed`` and this message, so a
    broken operator is never reported as an infeasible or indefinite problem.
    """


def _explicit_matrix(A) -> bool:
    return isinstance(A, np.ndarray) or sp.issparse(A)


class Operator(LinearOperator):
    """A linear operator that counts and times every product.

    Parameters
    ----------
    A : ndarray, scipy sparse matrix, LinearOperator, or callable
        The operator. A callable must map a 1-D vector to a 1-D vector and needs
        ``shape``.
    shape : tuple of int, optional
        Required when ``A`` is a callable.
    cost : float, optional
        Declared seconds per MVP (stored sets declare the cost measured when they
        were generated). When omitted the cost is the measured mean wall time per
        product of this operator.
    name : str
        Label used in results (``"high"`` for the high-fidelity operator, the
        fidelity name such as ``"p4"`` for low-fidelity ones).
    rtol : float, optional
        Declared relative accuracy of a product: ``||A v - exact|| <= rtol ||A v||``
        (e.g. the tolerance of the iterative solve each product is). Solvers do
        not tighten their stop test below what it allows (see
        :meth:`lcpbench.core.context.SolverContext.threshold`). None (default)
        means exact to rounding.
    work : callable, optional
        ``work()`` returns the cumulative inner applications the wrapped operator
        has made so far (a number, or a mapping kind -> number such as
        ``{"forward": ..., "adjoint": ...}``); it must only grow.  It is read
        before and after every counted product and the difference is charged to
        that product (:attr:`applications`, :attr:`applications_by_kind`).
        Without it every counted product is one application (kind ``"product"``).
    cold_applications : float, optional
        Inner applications one product takes from a cold start (no recycled
        information): the unit that turns applications into products.  When
        omitted it is the applications of the first counted product that made
        any (measured per operator copy, i.e. per solve); without ``work`` it is 1.

    Notes
    -----
    Looser products on request: when the wrapped operator has an attribute
    ``at_accuracy`` (a callable ``rtol -> context manager`` inside which its products are
    made to relative accuracy ``rtol``, e.g. an iterative solve stopped earlier; the
    boundary-integral contact operators have one), :meth:`product_within` makes a counted
    product to a requested accuracy looser than ``rtol``.  A solver asks for it where it
    needs no more (inexact products); such a product counts as one MVP, its inner
    applications are charged as any product's, and it is never reused as an accurate
    product (:meth:`last_product`).

    ``count`` is the number of MVPs (columns) applied, ``seconds`` the wall time
    spent in products. The last single-vector product is remembered (input and
    output), so the framework can confirm a solver's claim at the vector it last
    applied without paying for the product again. :meth:`copy` gives an operator that shares the underlying
    matrix and declared cost but starts with fresh counters; the framework
    makes one per solve so that solves never share counts.
    """

    _impl: Any                      # ndarray, sparse matrix or LinearOperator
    _declared_cost: Optional[float]
    _explicit: bool
    _work: Optional[Callable[[], WorkCounts]]
    _declared_cold: Optional[float]

    def __init__(self, A, shape: Optional[tuple] = None, *, cost: Optional[float] = None,
                 name: str = "high", dtype=np.float64, rtol: Optional[float] = None,
                 work: Optional[Callable[[], WorkCounts]] = None,
                 cold_applications: Optional[float] = None):
        checks: set[tuple[float, bool]] = set()    # what LCP checked of the matrix
        if isinstance(A, Operator):
            impl = A._impl
            shape = A.shape
            cost = A._declared_cost if cost is None else cost
            rtol = A.rtol if rtol is None else rtol
            work = A._work if work is None else work
            cold_applications = (A._declared_cold if cold_applications is None
                                 else cold_applications)
            self._explicit = A._explicit
            checks = A._checks                     # the same matrix: its checks hold
        elif _explicit_matrix(A):
            arr = A
            if isinstance(arr, np.ndarray):
                if arr.ndim != 2:
                    raise ValueError(f"operator {name!r}: expected a 2-D matrix, got an array "
                                     f"with {arr.ndim} dimension(s); pass an (n, n) matrix")
                if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
                    raise TypeError(f"operator {name!r}: matrix dtype {arr.dtype} is not real; "
                                    "pass a real float64 matrix (e.g. A.astype(float))")
                arr = np.asarray(arr, dtype=np.float64)
            else:
                # dtype, not .data: DOK and LIL matrices have no data array
                if np.iscomplexobj(np.empty(0, dtype=arr.dtype)) \
                        or not np.issubdtype(arr.dtype, np.number):
                    raise TypeError(f"operator {name!r}: sparse dtype {arr.dtype} is not real; "
                                    "pass a real float64 matrix")
                arr = sp.csr_matrix(arr, dtype=np.float64)
            impl = arr
            shape = arr.shape
            self._explicit = True
        elif isinstance(A, LinearOperator):
            impl = A
            shape = A.shape
            self._explicit = False
        elif callable(A):
            if shape is None:
                raise ValueError(f"operator {name!r}: a matvec callable needs shape=(n, n)")
            impl = LinearOperator(tuple(shape), matvec=A, dtype=np.float64)
            self._explicit = False
        else:
            raise TypeError(f"operator {name!r}: cannot make an operator from {type(A).__name__}; "
                            "pass an ndarray, a scipy sparse matrix, a LinearOperator, "
                            "or a callable with shape=")
        shape = tuple(int(s) for s in shape)
        if len(shape) != 2:
            raise ValueError(f"operator {name!r}: shape must be (n, n), got {shape}")
        super().__init__(dtype=np.dtype(dtype), shape=shape)
        self._impl = impl
        self._checks: set[tuple[float, bool]] = checks
        if cost is not None:
            cost = float(cost)
            if not np.isfinite(cost) or cost <= 0:
                raise ValueError(f"operator {name!r}: cost must be a positive number of seconds "
                                 f"per MVP, got {cost}")
        self._declared_cost = cost
        if rtol is not None:
            rtol = float(rtol)
            if not (np.isfinite(rtol) and 0 <= rtol < 1):
                raise ValueError(f"operator {name!r}: rtol (relative accuracy of a product) must "
                                 f"be in [0, 1), got {rtol}")
        self.rtol: Optional[float] = rtol
        self.name = name
        self._init_work(work, cold_applications)
        self._last: Optional[tuple[np.ndarray, np.ndarray]] = None
        self._init_counts()
        #: Counted products made to a looser accuracy (:meth:`product_within`).
        self.loose = 0
        self._loose_now = False
        self.nonfinite_at: Optional[int] = None
        #: Products the framework made at this operator, not the solver: its uncounted ones
        #: (verification, accuracy probes, cost timing, ...) and the counted ones it adds
        #: itself (confirmations, cost calibration), in columns.
        self.framework_products = 0
        self.history_products = 0   #: uncounted columns of the verified history, kept apart
        self._guard: Optional[Callable[[Operator, int], None]] = None
        #: The largest machine epsilon of a product's output dtype narrower than float64
        #: (float32: 1.2e-7), 0 while every product came back in float64.
        self.output_eps = 0.0

    def _init_counts(self) -> None:
        self.count = 0
        self.seconds = 0.0
        self.calls = 0
        #: Seconds and inner applications after the first call (which may pay one-off work:
        #: compiling kernels, building tables), for :attr:`steady_application_seconds`.
        self._after_first: Optional[tuple[float, float]] = None

    def _init_work(self, work: Optional[Callable[[], WorkCounts]],
                   cold: Optional[float]) -> None:
        """Check and store the work hook and the declared cold applications; zero the tallies."""
        if work is not None and not callable(work):
            raise TypeError(f"operator {self.name!r}: work must be a callable returning the "
                            f"cumulative inner applications, got {type(work).__name__}")
        if cold is not None:
            cold = float(cold)
            if not (np.isfinite(cold) and cold > 0):
                raise ValueError(f"operator {self.name!r}: cold_applications must be a positive "
                                 f"number of inner applications per product, got {cold}")
        self._work = work
        self._declared_cold = cold
        self._first_apps: Optional[float] = None
        #: Inner applications charged to counted products, per kind.
        self.applications_by_kind: dict[str, float] = {}

    def _read_work(self) -> dict[str, float]:
        """The hook's cumulative applications as ``{kind: number}``."""
        assert self._work is not None
        try:
            got = self._work()
        except Exception as exc:
            raise OperatorError(f"operator {self.name!r}: its work hook raised "
                                f"{type(exc).__name__}: {exc}") from exc
        items = got.items() if isinstance(got, Mapping) else [("applications", got)]
        out = {}
        for kind, v in items:
            v = float(v)
            if not (np.isfinite(v) and v >= 0):
                raise OperatorError(f"operator {self.name!r}: its work hook reported {v} "
                                    f"{kind!r} applications; it must return non-negative "
                                    "cumulative counts")
            out[str(kind)] = v
        return out

    def _charge(self, before: Optional[dict[str, float]], k: int) -> None:
        """Charge one counted product (``k`` columns): the hook's increase, or ``k``."""
        if before is None:
            delta = {"product": float(k)}
        else:
            after = self._read_work()
            delta = {kind: after[kind] - before.get(kind, 0.0) for kind in after}
            if any(d < 0 for d in delta.values()):
                raise OperatorError(f"operator {self.name!r}: its work hook went down during a "
                                    f"product ({before} -> {after}); it must return cumulative "
                                    "counts that only grow")
        for kind, d in delta.items():
            self.applications_by_kind[kind] = self.applications_by_kind.get(kind, 0.0) + d
        total = sum(delta.values())
        if self._first_apps is None and total > 0 and not self._loose_now:
            self._first_apps = total / k

    def checked(self, symmetric_rtol: float, psd: bool) -> bool:
        """True when this matrix already passed the problem checks at ``symmetric_rtol``
        (and the definiteness test when ``psd``): :class:`~lcpbench.LCP` checks a matrix
        once per operator and its copies, not once per problem built on it."""
        return any(r <= symmetric_rtol and (p or not psd) for r, p in self._checks)

    def mark_checked(self, symmetric_rtol: float, psd: bool) -> None:
        """Record that the matrix passed the problem checks (see :meth:`checked`)."""
        self._checks.add((float(symmetric_rtol), bool(psd)))

    def install_guard(self, guard: Optional[Callable[[Operator, int], None]]) -> None:
        """Call ``guard(self, k)`` before every counted product of ``k`` columns (None: no guard).

        The framework's budget check: the guard raises
        :class:`BudgetExhausted` to refuse a product. Solvers never install one.
        """
        self._guard = guard

    @contextlib.contextmanager
    def unguarded(self) -> Iterator[None]:
        """A context in which counted products are not held to the guard (a measurement
        the framework makes, not a solver's step)."""
        guard, self._guard = self._guard, None
        try:
            yield
        finally:
            self._guard = guard

    # ------------------------------------------------------------------ counting
    def _apply(self, X: np.ndarray) -> np.ndarray:
        # A zero column costs nothing: A @ 0 = 0 exactly for any linear operator,
        # so no PDE solve is needed (e.g. the gradient b at the cold start x0 = 0).
        if X.ndim == 1:
            k = 1 if np.count_nonzero(X) else 0
        else:
            k = int(np.count_nonzero(np.any(X != 0, axis=0)))
        if k == 0:
            return np.zeros(self.shape[0] if X.ndim == 1 else (self.shape[0], X.shape[1]))
        if self._guard is not None:
            self._guard(self, k)
        before = self._read_work() if self._work is not None else None
        t0 = time.perf_counter()
        Y = _checked_apply(self, X)
        self.seconds += time.perf_counter() - t0
        self._charge(before, k)
        self.count += k
        self.calls += 1
        if self.calls == 1:
            self._after_first = (self.seconds, self.applications)
        if not all_finite(Y) and all_finite(X):
            self.nonfinite_at = self.nonfinite_at or self.count
            raise NonFiniteProduct(f"operator returned non-finite values at product "
                                   f"{self.nonfinite_at}"
                                   + ("" if self.name == "high" else f" (operator {self.name!r})"))
        if X.ndim == 1:
            self._last = None if self._loose_now else (X.copy(), Y.copy())
        return Y

    @property
    def relaxable(self) -> bool:
        """True when products can be asked for a looser accuracy (:meth:`product_within`)."""
        return callable(getattr(self._impl, "at_accuracy", None))

    def product_within(self, x: np.ndarray, rtol: float) -> np.ndarray:
        """``A x`` to relative accuracy ``rtol`` (``||error|| <= rtol ||A x||``), one counted MVP.

        Looser than the operator's own accuracy only when the wrapped operator offers it
        (:attr:`relaxable`) and ``rtol`` exceeds :attr:`rtol`; otherwise the ordinary
        product.  The product is counted and charged its inner applications as any
        other, is not remembered as the last product (the framework never confirms a
        claim with it), and does not set :attr:`cold_applications`.

        Raises
        ------
        ValueError
            If ``rtol`` is not in (0, 1).
        """
        rtol = float(rtol)
        if not (np.isfinite(rtol) and 0 < rtol < 1):
            raise ValueError(f"operator {self.name!r}: a product's requested accuracy must be "
                             f"in (0, 1), got {rtol}")
        if not self.relaxable or rtol <= (self.rtol or 0.0):
            return self._matvec(x)
        self._loose_now = True
        try:
            with self._impl.at_accuracy(rtol):
                y = self._matvec(x)
            self.loose += 1
        finally:
            self._loose_now = False
        return y

    def last_product(self, x: np.ndarray) -> Optional[np.ndarray]:
        """``A x`` if the last counted single-vector product was at exactly ``x``, else None."""
        if self._last is None or self._last[0].shape != np.shape(x):
            return None
        return self._last[1].copy() if np.array_equal(self._last[0], x) else None

    def __matmul__(self, other):
        # the products of a solve: a float64 vector or block goes straight to the count,
        # without scipy's general dispatch (scalars, other operators) in front of it
        if type(other) is np.ndarray and other.dtype == np.float64 and other.ndim in (1, 2) \
                and other.shape[0] == self.shape[1]:
            return self._apply(other)
        return super().__matmul__(other)

    def dot(self, x):
        return self.__matmul__(x)

    def _matvec(self, x):
        x = np.asarray(x, dtype=np.float64)
        return self._apply(x.reshape(-1)).reshape(x.shape)

    def _matmat(self, X):
        return self._apply(np.asarray(X, dtype=np.float64))

    # The LCP matrices are symmetric: the adjoint is the operator itself, counted.
    def _rmatvec(self, x):
        return self._matvec(x)

    def _rmatmat(self, X):
        return self._matmat(X)

    def _adjoint(self):
        return self

    def _transpose(self):
        return self

    # ------------------------------------------------------------------ cost
    @property
    def explicit(self) -> bool:
        """True when the operator wraps an explicit (dense or sparse) matrix."""
        return self._explicit

    @property
    def declared_cost(self) -> Optional[float]:
        """Declared seconds per MVP, or None."""
        return self._declared_cost

    @property
    def measured_cost(self) -> Optional[float]:
        """Measured seconds per MVP so far, or None before the first product.

        The mean wall time per product; for an operator with a ``work`` hook whose
        products made inner applications, the seconds per application times
        :attr:`cold_applications`: the cost of one product from a cold start, estimated
        from the products made (with Krylov recycling later products are cheaper than
        the first, and a plain mean would price the operator by its mix of both)."""
        if not self.count:
            return None
        apps, cold = self.applications, self.cold_applications
        if self._work is not None and apps > 0 and cold:
            return self.seconds / apps * cold
        return self.seconds / self.count

    @property
    def cost(self) -> Optional[float]:
        """Seconds per MVP: declared if given, else measured (None if unknown)."""
        return self._declared_cost if self._declared_cost is not None else self.measured_cost

    # ------------------------------------------------------------------ work
    @property
    def has_work_hook(self) -> bool:
        """True when the operator reports its inner applications (``work=``)."""
        return self._work is not None

    @property
    def applications(self) -> float:
        """Inner applications charged to counted products (= :attr:`count` without a hook)."""
        return float(sum(self.applications_by_kind.values()))

    @property
    def cold_applications(self) -> Optional[float]:
        """Applications of one product from a cold start: declared, else those of the first
        counted product that made any (1 without a hook); None before any product."""
        if self._declared_cold is not None:
            return self._declared_cold
        if self._work is None:
            return 1.0
        return self._first_apps

    @property
    def steady_application_seconds(self) -> Optional[float]:
        """Seconds per inner application over the calls after the first, or None.

        The first call of an operator may pay one-off work (the first compilation of its
        kernels, a table built on first use), so a price taken from it alone can be many
        times the steady one. None before a second call that made applications.
        """
        if self._after_first is None or self.calls < 2:
            return None
        s0, a0 = self._after_first
        apps = self.applications - a0
        return (self.seconds - s0) / apps if apps > 0 else None

    def application_cost(self) -> Optional[float]:
        """Seconds per inner application: :attr:`cost` / :attr:`cold_applications`.

        The application-weighted cost of a solve (``SolveResult.app_cost``) is
        ``sum(applications_op * application_cost_op) / cost_high``: high products at
        their cold number of applications.  When every product takes the cold
        number of applications it equals the E-MVPs; with Krylov recycling later
        products take fewer and it is smaller.  None when either part is unknown.
        """
        c, a = self.cost, self.cold_applications
        return None if c is None or a is None else c / a

    def copy(self, name: Optional[str] = None) -> Operator:
        """A new operator on the same matrix, declared cost and work hook, with zeroed counters."""
        op = Operator(self, name=self.name if name is None else name)
        return op

    def __repr__(self) -> str:
        kind = type(self._impl).__name__
        return (f"<Operator {self.name!r} {self.shape[0]}x{self.shape[1]} ({kind}), "
                f"count={self.count}, applications={self.applications:g}, cost={self.cost}>")


def all_finite(v: np.ndarray) -> bool:
    """True when every entry of ``v`` is finite (no floating-point warnings)."""
    return bool(np.isfinite(v).all())


def _checked_apply(op: Operator, X: np.ndarray) -> np.ndarray:
    """``_raw_apply`` that names the operator when its code raises or answers with a wrong shape."""
    try:
        Y = _raw_apply(op._impl, X)
    except (BudgetExhausted, OperatorError):
        raise
    except Exception as exc:
        raise OperatorError(f"operator {op.name!r} raised {type(exc).__name__}: {exc}") from exc
    if Y.dtype.kind == "c" or not np.issubdtype(Y.dtype, np.number):
        raise OperatorError(f"operator {op.name!r} returned {Y.dtype} values; the LCP is real, so "
                            "its matvec must return real numbers (take .real if the imaginary "
                            "part is rounding)")
    if Y.dtype.kind == "f" and Y.dtype.itemsize < 8:
        op.output_eps = max(op.output_eps, float(np.finfo(Y.dtype).eps))
    want = (op.shape[0],) + X.shape[1:]
    if Y.shape != want:
        raise OperatorError(f"operator {op.name!r} returned an array of shape {Y.shape} for an "
                            f"input of shape {X.shape}; expected {want}: its matvec must map "
                            f"length-{op.shape[1]} vectors to length-{op.shape[0]} vectors")
    return Y


def _raw_apply(impl, X: np.ndarray) -> np.ndarray:
    if isinstance(impl, np.ndarray):
        return impl @ X
    if sp.issparse(impl):
        return np.asarray(impl @ X)
    # The user's code works on its own copy and hands back an array of its own: an
    # operator that writes into its input (``cho_solve(..., overwrite_b=True)``) or reuses
    # its output buffer must not overwrite a vector the framework keeps (a solver's
    # answer, the iterate it verifies, the product it remembers).
    X = X.copy()
    if X.ndim == 1:
        return np.array(impl.matvec(X)).reshape(-1)
    return np.array(impl.matmat(X))


def apply_uncounted(op: Operator, X: np.ndarray, *, history: bool = False) -> np.ndarray:
    """Apply ``op`` without counting or timing: for the framework's verification only.

    Solvers must never call this; the test-suite checks that no solver module
    imports it. Each column is tallied in ``op.framework_products``, or in
    ``op.history_products`` for the verified history (``history=True``). Raises
    :class:`OperatorError` naming the operator when its code fails.
    """
    X = np.asarray(X, dtype=np.float64)
    k = 1 if X.ndim == 1 else int(X.shape[1])
    if history:
        op.history_products += k
    else:
        op.framework_products += k
    return _checked_apply(op, X)


def dense_uncounted(op: Operator) -> np.ndarray:
    """The operator as a dense matrix, formed without counting (framework only).

    Explicit matrices are returned directly (densified); other operators are
    applied to the columns of the identity.
    """
    impl = op._impl
    if isinstance(impl, np.ndarray):
        return impl.copy()
    if sp.issparse(impl):
        return impl.toarray()
    return apply_uncounted(op, np.eye(op.shape[1]))


def as_operator(A, *, name: str = "high", cost: Optional[float] = None) -> Operator:
    """Wrap ``A`` in a counted :class:`Operator` (no-op copy semantics for Operators)."""
    if isinstance(A, Operator):
        return A
    if isinstance(A, LinearOperator) or _explicit_matrix(A) or callable(A):
        return Operator(A, cost=cost, name=name)
    try:
        return Operator(aslinearoperator(A), cost=cost, name=name)
    except Exception as exc:  # pragma: no cover - message only
        raise TypeError(f"cannot make an operator from {type(A).__name__}: {exc}") from None
