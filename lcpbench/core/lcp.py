"""The LCP model: find x >= 0 with w = A x + b >= 0 and x . w = 0."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from lcpbench.core.operator import Operator, apply_uncounted, as_operator, dense_uncounted

__all__ = ["LCP", "SYMMETRY_RTOL", "PSD_CHECK_MAX_N"]

#: Relative tolerance of the symmetry check on explicit matrices:
#: ``max|A - A'| <= SYMMETRY_RTOL * max|A|``. The live BIM mobility is only
#: symmetric to ~1e-3 (docs/mobility.md), which is why its problem plugin symmetrises
#: explicitly before building an LCP.
SYMMETRY_RTOL = 1e-10


#: Largest n whose positive semidefiniteness is checked by a dense eigenvalue computation
#: (about 30 MB for a sparse matrix densified for the check; beyond it the check is skipped).
PSD_CHECK_MAX_N = 2000


#: Rows per block of the symmetry check (:func:`_asymmetry`): a block and its transposed
#: counterpart stay in cache, and no temporary of the matrix's size is formed.
SYMMETRY_BLOCK = 128


def _asymmetry(M: np.ndarray) -> float:
    """``max|M - M'|`` of a dense matrix, block by block over its upper triangle."""
    n = M.shape[0]
    worst = 0.0
    for i in range(0, n, SYMMETRY_BLOCK):
        j = i + SYMMETRY_BLOCK
        worst = max(worst, float(np.max(np.abs(M[i:j, i:] - M[i:, i:j].T))))
    return worst


def _nonfinite_entry(name: str, M: np.ndarray) -> ValueError:
    bad = np.argwhere(~np.isfinite(M))[0]
    return ValueError(f"LCP field {name}: entry {tuple(int(i) for i in bad)} is "
                      f"{M[tuple(bad)]}; all entries must be finite")


def _semidefinite(M, n: int, scale: float) -> Optional[float]:
    """None when ``M`` is positive semidefinite to ``1e-8 max|M| n``, else its smallest eigenvalue.

    The cheap test is a Cholesky factorisation of ``M + tau I`` with that ``tau``
    (about ``n^3 / 3`` operations, a tenth of an eigenvalue computation): it succeeds
    exactly when the smallest eigenvalue exceeds ``-tau``, to a rounding far below
    ``tau``. Only when it fails are the eigenvalues computed, for the message (and a
    borderline matrix the factorisation refused is accepted when they are within
    ``-tau``).
    """
    dense = M.toarray() if sp.issparse(M) else np.array(M, dtype=np.float64)
    # Relative to max|A| (not to max(max|A|, 1)): -1e-9 I is negative definite too.
    tau = 1e-8 * scale * n
    dense[np.diag_indices(n)] += tau
    try:
        scipy.linalg.cholesky(dense, lower=True, overwrite_a=True, check_finite=False)
        return None
    except np.linalg.LinAlgError:
        pass
    dense = M.toarray() if sp.issparse(M) else np.asarray(M)
    lam_min = float(np.linalg.eigvalsh((dense + dense.T) / 2)[0])
    return lam_min if lam_min < -tau else None


def _check_explicit(name: str, M, n: int, symmetric_rtol: float, psd: bool = True) -> None:
    """Finite entries, symmetry and (up to :data:`PSD_CHECK_MAX_N`) semidefiniteness.

    A sparse matrix is checked on its stored entries and its sparse transpose;
    it is densified only for the definiteness test, and only up to
    :data:`PSD_CHECK_MAX_N`, so validation never costs more memory than the
    matrix itself beyond that size. A dense matrix costs two passes over it
    (its extreme entries, its symmetry block by block) and the Cholesky test of
    :func:`_semidefinite`; an operator keeps what was checked
    (:meth:`~lcpbench.core.operator.Operator.checked`), so the same matrix is
    checked once however many problems are built on it.
    """
    if sp.issparse(M):
        M = sp.csr_matrix(M)
        vals = M.data
        if not np.all(np.isfinite(vals)):
            coo = M.tocoo()
            k = int(np.argmax(~np.isfinite(coo.data)))
            raise ValueError(f"LCP field {name}: entry ({int(coo.row[k])}, {int(coo.col[k])}) is "
                             f"{coo.data[k]}; all entries must be finite")
        scale = float(np.max(np.abs(vals))) if vals.size else 0.0
        diff = (M - M.T).tocsr()
        asym = float(np.max(np.abs(diff.data))) if diff.nnz else 0.0
    else:
        hi, lo = (float(M.max()), float(M.min())) if M.size else (0.0, 0.0)
        if not (np.isfinite(hi) and np.isfinite(lo)):
            raise _nonfinite_entry(name, M)
        scale = max(abs(hi), abs(lo))
        asym = _asymmetry(M) if M.size else 0.0
    if asym > symmetric_rtol * max(scale, np.finfo(float).tiny):
        raise ValueError(
            f"LCP field {name}: matrix is not symmetric (max|A-A'| = {asym:.3g}, "
            f"{asym / scale:.3g} relative > {symmetric_rtol:g}); symmetrise it with "
            "(A + A.T) / 2 or pass symmetric_rtol= to accept it")
    if psd and 0 < n <= PSD_CHECK_MAX_N and scale > 0:
        lam_min = _semidefinite(M, n, scale)
        if lam_min is not None:
            raise ValueError(
                f"LCP field {name}: matrix is not positive semidefinite (smallest eigenvalue "
                f"{lam_min:.3g}); the symmetric LCP needs A >= 0. Pass psd_check=False to "
                "build it anyway (e.g. for an indefinite low-fidelity model)")


