"""Boundary-integral Stokes mobility of rigid spheres (``model="bim"``).

Second-kind traction formulation (Corona, Greengard, Rachh, Veerapaneni, JCP
2017): the fluid velocity is the single layer ``u = sum_j S_j sigma_j`` of one
traction density per sphere, and the densities solve

    (1/2 I + K' + L) sigma_i + sum_{j != i} T_ij sigma_j = B'(F_i, T_i),

where ``1/2 I + K'`` is the interior traction of the sphere's own single layer
(spectral, :mod:`sphere_vsh`), ``L = B' C`` restores the rigid-body modes
(``C`` = net force and torque), ``B'(F, T) = F/(4 pi a^2) + 3 T x n/(8 pi a^3)``
and ``T_ij`` is the traction on sphere i (normal n_i) of sphere j's single
layer.  Taking ``C`` of the equation gives ``C sigma_i = (F_i, T_i)``; the rest
says the flow inside every sphere is traction free, hence rigid.  Velocities
are read off as the surface mean of ``u`` and ``3/(8 pi a^4)`` times the
integral of ``(y - c) x u``.

Interactions between spheres (ordered pair (i, j), ``rho = (d_ij - a_i)/a_j``), split by
accuracy, not by a fixed distance:

* direct smooth quadrature (compiled, vectorised, parallel over targets) on a source
  grid of order q in ``ceil(p/2), ceil(3p/4)`` (density truncated to degree q),
  ``p`` (native), ``p+2, ..., 2p`` (density interpolated by spherical-harmonic
  synthesis): the coarsest grid whose *measured* quadrature error at distance
  ``rho`` is below ``quad_tol`` per unit density
  (:func:`sphere_vsh.quadrature_radius`).  ``quad_tol`` defaults to
  ``eps_gmres / 100``, also below the order-p discretisation error for gaps
  >= 0.1a (DESIGN.md);
* closer pairs: exact exterior spherical-harmonic expansions of the band-limited
  density (Corona & Veerapaneni, JCP 2018), stored as dense coefficient blocks
  (``3N x n_vsh``: traction on sphere i per VSH coefficient of sphere j) within
  ``near_block_mb``, closest first; pairs that would need a grid of order >= 1.5 p
  also get blocks while the budget lasts (a block product is cheaper than that
  sum); expansion pairs beyond the budget are evaluated on the fly (same values).
  Pairs with a gap below twice the source radius are always expansion pairs, and
  their traction is evaluated on sphere i's grid of order 2p and projected onto its
  degree-p VSH (a Galerkin treatment of the near field,
  :func:`sphere_vsh.projection_matrix`): sampling the sharply peaked near traction
  at the order-p nodes aliases it, and made the operator indefinite (GMRES stalled
  at p = 4 and 6 when a node faced a neighbour at gap 0.01a);
* optional far field ``far="fmm"``: fmm3dpy's Stokes FMM over all native grid
  points, with the self and non-native pairs removed by direct sums and replaced
  by their accurate values (:mod:`fmm`); worth it only for large M.
* the off-sphere velocity read-off uses the same expansions at the centres with
  Faxen's laws ``U = u(c) + a^2/6 lap u(c)``, ``Omega = curl u(c)/2``, which are
  the exact surface mean and rotation of a Stokes flow regular in the ball.

GMRES is relaxed (inexact Krylov): once the residual estimate has dropped to
``10^-k``, products use the split for ``quad_tol * 10^k`` (at most 1e-4),
because later Krylov directions enter the solution with weights of the size of
the residual; residuals at restarts and the reported final residual use full
accuracy.  GMRES is scipy's (``krylov="scipy"``, default: :func:`scipy_gmres_solve`
drives ``scipy.sparse.linalg.gmres`` one restart cycle at a time so that it knows the
rung of every product) or a compiled one (``krylov="compiled"``, :func:`gmres_solve`);
both take the same steps.  Dense per-sphere products run in compiled loops and scipy's
vector work with BLAS limited to one thread (threadpoolctl): threaded BLAS would compete
with the compiled parallel kernels on few cores (up to 100x slower on 2 cores).

The transpose of the discrete mobility (``rmatvec``; the discrete map is symmetric only
to about 1e-3 near contact, and the contact layer symmetrises with it) is
``M' = Bt' G^{-T} P' R'`` for ``M = R P G^{-1} Bt`` (``Bt`` = :meth:`BimMobility.rhs`, ``G``
the preconditioned traction operator, ``P`` the one-body preconditioner, ``R`` the
read-off): every piece is transposed exactly (compiled transposed kernels for the direct
sums, the stored blocks, the on-the-fly expansions and the Faxen read-off), and ``G'`` is
solved by the same GMRES at full accuracy.  With ``far="fmm"`` the FMM sum is
transposed by a stresslet FMM at the same tolerance.

The setup done once per configuration (grids, pair lists per accuracy rung,
source points, blocks) is reused by every product.  Accuracy to expect
(DESIGN.md): p = 8 gives about 1e-7 at gap 1a and 1e-5 at gap 0.5a, and
degrades near contact (O(1) squeeze errors at gap 0.01a): p = 8 is not ground
truth near contact.
"""

from __future__ import annotations

import warnings
from collections import deque

import numpy as np
from scipy.sparse.linalg import LinearOperator
from scipy.sparse.linalg import gmres as _scipy_gmres
from threadpoolctl import ThreadpoolController

from .geometry import check_configuration, check_no_overlap, check_viscosity
from .kernels import (
    apply_blocks,
    apply_blocks_adjoint,
    apply_blocks_adjoint_serial,
    apply_blocks_serial,
    center_readout,
    center_readout_adjoint,
    combine_rows,
    direct_traction_adjoint,
    direct_traction_adjoint_serial,
    direct_traction_adjoint_skip,
    direct_traction_ranges,
    direct_traction_ranges_serial,
    direct_traction_skip,
    orthogonalize,
    rows_times,
    rows_times_serial,
    synthesize_forces,
    synthesize_forces_serial,
    traction_expansion,
    traction_expansion_adjoint,
    traction_response_batch,
)
from .sphere_vsh import (
    _coefficient_matrix,
    _expansion_factors,
    default_quad_tol,
    expansion_coefficients,
    grid_levels,
    projection_matrix,
    quadrature_radius,
    sampled_basis,
    self_operators,
    sphere_grid,
    vsh_basis,
)

__all__ = ["BimMobility", "bim_mobility", "BimConvergenceWarning", "far_ratio", "gmres_solve",
           "scipy_gmres_solve", "KRYLOV_METHODS"]

_PARALLEL_WORK = 4e6
"""Products with fewer multiply-adds than this run in the serial build of a kernel."""

_NEAR_UPSAMPLE = 2.0
"""The traction of a pair in the projected zone is evaluated on the grid of order
``ceil(_NEAR_UPSAMPLE * p)`` and projected onto degree p.  Measured on a packed 27-sphere
cluster (gaps >= 0.1a): factors 1.5, 2 and 3 give the same spectra, and asymmetries
``max|A - A'|/max|A|`` of D'MD at p = 6 of 2.7e-3, 2.2e-4 and 1.3e-4; 1 is plain node
sampling."""

_PROJECT_RHO = 3.0
"""Pairs with ``rho = (d_ij - a_i)/a_j < 3`` (gap below 2 a_j) are always expansion pairs
with the projected near field, whatever the quadrature tolerance, so that the
discretisation does not change with ``eps_gmres``; beyond, values at the nodes
(quadrature, or expansions at tight tolerances).  Measured on the same cluster at
p = 6: zone radii 2, 3, 4, 6 give asymmetries 6.7e-4, 2.2e-4, 1.9e-4, 1.9e-4."""

_RELAX_STEP = 10.0
"""Ratio of successive quadrature tolerances on the ladder of relaxed GMRES."""


