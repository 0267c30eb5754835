"""A distance-split low fidelity: the p = 8 near field, a truncated far field, a loose GMRES.

Usage::

    python benchmarks/far_truncation.py                           # q = 3, 4, 6 beyond gap 0.5
    python benchmarks/far_truncation.py --q 4 6 --near-gap 0.5 1.5 --eps 1e-3 1e-4

The low keeps the high fidelity's own discretisation and set-up (p = 8 densities, its stored
near-field blocks, its self operators and preconditioner) and changes two things: pairs at
a gap of at least ``--near-gap`` interact only through the source density's vector spherical
harmonics of degree <= q, and the target traction they produce is projected onto degree
<= q (a ``nv(q) x nv(q)`` block instead of ``3N x nv(p)``); GMRES stops at ``--eps``. The
script forms the low densely and prints its relative 2-norm error against the high contact
matrix, the GMRES products of one cold product against the high's, and the block work per
product relative to the high's (multiply-adds of the near-field blocks, which are most of
the work of a product at these sizes). The last column, iterations ratio times work ratio,
is the cost ratio the split would reach if its blocks ran as fast as the high's per
multiply-add: a bound from below for this prototype, not a timing.
"""

from __future__ import annotations

import argparse

import numpy as np
import scipy.sparse as sp

from common import packed_lattice
from low_fidelity import build, dense_sym

from lcpbench.problems.suspension.bim import BimMobility
from lcpbench.problems.suspension.bim_recycle import RecycledGCR
from lcpbench.problems.suspension.kernels import apply_blocks


class SplitFarField:
    """The mobility of ``high`` with far pairs truncated at degree ``q``, solved to ``eps``."""

    def __init__(self, high: BimMobility, q: int, near_gap: float, eps: float):
        self.high, self.eps = high, eps
        plan, basis = high.plan, high.basis
        c, r = high.centers, high.radii
        gap = np.linalg.norm(c[:, None] - c[None], axis=2) - r[:, None] - r[None, :]
        tgt, src = plan.block_tgt, plan.block_src
        if plan.n_far_pairs:
            raise ValueError("every pair must have a stored block (raise near_block_mb)")
        near = gap[tgt, src] < near_gap
        full, cut = np.nonzero(near)[0], np.nonzero(~near)[0]
        sel = np.nonzero(basis.degree <= q)[0]
        self.E = np.ascontiguousarray(plan.blocks[full])
        self.ptr = np.searchsorted(tgt[full], np.arange(high.M + 1)).astype(np.int64)
        self.src = np.ascontiguousarray(src[full])
        self.sel = sel
        self.C = np.einsum("ik,bkj->bij", basis.A[sel], plan.blocks[cut][:, :, sel])
        self.cut_src = src[cut]
        self.to_target = sp.csr_matrix((np.ones(cut.size), (tgt[cut], np.arange(cut.size))),
                                       shape=(high.M, cut.size))
        self.synth = np.ascontiguousarray(basis.B[:, sel].T)
        self.work = (self.E.size + self.C.size) / plan.blocks.size
        n = high.M * 3 * high._N
        self.gcr = RecycledGCR(lambda v: self.apply(high._precondition(v)), n, 0)
        self.iterations: list[int] = []

    def apply(self, sigma: np.ndarray) -> np.ndarray:
        h = self.high
        s = np.ascontiguousarray(sigma.reshape(h.M, -1))
        out = s @ h._self_block
        coef = np.ascontiguousarray(s @ h._analysis_T)
        apply_blocks(self.E, self.ptr, self.src, coef, out)
        far = np.einsum("bij,bj->bi", self.C, coef[:, self.sel][self.cut_src])
        out += (self.to_target @ far) @ self.synth
        return out.reshape(-1)

    def matvec(self, ft: np.ndarray) -> np.ndarray:
        h = self.high
        y, new, _res = self.gcr.solve(h.rhs(ft), self.eps, 500)
        self.iterations.append(new)
        return h.velocities(h._precondition(y)).reshape(-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="lattice", help="lattice (0.1a) or paper-lattice (0.3a)")
    ap.add_argument("--m", type=int, default=3)
    ap.add_argument("--pack", type=int, default=40, help="RPY steps before the measurement")
    ap.add_argument("--q", type=int, nargs="+", default=[3, 4, 6])
    ap.add_argument("--near-gap", type=float, nargs="+", default=[0.5])
    ap.add_argument("--eps", type=float, nargs="+", default=[1e-3, 1e-4])
    args = ap.parse_args()
    scene = packed_lattice(args.m, args.pack, args.scene)
    prob = build(scene, [], 8, 1e-8)
    A = dense_sym(prob.lcp.A)
    nA = np.linalg.norm(A, 2)
    D, Dt = prob.contacts.D, prob.contacts.D.T.tocsr()
    high = BimMobility(scene.centers, scene.radii, p=8, eps_gmres=1e-8)
    v = np.linspace(1.0, 2.0, 6 * high.M)
    high @ v
    its_high = high.gmres_iterations[0]
    print(f"{args.scene} m = {args.m}: n = {prob.lcp.n}; high: {its_high} GMRES products cold")
    print("| q | near gap | eps | rel. 2-norm error | products cold | block work | bound |")
    print("|---|---|---|---|---|---|---|")
    for q in args.q:
        for g in args.near_gap:
            for eps in args.eps:
                low = SplitFarField(high, q, g, eps)
                low.matvec(v)
                its = low.iterations[0]
                cols = [Dt @ low.matvec(D @ e) for e in np.eye(prob.lcp.n)]
                L = np.column_stack(cols)
                err = np.linalg.norm(0.5 * (L + L.T) - A, 2) / nA
                bound = its / its_high * low.work
                print(f"| {q} | {g:g} | {eps:g} | {err:.3g} | {its} | {low.work:.3f} | "
                      f"{bound:.3f} |", flush=True)


if __name__ == "__main__":
    main()