@dataclass
class LCP:
    """A symmetric linear complementarity problem ``0 <= x  _|_  A x + b >= 0``.

    Parameters
    ----------
    A : Operator, ndarray, scipy sparse matrix, LinearOperator, or callable
        The high-fidelity matrix (symmetric positive semidefinite). It is wrapped
        in a counted :class:`~lcpbench.Operator` named ``"high"``.
    b : array_like, shape (n,)
    x0 : array_like, optional
        Warm start (non-negative). Solvers start from ``x0`` when given, else 0.
    low : mapping of str to operator, optional
        Low-fidelity operators by name (e.g. ``{"p4": ..., "rpy": ...}``); their
        ``cost`` (seconds per MVP) converts their products into E-MVPs.
    name : str
        Instance name (problem family and id).
    meta : dict
        Free-form metadata (step, M, p, eps_gmres, seed, ...).
    reference : mapping, optional
        A stored reference solution (``x``, ``w``, ``objective``), if known.
    symmetric_rtol : float
        Relative tolerance of the symmetry check for explicit matrices
        (default :data:`SYMMETRY_RTOL`).
    psd_check : bool
        Check positive semidefiniteness of explicit matrices up to n = 2000 (a
        Cholesky factorisation of ``A + tau I``, about ``n^3 / 3`` operations;
        ``False`` when the caller knows A is semidefinite, e.g.
        ``lcpbench.solve(..., psd=True)``). The checks of an explicit matrix are
        made once per :class:`~lcpbench.Operator`: problems built on the same
        operator (a time stepper's, a benchmark's repeated solves) are not checked
        again. Low-fidelity operators are never checked for definiteness: an
        indefinite model is a legitimate test case.

    Raises
    ------
    ValueError, TypeError
        Naming the field that is wrong and how to fix it.
    """

    A: Any
    b: Any
    x0: Any = None
    low: Mapping[str, Any] = field(default_factory=dict)
    name: str = "lcp"
    meta: dict = field(default_factory=dict)
    reference: Optional[Mapping[str, Any]] = None
    symmetric_rtol: float = SYMMETRY_RTOL
    psd_check: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.A, (list, tuple)):
            self.A = np.asarray(self.A)
        if isinstance(self.A, np.ndarray) and self.A.dtype == object:
            raise TypeError("LCP field A: object array; pass a numeric float64 matrix")
        self.A = as_operator(self.A, name="high")
        n, m = self.A.shape
        if n != m:
            raise ValueError(f"LCP field A: matrix must be square, got shape {self.A.shape}; "
                             "an LCP needs an (n, n) matrix")
        b = np.asarray(self.b)
        if b.dtype == object or not (np.issubdtype(b.dtype, np.number) or b.dtype == bool):
            raise TypeError(f"LCP field b: dtype {b.dtype} is not numeric; pass a float64 vector")
        if np.iscomplexobj(b):
            raise TypeError("LCP field b: complex values; the LCP is real")
        b = b.astype(np.float64).reshape(-1) if b.ndim <= 1 or 1 in b.shape else b
        if b.ndim != 1:
            raise ValueError(f"LCP field b: expected a vector, got shape {np.shape(self.b)}")
        if b.shape[0] != n:
            raise ValueError(f"LCP field b: length {b.shape[0]} does not match A of shape "
                             f"{self.A.shape}; b must have n = {n} entries")
        if not np.all(np.isfinite(b)):
            i = int(np.argmax(~np.isfinite(b)))
            raise ValueError(f"LCP field b: entry {i} is {b[i]}; all entries must be finite")
        self.b = b
        psd = self.psd_check and n <= PSD_CHECK_MAX_N
        if self.A.explicit and not self.A.checked(self.symmetric_rtol, psd):
            _check_explicit("A", self.A._impl, n, self.symmetric_rtol, psd=psd)
            self.A.mark_checked(self.symmetric_rtol, psd)
        if self.x0 is not None:
            if np.iscomplexobj(self.x0):
                raise TypeError("LCP field x0: complex values; the LCP is real, pass a real "
                                "warm start")
            x0 = np.asarray(self.x0, dtype=np.float64).reshape(-1)
            if x0.shape[0] != n:
                raise ValueError(f"LCP field x0: length {x0.shape[0]} does not match n = {n}")
            if not np.all(np.isfinite(x0)):
                raise ValueError("LCP field x0: non-finite entries; pass a finite warm start")
            if np.any(x0 < 0):
                raise ValueError("LCP field x0: negative entries; a warm start must satisfy "
                                 "x0 >= 0 (project it with np.maximum(x0, 0))")
            self.x0 = x0
        low = {}
        for key, op in dict(self.low or {}).items():
            op = as_operator(op if not isinstance(op, (list, tuple)) else np.asarray(op),
                             name=str(key))
            if isinstance(op, Operator) and op.name != key:
                op = Operator(op, name=str(key))
            if op.shape != (n, n):
                raise ValueError(f"LCP field low[{key!r}]: shape {op.shape} does not match "
                                 f"A of shape {(n, n)}")
            if op.explicit:
                _check_explicit(f"low[{key!r}]", op._impl, n, self.symmetric_rtol, psd=False)
            low[str(key)] = op
        self.low = low
        declared = {k: op.declared_cost is not None for k, op in self.operators().items()}
        if low and len(set(declared.values())) > 1:
            have = ", ".join(k for k, v in declared.items() if v)
            lack = ", ".join(k for k, v in declared.items() if not v)
            raise ValueError(f"LCP field low: costs are declared for {have} but not for {lack}; "
                             "E-MVPs compare costs, so declare cost= (seconds per MVP, or any "
                             "common unit) on every operator, or on none to measure them all")
        self.meta = dict(self.meta or {})

    # ------------------------------------------------------------------ helpers
    @property
    def n(self) -> int:
        """Number of contacts (unknowns)."""
        return int(self.A.shape[0])

    def fresh(self) -> LCP:
        """A copy whose operators share the matrices but have zeroed counters."""
        new = object.__new__(LCP)
        new.__dict__.update(self.__dict__)
        new.A = self.A.copy()
        new.low = {k: v.copy() for k, v in self.low.items()}
        new.meta = dict(self.meta)
        return new

    def operators(self) -> dict:
        """All operators of the instance: ``{"high": A, **low}``."""
        return {"high": self.A, **self.low}

    def emvps(self) -> float:
        """Effective MVPs so far: ``sum(count * cost) / cost_high`` over all operators.

        A low-fidelity operator with products but no known cost is an error,
        because its products cannot be converted honestly.
        """
        total = float(self.A.count)
        if not any(op.count for op in self.low.values()):
            return total
        c_high = self.high_cost()
        for name, op in self.low.items():
            if op.count:
                c = op.cost
                if c is None:
                    raise ValueError(f"low-fidelity operator {name!r} has no cost; declare "
                                     "cost= seconds per MVP")
                total += op.count * c / c_high
        return total

    def high_cost(self) -> float:
        """Seconds per high-fidelity MVP: declared, measured, or calibrated once.

        Calibration is one counted product (with the ones vector), used only
        when the solve has used low-fidelity products and no high-fidelity
        timing exists; it shows in the high-fidelity count like any other product.
        """
        c = self.A.cost
        if c is None:
            with self.A.unguarded():                        # a measurement, not a solver step
                self.A @ np.ones(self.n)
            self.A.framework_products += 1
            c = self.A.measured_cost
        return c

    def app_cost(self) -> float:
        """Application-weighted cost so far, in high products at their cold applications.

        ``sum(applications_op * application_cost_op) / cost_high`` over the operators
        (:meth:`Operator.application_cost`).  When every product takes its operator's
        cold number of applications (always so for operators without a ``work`` hook)
        this is :meth:`emvps`; with recycled Krylov directions it is smaller.  With
        only high-fidelity products it is ``applications_high / cold_applications_high``
        and needs no timing.  nan when a used operator's cold applications are unknown.
        """
        used = {k: op for k, op in self.operators().items() if op.applications}
        if not used:
            return 0.0
        if set(used) == {"high"}:
            cold = self.A.cold_applications
            return self.A.applications / cold if cold else float("nan")
        c_high = self.high_cost()
        total = 0.0
        for op in used.values():
            per = op.application_cost()
            if per is None:
                return float("nan")
            total += op.applications * per / c_high
        return total

    def work_counts(self) -> dict:
        """Inner applications per operator and kind: ``{"high": {"forward": ..}, ..}``."""
        return {k: dict(op.applications_by_kind) for k, op in self.operators().items()
                if op.applications_by_kind}

    def lofi_counts(self) -> dict:
        """Products per low-fidelity operator."""
        return {k: int(v.count) for k, v in self.low.items()}

    def residual_w(self, x: np.ndarray) -> np.ndarray:
        """``A x + b`` by one uncounted product (framework verification)."""
        if self.n == 0:
            return np.zeros(0)
        return apply_uncounted(self.A, x) + self.b

    def dense(self) -> np.ndarray:
        """The high-fidelity matrix as dense (uncounted; framework/reference use)."""
        return dense_uncounted(self.A)

    def __repr__(self) -> str:
        return f"<LCP {self.name!r} n={self.n} low={list(self.low)}>"