class BimConvergenceWarning(RuntimeWarning):
    """GMRES stopped before reaching the requested tolerance."""


def far_ratio(p: int, tol: float = 1e-10) -> float:
    """Scaled distance ``r = (d - a_i)/a_j`` beyond which direct quadrature on the native
    order-p grid is accurate to ``tol`` per unit density (measured, see
    :func:`sphere_vsh.quadrature_radius`)."""
    return quadrature_radius(_check_p(p), int(p), float(tol))


def _check_p(p) -> int:
    if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 1:
        raise ValueError(f"p = {p!r} must be an integer >= 1 (the spherical-harmonic order; "
                         "8 is high fidelity away from contact, 3-6 are typical low fidelities)")
    return int(p)


def _check_eps(eps) -> float:
    try:
        e = float(eps)
    except (TypeError, ValueError):
        raise ValueError(f"eps_gmres = {eps!r} must be a number in (0, 1)") from None
    if not (np.isfinite(e) and 0 < e < 1):
        raise ValueError(f"eps_gmres = {eps!r} must be a finite number in (0, 1), "
                         "e.g. 1e-8 (relative GMRES residual)")
    return e


def _csr(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    ptr = np.zeros(len(lists) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(x) for x in lists])
    idx = np.array([j for x in lists for j in x], dtype=np.int64)
    return ptr, idx


def _group_ranges(ptr: np.ndarray, start: np.ndarray, stop: np.ndarray, n_per: int) -> dict:
    """Regroup per-target source ranges (``ptr, start, stop`` as in ``_dir_ranges``: target
    sphere i sums ``start[k]:stop[k]`` for k in ``ptr[i]:ptr[i+1]``) by source range, for
    the transposed sums (:func:`kernels.direct_traction_adjoint`)."""
    triples = sorted((int(start[k]), int(stop[k]), i)
                     for i in range(ptr.size - 1) for k in range(ptr[i], ptr[i + 1]))
    starts = np.array([t[0] for t in triples], dtype=np.int64)
    first = (np.nonzero(np.r_[True, starts[1:] != starts[:-1]])[0] if triples
             else np.zeros(0, dtype=np.int64))
    return {"start": starts[first],
            "stop": np.array([triples[k][1] for k in first], dtype=np.int64),
            "ptr": np.r_[first, len(triples)].astype(np.int64),
            "tgt": np.array([t[2] for t in triples], dtype=np.int64),
            "work": n_per * sum(b - a for a, b, _ in triples)}


def gmres_solve(matvec, b: np.ndarray, x0: np.ndarray, rtol: float, restart: int,
                maxiter: int, rungs: int = 1, step: float = 100.0,
                relax: float = 1.0) -> tuple[np.ndarray, int, float]:
    """Restarted, optionally relaxed GMRES (Givens rotations, CGS2 Arnoldi) for ``A x = b``.

    ``matvec(x, k)`` applies A with accuracy rung ``k`` (0 = full accuracy, rung k
    ``step**k`` times less accurate).  Relaxation (inexact Krylov; Bouras & Fraysse 2005,
    Simoncini & Szyld 2003): once the relative residual estimate has dropped to
    ``relax / step**k``, the product error can grow by ``step**k`` without spoiling the
    final residual, because later Krylov directions enter the solution with weights of
    the size of the residual.  Residuals at restarts and at the end are always measured
    with rung 0, so a relaxation that went too far only costs iterations.

    Stops when the relative residual ``||b - A x|| / ||b||`` (the recurrence estimate,
    re-measured with full accuracy) is at most ``rtol`` or after ``maxiter`` inner
    iterations.  Vector work runs in serial compiled loops: on few cores, BLAS
    threads would compete with the parallel compiled kernels of the product.

    Returns
    -------
    x, iterations, relative residual ``||b - A x|| / ||b||`` of the returned x, measured
    with a full-accuracy (rung 0) product
    """
    nb = float(np.linalg.norm(b))
    x = np.array(x0, dtype=float)
    n = b.size
    m = max(1, min(restart, n))
    V = np.empty((m + 1, n))
    H = np.zeros((m + 1, m))
    cs, sn = np.zeros(m), np.zeros(m)
    its = 0
    res = np.inf
    while True:
        r = b - matvec(x, 0)
        beta = float(np.sqrt(np.dot(r, r)))
        res = beta / nb
        if res <= rtol or its >= maxiter:
            return x, its, res
        V[0] = r / beta
        g = np.zeros(m + 1)
        g[0] = beta
        k = 0
        while k < m and its < maxiter:
            est = abs(g[k]) / nb
            rung = 0
            while rung + 1 < rungs and est * step ** (rung + 1) <= relax:
                rung += 1
            w = matvec(V[k], rung)
            hn = orthogonalize(V, k + 1, w, H[:, k])
            H[k + 1, k] = hn
            for j in range(k):                       # apply previous rotations
                t = cs[j] * H[j, k] + sn[j] * H[j + 1, k]
                H[j + 1, k] = -sn[j] * H[j, k] + cs[j] * H[j + 1, k]
                H[j, k] = t
            den = np.hypot(H[k, k], hn)
            cs[k], sn[k] = (1.0, 0.0) if den == 0.0 else (H[k, k] / den, hn / den)
            H[k, k] = den
            H[k + 1, k] = 0.0
            g[k + 1] = -sn[k] * g[k]
            g[k] = cs[k] * g[k]
            its += 1
            k += 1
            if hn > 0.0:
                V[k] = w / hn
            if abs(g[k]) / nb <= rtol or hn == 0.0:
                break
        y = np.zeros(k)
        for i in range(k - 1, -1, -1):               # back substitution
            y[i] = (g[i] - H[i, i + 1:k] @ y[i + 1:]) / H[i, i]
        combine_rows(V, y, x)
        if abs(g[k]) / nb <= rtol:
            r = b - matvec(x, 0)
            res = float(np.sqrt(np.dot(r, r))) / nb
            if res <= rtol or its >= maxiter:
                return x, its, res


KRYLOV_METHODS = ("scipy", "compiled")
"""Allowed values of ``BimMobility(krylov=...)``."""

_BLAS_LIMITER: list = []
"""Lazily built ``threadpoolctl.ThreadpoolController`` (scanning the loaded libraries
once instead of at every solve)."""


def _single_thread_blas():
    """Context manager limiting BLAS to one thread (threadpoolctl), so that numpy's vector
    work inside scipy's GMRES does not compete with the parallel compiled kernels."""
    if not _BLAS_LIMITER:
        _BLAS_LIMITER.append(ThreadpoolController())
    return _BLAS_LIMITER[0].limit(limits=1, user_api="blas")


