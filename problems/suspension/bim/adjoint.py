"""Exact transposes of the pieces of the boundary-integral mobility (``BimMobility.rmatvec``).

The mobility is ``M = R P G^{-1} Bt`` with ``Bt`` = :meth:`.setup.BimSetup.rhs`, ``G v =
A_bie(P v)`` (``A_bie`` the traction operator, ``P`` the one-body preconditioner) and ``R``
the read-off of the rigid velocities, so ``M' = Bt' G^{-T} P' R'`` with ``G' = P' A_bie'``.
Every piece here is the exact transpose of the discrete forward piece at full accuracy:
the self operators and the read-off as dense per-sphere matrices, the near-field blocks by
their own ``add_transpose`` (:mod:`.blocks`, :mod:`.split`), the on-the-fly expansions, the
Faxen read-off and the direct sums by the transposed compiled kernels
(:mod:`.kernels_adjoint`), and the far field's own sum by its strategy
(:meth:`.farfield.FarField.add_transpose`; a stresslet FMM for the FMM).  The extra memory is one complex array of ``5 (p+1)^2`` coefficients per sphere, a few ``3N x 3N``
one-sphere matrices and index arrays, built on first use; no per-pair matrices.  The pieces
read the shared :class:`.setup.BimSetup`; they hold no reference to an operator.
"""

from __future__ import annotations

import numpy as np

from .farfield import group_ranges
from .kernels import PARALLEL_WORK, dense_rows
from .kernels_adjoint import (
    center_readout_adjoint,
    direct_traction_adjoint,
    direct_traction_adjoint_serial,
    traction_expansion_adjoint,
)
from .pairs import csr
from .setup import BimSetup
from .sphere_vsh import SphereGrid, coefficient_matrix, sphere_grid

__all__ = ["AdjointPieces"]


