"""The boundary-integral Stokes mobility of rigid spheres (``model="bim"``).

The module map (the one map of this package: docs/mobility.md and docs/architecture.md point
here).  A module imports only modules below its own group or later in its own group, never one
above; ``tests/test_code_shape.py`` checks that there is no import circle.

The operators

* :mod:`.split`: the distance-split low fidelity (:class:`SplitMobility`: its own near-field
  part, degree-truncated or compressed, on the high's set-up).
* :mod:`.operator`: :class:`BimMobility`, forward and exact transposed products and both at
  once; it owns a :class:`.solves.KrylovSolves` (by composition).
* :mod:`.solves`: the operator's Krylov part: recycled spaces, records, the stopping
  tolerance (``eps_gmres``, or looser inside ``at_accuracy``), convergence reports.
* :mod:`.adjoint`: the exact transposes of the forward pieces (:class:`.adjoint.AdjointPieces`).

The set-up of one configuration (shared by the operator, its twins, its transpose and the
split lows)

* :mod:`.blocks`: the stored near-field blocks applied forward, transposed and fused.
* :mod:`.setup`: :class:`BimSetup`: grids, one-sphere operators, target points and the
  forward pieces without the near blocks.
* :mod:`.pairs`: :class:`.pairs.PairPlan`: how each pair of spheres is evaluated (source
  grids per rung, expansion pairs, stored blocks, on-the-fly pairs) and the block builder.
* :mod:`.pair_parts`: the plan's three parts: quadrature pairs, stored near blocks,
  expansion pairs on the fly.
* :mod:`.farfield`: the far field as one strategy object (:class:`.farfield.DirectSums`,
  :class:`.farfield.FmmSums`) owning its forward and transposed sums.

The near field's pair operators

* :mod:`.kernels_rotated`: blocks in rotated form (Wigner matrices and coaxial entries),
  the per-pair compiled products (the reference), the block stack assembled on demand.
* :mod:`.pair_frame`: the table pairs' products in the pair frame, batched over pairs.
* :mod:`.panel_kernels`, :mod:`.panel_source`: the pair frame's inner loops on panels of 32
  columns, summed in registers, and the generator that writes them out.
* :mod:`.rotation`: rotations of the real vector spherical harmonics.
* :mod:`.coaxial`: the coaxial pair table (blocks of equal spheres on the z axis by distance).

One sphere and the compiled kernels

* :mod:`.sphere_vsh`: grids, vector spherical harmonics and the one-sphere operators.
* :mod:`.kernels_adjoint`, :mod:`.kernels`: the compiled forward and transposed kernels.
* :mod:`.harmonics`, :mod:`.jit`: solid harmonics and the compiled-build helpers.
* :mod:`.fmm`: fmm3dpy's Stokes FMM, forward and transposed, and the crossover.

The Krylov solvers (no import of the rest)

* :mod:`.gmres`: relaxed restarted GMRES with block orthogonalisation.
* :mod:`.recycle`: Krylov recycling (:class:`.recycle.RecycledGCR`) and its memory budget.
* :mod:`.gram_schmidt`: classical Gram-Schmidt against an orthonormal block (both above).
"""

from .operator import BimConvergenceWarning, BimMobility, bim_mobility
from .setup import BimSetup
from .split import DEFAULT_NEAR_GAP, SplitMobility, split_mobility

__all__ = ["BimMobility", "bim_mobility", "BimConvergenceWarning", "BimSetup",
           "SplitMobility", "split_mobility", "DEFAULT_NEAR_GAP"]