def scipy_gmres_solve(matvec, b: np.ndarray, x0: np.ndarray, rtol: float, restart: int,
                      maxiter: int, rungs: int = 1, step: float = 100.0,
                      relax: float = 1.0) -> tuple[np.ndarray, int, float]:
    """Restarted, optionally relaxed GMRES for ``A x = b`` by ``scipy.sparse.linalg.gmres``.

    Same contract as :func:`gmres_solve` (``matvec(x, k)`` applies A at accuracy rung k,
    same relaxation rule, same stopping test and return values), with scipy doing the
    Arnoldi process and the least-squares updates.  scipy is called once per restart
    cycle (``maxiter=1``, ``restart`` capped by the iterations left, ``rtol``, ``atol=0``,
    ``x0`` = the current iterate, first the warm start), so that:

    * the rung of every product is known before it is made: a ``callback_type="pr_norm"``
      callback records the residual estimate after each inner iteration and the next
      product uses the rung that estimate allows; when the callback shows that the cycle
      ends (estimate at most ``rtol`` or ``restart`` inner iterations) the next product,
      scipy's residual ``b - A x`` at the end of the cycle, is made at rung 0;
    * every convergence decision here uses a full-accuracy residual: the last product of
      the cycle is reused when it was a rung-0 product of the returned iterate (the
      usual case), otherwise (e.g. an unforeseen Arnoldi breakdown) ``b - A x`` is
      recomputed at rung 0.  The rung-0 product at the start of the next scipy call is
      served from the same cache, so a restart costs no extra product.

    The total number of inner iterations never exceeds ``maxiter``.  Vector work runs in
    numpy with BLAS limited to one thread (threadpoolctl).

    Returns
    -------
    x, iterations, relative residual (full accuracy)
    """
    b = np.asarray(b, dtype=float)
    n = b.size
    nb = float(np.linalg.norm(b))
    x = np.array(x0, dtype=float)
    if nb == 0.0:
        return np.zeros(n), 0, 0.0
    m = max(1, min(int(restart), n))
    # rung: accuracy of the next product; then: rung after it (set when that product is
    # scipy's initial residual b - A x0); its / cycle: inner iterations, total and in cycle
    state = {"rung": 0, "then": None, "its": 0, "cycle": 0, "restart": m}
    cache: dict = {}                        # last product: input copy, rung, output

    def product(v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=float).reshape(-1)
        rung = state["rung"]
        if state["then"] is not None:
            state["rung"], state["then"] = state["then"], None
        if rung == 0 and cache.get("rung") == 0 and np.array_equal(cache["x"], v):
            return cache["y"].copy()
        y = np.asarray(matvec(v, rung), dtype=float).reshape(-1)
        cache.update(x=v.copy(), rung=rung, y=y)
        return y.copy()

    def rung_for(est: float) -> int:
        k = 0
        while k + 1 < rungs and est * step ** (k + 1) <= relax:
            k += 1
        return k

    def callback(pr_norm: float) -> None:
        state["its"] += 1
        state["cycle"] += 1
        ends = pr_norm <= rtol * (1 + 1e-8) or state["cycle"] >= state["restart"]
        state["rung"] = 0 if ends else rung_for(float(pr_norm))

    def residual(z: np.ndarray) -> float:
        state["rung"], state["then"] = 0, None
        return float(np.linalg.norm(b - product(z))) / nb

    op = LinearOperator((n, n), matvec=product, dtype=np.float64)
    with _single_thread_blas():
        res = residual(x)
        while res > rtol and state["its"] < maxiter:
            state["cycle"] = 0
            state["restart"] = min(m, maxiter - state["its"])
            if x.any():                     # scipy first forms b - A x0: rung 0 (cached)
                state["rung"], state["then"] = 0, rung_for(res)
            else:                           # scipy starts from r = b, no product
                state["rung"], state["then"] = rung_for(res), None
            its_before = state["its"]
            x, _ = _scipy_gmres(op, b, x0=x.copy(), rtol=rtol, atol=0.0,
                                restart=state["restart"], maxiter=1, callback=callback,
                                callback_type="pr_norm")
            x = np.asarray(x, dtype=float).reshape(-1)
            res = residual(x)
            if state["its"] == its_before:  # scipy took no step: stop rather than loop
                break
    return x, state["its"], res


def _fmm_traction_adjoint(points: np.ndarray, normals: np.ndarray, trac_bar: np.ndarray,
                          eps: float) -> np.ndarray:
    """Transpose of :func:`fmm.fmm_traction` (points are sources and targets alike).

    The traction at ``x_k`` (normal ``n_k``) of a point force ``f`` at ``y`` is
    ``-(3/4 pi) (r.n_k) r (r.f) / |r|^5`` with ``r = x_k - y``; its transpose, the adjoint
    force at ``y`` of adjoint tractions ``b_k``, is ``(3/4 pi) sum_k r' (r'.b_k)(r'.n_k) /
    |r'|^5`` with ``r' = y - x_k``: the velocity of stresslets of strength ``b_k`` and
    orientation ``n_k``, which is fmm3dpy's stresslet normalisation (checked against the
    direct sum to 1e-15).  Self points are excluded, as in the forward FMM.

    Returns
    -------
    ndarray, shape (n, 3)
        Adjoint point forces at every point.
    """
    import fmm3dpy

    out = fmm3dpy.stfmm3d(eps=float(max(eps, 1e-15)), sources=np.ascontiguousarray(points.T),
                          strslet=np.ascontiguousarray(trac_bar.T),
                          strsvec=np.ascontiguousarray(normals.T), ifppreg=1)
    return np.ascontiguousarray(np.asarray(out.pot).reshape(3, -1).T)


