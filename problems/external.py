"""Problem families read from other libraries' files: ``siconos`` and ``fclib``.

The formats live in :mod:`lcpbench.problems.siconos` (Siconos numerics ``.dat``
text) and :mod:`lcpbench.problems.fclib` (FCLIB local problems in HDF5); their
readers and writers are re-exported here. A ``path`` parameter names one file
or a folder of them (read in sorted order).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from lcpbench import LCP, register_problem
from lcpbench.core.specs import Bounds, CheckedParams

from .fclib import FCLIB_DEFAULT_SYMMETRIZE_RTOL, read_fclib_local, write_fclib_local
from .formats import input_files
from .siconos import SICONOS_STORAGES, SiconosFormatError, read_siconos_lcp, write_siconos_lcp

__all__ = ["read_siconos_lcp", "write_siconos_lcp", "read_fclib_local", "write_fclib_local",
           "SiconosFormatError", "SICONOS_STORAGES", "FCLIB_DEFAULT_SYMMETRIZE_RTOL"]

#: A relative asymmetry tolerance: >= 0, inf symmetrises any matrix.
_Rtol = Annotated[float, Bounds(ge=0, finite=False)]


@dataclass(frozen=True)
class SiconosParams(CheckedParams):
    """Parameters of siconos.

    Parameters
    ----------
    path : str
        A Siconos numerics LCP ``.dat`` file, or a folder of them (``*.dat``, sorted).
    symmetrize_rtol : float
        Largest relative asymmetry replaced by (A + A')/2 with a warning (default 0:
        non-symmetric files raise).
    """

    path: str = ""
    symmetrize_rtol: _Rtol = 0.0

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("path is required: siconos:path=FILE.dat (or a folder)")
        super().__post_init__()


@register_problem("siconos", SiconosParams)
def siconos(p: SiconosParams) -> list[LCP]:
    """LCPs in the Siconos numerics text format (dense, sparse-block or CSparse storage)."""
    return [read_siconos_lcp(f, symmetrize_rtol=p.symmetrize_rtol)
            for f in input_files(p.path, ("*.dat",), "Siconos .dat")]


@dataclass(frozen=True)
class FclibParams(CheckedParams):
    """Parameters of fclib.

    Parameters
    ----------
    path : str
        An FCLIB local problem (``.hdf5``/``.h5``), or a folder of them (sorted).
    symmetrize_rtol : float
        Largest relative asymmetry of W_nn replaced by its symmetric part with a warning
        (default 1e-6); larger asymmetry raises.
    """

    path: str = ""
    symmetrize_rtol: _Rtol = FCLIB_DEFAULT_SYMMETRIZE_RTOL

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("path is required: fclib:path=FILE.hdf5 (or a folder)")
        super().__post_init__()


@register_problem("fclib", FclibParams)
def fclib(p: FclibParams) -> list[LCP]:
    """Normal-contact LCPs of FCLIB local frictional-contact problems (HDF5)."""
    return [read_fclib_local(f, symmetrize_rtol=p.symmetrize_rtol)
            for f in input_files(p.path, ("*.hdf5", "*.h5"), "FCLIB")]
