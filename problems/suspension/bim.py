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
  (``n_vsh x n_vsh``: the traction's degree-p VSH coefficients on sphere i per VSH
  coefficient of sphere j; :meth:`bim_pairs.PairPlan._build_blocks` says why the
  traction's nodal rest above degree p can be dropped) within
  ``near_block_mb``, closest first; pairs that would need a source grid finer than p
  also get blocks while the budget lasts (a block product is much cheaper than that
  sum, see :mod:`bim_pairs`); expansion pairs beyond the budget are evaluated on the
  fly (same values).
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
accuracy.  GMRES is scipy's, driven one restart cycle at a time so that it knows the
rung of every product (:func:`bim_gmres.relaxed_gmres`).  Dense per-sphere products run
in compiled loops and scipy's vector work with BLAS limited to one thread
(threadpoolctl): threaded BLAS would compete with the compiled parallel kernels on few
cores (up to 100x slower on 2 cores).

The transpose of the discrete mobility (``rmatvec``; the discrete map is symmetric only
to about 1e-3 near contact, and the contact layer symmetrises with it) is
``M' = Bt' G^{-T} P' R'`` for ``M = R P G^{-1} Bt`` (``Bt`` = :meth:`BimMobility.rhs`, ``G``
the preconditioned traction operator, ``P`` the one-body preconditioner, ``R`` the
read-off): every piece is transposed exactly (:mod:`bim_adjoint`), and ``G'`` is solved
by the same GMRES at full accuracy.

The setup done once per configuration (grids, pair lists per accuracy rung,
source points, blocks; :mod:`bim_pairs`) is reused by every product.  Accuracy to expect
(DESIGN.md): p = 8 gives about 1e-7 at gap 1a and 1e-5 at gap 0.5a, and
degrades near contact (O(1) squeeze errors at gap 0.01a): p = 8 is not ground
truth near contact.
"""

from __future__ import annotations

import contextlib
import copy
import warnings
import weakref
from collections.abc import Iterator

import numpy as np
from scipy.sparse.linalg import LinearOperator

from lcpbench.toolkit.blas import on_one_blas_thread

from .bim_adjoint import AdjointPieces
from .bim_gmres import relaxed_gmres
from .bim_pairs import RELAX_STEP, PairPlan
from .bim_recycle import RecycledGCR, default_capacity
from .bim_transpose import TransposedProducts
from .geometry import check_configuration, check_no_overlap, check_viscosity
from .kernels import (
    PARALLEL_WORK,
    apply_blocks,
    apply_blocks_serial,
    center_readout,
    dense_rows,
    direct_traction_ranges,
    direct_traction_ranges_serial,
    direct_traction_skip,
    synthesize_forces,
    synthesize_forces_serial,
    traction_expansion,
)
from .sphere_vsh import (
    default_quad_tol,
    expansion_coefficients,
    projection_matrix,
    self_operators,
    sphere_grid,
    vsh_basis,
)

__all__ = ["BimMobility", "bim_mobility", "BimConvergenceWarning"]

_NEAR_UPSAMPLE = 2.0
"""The traction of a pair in the projected zone is evaluated on the grid of order
``ceil(_NEAR_UPSAMPLE * p)`` and projected onto degree p.  Measured on a packed 27-sphere
cluster (gaps >= 0.1a): factors 1.5, 2 and 3 give the same spectra, and asymmetries
``max|A - A'|/max|A|`` of D'MD at p = 6 of 2.7e-3, 2.2e-4 and 1.3e-4; 1 is plain node
sampling."""

_SUMMARY = ("tolerance_ladder", "level_radii", "pairs_per_level", "n_far_pairs",
            "n_near_pairs", "n_block_pairs")
"""Attributes of the pair set-up that the operator shows as its own."""


class BimConvergenceWarning(RuntimeWarning):
    """GMRES stopped before reaching the requested tolerance."""


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


class BimMobility(TransposedProducts, LinearOperator):
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
    recycle : int, optional
        Krylov directions kept from solve to solve, for the forward and for the
        transposed equation each (:mod:`bim_recycle`): later solves start from the
        projection onto them and add directions only for what is left, at full accuracy
        (no relaxation), ending with one true-residual check.  Default: as many as fit
        in 256 MB per equation.  0 turns recycling off: every solve is relaxed restarted
        GMRES from the one-body approximation (:func:`bim_gmres.relaxed_gmres`).
    maxiter : int
        Maximum total number of GMRES iterations per product.
    near_block_mb : float
        Memory budget (MB) for the dense near-field blocks built once per
        configuration (``n_vsh x n_vsh`` doubles per pair, 0.45 MB at p = 8); the
        closest pairs get blocks first (every pair of 64 spheres at p = 8 takes
        1.8 GiB), the remaining expansion pairs are evaluated on the fly (same values,
        slower).
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
    plan : bim_pairs.PairPlan
        How every pair of spheres is evaluated (set up once per configuration).
    """

    def __init__(self, centers, radii, *, p: int = 8, eps_gmres: float = 1e-8,
                 mu: float = 1.0, on_failure: str = "warn", recycle: int | None = None,
                 maxiter: int = 500, near_block_mb: float = 4096.0,
                 quad_tol: float | None = None, far: str = "direct",
                 near_upsample: float = _NEAR_UPSAMPLE) -> None:
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
        self.quad_tol = default_quad_tol(self.eps_gmres) if quad_tol is None else float(quad_tol)
        if not (np.isfinite(self.quad_tol) and 0 < self.quad_tol < 1):
            raise ValueError(f"quad_tol = {quad_tol!r} must be a number in (0, 1), e.g. 1e-10 "
                             "(accuracy of the quadrature between spheres)")
        try:
            up = float(near_upsample)
        except (TypeError, ValueError):
            up = float("nan")
        if isinstance(near_upsample, bool) or not (np.isfinite(up) and up >= 1):
            raise ValueError(f"near_upsample = {near_upsample!r} must be a number >= 1 (order of "
                             "the near-field target grid in units of p; 1 = sample at the nodes)")
        if far == "fmm":
            from .fmm import check_fmm
            check_fmm()
        self.far = far
        self.on_failure = on_failure
        self.maxiter = int(maxiter)
        self.near_block_mb = float(near_block_mb)
        self.near_upsample = up
        M = c.shape[0]
        super().__init__(dtype=np.float64, shape=(6 * M, 6 * M))
        self.centers, self.radii, self.M = c, r, M
        self.self_ops = self_operators(self.p)
        self._grid = sphere_grid(self.p)
        N = self._grid.size
        self._N = N
        nodes = self._grid.nodes
        self.tgt_pts = np.ascontiguousarray((c[:, None, :] + r[:, None, None] * nodes[None])
                                            .reshape(-1, 3))
        self.tgt_nrm = np.ascontiguousarray(np.tile(nodes, (M, 1)))
        self._tgt_sphere = np.repeat(np.arange(M, dtype=np.int64), N)
        self._self_block = np.ascontiguousarray((self.self_ops.Kp + self.self_ops.L).T)
        self._precond_T = np.ascontiguousarray(self.self_ops.precond.T)
        self.readout = self.self_ops.readout @ self.self_ops.S     # (6, 3N) unit sphere
        self.basis = vsh_basis(self.p)
        self._analysis_T = np.ascontiguousarray(self.basis.A.T)
        # coefficients of the preconditioned density P y in one product: y @ P' A'
        self._precond_analysis_T = np.ascontiguousarray(self._precond_T @ self._analysis_T)
        q_near = max(self.p, int(np.ceil(up * self.p - 1e-9)))
        self._near_grid = sphere_grid(q_near)
        self._near_proj = (None if q_near == self.p           # plain node sampling
                           else projection_matrix(self.p, q_near))
        self._setup_interactions()
        n = M * 3 * N
        self.recycle = default_capacity(n) if recycle is None else max(int(recycle), 0)
        self._fresh_solvers()

    def _new_recyclers(self) -> tuple:
        """Empty recycled spaces for the forward and the transposed equation (None, None
        without recycling)."""
        n, cap = self.M * 3 * self._N, self.recycle
        if not cap:
            return None, None
        # the solvers reach this operator through a weak reference: a strong one would make
        # a reference cycle, and the blocks and kept directions of every configuration would
        # wait for Python's cyclic collector (measured: +20-70 MB per time step, until a
        # 27-sphere simulation was killed for want of memory after 80 steps)
        me = weakref.ref(self)
        return (RecycledGCR(lambda v: me()._apply_preconditioned(v), n, cap),
                RecycledGCR(lambda v: me().adjoint_pieces.operator(v), n, cap))

    @contextlib.contextmanager
    def cold_products(self) -> Iterator[None]:
        """Products made inside start from empty recycled spaces, as the first product of
        a configuration does; the kept directions are put back afterwards.  For timing one
        product at its first-product cost (:func:`lcpbench.core.operator.measure_cost`):
        with recycling every later product needs fewer new directions."""
        saved = self._recycler, self._adj_recycler
        self._recycler, self._adj_recycler = self._new_recyclers()
        try:
            yield
        finally:
            self._recycler, self._adj_recycler = saved

    def _fresh_solvers(self) -> None:
        """New (empty) recycled spaces and empty iteration and residual records."""
        self._recycler, self._adj_recycler = self._new_recyclers()
        self.gmres_iterations: list[int] = []
        self.residuals: list[float] = []
        self.adjoint_iterations: list[int] = []
        self.adjoint_residuals: list[float] = []

    def at_tolerance(self, eps_gmres: float) -> BimMobility:
        """The same discrete mobility solved to another GMRES tolerance, on this one's set-up.

        The twin shares everything that depends only on the configuration and the order
        (pair plan, stored near blocks, self operators, the transposed pieces), so it
        costs no second set-up; it has its own recycled spaces and records, so that its
        products neither use nor feed this operator's kept directions (each product's
        cost stays its own, as a low fidelity's cost ratio needs).  This is how a low
        fidelity of the high's own order, e.g. ``p8e3`` beside ``p = 8, eps 1e-8``, is
        built (:func:`.contacts.build_contact_problem`): it differs from the high only by
        where GMRES stops.

        Raises
        ------
        ValueError
            If ``eps_gmres`` is not in (0, 1).
        """
        eps = _check_eps(eps_gmres)
        _ = self.adjoint_pieces                     # built once, shared by the twin
        twin = copy.copy(self)
        twin.eps_gmres = eps
        twin._fresh_solvers()
        return twin

    def _setup_interactions(self, all_expansion: bool = False) -> None:
        """(Re)build the pair set-up (:class:`bim_pairs.PairPlan`); ``all_expansion``
        evaluates every pair by its exact expansion (for testing)."""
        self.plan = PairPlan(self.centers, self.radii, self.p, self.quad_tol, self.far,
                             self._grid, self._near_grid, self._near_proj, self.basis,
                             self.near_block_mb, all_expansion)
        for name in _SUMMARY:
            setattr(self, name, getattr(self.plan, name))
        self._pieces: AdjointPieces | None = None     # built on first use
        for rec in (getattr(self, "_recycler", None), getattr(self, "_adj_recycler", None)):
            if rec is not None:                       # kept directions of the old operator
                rec.clear()

    # ---- the boundary integral operator -------------------------------------------------
    def _source_forces(self, s: np.ndarray, coef: np.ndarray) -> list[np.ndarray]:
        """Point forces (density times weight) at every source level, as three arrays;
        upsampled levels are synthesised from the VSH coefficients ``coef``."""
        plan = self.plan
        f = [np.empty(plan.n_src) for _ in range(3)]
        for L, _q in enumerate(plan.levels):
            J = plan.lvl_spheres[L]
            if J.size == 0:
                continue
            b0 = plan.lvl_base[L]
            if plan.synth[L] is None:
                nq = self._N
                F = s[J].reshape(J.size, nq, 3) * plan.src_scale[L][:, :, None]
                for k in range(3):
                    f[k][b0:b0 + J.size * nq] = F[:, :, k].reshape(-1)
            else:
                fn = (synthesize_forces if J.size * plan.synth[L].size > PARALLEL_WORK
                      else synthesize_forces_serial)
                fn(coef, J, plan.synth[L], plan.src_scale[L], b0, *f)
        return f

    def _apply_bie(self, sigma: np.ndarray, rung: int = 0) -> np.ndarray:
        """``(1/2 I + K' + L) sigma + sum_j T_ij sigma_j`` for stacked densities, with the
        quadrature between spheres accurate to ``tolerance_ladder[rung]``."""
        out, coef = self._apply_bie_unblocked(sigma, rung)
        if coef is not None:
            out += self._block_part(coef)
        return out.reshape(-1)

    def _apply_preconditioned(self, y: np.ndarray, rung: int = 0) -> np.ndarray:
        """The preconditioned operator ``G y = _apply_bie(P y)`` that GMRES solves with.

        ``P`` is the inverse of the one-sphere operator, so the self part of ``G`` is the
        identity: ``G y = y + sum_j T_ij (P y)_j``, one per-sphere product fewer than
        applying the self operator to ``P y``; when every pair has a stored block the
        blocks need only the coefficients of ``P y``, one product with ``P' A'`` (the
        same values to rounding)."""
        out, coef = self._preconditioned_unblocked(y, rung)
        if coef is not None:
            out += self._block_part(coef)
        return out.reshape(-1)

    def _preconditioned_unblocked(self, y: np.ndarray, rung: int = 0
                                  ) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`_apply_preconditioned` without the stored blocks: ``(out, coef)`` as
        :meth:`_apply_bie_unblocked` gives them for ``P y``."""
        M, N, plan = self.M, self._N, self.plan
        x = np.ascontiguousarray(y.reshape(M, 3 * N))
        if M == 1:
            return x.copy(), None
        if plan.fly_idx.size or plan.flyn_idx.size or plan.n_src:
            out, coef = self._apply_bie_unblocked(dense_rows(x, self._precond_T), rung,
                                                  self_part=False)
            return out + x, coef
        return x.copy(), dense_rows(x, self._precond_analysis_T)

    def _block_part(self, coef: np.ndarray) -> np.ndarray:
        """The stored near blocks applied to the VSH coefficients ``coef``, on the grid
        ``(M, 3N)`` (zeros when no pair has a block)."""
        plan = self.plan
        if not plan.n_block_pairs:
            return np.zeros((self.M, 3 * self._N))
        fn = apply_blocks if plan.blocks.size > PARALLEL_WORK else apply_blocks_serial
        acc = np.zeros((self.M, plan.blocks.shape[1]))
        fn(plan.blocks, plan.block_ptr, plan.block_src, coef, acc)
        return dense_rows(acc, plan.block_synth)

    def _apply_bie_unblocked(self, sigma: np.ndarray, rung: int = 0, self_part: bool = True
                             ) -> tuple[np.ndarray, np.ndarray | None]:
        """:meth:`_apply_bie` without the stored near blocks (and without the one-sphere
        operator when ``self_part`` is False): ``(out, coef)`` with ``out`` of shape
        ``(M, 3N)`` and ``coef`` the VSH coefficients the blocks act on (None for one
        sphere)."""
        M, N, p, plan = self.M, self._N, self.p, self.plan
        s = np.ascontiguousarray(sigma.reshape(M, 3 * N))
        out = dense_rows(s, self._self_block) if self_part else np.zeros((M, 3 * N))
        coef = None
        if M > 1:
            coef = dense_rows(s, self._analysis_T)
            trac = np.zeros((M * N, 3))
            if plan.fly_idx.size:
                out += self._near_on_the_fly(s)
            if plan.flyn_idx.size:                  # expansion pairs beyond the zone
                traction_expansion(self.tgt_pts, self.tgt_nrm, self._tgt_sphere,
                                   plan.flyn_ptr, plan.flyn_idx, self.centers, self.radii,
                                   expansion_coefficients(p, s), p, trac)
            if plan.n_src:
                f = self._source_forces(s, coef)
                ptr, start, stop = plan.dir_ranges[min(rung, len(plan.dir_ranges) - 1)]
                if stop.size:
                    work = N * int((stop - start).sum())
                    fn = (direct_traction_ranges if work > PARALLEL_WORK
                          else direct_traction_ranges_serial)
                    fn(self.tgt_pts, self.tgt_nrm, self._tgt_sphere,
                       ptr, start, stop, *plan.src_xyz, *f, trac, False)
                if self.far == "fmm":
                    from .fmm import fmm_traction
                    b0 = plan.lvl_base[plan.native]
                    trac += fmm_traction(self.tgt_pts, self.tgt_nrm,
                                         np.stack([x[b0:b0 + M * N] for x in f], axis=1),
                                         self.quad_tol)
                    ptr, start, stop = plan.fmm_sub
                    sub = np.zeros((M * N, 3))
                    direct_traction_skip(self.tgt_pts, self.tgt_nrm, self._tgt_sphere,
                                         ptr, start, stop, *plan.src_xyz, *f, sub, True)
                    trac -= sub
            out += trac.reshape(M, 3 * N)
        return out, coef

    def _near_on_the_fly(self, s: np.ndarray) -> np.ndarray:
        """Near-field traction of the projected-zone expansion pairs without a stored
        block: evaluated on the finer grid of every sphere that has such pairs and
        projected onto degree p (the same values a stored block gives)."""
        M, N, p, plan = self.M, self._N, self.p, self.plan
        nodes = self._near_grid.nodes
        Nq = nodes.shape[0]
        tgt_i = np.nonzero(np.diff(plan.fly_ptr))[0]
        pts = (self.centers[tgt_i, None, :] + self.radii[tgt_i, None, None] * nodes[None])
        trac = np.zeros((tgt_i.size * Nq, 3))
        traction_expansion(np.ascontiguousarray(pts.reshape(-1, 3)),
                           np.ascontiguousarray(np.tile(nodes, (tgt_i.size, 1))),
                           np.repeat(tgt_i, Nq).astype(np.int64), plan.fly_ptr, plan.fly_idx,
                           self.centers, self.radii, expansion_coefficients(p, s), p, trac)
        out = np.zeros((M, 3 * N))
        trac = trac.reshape(tgt_i.size, 3 * Nq)
        out[tgt_i] = (trac if self._near_proj is None
                      else dense_rows(trac, np.ascontiguousarray(self._near_proj.T)))
        return out

    def _precondition(self, y: np.ndarray) -> np.ndarray:
        return dense_rows(y.reshape(self.M, -1), self._precond_T).reshape(-1)

    def _unprecondition(self, sigma: np.ndarray) -> np.ndarray:
        return dense_rows(sigma.reshape(self.M, -1), self._self_block).reshape(-1)

    def rhs(self, ft: np.ndarray) -> np.ndarray:
        """``B'(F, T)`` on every grid: stacked densities of length ``6 M p (p+1)``."""
        ft = np.asarray(ft, dtype=float).reshape(self.M, 6)
        nodes = self._grid.nodes
        a = self.radii[:, None, None]
        b = (ft[:, None, :3] / (4 * np.pi * a ** 2)
             + 3.0 * np.cross(ft[:, None, 3:], nodes[None]) / (8 * np.pi * a ** 3))
        return b.reshape(-1)

    def _solve(self, what: str, operator, b: np.ndarray, start: np.ndarray, rungs: int,
               iterations: list, residuals: list) -> np.ndarray:
        """GMRES on ``operator(v, rung)`` from ``start`` to ``eps_gmres`` (restart 60,
        ``maxiter``); records the iterations and the full-accuracy residual and reports
        non-convergence (:meth:`_report`)."""
        restart = max(1, min(b.size, 60, self.maxiter))
        x, its, res = relaxed_gmres(operator, b, start, self.eps_gmres, restart, self.maxiter,
                                    rungs=rungs, step=RELAX_STEP)
        self._record(what, its, res, iterations, residuals)
        return x

    def solve_density(self, ft: np.ndarray) -> np.ndarray:
        """Solve the traction equation for forces and torques ``ft`` (length 6M)."""
        b = self.rhs(ft)
        if float(np.linalg.norm(b)) == 0.0:
            self.gmres_iterations.append(0)
            self.residuals.append(0.0)
            return np.zeros_like(b)
        if self._recycler is not None:
            return self._precondition(self._recycled_solve("BIM GMRES", self._recycler, b,
                                                           self.gmres_iterations,
                                                           self.residuals))
        y0 = self._unprecondition(self._precondition(b))
        y = self._solve("BIM GMRES", lambda v, k: self._apply_preconditioned(v, k),
                        b, y0, len(self.plan.dir_ranges), self.gmres_iterations,
                        self.residuals)
        return self._precondition(y)

    def _recycled_solve(self, what: str, solver: RecycledGCR, b: np.ndarray,
                        iterations: list, residuals: list) -> np.ndarray:
        """:meth:`RecycledGCR.solve` to ``eps_gmres`` within ``maxiter`` new directions;
        records the iterations (new directions plus the residual checks: the products
        made) and the true residual, and reports non-convergence (:meth:`_report`)."""
        before = solver.products
        y, _new, res = solver.solve(b, self.eps_gmres, self.maxiter)
        self._record(what, solver.products - before, res, iterations, residuals)
        return y

    def _record(self, what: str, its: int, res: float, iterations: list,
                residuals: list) -> None:
        """Append a solve's products and residual to its lists and report non-convergence."""
        iterations.append(its)
        residuals.append(res)
        self._report(what, res, its)

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
        warnings.warn(msg, BimConvergenceWarning, stacklevel=6)

    def velocities(self, sigma: np.ndarray) -> np.ndarray:
        """Rigid velocities (M, 6) read off from stacked densities."""
        M, N = self.M, self._N
        s = sigma.reshape(M, 3 * N)
        ro = s @ self.readout.T                       # unit sphere, mu = 1
        out = np.empty((M, 6))
        out[:, :3] = ro[:, :3] * (self.radii / self.mu)[:, None]
        out[:, 3:] = ro[:, 3:] / self.mu
        if M > 1:
            D = expansion_coefficients(self.p, s)
            center_readout(self.centers, self.radii, D, self.p, self.mu, out)
        return out

    @on_one_blas_thread
    def _matvec(self, x: np.ndarray) -> np.ndarray:
        x = self._checked_loads(x, "forces/torques")
        sigma = self.solve_density(x)
        return self.velocities(sigma).reshape(-1)


    def _checked_loads(self, v, what: str) -> np.ndarray:
        v = np.asarray(v, dtype=float).reshape(-1)
        if v.size != 6 * self.M:
            raise ValueError(f"{what} have {v.size} entries; a mobility of {self.M} spheres "
                             f"needs {6 * self.M} (6 per sphere: force then torque, or "
                             "velocity then rotation)")
        if not np.isfinite(v).all():
            raise ValueError(f"{what} contain NaN or inf; pass finite values")
        return v


def bim_mobility(centers, radii, *, p: int = 8, eps_gmres: float = 1e-8,
                 mu: float = 1.0, far: str = "direct",
                 quad_tol: float | None = None) -> BimMobility:
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

    Returns
    -------
    BimMobility
        A ``scipy.sparse.linalg.LinearOperator`` of shape (6M, 6M) mapping
        (F, T) per sphere to (U, Omega) per sphere; ``.gmres_iterations`` lists
        the iterations of every product.
    """
    return BimMobility(centers, radii, p=p, eps_gmres=eps_gmres, mu=mu, far=far,
                       quad_tol=quad_tol)
