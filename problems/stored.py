"""Stored sets as problem families: ``stored:path=FILE.h5`` and one ``set-<stem>`` per shipped set.

The file format, its writer and its verified reader are the framework's
(:mod:`lcpbench.sets`); this plugin turns files into problem families. Every
``problems/data/*.h5`` becomes a problem family ``set-<stem>`` wherever the plugin loads
(CLI, library, dask workers), and is announced to the framework with
:func:`lcpbench.core.registry.register_set` together with the E-MVP baselines of
``lcpbench check`` (``problems/data/baselines.json``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from lcpbench import LCP, register_problem
from lcpbench.core.registry import register_set
from lcpbench.sets import instance_ids, parse_instances, read_set, set_problem_name
from lcpbench.sets.common import _natural_key

__all__ = ["DATA_DIR", "BASELINES", "DEFAULT_SETS", "shipped_sets", "StoredParams",
           "ShippedSetParams", "register_shipped_sets"]

#: Folder of the sets shipped with lcpbench.
DATA_DIR = Path(__file__).resolve().parent / "data"
#: E-MVP baselines of the shipped sets (``lcpbench check``).
BASELINES = DATA_DIR / "baselines.json"


def shipped_sets() -> dict[str, Path]:
    """The sets shipped with lcpbench: ``{stem: path}`` of ``problems/data/*.h5``."""
    if not DATA_DIR.is_dir():
        return {}
    return {p.stem: p for p in sorted(DATA_DIR.glob("*.h5"), key=lambda q: _natural_key(q.stem))}


@dataclass(frozen=True)
class StoredParams:
    """Parameters of stored.

    Parameters
    ----------
    path : str
        The ``.h5`` file, or the name of a shipped set (``shipped_sets()``).
    instances : str
        Positions to read, e.g. ``"0-9"`` or ``"0,3,5-7"`` (inclusive; default all).
    """

    path: str = ""
    instances: str = ""

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("path is required: stored:path=FILE.h5 (or a shipped set name: "
                             f"{', '.join(shipped_sets()) or 'none shipped'})")


@register_problem("stored", StoredParams)
def stored(p: StoredParams) -> list[LCP]:
    """A stored HDF5 set, verified on reading (checksums, shapes, format version)."""
    path = Path(p.path)
    if not path.exists() and p.path in shipped_sets():
        path = shipped_sets()[p.path]
    ids = instance_ids(path)
    chosen = [ids[i] for i in parse_instances(p.instances, len(ids))]
    return read_set(path, chosen)


# ----------------------------------------------------------------------------- shipped sets
# Every problems/data/*.h5 is a problem family ``set-<stem>`` wherever this plugin loads
# (CLI, library, dask workers), not only where the CLI imported it.

@dataclass(frozen=True)
class ShippedSetParams:
    """Parameters of a shipped stored set.

    Parameters
    ----------
    instances : str
        Positions to read, e.g. ``"0-9"`` or ``"0,3,5-7"`` (inclusive; default all).
    """

    instances: str = ""


#: Shipped sets in the default sweep of ``lcpbench run`` (with the hard-case families): the
#: 0.1a lattice (the hard case) and the authors' 0.3a lattice, where the method paper's
#: offline result can be checked (its lows p = 3, 4, 6 and the distance-split lows).
DEFAULT_SETS = ("lattice-bim-m3", "paper-lattice-m3")


def register_shipped_sets() -> list[str]:
    """Register problem ``set-<stem>`` for every shipped set; returns the names.

    Each reads its file with the ``stored`` plugin (verified on reading). Names
    already registered by the same function are left as they are. The sets in
    :data:`DEFAULT_SETS` join the default sweep of ``lcpbench run``.
    """
    names = []
    for stem, path in shipped_sets().items():
        pname = set_problem_name(stem)

        def load(p: ShippedSetParams, _path: Path = path):
            return stored(StoredParams(path=str(_path), instances=p.instances))

        load.__doc__ = f"Shipped stored set {stem} ({path.name}), verified on reading."
        load.__qualname__ = f"shipped_set_{pname}"
        try:
            register_problem(pname, ShippedSetParams, default=stem in DEFAULT_SETS)(load)
        except ValueError:
            continue                     # a plugin of that name exists: keep it
        register_set(stem, path, problem=pname, baselines=BASELINES)
        names.append(pname)
    return names


register_shipped_sets()
