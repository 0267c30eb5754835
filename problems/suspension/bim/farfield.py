"""The far field of the boundary-integral mobility: how the pairs summed by quadrature
between spheres are summed, one strategy object per set-up.

The pair plan (:mod:`.pairs`) asks its strategy which source grid a pair may use, whether the
quadrature may be relaxed along the tolerance ladder of relaxed GMRES and which source
ranges the direct sums cover; the forward product (:class:`.setup.BimSetup`) and its
transpose (:class:`.adjoint.AdjointPieces`) call the strategy's own forward and transposed
sums after the shared direct sums.

* :class:`DirectSums`: compiled direct quadrature on the coarsest source grid accurate for
  each pair, relaxed per rung; nothing beyond the shared direct sums.
* :class:`FmmSums`: fmm3dpy's Stokes FMM over every native grid point (:mod:`.fmm`), minus
  the pairs the native grid does not resolve and each sphere's own points (summed directly
  instead); transposed by a stresslet FMM; not relaxed.

:func:`far_field` makes one by name; ``"auto"`` chooses by the measured crossover
(:func:`.fmm.resolve_far`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from .fmm import check_fmm, fmm_traction, fmm_traction_adjoint, resolve_far
from .kernels import direct_traction_skip
from .kernels_adjoint import direct_traction_adjoint_skip

__all__ = ["FarField", "DirectSums", "FmmSums", "far_field", "group_ranges", "SumsSetup"]

Ranges = tuple[np.ndarray, np.ndarray, np.ndarray]
"""Per-target source ranges ``(ptr, start, stop)``: target sphere i sums the source points
``start[k]:stop[k]`` for k in ``ptr[i]:ptr[i+1]``."""


class SumsSetup(Protocol):
    """What the sums read of the set-up (:class:`.setup.BimSetup`, which imports this
    module): the pair plan, the sizes, the target points and the quadrature tolerance."""

    plan: Any
    M: int
    N: int
    tgt_pts: np.ndarray
    tgt_nrm: np.ndarray
    tgt_sphere: np.ndarray
    quad_tol: float


def group_ranges(ptr: np.ndarray, start: np.ndarray, stop: np.ndarray, n_per: int) -> dict:
    """Regroup per-target source ranges (:data:`Ranges`) by source range, for the
    transposed sums (:func:`.kernels_adjoint.direct_traction_adjoint`)."""
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


class FarField:
    """How the quadrature pairs between spheres are summed (base of the strategies).

    Attributes
    ----------
    name : str
        ``"direct"`` or ``"fmm"``.
    relaxes : bool
        Whether the quadrature may follow the tolerance ladder of relaxed GMRES.
    """

    name = ""
    relaxes = True

    def levels(self, level_of: np.ndarray, native: int) -> np.ndarray:
        """The source level of every pair at full accuracy, given the accurate one."""
        return level_of

    def native_sources(self, used: np.ndarray, M: int) -> np.ndarray:
        """The spheres whose native grid is a source level, given those the pairs use."""
        return used

    def ranges(self, level_of: np.ndarray, ladder: list[np.ndarray], native: int,
               ranges: Callable[[np.ndarray, Callable], Ranges]) -> list[Ranges]:
        """The direct sums' source ranges per rung; ``ranges(levels, keep)`` gives those of
        the pairs whose level ``keep`` accepts."""
        return [ranges(lv, lambda x: x >= 0) for lv in ladder]

    def add_forward(self, setup: SumsSetup, forces: list[np.ndarray], trac: np.ndarray) -> None:
        """Adds this strategy's sum to the traction ``trac`` (M N, 3) of the point forces
        ``forces`` (three arrays over every source level), after the direct sums."""

    def add_transpose(self, setup: SumsSetup, tb: np.ndarray, tgt: tuple, f_bar: list) -> None:
        """Transpose of :meth:`add_forward`: adds to the adjoint point forces ``f_bar`` those
        of the adjoint tractions ``tb`` (M N, 3) at the target points and normals ``tgt``
        (six contiguous coordinate arrays)."""


class DirectSums(FarField):
    """Every quadrature pair by compiled direct sums on its coarsest accurate grid, relaxed
    per rung (the direct sums themselves are the set-up's and the transposed pieces')."""

    name = "direct"


class FmmSums(FarField):
    """fmm3dpy's Stokes FMM over every native grid point at the quadrature tolerance, with
    the native pairs it must not include (pairs needing a finer grid, each sphere's own
    points) removed by direct sums; the pairs on finer grids are direct sums.  Not relaxed.

    Raises
    ------
    ImportError
        fmm3dpy is not installed (extra ``fmm``).
    """

    name = "fmm"
    relaxes = False

    def __init__(self) -> None:
        check_fmm()
        self.removed: Ranges | None = None      # native ranges removed from the FMM sum
        self._removed_by_source: dict | None = None

    def levels(self, level_of: np.ndarray, native: int) -> np.ndarray:
        level_of[(level_of >= 0) & (level_of < native)] = native     # no coarser levels
        return level_of

    def native_sources(self, used: np.ndarray, M: int) -> np.ndarray:
        return np.arange(M)

    def ranges(self, level_of: np.ndarray, ladder: list[np.ndarray], native: int,
               ranges: Callable[[np.ndarray, Callable], Ranges]) -> list[Ranges]:
        # the FMM sums all native points; remove its native self and non-native pairs
        self.removed = ranges(np.where(level_of == native, -2, native),
                              lambda lv: lv == native)
        self._removed_by_source = None
        return [ranges(level_of, lambda lv: lv > native)]

    def _removed(self) -> Ranges:
        assert self.removed is not None, "the pair plan sets the ranges (BimSetup builds it)"
        return self.removed

    def add_forward(self, setup: SumsSetup, forces: list[np.ndarray], trac: np.ndarray) -> None:
        plan, M, N = setup.plan, setup.M, setup.N
        b0 = plan.quadrature.lvl_base[plan.quadrature.native]
        trac += fmm_traction(setup.tgt_pts, setup.tgt_nrm,
                             np.stack([x[b0:b0 + M * N] for x in forces], axis=1),
                             setup.quad_tol)
        ptr, start, stop = self._removed()
        sub = np.zeros((M * N, 3))
        direct_traction_skip(setup.tgt_pts, setup.tgt_nrm, setup.tgt_sphere,
                             ptr, start, stop, *plan.quadrature.src_xyz, *forces, sub, True)
        trac -= sub

    def add_transpose(self, setup: SumsSetup, tb: np.ndarray, tgt: tuple, f_bar: list) -> None:
        plan, M, N = setup.plan, setup.M, setup.N
        if self._removed_by_source is None:
            self._removed_by_source = group_ranges(*self._removed(), N)
        g = self._removed_by_source
        b0 = plan.quadrature.lvl_base[plan.quadrature.native]
        fb = fmm_traction_adjoint(setup.tgt_pts, setup.tgt_nrm, tb, setup.quad_tol)
        sub = [np.zeros(plan.quadrature.n_src) for _ in range(3)]
        tbc = tuple(np.ascontiguousarray(tb[:, k]) for k in range(3))
        direct_traction_adjoint_skip(*tgt, *tbc, N, g["ptr"], g["tgt"], g["start"],
                                     g["stop"], *plan.quadrature.src_xyz, *sub, True)
        for k in range(3):
            f_bar[k][b0:b0 + M * N] += fb[:, k]
            f_bar[k] -= sub[k]


def far_field(name: str, M: int) -> FarField:
    """The far-field strategy ``name`` (``"direct"``, ``"fmm"`` or ``"auto"``: the FMM from
    the measured crossover on, :func:`.fmm.resolve_far`) for ``M`` spheres.

    Raises
    ------
    ValueError
        ``name`` is not one of :data:`.fmm.FAR_ENGINES`.
    ImportError
        The FMM is asked for and fmm3dpy is not installed.
    """
    return FmmSums() if resolve_far(name, M) == "fmm" else DirectSums()