class BimMobility(LinearOperator):
    """Mobility of M rigid spheres by the traction boundary integral equation.

    Input per sphere ``(Fx, Fy, Fz, Tx, Ty, Tz)``, output
    ``(Ux, Uy, Uz, Wx, Wy, Wz)``; shape ``(6M, 6M)``.

    Parameters
    ----------
    centers : array_like, shape (M, 3)
    radii : float or array_like, shape (M,)
    p : int
        Spherical-harmonic order; ``6 p (p+1)`` unknowns per sphere.
    eps_gmres : float
        Relative residual tolerance of GMRES.
    mu : float
        Viscosity.
    on_failure : {"warn", "raise"}
        What to do when GMRES does not reach ``eps_gmres``: warn with
        :class:`BimConvergenceWarning` (the result is still returned) or raise
        ``RuntimeError``.  Both report the reached residual.
    recycle : int
        Number of previous solutions kept for the warm start.
    maxiter : int
        Maximum total number of GMRES iterations per product.
    near_block_mb : float
        Memory budget (MB) for the dense near-field blocks built once per
        configuration (``3N x n_vsh`` doubles per pair, 0.8 MB at p = 8); the
        closest pairs get blocks first, the remaining expansion pairs are
        evaluated on the fly (same values, slower).
    quad_tol : float, optional
        Accuracy (per unit density) of the quadrature between spheres; default
        ``eps_gmres / 100`` (clamped to [1e-15, 1e-4]).
    far : {"direct", "fmm"}
        Far-field engine: compiled direct sums, or fmm3dpy's ``stfmm3d`` (extra
        ``fmm``; pays off only beyond roughly 50-100k grid points).
    near_upsample : float
        The traction of a close (expansion) pair is evaluated on the grid of order
        ``ceil(near_upsample * p)`` and projected onto degree p; 1 samples it at the
        nodes (Nystrom), which aliases the peaked near traction and can make the
        operator indefinite near contact (default 2).  Every pair with a gap below
        twice the source radius is an expansion pair (projected) at any ``eps_gmres``,
        so the discretisation does not depend on the tolerance; pairs farther apart
        are sampled at the nodes.
    krylov : {"scipy", "compiled"}
        GMRES implementation of the forward and adjoint solves: ``scipy.sparse.linalg.gmres``
        driven one restart cycle at a time with BLAS limited to one thread
        (:func:`scipy_gmres_solve`), or the compiled :func:`gmres_solve`.  Both use the
        one-body right preconditioner, the warm start, ``eps_gmres``, restart 60,
        ``maxiter`` inner iterations in total and the same relaxed accuracy (full-accuracy
        residuals at restarts and at the end), and report non-convergence the same way.

    Attributes
    ----------
    gmres_iterations : list of int
        Iterations of every product, in order.
    residuals : list of float
        Final relative residual ``||b - A sigma|| / ||b||`` of every product.
    adjoint_iterations, adjoint_residuals : list
        The same for every transposed product (:meth:`rmatvec`, see :meth:`_rmatvec`).
    n_far_pairs, n_near_pairs : int
        Ordered pairs handled by direct quadrature (not blocked) and pairs too
        close for any source grid (expansions).
    n_block_pairs : int
        Pairs whose dense block is stored.
    pairs_per_level : dict
        Source-grid order -> ordered pairs summed directly on it at full accuracy
        (pairs with a stored block not counted).
    level_radii : dict
        Source-grid order -> scaled distance beyond which it is accurate to ``quad_tol``.
    tolerance_ladder : tuple of float
        Quadrature accuracies used by relaxed GMRES (first = ``quad_tol``).
    """

    def __init__(self, centers, radii, *, p: int = 8, eps_gmres: float = 1e-8,
                 mu: float = 1.0, on_failure: str = "warn", recycle: int = 8,
                 maxiter: int = 500, near_block_mb: float = 2048.0,
                 quad_tol: float | None = None, far: str = "direct",
                 fmm_min_points: int = 0, near_upsample: float = _NEAR_UPSAMPLE,
                 krylov: str = "scipy") -> None:
        c, r = check_configuration(centers, radii)
        self.p = _check_p(p)
        self.eps_gmres = _check_eps(eps_gmres)
        self.mu = check_viscosity(mu)
        check_no_overlap(c, r, "bim")
        if on_failure not in ("warn", "raise"):
            raise ValueError(f"on_failure = {on_failure!r}; use 'warn' or 'raise'")
        if far not in ("direct", "fmm"):
            raise ValueError(f"far = {far!r}; use 'direct' (compiled direct sums) or 'fmm' "
                             "(fmm3dpy.stfmm3d, install the extra 'fmm')")
        if not isinstance(krylov, str) or krylov not in KRYLOV_METHODS:
            raise ValueError(f"krylov = {krylov!r}; use 'scipy' (scipy.sparse.linalg.gmres) or "
                             "'compiled' (the compiled restarted GMRES of this module)")
        self.krylov = krylov
        self.quad_tol = default_quad_tol(self.eps_gmres) if quad_tol is None else float(quad_tol)
        if not (np.isfinite(self.quad_tol) and 0 < self.quad_tol < 1):
            raise ValueError(f"quad_tol = {quad_tol!r} must be a number in (0, 1), e.g. 1e-10 "
                             "(accuracy of the quadrature between spheres)")
        if far == "fmm":
            from .fmm import check_fmm
            check_fmm()
        self.far = far
        self.on_failure = on_failure
        self.maxiter = int(maxiter)
        M = c.shape[0]
        super().__init__(dtype=np.float64, shape=(6 * M, 6 * M))
        self.centers, self.radii, self.M = c, r, M
        self._so = self_operators(self.p)
        self._grid = sphere_grid(self.p)
        N = self._grid.size
        self._N = N
        nodes = self._grid.nodes
        self._tgt_pts = np.ascontiguousarray((c[:, None, :] + r[:, None, None] * nodes[None]).reshape(-1, 3))
        self._tgt_nrm = np.ascontiguousarray(np.tile(nodes, (M, 1)))
        self._tgt_sphere = np.repeat(np.arange(M, dtype=np.int64), N)
        self.near_block_mb = float(near_block_mb)
        self._self_block = np.ascontiguousarray((self._so.Kp + self._so.L).T)
        self._precond_T = np.ascontiguousarray(self._so.precond.T)
        self._read_S = self._so.readout @ self._so.S          # (6, 3N) unit sphere
        self._basis = vsh_basis(self.p)
        self._analysis_T = np.ascontiguousarray(self._basis.A.T)
        try:
            up = float(near_upsample)
        except (TypeError, ValueError):
            up = float("nan")
        if isinstance(near_upsample, bool) or not (np.isfinite(up) and up >= 1):
            raise ValueError(f"near_upsample = {near_upsample!r} must be a number >= 1 (order of "
                             "the near-field target grid in units of p; 1 = sample at the nodes)")
        self.near_upsample = up
        q_near = max(self.p, int(np.ceil(up * self.p - 1e-9)))
        self._near_grid = sphere_grid(q_near)
        self._near_proj = (None if q_near == self.p           # plain node sampling
                           else projection_matrix(self.p, q_near))
        self._setup_interactions()
        self._history: deque = deque(maxlen=max(int(recycle), 0))
        self.gmres_iterations: list[int] = []
        self.residuals: list[float] = []
        self._adj_history: deque = deque(maxlen=max(int(recycle), 0))
        self._adj: dict | None = None             # transposed structures, built on first use
        self.adjoint_iterations: list[int] = []
        self.adjoint_residuals: list[float] = []

    # ---- pair classification ----------------------------------------------------------------
    def _setup_interactions(self, all_expansion: bool = False) -> None:
        """Split the ordered pairs (i, j) by ``rho = (d_ij - a_i)/a_j``: direct quadrature on
        the coarsest source grid (:func:`sphere_vsh.grid_levels`) accurate to the
        tolerance there (:func:`sphere_vsh.quadrature_radius`), once per rung of the
        tolerance ladder, else exact expansions (dense blocks within ``near_block_mb``,
        the rest on the fly).  ``all_expansion`` puts every pair in the last group
        (for testing)."""
        M, p = self.M, self.p
        c, r = self.centers, self.radii
        levels = grid_levels(p)
        # accuracy ladder for relaxed (inexact) GMRES: quad_tol * RELAX_STEP^k <= 1e-4
        tols = [self.quad_tol]
        if self.far == "direct":
            while tols[-1] * _RELAX_STEP <= 1e-4 * (1 + 1e-9) and len(tols) < 12:
                tols.append(tols[-1] * _RELAX_STEP)
        self.tolerance_ladder = tuple(tols)
        rho = np.full((M, M), np.inf)
        if M > 1:
            d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
            rho = (d - r[:, None]) / r[None, :]
            np.fill_diagonal(rho, np.inf)

        def classify(tol: float) -> tuple[np.ndarray, np.ndarray]:
            if M == 1:                                     # no pairs: nothing to measure
                radius = np.full(len(levels), np.inf)
            else:
                radius = np.minimum.accumulate([quadrature_radius(p, q, tol) for q in levels])
            lv = np.full((M, M), -2, dtype=np.int64)       # -1: self, -2: expansion
            for L in range(len(levels) - 1, -1, -1):
                lv[rho >= radius[L]] = L
            np.fill_diagonal(lv, -1)
            return lv, radius

        level_of, radius = classify(self.quad_tol)
        native = levels.index(p)
        self._native = native
        if self.far == "fmm":       # the FMM works on the native grid: no coarser levels
            level_of[(level_of >= 0) & (level_of < native)] = native
        if self._near_proj is not None:     # the projected zone: expansions at any tolerance
            level_of[(rho < _PROJECT_RHO) & (level_of >= 0)] = -2
        if all_expansion:
            level_of[:] = -2
            np.fill_diagonal(level_of, -1)
        self.level_radii = dict(zip(levels, radius.tolist()))
        ladder_levels = [level_of]
        for tol in tols[1:]:
            lv, _ = classify(tol)
            ladder_levels.append(np.where(level_of == -2, -2, lv))   # expansion pairs stay
        self._levels = levels
        self._level_of = level_of
        self._build_blocks()
        level_of = np.where(self._blocked, -2, level_of)
        ladder_levels = [np.where(self._blocked, -2, lv) for lv in ladder_levels]
        # sources per level: the spheres any rung of the ladder uses at that level
        self._lvl_spheres, self._lvl_base = [], []
        base = 0
        for L, q in enumerate(levels):
            used = np.nonzero(np.any([(lv == L).any(axis=0) for lv in ladder_levels], axis=0))[0]
            if L == native and self.far == "fmm":
                used = np.arange(M)
            self._lvl_spheres.append(used)
            self._lvl_base.append(base)
            base += used.size * sphere_grid(q).size
        self._n_src = base
        xyz = np.empty((3, base))
        self._src_scale = []
        slot = np.full((len(levels), M), -1, dtype=np.int64)
        for L, q in enumerate(levels):
            g = sphere_grid(q)
            J = self._lvl_spheres[L]
            b0 = self._lvl_base[L]
            pts = c[J, None, :] + r[J, None, None] * g.nodes[None]
            xyz[:, b0:b0 + J.size * g.size] = pts.reshape(-1, 3).T
            self._src_scale.append(np.ascontiguousarray((r[J] ** 2)[:, None] * g.weights[None, :]))
            slot[L, J] = b0 + np.arange(J.size) * g.size
        self._src_xyz = [np.ascontiguousarray(xyz[k]) for k in range(3)]
        self._synth = [None if q == p or self._lvl_spheres[L].size == 0
                       else np.ascontiguousarray(sampled_basis(p, q).T)
                       for L, q in enumerate(levels)]
        nq = np.array([sphere_grid(q).size for q in levels], dtype=np.int64)

        def ranges(lv: np.ndarray, keep) -> tuple[np.ndarray, ...]:
            ii, jj = np.nonzero(keep(lv))                   # row-major: grouped by target i
            L = lv[ii, jj]
            start = slot[L, jj]
            ptr = np.searchsorted(ii, np.arange(M + 1)).astype(np.int64)
            return ptr, start.astype(np.int64), (start + nq[L]).astype(np.int64)

        if self.far == "fmm":
            # FMM sums all native points; remove its native self and non-native pairs
            self._dir_ranges = [ranges(level_of, lambda lv: lv > native)]
            self._fmm_sub = ranges(np.where(level_of == native, -2, native),
                                   lambda lv: lv == native)
        else:
            self._dir_ranges = [ranges(lv, lambda x: x >= 0) for lv in ladder_levels]
        self.pairs_per_level = {q: int((level_of == L).sum()) for L, q in enumerate(levels)}
        self.n_far_pairs = int((level_of >= 0).sum())
        self.n_near_pairs = int((self._level_of == -2).sum())

    # ---- near-field blocks ----------------------------------------------------------------
    def _build_blocks(self) -> None:
        """Dense near-field blocks (traction on sphere i per VSH coefficient of sphere j),
        closest pairs first, within the memory budget; the other expansion pairs
        are kept for on-the-fly evaluation."""
        M, N, p = self.M, self._N, self.p
        b = self._basis
        nv = b.B.shape[1]
        flat = np.argmax(np.abs(b.to_complex), axis=0)
        cfac = b.to_complex[flat, np.arange(nv)]
        # candidates: expansion pairs, then pairs whose quadrature needs a source grid of
        # order >= 1.5 p (a stored block is then cheaper per product than the sum)
        lv = self._level_of
        fine = [L for L, q in enumerate(self._levels) if 2 * q >= 3 * p]
        ii, jj = np.nonzero((lv == -2) | np.isin(lv, fine))
        pairs = list(zip(ii.tolist(), jj.tolist()))
        if pairs:
            d = np.array([np.linalg.norm(self.centers[i] - self.centers[j]) - self.radii[i]
                          for i, j in pairs]) / np.array([self.radii[j] for _, j in pairs])
            pairs = [pairs[k] for k in np.argsort(d, kind="stable")]
        per_block = 3 * N * nv * 8 / 2 ** 20
        nb = min(len(pairs), int(self.near_block_mb // per_block)) if per_block > 0 else 0
        blocked, rest = pairs[:nb], pairs[nb:]
        blocked.sort()                                     # grouped by target sphere
        fac = np.ascontiguousarray(_expansion_factors(p))
        E = np.empty((len(blocked), 3 * N, nv))
        # expansion pairs: responses on the finer grid, projected onto degree p;
        # quadrature pairs (smooth traction) and node sampling: at the native nodes
        projected = np.array([self._projected(i, j) for i, j in blocked], dtype=bool)
        for proj in (True, False):
            idx = np.nonzero(projected == proj)[0]
            nodes = self._near_grid.nodes if proj else self._grid.nodes
            Nq = nodes.shape[0]
            chunk = max(1, int(64e6 // (Nq * 9 * (p + 1) ** 2 * 16)))     # ~64 MB of responses
            for k0 in range(0, idx.size, chunk):
                part = idx[k0:k0 + chunk]
                ii = np.array([blocked[k][0] for k in part])
                jj = np.array([blocked[k][1] for k in part])
                tgt = (self.centers[ii, None, :] + self.radii[ii, None, None] * nodes[None]).reshape(-1, 3)
                resp = np.empty((tgt.shape[0], 3, p + 1, p + 1, 3), dtype=np.complex128)
                traction_response_batch(np.ascontiguousarray(tgt),
                                        np.ascontiguousarray(np.tile(nodes, (len(part), 1))),
                                        np.ascontiguousarray(np.repeat(self.centers[jj], Nq, axis=0)),
                                        np.repeat(self.radii[jj], Nq), p, fac, resp)
                R = resp.reshape(len(part), Nq, -1, 3).transpose(0, 1, 3, 2).reshape(len(part), 3 * Nq, -1)
                Ep = (R[:, :, flat] * cfac[None, None, :]).real
                E[part] = np.matmul(self._near_proj, Ep) if proj else Ep
        self._blocks = E
        self._block_tgt = np.array([i for i, _ in blocked], dtype=np.int64)
        self._block_src = np.array([j for _, j in blocked], dtype=np.int64)
        self._block_ptr = np.searchsorted(self._block_tgt, np.arange(M + 1)).astype(np.int64)
        lists: list[list[int]] = [[] for _ in range(M)]          # projected (zone)
        node_lists: list[list[int]] = [[] for _ in range(M)]     # sampled at the nodes
        for i, j in rest:
            if self._level_of[i, j] == -2:
                (lists if self._near_proj is None or self._projected(i, j) else node_lists)[i].append(j)
        self._blocked = np.zeros((M, M), dtype=bool)
        for i, j in blocked:
            self._blocked[i, j] = True
        self._fly_ptr, self._fly_idx = _csr(lists)
        self._flyn_ptr, self._flyn_idx = _csr(node_lists)
        self.n_block_pairs = len(blocked)

    def _projected(self, i: int, j: int) -> bool:
        """Whether pair (i, j) gets the projected near field (the zone ``rho < 2``)."""
        if self._near_proj is None or self._level_of[i, j] != -2:
            return False
        d = float(np.linalg.norm(self.centers[i] - self.centers[j]))
        return (d - self.radii[i]) / self.radii[j] < _PROJECT_RHO

    # ---- the boundary integral operator -------------------------------------------------
    def _rows(self, X: np.ndarray, W: np.ndarray) -> np.ndarray:
        """``X @ W`` for the small dense products of every product (no BLAS threads)."""
        out = np.zeros((X.shape[0], W.shape[1]))
        fn = rows_times if X.size * W.shape[1] > _PARALLEL_WORK else rows_times_serial
        fn(np.ascontiguousarray(X), W, out)
        return out

    def _source_forces(self, s: np.ndarray, coef: np.ndarray) -> list[np.ndarray]:
        """Point forces (density times weight) at every source level, as three arrays;
        upsampled levels are synthesised from the VSH coefficients ``coef``."""
        f = [np.empty(self._n_src) for _ in range(3)]
        for L, q in enumerate(self._levels):
            J = self._lvl_spheres[L]
            if J.size == 0:
                continue
            b0 = self._lvl_base[L]
            if self._synth[L] is None:
                nq = self._N
                F = s[J].reshape(J.size, nq, 3) * self._src_scale[L][:, :, None]
                for k in range(3):
                    f[k][b0:b0 + J.size * nq] = F[:, :, k].reshape(-1)
            else:
                fn = (synthesize_forces if J.size * self._synth[L].size > _PARALLEL_WORK
                      else synthesize_forces_serial)
                fn(coef, J, self._synth[L], self._src_scale[L], b0, *f)
        return f

    def _apply_bie(self, sigma: np.ndarray, rung: int = 0) -> np.ndarray:
        """``(1/2 I + K' + L) sigma + sum_j T_ij sigma_j`` for stacked densities, with the
        quadrature between spheres accurate to ``tolerance_ladder[rung]``."""
        M, N, p = self.M, self._N, self.p
        s = np.ascontiguousarray(sigma.reshape(M, 3 * N))
        out = self._rows(s, self._self_block)
        if M > 1:
            coef = self._rows(s, self._analysis_T)
            trac = np.zeros((M * N, 3))
            if self._fly_idx.size:
                out += self._near_on_the_fly(s)
            if self._flyn_idx.size:                 # expansion pairs beyond the zone
                traction_expansion(self._tgt_pts, self._tgt_nrm, self._tgt_sphere,
                                   self._flyn_ptr, self._flyn_idx, self.centers, self.radii,
                                   expansion_coefficients(p, s), p, trac)
            if self._n_src:
                f = self._source_forces(s, coef)
                ptr, start, stop = self._dir_ranges[min(rung, len(self._dir_ranges) - 1)]
                if stop.size:
                    work = N * int((stop - start).sum())
                    fn = (direct_traction_ranges if work > _PARALLEL_WORK
                          else direct_traction_ranges_serial)
                    fn(self._tgt_pts, self._tgt_nrm, self._tgt_sphere,
                       ptr, start, stop, *self._src_xyz, *f, trac, False)
                if self.far == "fmm":
                    from .fmm import fmm_traction
                    b0 = self._lvl_base[self._native]
                    trac += fmm_traction(self._tgt_pts, self._tgt_nrm,
                                         np.stack([x[b0:b0 + M * N] for x in f], axis=1),
                                         self.quad_tol)
                    ptr, start, stop = self._fmm_sub
                    sub = np.zeros((M * N, 3))
                    direct_traction_skip(self._tgt_pts, self._tgt_nrm, self._tgt_sphere,
                                         ptr, start, stop, *self._src_xyz, *f, sub, True)
                    trac -= sub
            out += trac.reshape(M, 3 * N)
            if self.n_block_pairs:
                fn = apply_blocks if self._blocks.size > _PARALLEL_WORK else apply_blocks_serial
                fn(self._blocks, self._block_ptr, self._block_src, coef, out)
        return out.reshape(-1)

    def _near_on_the_fly(self, s: np.ndarray) -> np.ndarray:
        """Near-field traction of the projected-zone expansion pairs without a stored
        block: evaluated on the finer grid of every sphere that has such pairs and
        projected onto degree p (the same values a stored block gives)."""
        M, N, p = self.M, self._N, self.p
        nodes = self._near_grid.nodes
        Nq = nodes.shape[0]
        tgt_i = np.nonzero(np.diff(self._fly_ptr))[0]
        pts = (self.centers[tgt_i, None, :] + self.radii[tgt_i, None, None] * nodes[None]).reshape(-1, 3)
        trac = np.zeros((pts.shape[0], 3))
        traction_expansion(np.ascontiguousarray(pts), np.ascontiguousarray(np.tile(nodes, (tgt_i.size, 1))),
                           np.repeat(tgt_i, Nq).astype(np.int64), self._fly_ptr, self._fly_idx,
                           self.centers, self.radii, expansion_coefficients(p, s), p, trac)
        out = np.zeros((M, 3 * N))
        trac = trac.reshape(tgt_i.size, 3 * Nq)
        out[tgt_i] = trac if self._near_proj is None else self._rows(trac, np.ascontiguousarray(self._near_proj.T))
        return out

    def _precondition(self, y: np.ndarray) -> np.ndarray:
        return self._rows(y.reshape(self.M, -1), self._precond_T).reshape(-1)

    def _unprecondition(self, sigma: np.ndarray) -> np.ndarray:
        return self._rows(sigma.reshape(self.M, -1), self._self_block).reshape(-1)

    def rhs(self, ft: np.ndarray) -> np.ndarray:
        """``B'(F, T)`` on every grid: stacked densities of length ``6 M p (p+1)``."""
        ft = np.asarray(ft, dtype=float).reshape(self.M, 6)
        nodes = self._grid.nodes
        a = self.radii[:, None, None]
        b = (ft[:, None, :3] / (4 * np.pi * a ** 2)
             + 3.0 * np.cross(ft[:, None, 3:], nodes[None]) / (8 * np.pi * a ** 3))
        return b.reshape(-1)

    def _warm_start(self, b: np.ndarray) -> np.ndarray:
        """Best combination of the stored solutions plus one-body correction."""
        if not self._history:
            return self._precondition(b)
        Bk = np.stack([h[1] for h in self._history], axis=1)
        Sk = np.stack([h[0] for h in self._history], axis=1)
        alpha = np.linalg.lstsq(Bk, b, rcond=None)[0]
        return Sk @ alpha + self._precondition(b - Bk @ alpha)

    def solve_density(self, ft: np.ndarray) -> np.ndarray:
        """Solve the traction equation for forces and torques ``ft`` (length 6M)."""
        b = self.rhs(ft)
        nb = float(np.linalg.norm(b))
        if nb == 0.0:
            self.gmres_iterations.append(0)
            self.residuals.append(0.0)
            return np.zeros_like(b)
        n = b.size
        sigma0 = self._warm_start(b)
        y0 = self._unprecondition(sigma0)
        restart = max(1, min(n, 60, self.maxiter))
        solver = scipy_gmres_solve if self.krylov == "scipy" else gmres_solve
        y, its, res_g = solver(lambda v, k: self._apply_bie(self._precondition(v), k), b, y0,
                               self.eps_gmres, restart, self.maxiter,
                               rungs=len(self._dir_ranges), step=_RELAX_STEP)
        sigma = self._precondition(y)
        # both GMRES drivers return the full-accuracy residual of y: ||b - A_bie(P y)|| / ||b||
        self.gmres_iterations.append(its)
        self.residuals.append(res_g)
        self._report("BIM GMRES", res_g, its)
        if self._history.maxlen:
            self._history.append((sigma, b))
        return sigma

    def _report(self, what: str, res: float, its: int) -> None:
        """Warn (or raise, ``on_failure="raise"``) when a solve's full-accuracy relative
        residual ``res`` missed ``eps_gmres``."""
        if res <= self.eps_gmres:
            return
        msg = (f"{what} did not converge: relative residual {res:.3g} after {its} "
               f"iterations (eps_gmres = {self.eps_gmres:g}, M = {self.M}, p = {self.p}); "
               "raise maxiter or eps_gmres, or check for near-contact spheres")
        if self.on_failure == "raise":
            raise RuntimeError(msg)
        warnings.warn(msg, BimConvergenceWarning, stacklevel=4)

    def velocities(self, sigma: np.ndarray) -> np.ndarray:
        """Rigid velocities (M, 6) read off from stacked densities."""
        M, N = self.M, self._N
        s = sigma.reshape(M, 3 * N)
        ro = s @ self._read_S.T                       # unit sphere, mu = 1
        out = np.empty((M, 6))
        out[:, :3] = ro[:, :3] * (self.radii / self.mu)[:, None]
        out[:, 3:] = ro[:, 3:] / self.mu
        if M > 1:
            D = expansion_coefficients(self.p, s)
            center_readout(self.centers, self.radii, D, self.p, self.mu, out)
        return out

    def _matvec(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float).reshape(-1)
        if not np.isfinite(x).all():
            raise ValueError("forces/torques contain NaN or inf; pass finite values")
        sigma = self.solve_density(x)
        return self.velocities(sigma).reshape(-1)

    # ---- the transposed (adjoint) product ------------------------------------------------
    # M = R P G^{-1} Bt with Bt = rhs, G v = A_bie(P v), P = one-body preconditioner and
    # R = velocities, so M' = Bt' G^{-T} P' R' with G' = P' A_bie'.  Every piece below is
    # the exact transpose of the discrete forward piece (full accuracy, rung 0).  The
    # expansion pieces (Faxen read-off, on-the-fly near field) use transposed compiled
    # kernels rather than per-pair matrices: the extra memory is one complex array of
    # 5 (p+1)^2 coefficients per sphere (0.8 MB at M = 125, p = 8), a few 3N x 3N
    # one-sphere matrices and index arrays; the stored near blocks are reused as they are.

    def _adjoint_setup(self) -> dict:
        """Structures of the transposed product, built once on first adjoint use."""
        if self._adj is not None:
            return self._adj
        M, N, p = self.M, self._N, self.p
        adj: dict = {
            "self": np.ascontiguousarray(self._so.Kp + self._so.L),
            "precond": np.ascontiguousarray(self._so.precond),
            "analysis": np.ascontiguousarray(self._basis.A),
            "read": np.ascontiguousarray(self._read_S),
            "proj": None if self._near_proj is None else np.ascontiguousarray(self._near_proj),
            "synth": [None if S is None else np.ascontiguousarray(S.T) for S in self._synth],
            "tgt": tuple(np.ascontiguousarray(a[:, k]) for a in (self._tgt_pts, self._tgt_nrm)
                         for k in range(3)),
        }
        Cm = _coefficient_matrix(p)                              # (3N, 5 (p+1)^2), D = s @ Cm
        adj["coef"] = np.ascontiguousarray(np.vstack([Cm.T.real, -Cm.T.imag]))
        # direct sums at full accuracy (rung 0), grouped by source range; with far="fmm"
        # also the native-grid pairs the forward product subtracts from the FMM sum
        adj["direct"] = _group_ranges(*self._dir_ranges[0], N) if self._n_src else None
        adj["fmm_sub"] = _group_ranges(*self._fmm_sub, N) if self.far == "fmm" else None
        # on-the-fly expansion pairs, by source sphere
        adj["fly"] = [self._fly_group(ptr, idx, grid) for ptr, idx, grid in (
            (self._fly_ptr, self._fly_idx, self._near_grid),        # projected zone
            (self._flyn_ptr, self._flyn_idx, self._grid)) if idx.size]   # node-sampled
        # stored blocks, by source sphere
        if self.n_block_pairs:
            order = np.argsort(self._block_src, kind="stable").astype(np.int64)
            adj["blk_order"] = order
            adj["blk_ptr"] = np.searchsorted(self._block_src[order], np.arange(M + 1)).astype(np.int64)
        self._adj = adj
        return adj

    def _expansion_adjoint(self, Dbar: np.ndarray) -> np.ndarray:
        """Transpose of :func:`sphere_vsh.expansion_coefficients`: complex adjoint
        coefficients (M, 5, p+1, p+1) -> grid densities (M, 3N)."""
        flat = Dbar.reshape(self.M, -1)
        return self._rows(np.hstack([flat.real, flat.imag]), self._adjoint_setup()["coef"])

    def _fly_group(self, ptr: np.ndarray, idx: np.ndarray, grid) -> dict:
        """Adjoint structures of one group of on-the-fly expansion pairs (target lists
        ``ptr``/``idx``) evaluated on ``grid``: target points and pairs by source sphere."""
        tgt_i = np.nonzero(np.diff(ptr))[0]
        nodes = grid.nodes
        lists: list[list[int]] = [[] for _ in range(self.M)]
        for b, i in enumerate(tgt_i):
            for j in idx[ptr[i]:ptr[i + 1]]:
                lists[j].append(b)
        src_ptr, blk = _csr(lists)
        return {"tgt": tgt_i, "size": grid.size, "ptr": src_ptr, "blk": blk,
                "projected": grid is self._near_grid and self._near_proj is not None,
                "pts": np.ascontiguousarray(
                    (self.centers[tgt_i, None, :] + self.radii[tgt_i, None, None] * nodes[None]).reshape(-1, 3)),
                "nrm": np.ascontiguousarray(np.tile(nodes, (tgt_i.size, 1)))}

    def _near_on_the_fly_adjoint(self, ob: np.ndarray) -> np.ndarray:
        """Transpose of the on-the-fly expansion pairs of :meth:`_apply_bie` (projected
        zone, :meth:`_near_on_the_fly`, and node-sampled pairs beyond it) for adjoint
        tractions ``ob`` (M, 3N)."""
        adj = self._adjoint_setup()
        p = self.p
        Dbar = np.zeros((self.M, 5, p + 1, p + 1), dtype=np.complex128)
        for g in adj["fly"]:
            tb = self._rows(ob[g["tgt"]], adj["proj"]) if g["projected"] else ob[g["tgt"]]
            traction_expansion_adjoint(g["pts"], g["nrm"], g["size"], g["ptr"], g["blk"],
                                       self.centers, self.radii,
                                       np.ascontiguousarray(tb.reshape(-1, 3)), p, Dbar)
        return self._expansion_adjoint(Dbar)

    def _source_forces_adjoint(self, f_bar: list[np.ndarray], s_bar: np.ndarray,
                               coef_bar: np.ndarray) -> None:
        """Transpose of :meth:`_source_forces`: adds the adjoint point forces to the
        densities ``s_bar`` (native levels) and to the VSH coefficients ``coef_bar``."""
        synth = self._adjoint_setup()["synth"]
        for L, q in enumerate(self._levels):
            J = self._lvl_spheres[L]
            if J.size == 0:
                continue
            b0 = self._lvl_base[L]
            nq = sphere_grid(q).size
            Fb = np.stack([f[b0:b0 + J.size * nq] for f in f_bar], axis=1).reshape(J.size, nq, 3)
            Fb = (Fb * self._src_scale[L][:, :, None]).reshape(J.size, 3 * nq)
            if synth[L] is None:
                s_bar[J] += Fb
            else:
                coef_bar[J] += self._rows(Fb, synth[L])

    def _apply_bie_adjoint(self, w: np.ndarray) -> np.ndarray:
        """Transpose of :meth:`_apply_bie` at full accuracy (rung 0).  With ``far="fmm"``
        the FMM sum is transposed by a stresslet FMM (:func:`_fmm_traction_adjoint`, same
        tolerance) and the native-grid pairs the forward product removes are removed by
        transposed direct sums, so the adjoint matches the forward to the FMM tolerance."""
        adj = self._adjoint_setup()
        M, N = self.M, self._N
        ob = np.ascontiguousarray(np.asarray(w, dtype=float).reshape(M, 3 * N))
        out = self._rows(ob, adj["self"])
        if M > 1:
            coef_bar = np.zeros((M, self._analysis_T.shape[1]))
            if self._fly_idx.size or self._flyn_idx.size:
                out += self._near_on_the_fly_adjoint(ob)
            if self._n_src:
                tb = ob.reshape(M * N, 3)
                tbc = tuple(np.ascontiguousarray(tb[:, k]) for k in range(3))
                f_bar = [np.zeros(self._n_src) for _ in range(3)]
                g = adj["direct"]
                if g["start"].size:
                    fn = (direct_traction_adjoint if g["work"] > _PARALLEL_WORK
                          else direct_traction_adjoint_serial)
                    fn(*adj["tgt"], *tbc, N, g["ptr"], g["tgt"], g["start"], g["stop"],
                       *self._src_xyz, *f_bar, False)
                if self.far == "fmm":
                    b0 = self._lvl_base[self._native]
                    fb = _fmm_traction_adjoint(self._tgt_pts, self._tgt_nrm, tb, self.quad_tol)
                    sub = [np.zeros(self._n_src) for _ in range(3)]
                    g = adj["fmm_sub"]
                    direct_traction_adjoint_skip(*adj["tgt"], *tbc, N, g["ptr"], g["tgt"],
                                                 g["start"], g["stop"], *self._src_xyz, *sub, True)
                    for k in range(3):
                        f_bar[k][b0:b0 + M * N] += fb[:, k]
                        f_bar[k] -= sub[k]
                self._source_forces_adjoint(f_bar, out, coef_bar)
            if self.n_block_pairs:
                fn = (apply_blocks_adjoint if self._blocks.size > _PARALLEL_WORK
                      else apply_blocks_adjoint_serial)
                fn(self._blocks, adj["blk_ptr"], adj["blk_order"], self._block_tgt, ob, coef_bar)
            out += self._rows(coef_bar, adj["analysis"])
        return out.reshape(-1)

    def _precondition_adjoint(self, z: np.ndarray) -> np.ndarray:
        """Transpose of :meth:`_precondition`."""
        return self._rows(z.reshape(self.M, -1), self._adjoint_setup()["precond"]).reshape(-1)

    def velocities_adjoint(self, u: np.ndarray) -> np.ndarray:
        """Transpose of :meth:`velocities`: rigid velocities (M, 6) -> stacked densities.

        The self read-off is a dense (6, 3N) matrix per sphere; the Faxen read-off of the
        other spheres' expansions is transposed by a compiled kernel
        (:func:`kernels.center_readout_adjoint`), no per-pair matrices are stored."""
        M, p = self.M, self.p
        u = np.ascontiguousarray(np.asarray(u, dtype=float).reshape(M, 6))
        us = np.empty((M, 6))
        us[:, :3] = u[:, :3] * (self.radii / self.mu)[:, None]
        us[:, 3:] = u[:, 3:] / self.mu
        s = self._rows(us, self._adjoint_setup()["read"])
        if M > 1:
            Dbar = np.zeros((M, 5, p + 1, p + 1), dtype=np.complex128)
            center_readout_adjoint(self.centers, self.radii, u, p, self.mu, Dbar)
            s += self._expansion_adjoint(Dbar)
        return s.reshape(-1)

    def rhs_adjoint(self, w: np.ndarray) -> np.ndarray:
        """Transpose of :meth:`rhs`: stacked densities -> (F, T) per sphere (length 6M)."""
        w = np.asarray(w, dtype=float).reshape(self.M, self._N, 3)
        a = self.radii[:, None]
        out = np.empty((self.M, 6))
        out[:, :3] = w.sum(axis=1) / (4 * np.pi * a ** 2)
        out[:, 3:] = 3.0 * np.cross(self._grid.nodes[None], w).sum(axis=1) / (8 * np.pi * a ** 3)
        return out.reshape(-1)

    def _adjoint_operator(self, v: np.ndarray) -> np.ndarray:
        """``G' v = P' A_bie' v``, the transpose of the preconditioned GMRES operator."""
        return self._precondition_adjoint(self._apply_bie_adjoint(v))

    def solve_adjoint(self, z: np.ndarray) -> np.ndarray:
        """Solve ``G' w = z`` by GMRES (tolerance ``eps_gmres``, same restart and maxiter as
        the forward solve, full accuracy) from a one-body start (``G' = I`` for one
        sphere) improved by the stored adjoint solutions; convergence is reported as in
        :meth:`solve_density`."""
        z = np.asarray(z, dtype=float).reshape(-1)
        nz = float(np.linalg.norm(z))
        if nz == 0.0:
            self.adjoint_iterations.append(0)
            self.adjoint_residuals.append(0.0)
            return np.zeros_like(z)
        if self._adj_history:
            Zk = np.stack([h[1] for h in self._adj_history], axis=1)
            Wk = np.stack([h[0] for h in self._adj_history], axis=1)
            alpha = np.linalg.lstsq(Zk, z, rcond=None)[0]
            w0 = Wk @ alpha + (z - Zk @ alpha)
        else:
            w0 = z.copy()
        restart = max(1, min(z.size, 60, self.maxiter))
        solver = scipy_gmres_solve if self.krylov == "scipy" else gmres_solve
        w, its, res_g = solver(lambda v, k: self._adjoint_operator(v), z, w0,
                               self.eps_gmres, restart, self.maxiter, rungs=1)
        self.adjoint_iterations.append(its)
        self.adjoint_residuals.append(res_g)              # full accuracy, as above
        self._report("BIM adjoint GMRES", res_g, its)
        if self._adj_history.maxlen:
            self._adj_history.append((w, z))
        return w

    def _rmatvec(self, y: np.ndarray) -> np.ndarray:
        """Exact transpose of the discrete mobility: ``M' y = Bt' G^{-T} P' R' y``.

        The discrete map is symmetric only to about 1e-3; this is its transpose to the
        GMRES tolerance (a dot-product test ``<y, M x> = <M' y, x>`` holds to about
        ``eps_gmres`` times the conditioning: 1e-12 for eps_gmres = 1e-12 on the test
        clusters, 1e-8 on the packed 27-sphere lattice at eps_gmres = 1e-8).  Called by
        scipy's ``rmatvec``, ``A.T @ y`` and ``A.H @ y``.

        Cost: one GMRES solve like the forward product, at full quadrature accuracy
        (no relaxation), about the forward time.  Memory: no per-pair matrices; the
        stored near blocks are reused and the expansion pieces are transposed by
        compiled kernels, so the extra memory is a complex array of ``5 (p+1)^2``
        coefficients per sphere (0.8 MB at M = 125, p = 8), a few ``3N x 3N`` one-sphere
        matrices and index arrays, built on first use.  With ``far="fmm"`` the FMM sum is
        transposed by fmm3dpy's stresslet FMM (the traction kernel of a point force,
        read as a function of the source, is a stresslet).
        Iterations and residuals go to ``adjoint_iterations`` and ``adjoint_residuals``.

        Raises
        ------
        ValueError
            If ``y`` does not have 6M entries or contains NaN or inf.
        """
        y = np.asarray(y, dtype=float).reshape(-1)
        if y.size != 6 * self.M:
            raise ValueError(f"rmatvec needs {6 * self.M} velocities (U, Omega per sphere), "
                             f"got {y.size}")
        if not np.isfinite(y).all():
            raise ValueError("velocities passed to rmatvec contain NaN or inf; pass finite values")
        z = self._precondition_adjoint(self.velocities_adjoint(y))
        return self.rhs_adjoint(self.solve_adjoint(z))


def bim_mobility(centers, radii, *, p: int = 8, eps_gmres: float = 1e-8,
                 mu: float = 1.0, far: str = "direct",
                 quad_tol: float | None = None, krylov: str = "scipy") -> BimMobility:
    """Boundary-integral mobility operator of rigid spheres.

    Parameters
    ----------
    centers : array_like, shape (M, 3)
    radii : float or array_like, shape (M,)
    p : int
        Spherical-harmonic order (grid ``(p+1) x 2p`` per sphere).
    eps_gmres : float
        GMRES relative tolerance.
    mu : float
        Viscosity.
    far : {"direct", "fmm"}
        Far-field engine (see :class:`BimMobility`); "fmm" needs fmm3dpy.
    quad_tol : float, optional
        Quadrature accuracy between spheres (default ``eps_gmres / 100``).
    krylov : {"scipy", "compiled"}
        GMRES implementation (see :class:`BimMobility`).

    Returns
    -------
    BimMobility
        A ``scipy.sparse.linalg.LinearOperator`` of shape (6M, 6M) mapping
        (F, T) per sphere to (U, Omega) per sphere; ``.gmres_iterations`` lists
        the iterations of every product.
    """
    return BimMobility(centers, radii, p=p, eps_gmres=eps_gmres, mu=mu, far=far,
                       quad_tol=quad_tol, krylov=krylov)
