"""The set-up of the boundary-integral mobility and the forward pieces built on it.

:class:`BimSetup` is everything that depends only on the configuration and the order: the
grids, the one-sphere operators and preconditioner, the target points, and the pair plan
(:mod:`.pairs`).  It is built once per configuration and shared, by composition, by the
forward operator, its transpose (:mod:`.adjoint`), its twins at other GMRES tolerances and
the distance-split low fidelity (:mod:`.split`): none of them copies it.

Its methods are the forward pieces of ``M = R P G^{-1} Bt`` that do not involve the
stored near-field blocks (those are :mod:`.blocks` or the split's own): the right-hand side
``Bt`` (:meth:`BimSetup.rhs`), the read-off ``R`` (:meth:`BimSetup.velocities`), the
one-body preconditioner ``P`` and the traction operator without the blocks
(:meth:`BimSetup.apply_unblocked`).
"""

from __future__ import annotations

import numpy as np

from ..geometry import check_configuration, check_no_overlap, check_order, check_viscosity
from .farfield import FarField, far_field
from .kernels import (
    PARALLEL_WORK,
    center_readout,
    dense_rows,
    direct_traction_ranges,
    direct_traction_ranges_serial,
    synthesize_forces,
    synthesize_forces_serial,
    traction_expansion,
)
from .pairs import Grids, PairPlan
from .sphere_vsh import (
    expansion_coefficients,
    projection_matrix,
    self_operators,
    sphere_grid,
    vsh_basis,
)

__all__ = ["BimSetup", "NEAR_UPSAMPLE"]

NEAR_UPSAMPLE = 2.0
"""The traction of a pair in the projected zone is evaluated on the grid of order
``ceil(NEAR_UPSAMPLE * p)`` and projected onto degree p; 1 is plain node sampling (the
measured choice of the factor: docs/mobility.md, "Projected near field")."""


