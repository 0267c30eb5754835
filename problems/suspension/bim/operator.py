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
  >= 0.1a (docs/mobility.md);
* closer pairs: exact exterior spherical-harmonic expansions of the band-limited
  density (Corona & Veerapaneni, JCP 2018), stored as dense coefficient blocks
  (``n_vsh x n_vsh``: the traction's degree-p VSH coefficients on sphere i per VSH
  coefficient of sphere j; :meth:`.pairs.PairPlan._build_blocks` says why the
  traction's nodal rest above degree p can be dropped) within
  ``near_block_mb``, closest first; pairs that would need a source grid finer than p
  also get blocks while the budget lasts (a block product is much cheaper than that
  sum, see :mod:`.pairs`); expansion pairs beyond the budget are evaluated on the
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
accuracy.  GMRES runs one restart cycle at a time so that it knows the rung of every
product (:func:`.gmres.relaxed_gmres`).  Dense per-sphere products run
in compiled loops and scipy's vector work with BLAS limited to one thread
(threadpoolctl): threaded BLAS would compete with the compiled parallel kernels on few
cores (docs/mobility.md has the measured slow-down).

The transpose of the discrete mobility (``rmatvec``; the discrete map is symmetric only
to about 1e-3 near contact, and the contact layer symmetrises with it) is
``M' = Bt' G^{-T} P' R'`` for ``M = R P G^{-1} Bt`` (``Bt`` = :meth:`BimMobility.rhs`, ``G``
the preconditioned traction operator, ``P`` the one-body preconditioner, ``R`` the
read-off): every piece is transposed exactly (:mod:`.adjoint`), and ``G'`` is solved
by the same GMRES at full accuracy.

The set-up done once per configuration (grids, pair lists per accuracy rung, source
points, blocks; :mod:`.setup`, :mod:`.pairs`) is shared by every product, by the twins at
other tolerances (:meth:`BimMobility.at_tolerance`) and by the distance-split low
(:mod:`.split`).  Its accuracy against exact two-sphere series, and where p = 8 stops being
ground truth near contact, are measured in docs/mobility.md.
"""

from __future__ import annotations

import contextlib

import numpy as np
from scipy.sparse.linalg import LinearOperator

from lcpbench.toolkit.blas import on_one_blas_thread

from ..geometry import check_tolerance
from .adjoint import AdjointPieces
from .blocks import StoredBlocks
from .kernels import dense_rows
from .pairs import PairPlan
from .recycle import BUDGET_FLOOR, KrylovBudget, default_capacity, solve_together
from .setup import NEAR_UPSAMPLE, BimSetup
from .solves import BimConvergenceWarning, KrylovSolves
from .sphere_vsh import default_quad_tol

__all__ = ["BimMobility", "bim_mobility", "BimConvergenceWarning"]


def _plan_number(part: str, name: str, doc: str) -> property:
    """A read-only attribute of the operator that is the pair plan's ``part.name``."""
    return property(lambda self: getattr(getattr(self.setup.plan, part), name), doc=doc)


def _setup_number(name: str, doc: str) -> property:
    """A read-only attribute of the operator that is the set-up's ``name``."""
    return property(lambda self: getattr(self.setup, name), doc=doc)


def _solves_number(name: str, doc: str) -> property:
    """A read-only attribute of the operator that is its solves' ``name``."""
    return property(lambda self: getattr(self.solves, name), doc=doc)


class BimMobility(LinearOperator):
    """Mobility of M rigid spheres by the traction boundary integral equation.

    Input per sphere ``(Fx, Fy, Fz, Tx, Ty, Tz)``, output
    ``(Ux, Uy, Uz, Wx, Wy, Wz)``; shape ``(6M, 6M)``.  ``M.T @ y`` (``rmatvec``) is the
    exact transpose of the discrete map, solved to the same tolerance.

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
        transposed equation each (:mod:`.recycle`): later solves start from the
        projection onto them and add directions only for what is left, at full accuracy
        (no relaxation), ending with one true-residual check.  Default: as many as fit
        in the Krylov budget (``krylov``).  0 turns recycling off: every solve is relaxed
        restarted GMRES from the one-body approximation (:func:`.gmres.relaxed_gmres`).
    krylov : KrylovBudget or float, optional
        Memory budget of the kept directions (:class:`.recycle.KrylovBudget`), shared by
        both equations, the twins (:meth:`at_tolerance`) and the split lows built on this
        operator; a number is a new budget of that many MB (default
        :data:`.recycle.DEFAULT_KRYLOV_MB`; 0 turns recycling off).  One budget per time
        step bounds them all.
    maxiter : int
        Maximum total number of GMRES iterations per product.
    near_block_mb : float
        Memory budget (MB) for the dense near-field blocks built once per
        configuration (``n_vsh x n_vsh`` doubles per pair); the closest pairs get blocks
        first, the remaining expansion pairs are evaluated on the fly (same values,
        slower).
    quad_tol : float, optional
        Accuracy (per unit density) of the quadrature between spheres; default
        ``eps_gmres / 100`` (clamped to [1e-15, 1e-4]).
    far : {"direct", "fmm", "auto"}
        Far-field engine: compiled direct sums, fmm3dpy's ``stfmm3d`` (extra ``fmm``;
        pays off only for many grid points), or ``auto``: the FMM from the measured
        crossover on (:func:`.fmm.resolve_far`); ``setup.far`` is the engine used.
    near_upsample : float
        The traction of a close (expansion) pair is evaluated on the grid of order
        ``ceil(near_upsample * p)`` and projected onto degree p; 1 samples it at the
        nodes (Nystrom), which aliases the peaked near traction and can make the
        operator indefinite near contact (default 2).  Every pair with a gap below
        twice the source radius is an expansion pair (projected) at any ``eps_gmres``,
        so the discretisation does not depend on the tolerance; pairs farther apart
        are sampled at the nodes.
    pair_blocks : {"table-all", "table", "direct"}
        How the stored near-field blocks are built (:class:`.setup.BimSetup`): from the
        coaxial table in rotated form (default), or directly (the reference).

    Attributes
    ----------
    setup : BimSetup
        Grids, one-sphere operators and pair plan (shared with twins and split lows).
    near : StoredBlocks
        The near-field blocks the products apply (the split low has its own).
    gmres_iterations : list of int
        Iterations of every product, in order.
    residuals : list of float
        Final relative residual ``||b - A sigma|| / ||b||`` of every product.
    adjoint_iterations, adjoint_residuals : list
        The same for every transposed product.
    """

    setup: BimSetup
    _pieces: AdjointPieces | None

    def __init__(self, centers, radii, *, p: int = 8, eps_gmres: float = 1e-8,
                 mu: float = 1.0, on_failure: str = "warn", recycle: int | None = None,
                 maxiter: int = 500, near_block_mb: float = 4096.0,
                 quad_tol: float | None = None, far: str = "direct",
                 near_upsample: float = NEAR_UPSAMPLE,
                 krylov: KrylovBudget | float | None = None,
                 pair_blocks: str = "table-all") -> None:
        eps = check_tolerance(eps_gmres)
        budget = krylov if isinstance(krylov, KrylovBudget) else (
            KrylovBudget() if krylov is None else KrylovBudget(krylov))
        tol = default_quad_tol(eps) if quad_tol is None else float(quad_tol)
        setup = BimSetup(centers, radii, p=p, mu=mu, quad_tol=tol, far=far,
                         near_upsample=near_upsample, near_block_mb=near_block_mb,
                         pair_blocks=pair_blocks)
        cap = (recycle if recycle is not None else 0 if budget.nbytes == 0
               else max(default_capacity(setup.unknowns, budget.megabytes), BUDGET_FLOOR))
        self._assemble(setup, StoredBlocks(setup.plan), eps_gmres=eps, on_failure=on_failure,
                       maxiter=maxiter, recycle=cap, krylov=budget)

    def _assemble(self, setup: BimSetup, near, *, eps_gmres: float, on_failure: str,
                  maxiter: int, recycle: int, krylov: KrylovBudget,
                  pieces: AdjointPieces | None = None) -> None:
        """Builds the operator on a set-up and a near-field part (the constructor, the twins
        of :meth:`at_tolerance` and :mod:`.split` share this)."""
        if on_failure not in ("warn", "raise"):
            raise ValueError(f"on_failure = {on_failure!r}; use 'warn' or 'raise'")
        super().__init__(dtype=np.float64, shape=(6 * setup.M, 6 * setup.M))
        self.setup, self.near = setup, near
        self._pieces = pieces
        self.solves = KrylovSolves(self, unknowns=setup.unknowns, eps_gmres=eps_gmres,
                                   maxiter=maxiter, on_failure=on_failure, recycle=recycle,
                                   krylov=krylov, label=f"M = {setup.M}, p = {setup.p}")

    # ---- the solves' settings, records and contexts (:class:`.solves.KrylovSolves`) ---------
    eps_gmres = _solves_number("eps_gmres", "Relative residual tolerance of GMRES.")
    maxiter = _solves_number("maxiter", "Maximum total number of GMRES iterations per product.")
    on_failure = _solves_number("on_failure", "What a solve that misses ``eps_gmres`` does: "
                                "``\"warn\"`` or ``\"raise\"``.")
    recycle = _solves_number("recycle", "Krylov directions kept per equation (0: none).")
    krylov = _solves_number("krylov", "The memory budget of the kept directions.")
    solve_tol = _solves_number("solve_tol", "The tolerance the next solve stops at "
                               "(:attr:`.solves.KrylovSolves.solve_tol`).")
    gmres_iterations = _solves_number("gmres_iterations", "Products of every forward solve.")
    residuals = _solves_number("residuals", "Final relative residual of every forward solve.")
    adjoint_iterations = _solves_number("adjoint_iterations",
                                        "Products of every transposed solve.")
    adjoint_residuals = _solves_number("adjoint_residuals",
                                       "Final relative residual of every transposed solve.")

    def cold_products(self) -> contextlib.AbstractContextManager[None]:
        """:meth:`.solves.KrylovSolves.cold_products`: products made inside start from
        empty recycled spaces (for timing a product at its first-product cost)."""
        return self.solves.cold_products(self)

    def at_accuracy(self, rtol: float) -> contextlib.AbstractContextManager[None]:
        """:meth:`.solves.KrylovSolves.at_accuracy`: products made inside stop their solves
        at relative residual ``max(rtol, eps_gmres)``.

        Raises
        ------
        ValueError
            If ``rtol`` is not in (0, 1).
        """
        return self.solves.at_accuracy(rtol)

    def work_counts(self) -> dict[str, int]:
        """:meth:`.solves.KrylovSolves.work_counts`: inner applications made so far (the
        ``work`` hook of the counted operator)."""
        return self.solves.work_counts()

    # ---- what the set-up shows --------------------------------------------------------------
    M = _setup_number("M", "Number of spheres.")
    p = _setup_number("p", "Spherical-harmonic order.")
    N = _setup_number("N", "Grid points per sphere.")
    mu = _setup_number("mu", "Viscosity.")

    @property
    def quad_tol(self) -> float:
        """Quadrature accuracy between spheres of the full-accuracy rung."""
        return self.setup.quad_tol

    @property
    def centers(self) -> np.ndarray:
        """Sphere centres (M, 3)."""
        return self.setup.centers

    @property
    def radii(self) -> np.ndarray:
        """Sphere radii (M,)."""
        return self.setup.radii

    @property
    def plan(self) -> PairPlan:
        """How every pair of spheres is evaluated (:class:`.pairs.PairPlan`); its
        ``tolerance_ladder``, ``level_radii``, ``pairs_per_level``, ``n_far_pairs``,
        ``n_near_pairs`` and ``n_block_pairs`` summarise the set-up."""
        return self.setup.plan

    tolerance_ladder = _plan_number(
        "quadrature", "tolerance_ladder", "Quadrature accuracies of the rungs of relaxed GMRES "
        "(first = ``quad_tol``).")
    level_radii = _plan_number(
        "quadrature", "level_radii", "Source-grid order -> scaled distance beyond which it is "
        "accurate to ``quad_tol``.")
    pairs_per_level = _plan_number(
        "quadrature", "pairs_per_level", "Source-grid order -> ordered pairs summed directly on "
        "it at full accuracy.")
    n_far_pairs = _plan_number("quadrature", "n_far_pairs", "Ordered pairs handled by direct "
                               "quadrature (not blocked).")
    n_near_pairs = _plan_number("expansions", "n_near_pairs", "Ordered pairs too close for any "
                                "source grid (expansions).")
    n_block_pairs = _plan_number("near", "n_block_pairs",
                                 "Ordered pairs whose dense block is stored.")

    @property
    def recycled_directions(self) -> int:
        """Krylov directions kept for the forward equation (0 without recycling)."""
        space = self.solves.forward_space
        return 0 if space is None else space.size

    # ---- twins ----------------------------------------------------------------------------------
    def at_tolerance(self, eps_gmres: float) -> BimMobility:
        """The same discrete mobility solved to another GMRES tolerance, on this one's set-up.

        The twin shares everything that depends only on the configuration and the order
        (the set-up with its pair plan and stored near blocks, the transposed pieces), so
        it costs no second set-up; it has its own recycled spaces and records, so that its
        products neither use nor feed this operator's kept directions (each product's
        cost stays its own, as a low fidelity's cost ratio needs), and those spaces count
        against this operator's Krylov budget (:attr:`krylov`).  This is how a low
        fidelity of the high's own order, e.g. ``p8e3`` beside ``p = 8, eps 1e-8``, is
        built: it differs from the high only by where GMRES stops.

        Raises
        ------
        ValueError
            If ``eps_gmres`` is not in (0, 1).
        """
        eps = check_tolerance(eps_gmres)
        twin = BimMobility.__new__(BimMobility)
        twin._assemble(self.setup, self.near, eps_gmres=eps, on_failure=self.on_failure,
                       maxiter=self.maxiter, recycle=self.recycle, krylov=self.krylov,
                       pieces=self.adjoint_pieces)
        return twin

    # ---- the pieces of the product -----------------------------------------------------------
    @property
    def adjoint_pieces(self) -> AdjointPieces:
        """The exact transposes of the pieces of the product (:mod:`.adjoint`), built
        on first use and shared with the twins."""
        if self._pieces is None:
            self._pieces = AdjointPieces(self.setup, self.near)
        return self._pieces

    def apply_bie(self, sigma: np.ndarray, rung: int = 0) -> np.ndarray:
        """``(1/2 I + K' + L) sigma + sum_j T_ij sigma_j`` for stacked densities, with the
        quadrature between spheres accurate to ``plan.quadrature.tolerance_ladder[rung]``."""
        out, coef = self.setup.apply_unblocked(sigma, rung)
        if coef is not None:
            out += self.near.apply(coef)
        return out.reshape(-1)

    def apply_preconditioned(self, y: np.ndarray, rung: int = 0) -> np.ndarray:
        """The preconditioned operator ``G y = apply_bie(P y)`` that GMRES solves with
        (:meth:`.setup.BimSetup.preconditioned_unblocked` says how it is made)."""
        out, coef = self.setup.preconditioned_unblocked(y, rung)
        if coef is not None:
            out += self.near.apply(coef)
        return out.reshape(-1)

    def precondition(self, y: np.ndarray) -> np.ndarray:
        """The one-body preconditioner ``P``."""
        return self.setup.precondition(y)

    def rhs(self, ft: np.ndarray) -> np.ndarray:
        """``B'(F, T)`` on every grid: stacked densities of length ``6 M p (p+1)``."""
        return self.setup.rhs(ft)

    def velocities(self, sigma: np.ndarray) -> np.ndarray:
        """Rigid velocities (M, 6) read off from stacked densities."""
        return self.setup.velocities(sigma)

    def _apply_pair(self, u_f: np.ndarray, u_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``G u_f`` and ``G' u_a`` (full accuracy), with one pass over the near blocks when
        the near part offers it (``near.fused``)."""
        pieces = self.adjoint_pieces
        if not self.near.fused:
            return self.apply_preconditioned(u_f), pieces.operator(u_a)
        out, coef = self.setup.preconditioned_unblocked(u_f)
        out_a, coef_bar, ob = pieces.apply_bie_unblocked(u_a)
        if coef is not None and coef_bar is not None:
            self.near.apply_both(coef, ob, coef_bar, out)
            out_a += dense_rows(coef_bar, pieces.analysis)
        return out.reshape(-1), pieces.precondition(out_a.reshape(-1))

    # ---- the solves ------------------------------------------------------------------------
    def solve_density(self, ft: np.ndarray) -> np.ndarray:
        """Solve the traction equation for forces and torques ``ft`` (length 6M)."""
        return self.precondition(self._solve_preconditioned(ft))

    def _solve_preconditioned(self, ft: np.ndarray, guess: np.ndarray | None = None
                              ) -> np.ndarray:
        """The solution ``y`` of ``G y = Bt ft`` (density ``P y``), from ``guess`` if given."""
        records = (self.gmres_iterations, self.residuals)
        b = self.rhs(ft)
        if float(np.linalg.norm(b)) == 0.0:
            self.solves.record("BIM GMRES", 0, 0.0, records)
            return np.zeros_like(b)
        space = self.solves.forward_space
        if space is not None:
            return self.solves.recycled_solve("BIM GMRES", space, b, records, x0=guess)
        y0 = (self.setup.unprecondition(self.precondition(b)) if guess is None
              else np.asarray(guess, dtype=float))
        return self.solves.solve("BIM GMRES", self.apply_preconditioned, b, y0,
                           len(self.plan.quadrature.dir_ranges), records)

    @on_one_blas_thread
    def solve_loads(self, ft: np.ndarray, guess: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
        """``(M ft, y)``: the product and the solution ``y`` of the preconditioned traction
        equation, started from ``guess`` (the ``y`` of a nearby configuration, e.g. the
        previous step's: the densities live on grids that move with the spheres).  The
        guess costs one product (its residual) and is dropped when that residual is not
        below the right-hand side.  ``ValueError`` for loads without 6M finite entries or
        a guess without ``3 N M`` finite ones."""
        ft = self._checked_loads(ft, "forces/torques")
        if guess is not None:
            guess = np.asarray(guess, dtype=float).reshape(-1)
            if guess.size != self.setup.unknowns or not np.isfinite(guess).all():
                raise ValueError(f"the guess has {guess.size} entries; the densities of "
                                 f"{self.M} spheres at p = {self.p} need {self.setup.unknowns} "
                                 "finite ones (pass None for no guess)")
        y = self._solve_preconditioned(ft, guess)
        return self.velocities(self.precondition(y)).reshape(-1), y

    def solve_adjoint(self, z: np.ndarray) -> np.ndarray:
        """Solve ``G' w = z`` by GMRES (tolerance ``eps_gmres``, same restart and maxiter as
        the forward solve, full accuracy) from a one-body start (``G' = I`` for one
        sphere) improved by the stored adjoint solutions; convergence is reported as in
        :meth:`solve_density`."""
        records = (self.adjoint_iterations, self.adjoint_residuals)
        z = np.asarray(z, dtype=float).reshape(-1)
        if float(np.linalg.norm(z)) == 0.0:
            self.solves.record("BIM adjoint GMRES", 0, 0.0, records)
            return np.zeros_like(z)
        space = self.solves.adjoint_space
        if space is not None:
            return self.solves.recycled_solve("BIM adjoint GMRES", space, z, records)
        pieces = self.adjoint_pieces
        return self.solves.solve("BIM adjoint GMRES", lambda v, k: pieces.operator(v), z,
                                 z.copy(), 1, records)

    # ---- products ----------------------------------------------------------------------------
    @on_one_blas_thread
    def _matvec(self, x: np.ndarray) -> np.ndarray:
        x = self._checked_loads(x, "forces/torques")
        sigma = self.solve_density(x)
        return self.velocities(sigma).reshape(-1)

    @on_one_blas_thread
    def _rmatvec(self, y: np.ndarray) -> np.ndarray:
        """Exact transpose of the discrete mobility: ``M' y = Bt' G^{-T} P' R' y``.

        The transpose holds to the GMRES tolerance times the conditioning (a dot-product
        test ``<y, M x> = <M' y, x>``; docs/mobility.md has the measured values).  Called
        by scipy's ``rmatvec``, ``A.T @ y`` and ``A.H @ y``.  Cost: one GMRES solve like the
        forward product, at full quadrature accuracy (no relaxation); no per-pair matrices
        (:mod:`.adjoint`).  With ``far="fmm"`` the FMM sum is transposed by fmm3dpy's
        stresslet FMM.  Iterations and residuals go to ``adjoint_iterations`` and
        ``adjoint_residuals``.

        Raises
        ------
        ValueError
            If ``y`` does not have 6M entries or contains NaN or inf.
        """
        y = self._checked_loads(y, "velocities passed to rmatvec")
        pieces = self.adjoint_pieces
        z = pieces.precondition(pieces.velocities(y))
        return pieces.rhs(self.solve_adjoint(z))

    @on_one_blas_thread
    def matvec_rmatvec(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(M x, M' y)``: the forward and the transposed product together.

        With recycling on (the default) the two solves run in lock step
        (:func:`.recycle.solve_together`), so that while both need products every
        round reads the stored near blocks once for both; the answers are those of
        ``matvec`` and ``rmatvec`` (same tolerance, same kept directions).  This is the
        product of the explicitly symmetrised contact operator (:mod:`..operators`).

        Raises
        ------
        ValueError
            If ``x`` or ``y`` does not have 6M finite entries.
        """
        x = self._checked_loads(x, "forces/torques")
        y = self._checked_loads(y, "velocities passed to rmatvec")
        fwd, adj = self.solves.forward_space, self.solves.adjoint_space
        if fwd is None or adj is None:
            return self._matvec(x), self._rmatvec(y)
        pieces = self.adjoint_pieces
        b = self.rhs(x)
        z = pieces.precondition(pieces.velocities(y))

        def apply_many(vs: list) -> list:
            if vs[0] is not None and vs[1] is not None:
                return list(self._apply_pair(vs[0], vs[1]))
            return [None if vs[0] is None else fwd.apply(vs[0]),
                    None if vs[1] is None else adj.apply(vs[1])]

        before = (fwd.products, adj.products)
        (yf, _, rf), (wa, _, ra) = solve_together([(fwd, b), (adj, z)], apply_many,
                                                  self.solve_tol, self.maxiter)
        self.solves.record("BIM GMRES", fwd.products - before[0], rf,
                     (self.gmres_iterations, self.residuals))
        self.solves.record("BIM adjoint GMRES", adj.products - before[1], ra,
                     (self.adjoint_iterations, self.adjoint_residuals))
        u = self.velocities(self.precondition(yf)).reshape(-1)
        return u, pieces.rhs(wa)

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
                 quad_tol: float | None = None,
                 krylov: KrylovBudget | float | None = None) -> BimMobility:
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
    krylov : KrylovBudget or float, optional
        Budget of the kept Krylov directions (see :class:`BimMobility`).

    Returns
    -------
    BimMobility
        A ``scipy.sparse.linalg.LinearOperator`` of shape (6M, 6M) mapping
        (F, T) per sphere to (U, Omega) per sphere; ``.gmres_iterations`` lists
        the iterations of every product.
    """
    return BimMobility(centers, radii, p=p, eps_gmres=eps_gmres, mu=mu, far=far,
                       quad_tol=quad_tol, krylov=krylov)
