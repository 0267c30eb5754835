"""The boundary-integral Stokes mobility of rigid spheres (``model="bim"``), by its parts.

* set-up: :mod:`.setup` (:class:`BimSetup`: grids, one-sphere operators, target points and
  the forward pieces without the near blocks), shared by composition by every operator
  below; :mod:`.pairs` (:class:`PairPlan`: how each pair of spheres is evaluated, and the
  near-field block builder, where rotation tables would replace the direct build);
* the operators: :mod:`.operator` (:class:`BimMobility`: forward and exact transposed
  products and both at once), :mod:`.blocks` (the stored near blocks applied forward,
  transposed and fused), :mod:`.adjoint` (the transposed pieces), :mod:`.split` (the
  distance-split low fidelity: the same set-up with its own near-field part);
* the kernels: :mod:`.kernels`, :mod:`.kernels_adjoint`, :mod:`.harmonics`,
  :mod:`.sphere_vsh` (the one-sphere spectral operators), :mod:`.fmm`;
* the solves: :mod:`.gmres` (relaxed restarted GMRES), :mod:`.recycle` (Krylov recycling).

Imports go one way, from the operators down to the kernels; no module imports one above it.
"""

from .operator import BimConvergenceWarning, BimMobility, bim_mobility
from .setup import BimSetup
from .split import DEFAULT_NEAR_GAP, SplitMobility, split_mobility

__all__ = ["BimMobility", "bim_mobility", "BimConvergenceWarning", "BimSetup",
           "SplitMobility", "split_mobility", "DEFAULT_NEAR_GAP"]
