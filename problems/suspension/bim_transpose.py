"""The transposed product of the boundary-integral mobility and both products at once.

:class:`TransposedProducts` gives :class:`bim.BimMobility` its ``rmatvec`` (``M' = Bt'
G^{-T} P' R'``, every piece transposed exactly by :mod:`bim_adjoint` and ``G'`` solved by
the same GMRES at full accuracy) and ``matvec_rmatvec``, the forward and transposed
products in lock step, which read the stored near blocks once per round for both
(the product of the explicitly symmetrised contact operator, :mod:`.contacts`).  It is a
mixin: it uses the forward operator's set-up (``plan``, the preconditioner, the
recyclers, ``_solve`` and ``_record``) and keeps the adjoint's own state
(``_pieces``, ``adjoint_iterations``, ``adjoint_residuals``) on the same object.
"""

from __future__ import annotations

import numpy as np

from lcpbench.toolkit.blas import on_one_blas_thread

from .bim_adjoint import AdjointPieces
from .bim_recycle import solve_together
from .kernels import PARALLEL_WORK, dense_rows
from .kernels_adjoint import apply_blocks_both, apply_blocks_both_serial

__all__ = ["TransposedProducts"]


class TransposedProducts:
    """The transposed and the paired products of :class:`bim.BimMobility` (a mixin)."""

    # ---- both products at once -----------------------------------------------------------
    def _apply_pair(self, u_f: np.ndarray, u_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``G u_f`` and ``G' u_a`` (the preconditioned operator and its transpose, full
        accuracy) with one pass over the stored near blocks, which bound the cost of a
        product by memory traffic when they are many."""
        pieces = self.adjoint_pieces
        out, coef = self._preconditioned_unblocked(u_f)
        out_a, coef_bar, ob = pieces.apply_bie_unblocked(u_a)
        plan = self.plan
        if coef is not None and coef_bar is not None:
            if plan.n_block_pairs:
                part = np.empty((plan.block_src.size, coef.shape[1]))
                fn = (apply_blocks_both if plan.blocks.size > PARALLEL_WORK
                      else apply_blocks_both_serial)
                acc = np.zeros((self.M, plan.blocks.shape[1]))
                fn(plan.blocks, plan.block_ptr, plan.block_src, coef, acc,
                   dense_rows(ob, plan.block_synth_T), part)
                out += dense_rows(acc, plan.block_synth)
                coef_bar += pieces.by_source @ part
            out_a += dense_rows(coef_bar, pieces.analysis)
        return out.reshape(-1), pieces.precondition(out_a.reshape(-1))

    @on_one_blas_thread
    def matvec_rmatvec(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(M x, M' y)``: the forward and the transposed product together.

        With recycling on (the default) the two solves run in lock step
        (:func:`bim_recycle.solve_together`), so that while both need products every
        round reads the stored near blocks once for both; the answers are those of
        ``matvec`` and ``rmatvec`` (same tolerance, same kept directions).  This is the
        product of the explicitly symmetrised contact operator (:mod:`.contacts`).

        Raises
        ------
        ValueError
            If ``x`` or ``y`` does not have 6M finite entries.
        """
        x = self._checked_loads(x, "forces/torques")
        y = self._checked_loads(y, "velocities passed to rmatvec")
        if self._recycler is None or self._adj_recycler is None:
            return self._matvec(x), self._rmatvec(y)
        pieces = self.adjoint_pieces
        b = self.rhs(x)
        z = pieces.precondition(pieces.velocities(y))
        fwd, adj = self._recycler, self._adj_recycler

        def apply_many(vs: list) -> list:
            if vs[0] is not None and vs[1] is not None:
                return list(self._apply_pair(vs[0], vs[1]))
            return [None if vs[0] is None else fwd.apply(vs[0]),
                    None if vs[1] is None else adj.apply(vs[1])]

        before = (fwd.products, adj.products)
        (yf, _, rf), (wa, _, ra) = solve_together([(fwd, b), (adj, z)], apply_many,
                                                  self.eps_gmres, self.maxiter)
        self._record("BIM GMRES", fwd.products - before[0], rf, self.gmres_iterations,
                     self.residuals)
        self._record("BIM adjoint GMRES", adj.products - before[1], ra,
                     self.adjoint_iterations, self.adjoint_residuals)
        u = self.velocities(self._precondition(yf)).reshape(-1)
        return u, pieces.rhs(wa)

    # ---- the transposed (adjoint) product ------------------------------------------------
    @property
    def adjoint_pieces(self) -> AdjointPieces:
        """The exact transposes of the pieces of the product (:mod:`bim_adjoint`), built
        on first use."""
        if self._pieces is None:
            self._pieces = AdjointPieces(self)
        return self._pieces

    def solve_adjoint(self, z: np.ndarray) -> np.ndarray:
        """Solve ``G' w = z`` by GMRES (tolerance ``eps_gmres``, same restart and maxiter as
        the forward solve, full accuracy) from a one-body start (``G' = I`` for one
        sphere) improved by the stored adjoint solutions; convergence is reported as in
        :meth:`solve_density`."""
        z = np.asarray(z, dtype=float).reshape(-1)
        if float(np.linalg.norm(z)) == 0.0:
            self.adjoint_iterations.append(0)
            self.adjoint_residuals.append(0.0)
            return np.zeros_like(z)
        if self._adj_recycler is not None:
            return self._recycled_solve("BIM adjoint GMRES", self._adj_recycler, z,
                                        self.adjoint_iterations, self.adjoint_residuals)
        pieces = self.adjoint_pieces
        return self._solve("BIM adjoint GMRES", lambda v, k: pieces.operator(v), z, z.copy(), 1,
                           self.adjoint_iterations, self.adjoint_residuals)

    @on_one_blas_thread
    def _rmatvec(self, y: np.ndarray) -> np.ndarray:
        """Exact transpose of the discrete mobility: ``M' y = Bt' G^{-T} P' R' y``.

        The discrete map is symmetric only to about 1e-3; this is its transpose to the
        GMRES tolerance (a dot-product test ``<y, M x> = <M' y, x>`` holds to about
        ``eps_gmres`` times the conditioning: 1e-12 for eps_gmres = 1e-12 on the test
        clusters, 1e-8 on the packed 27-sphere lattice at eps_gmres = 1e-8).  Called by
        scipy's ``rmatvec``, ``A.T @ y`` and ``A.H @ y``.

        Cost: one GMRES solve like the forward product, at full quadrature accuracy
        (no relaxation), about the forward time.  Memory: no per-pair matrices
        (:mod:`bim_adjoint`).  With ``far="fmm"`` the FMM sum is transposed by fmm3dpy's
        stresslet FMM (the traction kernel of a point force, read as a function of the
        source, is a stresslet).  Iterations and residuals go to ``adjoint_iterations``
        and ``adjoint_residuals``.

        Raises
        ------
        ValueError
            If ``y`` does not have 6M entries or contains NaN or inf.
        """
        y = self._checked_loads(y, "velocities passed to rmatvec")
        pieces = self.adjoint_pieces
        z = pieces.precondition(pieces.velocities(y))
        return pieces.rhs(self.solve_adjoint(z))