class AdjointPieces:
    """Transposed pieces of the operator on one :class:`.setup.BimSetup` (structures built
    once).

    Parameters
    ----------
    setup : BimSetup
        The shared set-up; its pair plan is reused as it is.
    near : StoredBlocks or SplitBlocks
        The near-field part of the operator whose transpose this is.
    """

    def __init__(self, setup: BimSetup, near) -> None:
        self.setup, self.near = setup, near
        plan = setup.plan
        so = setup.self_ops
        self.self_block = np.ascontiguousarray(so.Kp + so.L)
        self.precond = np.ascontiguousarray(so.precond)
        self.analysis = np.ascontiguousarray(setup.basis.A)
        self.read = np.ascontiguousarray(setup.readout)
        self.proj = None if plan.near_proj is None else np.ascontiguousarray(plan.near_proj)
        quad = plan.quadrature
        self.synth = [None if S is None else np.ascontiguousarray(S.T) for S in quad.synth]
        self.tgt = tuple(np.ascontiguousarray(a[:, k]) for a in (setup.tgt_pts, setup.tgt_nrm)
                         for k in range(3))
        Cm = coefficient_matrix(setup.p)                        # (3N, 5 (p+1)^2), D = s @ Cm
        self.coef = np.ascontiguousarray(np.vstack([Cm.T.real, -Cm.T.imag]))
        # direct sums at full accuracy (rung 0), grouped by source range
        self.direct = group_ranges(*quad.dir_ranges[0], plan.N) if quad.n_src else None
        # on-the-fly expansion pairs, by source sphere
        self.fly = [self._fly_group(ptr, idx, grid, projected) for ptr, idx, grid, projected in (
            (plan.expansions.fly_ptr, plan.expansions.fly_idx, plan.near_grid,
             plan.near_proj is not None),
            (plan.expansions.flyn_ptr, plan.expansions.flyn_idx, plan.grid, False)) if idx.size]

    def _fly_group(self, ptr: np.ndarray, idx: np.ndarray, grid: SphereGrid,
                   projected: bool) -> dict:
        """Structures of one group of on-the-fly expansion pairs (target lists ``ptr``/``idx``)
        evaluated on ``grid``: target points and pairs by source sphere."""
        op = self.setup
        tgt_i = np.nonzero(np.diff(ptr))[0]
        nodes = grid.nodes
        lists: list[list[int]] = [[] for _ in range(op.M)]
        for b, i in enumerate(tgt_i):
            for j in idx[ptr[i]:ptr[i + 1]]:
                lists[j].append(b)
        src_ptr, blk = csr(lists)
        pts = op.centers[tgt_i, None, :] + op.radii[tgt_i, None, None] * nodes[None]
        return {"tgt": tgt_i, "size": grid.size, "ptr": src_ptr, "blk": blk,
                "projected": projected,
                "pts": np.ascontiguousarray(pts.reshape(-1, 3)),
                "nrm": np.ascontiguousarray(np.tile(nodes, (tgt_i.size, 1)))}

    def _expansion(self, Dbar: np.ndarray) -> np.ndarray:
        """Transpose of :func:`sphere_vsh.expansion_coefficients`: complex adjoint
        coefficients (M, 5, p+1, p+1) -> grid densities (M, 3N)."""
        flat = Dbar.reshape(self.setup.M, -1)
        return dense_rows(np.hstack([flat.real, flat.imag]), self.coef)

    def _near_on_the_fly(self, ob: np.ndarray) -> np.ndarray:
        """Transpose of the on-the-fly expansion pairs of the forward product (projected
        zone and node-sampled pairs beyond it) for adjoint tractions ``ob`` (M, 3N)."""
        op = self.setup
        p = op.p
        Dbar = np.zeros((op.M, 5, p + 1, p + 1), dtype=np.complex128)
        for g in self.fly:
            tb = ob[g["tgt"]]
            if g["projected"]:
                assert self.proj is not None
                tb = dense_rows(tb, self.proj)
            traction_expansion_adjoint(g["pts"], g["nrm"], g["size"], g["ptr"], g["blk"],
                                       op.centers, op.radii,
                                       np.ascontiguousarray(tb.reshape(-1, 3)), p, Dbar)
        return self._expansion(Dbar)

    def _source_forces(self, f_bar: list[np.ndarray], s_bar: np.ndarray,
                       coef_bar: np.ndarray) -> None:
        """Transpose of the forward source forces: adds the adjoint point forces to the
        densities ``s_bar`` (native levels) and to the VSH coefficients ``coef_bar``."""
        plan = self.setup.plan
        for L, q in enumerate(plan.quadrature.levels):
            J = plan.quadrature.lvl_spheres[L]
            if J.size == 0:
                continue
            b0 = plan.quadrature.lvl_base[L]
            nq = sphere_grid(q).size
            Fb = np.stack([f[b0:b0 + J.size * nq] for f in f_bar], axis=1).reshape(J.size, nq, 3)
            Fb = (Fb * plan.quadrature.src_scale[L][:, :, None]).reshape(J.size, 3 * nq)
            S = self.synth[L]
            if S is None:
                s_bar[J] += Fb
            else:
                coef_bar[J] += dense_rows(Fb, S)

    def apply_bie(self, w: np.ndarray) -> np.ndarray:
        """Transpose of the traction operator ``A_bie`` at full accuracy (rung 0).  The far
        field's sum is transposed by its strategy (:mod:`.farfield`): with the FMM by a
        stresslet FMM at the same tolerance, the native-grid pairs the forward product
        removes removed by transposed direct sums, so the adjoint matches the forward to
        the FMM tolerance."""
        out, coef_bar, ob = self.apply_bie_unblocked(w)
        if coef_bar is not None:
            self.near.add_transpose(ob, coef_bar)
            out += dense_rows(coef_bar, self.analysis)
        return out.reshape(-1)

    def apply_bie_unblocked(self, w: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """:meth:`apply_bie` without the stored blocks and the final synthesis:
        ``(out, coef_bar, ob)`` with ``out`` of shape ``(M, 3N)``, ``coef_bar`` the adjoint
        VSH coefficients gathered so far (None for one sphere; the caller adds the blocks'
        share and then ``coef_bar @ analysis`` to ``out``) and ``ob = w`` as ``(M, 3N)``."""
        op, plan = self.setup, self.setup.plan
        M, N = op.M, plan.N
        ob = np.ascontiguousarray(np.asarray(w, dtype=float).reshape(M, 3 * N))
        out = dense_rows(ob, self.self_block)
        coef_bar = None
        if M > 1:
            coef_bar = np.zeros((M, self.analysis.shape[0]))
            if plan.expansions.fly_idx.size or plan.expansions.flyn_idx.size:
                out += self._near_on_the_fly(ob)
            if plan.quadrature.n_src:
                tb = ob.reshape(M * N, 3)
                tbc = tuple(np.ascontiguousarray(tb[:, k]) for k in range(3))
                f_bar = [np.zeros(plan.quadrature.n_src) for _ in range(3)]
                g = self.direct
                assert g is not None                    # set whenever there are sources
                if g["start"].size:
                    fn = (direct_traction_adjoint if g["work"] > PARALLEL_WORK
                          else direct_traction_adjoint_serial)
                    fn(*self.tgt, *tbc, N, g["ptr"], g["tgt"], g["start"], g["stop"],
                       *plan.quadrature.src_xyz, *f_bar, False)
                op.far_field.add_transpose(op, tb, self.tgt, f_bar)
                self._source_forces(f_bar, out, coef_bar)
        return out, coef_bar, ob

    def precondition(self, z: np.ndarray) -> np.ndarray:
        """Transpose of the one-body preconditioner ``P``."""
        return dense_rows(z.reshape(self.setup.M, -1), self.precond).reshape(-1)

    def operator(self, v: np.ndarray) -> np.ndarray:
        """``G' v = P' A_bie' v``, the transpose of the preconditioned GMRES operator."""
        return self.precondition(self.apply_bie(v))

    def velocities(self, u: np.ndarray) -> np.ndarray:
        """Transpose of :meth:`.setup.BimSetup.velocities`: rigid velocities (M, 6) ->
        stacked densities.

        The self read-off is a dense (6, 3N) matrix per sphere; the Faxen read-off of the
        other spheres' expansions is transposed by a compiled kernel
        (:func:`kernels_adjoint.center_readout_adjoint`), no per-pair matrices are stored."""
        op = self.setup
        M, p = op.M, op.p
        u = np.ascontiguousarray(np.asarray(u, dtype=float).reshape(M, 6))
        us = np.empty((M, 6))
        us[:, :3] = u[:, :3] * (op.radii / op.mu)[:, None]
        us[:, 3:] = u[:, 3:] / op.mu
        s = dense_rows(us, self.read)
        if M > 1:
            Dbar = np.zeros((M, 5, p + 1, p + 1), dtype=np.complex128)
            center_readout_adjoint(op.centers, op.radii, u, p, op.mu, Dbar)
            s += self._expansion(Dbar)
        return s.reshape(-1)

    def rhs(self, w: np.ndarray) -> np.ndarray:
        """Transpose of :meth:`.setup.BimSetup.rhs`: stacked densities -> (F, T) per sphere
        (length 6M)."""
        op = self.setup
        w = np.asarray(w, dtype=float).reshape(op.M, op.plan.N, 3)
        a = op.radii[:, None]
        out = np.empty((op.M, 6))
        out[:, :3] = w.sum(axis=1) / (4 * np.pi * a ** 2)
        out[:, 3:] = 3.0 * np.cross(op.plan.grid.nodes[None], w).sum(axis=1) / (8 * np.pi * a ** 3)
        return out.reshape(-1)
