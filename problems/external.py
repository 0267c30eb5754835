"""Problem families read from other libraries' files: ``siconos`` and ``fclib``.

The formats live in :mod:`lcpbench.problems.siconos` (Siconos numerics ``.dat``
text) and :mod:`lcpbench.problems.fclib` (FCLIB local problems in HDF5); their
readers and writers are re-exported here. A ``path`` parameter names one file
or a folder of them (read in sorted order). A Siconos folder is read as far as it
goes: files whose problem lcpbench does not solve (MLCPs, non-symmetric or
indefinite matrices) are skipped and listed in one warning
(:func:`lcpbench.problems.formats.read_supported`); one such file named by ``path``
is an error.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, ClassVar

from lcpbench import LCP, register_problem
from lcpbench.core.specs import Bounds, CheckedParams

from .fclib import FCLIB_DEFAULT_SYMMETRIZE_RTOL, read_fclib_local, write_fclib_local
from .formats import UnsupportedProblem, input_files, read_supported
from .siconos import SICONOS_STORAGES, SiconosFormatError, read_siconos_lcp, write_siconos_lcp

__all__ = ["read_siconos_lcp", "write_siconos_lcp", "read_fclib_local", "write_fclib_local",
           "SiconosFormatError", "UnsupportedProblem", "SICONOS_STORAGES",
           "FCLIB_DEFAULT_SYMMETRIZE_RTOL"]

#: A relative asymmetry tolerance: >= 0, inf symmetrises any matrix.
_Rtol = Annotated[float, Bounds(ge=0, finite=False)]


@dataclass(frozen=True)
class _FileParams(CheckedParams):
    """Parameters of a family read from files.

    Parameters
    ----------
    path : str
        A file of the format, or a folder of them (read in sorted order).
    symmetrize_rtol : float
        Largest relative asymmetry replaced by the symmetric part, with a warning; a larger
        one raises (the policy of ``lcpbench.problems.formats``).
    """

    path: str = ""
    symmetrize_rtol: _Rtol = 0.0
    #: The family's spec with a file, for the "path is required" message.
    example: ClassVar[str] = ""

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError(f"path is required: {self.example} (or a folder)")
        super().__post_init__()


@dataclass(frozen=True)
class SiconosParams(_FileParams):
    """Parameters of siconos: ``path`` is a Siconos numerics LCP ``.dat`` file or a folder of
    them (``*.dat``); ``symmetrize_rtol`` defaults to 0, so a non-symmetric file raises (in a
    folder: is skipped and listed, as are MLCP files)."""

    example: ClassVar[str] = "siconos:path=FILE.dat"


@register_problem("siconos", SiconosParams)
def siconos(p: SiconosParams) -> list[LCP]:
    """LCPs in the Siconos numerics text format (dense, sparse-block or CSparse storage).

    A folder's MLCP, non-symmetric and indefinite files are skipped and listed in a warning.
    """
    files = input_files(p.path, ("*.dat",), "Siconos .dat")

    def read(f: Path) -> LCP:
        return read_siconos_lcp(f, symmetrize_rtol=p.symmetrize_rtol)

    if not Path(p.path).is_dir():
        return [read(files[0])]
    return read_supported(files, read, f"siconos:path={p.path}")


@dataclass(frozen=True)
class FclibParams(_FileParams):
    """Parameters of fclib: ``path`` is an FCLIB local problem (``.hdf5``/``.h5``) or a folder
    of them; ``symmetrize_rtol`` (default 1e-6) applies to ``W_nn``."""

    symmetrize_rtol: _Rtol = FCLIB_DEFAULT_SYMMETRIZE_RTOL
    example: ClassVar[str] = "fclib:path=FILE.hdf5"


@register_problem("fclib", FclibParams)
def fclib(p: FclibParams) -> list[LCP]:
    """Normal-contact LCPs of FCLIB local frictional-contact problems (HDF5).

    A folder's global problems, problems with equality constraints and non-symmetric or
    indefinite normal blocks are skipped and listed in a warning, as for ``siconos``.
    """
    files = input_files(p.path, ("*.hdf5", "*.h5"), "FCLIB")

    def read(f: Path) -> LCP:
        return read_fclib_local(f, symmetrize_rtol=p.symmetrize_rtol)

    if not Path(p.path).is_dir():
        return [read(files[0])]
    return read_supported(files, read, f"fclib:path={p.path}")