class BimSetup:
    """Grids, one-sphere operators and pair plan of one configuration at order ``p``.

    Parameters
    ----------
    centers : array_like, shape (M, 3)
    radii : float or array_like, shape (M,)
    p : int
        Spherical-harmonic order; ``6 p (p+1)`` unknowns per sphere.
    mu : float
        Viscosity.
    quad_tol : float
        Accuracy (per unit density) of the quadrature between spheres, in (0, 1).
    far : {"direct", "fmm", "auto"}
        Far-field engine (``auto``: :func:`.fmm.resolve_far`, by the number of spheres);
        :attr:`far` is the engine used, :attr:`far_field` its strategy
        (:mod:`.farfield`), which owns its forward and transposed sums.
    near_upsample : float
        Order of the near-field target grid in units of p (>= 1).
    near_block_mb : float
        Memory budget (MB) of the stored near-field blocks.
    pair_blocks : {"direct", "table", "table-all"}
        How the stored blocks are built: every block directly (the reference),
        projected-zone pairs of equal radii from the coaxial table and rotations
        (:mod:`.coaxial`, assembled), or every equal-radius pair from the table, kept in
        rotated form ("table-all", the default; see :meth:`.pairs.PairPlan._build_blocks`).

    Raises
    ------
    ValueError
        A bad configuration (overlapping spheres included) or a bad parameter.
    """

    def __init__(self, centers, radii, *, p: int, mu: float, quad_tol: float,
                 far: str = "direct", near_upsample: float = NEAR_UPSAMPLE,
                 near_block_mb: float = 4096.0, pair_blocks: str = "table-all") -> None:
        c, r = check_configuration(centers, radii)
        self.p = check_order(p)
        self.mu = check_viscosity(mu)
        check_no_overlap(c, r, "bim")
        self.far_field: FarField = far_field(far, c.shape[0])
        if not (np.isfinite(quad_tol) and 0 < quad_tol < 1):
            raise ValueError(f"quad_tol = {quad_tol!r} must be a number in (0, 1), e.g. 1e-10 "
                             "(accuracy of the quadrature between spheres)")
        try:
            up = float(near_upsample)
        except (TypeError, ValueError):
            up = float("nan")
        if isinstance(near_upsample, bool) or not (np.isfinite(up) and up >= 1):
            raise ValueError(f"near_upsample = {near_upsample!r} must be a number >= 1 (order of "
                             "the near-field target grid in units of p; 1 = sample at the nodes)")
        self.quad_tol, self.near_upsample = float(quad_tol), up
        self.near_block_mb = float(near_block_mb)
        self.centers, self.radii, self.M = c, r, c.shape[0]
        self._one_sphere()
        q_near = max(self.p, int(np.ceil(up * self.p - 1e-9)))
        near_grid = sphere_grid(q_near)
        near_proj = None if q_near == self.p else projection_matrix(self.p, q_near)
        self.plan = PairPlan(c, r, Grids(self.p, self.grid, near_grid, near_proj, self.basis),
                             quad_tol=self.quad_tol, far=self.far_field,
                             near_block_mb=self.near_block_mb, pair_blocks=pair_blocks)

    @property
    def far(self) -> str:
        """The far-field engine used, ``"direct"`` or ``"fmm"`` (:attr:`far_field`)."""
        return self.far_field.name

    def _one_sphere(self) -> None:
        """The grid, the one-sphere operators and the target points of every sphere."""
        c, r, M = self.centers, self.radii, self.M
        self.self_ops = self_operators(self.p)
        self.grid = sphere_grid(self.p)
        self.N = self.grid.size
        nodes = self.grid.nodes
        self.tgt_pts = np.ascontiguousarray((c[:, None, :] + r[:, None, None] * nodes[None])
                                            .reshape(-1, 3))
        self.tgt_nrm = np.ascontiguousarray(np.tile(nodes, (M, 1)))
        self.tgt_sphere = np.repeat(np.arange(M, dtype=np.int64), self.N)
        self.self_block = np.ascontiguousarray((self.self_ops.Kp + self.self_ops.L).T)
        self.precond_T = np.ascontiguousarray(self.self_ops.precond.T)
        self.readout = self.self_ops.readout @ self.self_ops.S     # (6, 3N) unit sphere
        self.basis = vsh_basis(self.p)
        self.analysis_T = np.ascontiguousarray(self.basis.A.T)
        # coefficients of the preconditioned density P y in one product: y @ P' A'
        self.precond_analysis_T = np.ascontiguousarray(self.precond_T @ self.analysis_T)

    @property
    def unknowns(self) -> int:
        """Length of the stacked densities, ``3 N M``."""
        return self.M * 3 * self.N

    # ---- right-hand side, read-off and preconditioner -----------------------------------
    def rhs(self, ft: np.ndarray) -> np.ndarray:
        """``B'(F, T)`` on every grid: stacked densities of length ``6 M p (p+1)``."""
        ft = np.asarray(ft, dtype=float).reshape(self.M, 6)
        nodes = self.grid.nodes
        a = self.radii[:, None, None]
        b = (ft[:, None, :3] / (4 * np.pi * a ** 2)
             + 3.0 * np.cross(ft[:, None, 3:], nodes[None]) / (8 * np.pi * a ** 3))
        return b.reshape(-1)

    def velocities(self, sigma: np.ndarray) -> np.ndarray:
        """Rigid velocities (M, 6) read off from stacked densities."""
        M, N = self.M, self.N
        s = sigma.reshape(M, 3 * N)
        ro = s @ self.readout.T                       # unit sphere, mu = 1
        out = np.empty((M, 6))
        out[:, :3] = ro[:, :3] * (self.radii / self.mu)[:, None]
        out[:, 3:] = ro[:, 3:] / self.mu
        if M > 1:
            D = expansion_coefficients(self.p, s)
            center_readout(self.centers, self.radii, D, self.p, self.mu, out)
        return out

    def precondition(self, y: np.ndarray) -> np.ndarray:
        """The one-body preconditioner ``P`` (the inverse of each sphere's self operator)."""
        return dense_rows(y.reshape(self.M, -1), self.precond_T).reshape(-1)

    def unprecondition(self, sigma: np.ndarray) -> np.ndarray:
        """Each sphere's self operator ``P^{-1}``."""
        return dense_rows(sigma.reshape(self.M, -1), self.self_block).reshape(-1)

    # ---- the traction operator without the stored blocks --------------------------------
    def preconditioned_unblocked(self, y: np.ndarray, rung: int = 0
                                 ) -> tuple[np.ndarray, np.ndarray | None]:
        """``G y = A_bie(P y)`` without the stored blocks: ``(out, coef)`` as
        :meth:`apply_unblocked` gives them for ``P y``.

        ``P`` inverts the one-sphere operator, so the self part of ``G`` is the identity:
        ``G y = y + sum_j T_ij (P y)_j``, one per-sphere product fewer than applying the self
        operator to ``P y``; when every pair has a stored block the blocks need only the
        coefficients of ``P y``, one product with ``P' A'`` (the same values to rounding)."""
        M, N, plan = self.M, self.N, self.plan
        x = np.ascontiguousarray(y.reshape(M, 3 * N))
        if M == 1:
            return x.copy(), None
        if plan.expansions.fly_idx.size or plan.expansions.flyn_idx.size or plan.quadrature.n_src:
            out, coef = self.apply_unblocked(dense_rows(x, self.precond_T), rung,
                                             self_part=False)
            return out + x, coef
        return x.copy(), dense_rows(x, self.precond_analysis_T)

    def apply_unblocked(self, sigma: np.ndarray, rung: int = 0, self_part: bool = True
                        ) -> tuple[np.ndarray, np.ndarray | None]:
        """``(1/2 I + K' + L) sigma + sum_j T_ij sigma_j`` without the stored near blocks
        (and without the one-sphere operator when ``self_part`` is False), with the
        quadrature between spheres accurate to ``plan.quadrature.tolerance_ladder[rung]``.

        Returns ``(out, coef)``: ``out`` of shape ``(M, 3N)`` and ``coef`` the VSH
        coefficients the blocks act on (None for one sphere)."""
        M, N, p, plan = self.M, self.N, self.p, self.plan
        s = np.ascontiguousarray(sigma.reshape(M, 3 * N))
        out = dense_rows(s, self.self_block) if self_part else np.zeros((M, 3 * N))
        coef = None
        if M > 1:
            coef = dense_rows(s, self.analysis_T)
            trac = np.zeros((M * N, 3))
            if plan.expansions.fly_idx.size:
                out += self._near_on_the_fly(s)
            if plan.expansions.flyn_idx.size:                  # expansion pairs beyond the zone
                traction_expansion(self.tgt_pts, self.tgt_nrm, self.tgt_sphere,
                                   plan.expansions.flyn_ptr, plan.expansions.flyn_idx,
                                   self.centers, self.radii,
                                   expansion_coefficients(p, s), p, trac)
            if plan.quadrature.n_src:
                self._direct_sums(s, coef, rung, trac)
            out += trac.reshape(M, 3 * N)
        return out, coef

    def _direct_sums(self, s: np.ndarray, coef: np.ndarray, rung: int,
                     trac: np.ndarray) -> None:
        """Adds the direct quadrature between spheres and the far field's own sum
        (:meth:`.farfield.FarField.add_forward`) to ``trac``."""
        N, plan = self.N, self.plan
        f = self._source_forces(s, coef)
        ranges = plan.quadrature.dir_ranges
        ptr, start, stop = ranges[min(rung, len(ranges) - 1)]
        if stop.size:
            work = N * int((stop - start).sum())
            fn = (direct_traction_ranges if work > PARALLEL_WORK
                  else direct_traction_ranges_serial)
            fn(self.tgt_pts, self.tgt_nrm, self.tgt_sphere,
               ptr, start, stop, *plan.quadrature.src_xyz, *f, trac, False)
        self.far_field.add_forward(self, f, trac)

    def _source_forces(self, s: np.ndarray, coef: np.ndarray) -> list[np.ndarray]:
        """Point forces (density times weight) at every source level, as three arrays;
        upsampled levels are synthesised from the VSH coefficients ``coef``."""
        plan = self.plan
        f = [np.empty(plan.quadrature.n_src) for _ in range(3)]
        for L, _q in enumerate(plan.quadrature.levels):
            J = plan.quadrature.lvl_spheres[L]
            if J.size == 0:
                continue
            b0 = plan.quadrature.lvl_base[L]
            S = plan.quadrature.synth[L]
            if S is None:
                nq = self.N
                F = s[J].reshape(J.size, nq, 3) * plan.quadrature.src_scale[L][:, :, None]
                for k in range(3):
                    f[k][b0:b0 + J.size * nq] = F[:, :, k].reshape(-1)
            else:
                fn = (synthesize_forces if J.size * S.size > PARALLEL_WORK
                      else synthesize_forces_serial)
                fn(coef, J, S, plan.quadrature.src_scale[L], b0, *f)
        return f

    def _near_on_the_fly(self, s: np.ndarray) -> np.ndarray:
        """Near-field traction of the projected-zone expansion pairs without a stored
        block: evaluated on the finer grid of every sphere that has such pairs and
        projected onto degree p (the same values a stored block gives)."""
        M, N, p, plan = self.M, self.N, self.p, self.plan
        nodes = plan.near_grid.nodes
        Nq = nodes.shape[0]
        tgt_i = np.nonzero(np.diff(plan.expansions.fly_ptr))[0]
        pts = (self.centers[tgt_i, None, :] + self.radii[tgt_i, None, None] * nodes[None])
        trac = np.zeros((tgt_i.size * Nq, 3))
        traction_expansion(np.ascontiguousarray(pts.reshape(-1, 3)),
                           np.ascontiguousarray(np.tile(nodes, (tgt_i.size, 1))),
                           np.repeat(tgt_i, Nq).astype(np.int64),
                           plan.expansions.fly_ptr, plan.expansions.fly_idx,
                           self.centers, self.radii, expansion_coefficients(p, s), p, trac)
        out = np.zeros((M, 3 * N))
        trac = trac.reshape(tgt_i.size, 3 * Nq)
        out[tgt_i] = (trac if plan.near_proj is None
                      else dense_rows(trac, np.ascontiguousarray(plan.near_proj.T)))
        return out
