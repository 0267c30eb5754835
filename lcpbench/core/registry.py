"""Registries of solvers, problems, scenes and stored sets, with typed parameters parsed from strings.

A solver plugin is a function ``solve(ctx, params) -> SolveResult`` decorated
with :func:`register_solver`; its parameters are a frozen dataclass. A problem
plugin is a function ``generate(params) -> list[LCP]`` decorated with
:func:`register_problem`. A scene plugin (an online simulation that poses one LCP
per time step) is a factory ``make(params) -> scene`` decorated with
:func:`register_scene`. A plugin that ships stored sets (HDF5 files) announces
them with :func:`register_set`. Built-in plugins (``lcpbench.solvers.*``,
``lcpbench.problems.*``) and third-party packages are found the same way, through
the entry-point groups ``lcpbench.solvers``, ``lcpbench.problems`` and
``lcpbench.scenes``; the core never imports a plugin by name.

The CLI form of a choice is ``name:key=value,key=value``; a value in brackets is
a list (``low=[p3,p4]``).
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib.util
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, Optional, Union

from lcpbench.core.specs import make_params, parse_spec

__all__ = [
    "LowOperators", "SolverInfo", "ProblemInfo", "register_solver", "register_problem", "get_solver",
    "get_problem", "solvers", "problems",
    "SceneInfo", "register_scene", "scenes", "get_scene", "make_scene",
    "SetInfo", "register_set", "stored_sets", "PluginError", "problem_estimate",
    "scene_estimate",
]


@dataclass(frozen=True)
class LowOperators:
    """Which parameters of a multi-fidelity solver name its low-fidelity operators.

    Declared with ``register_solver(..., multifidelity=LowOperators(...))``; the
    framework (the sweep, the command line's checks, ``requested_lows``) asks this
    declaration, never a parameter's name.

    Attributes
    ----------
    one : str
        The parameter naming one low operator, a string; empty at run time means
        "the LCP's only one", and a sweep runs a spec that leaves it empty once per
        low operator of an instance with several. Empty: no such parameter.
    chain : str
        The parameter naming an ordered list of low operators (empty list at run
        time: all of them). Empty: no such parameter.
    """

    one: str = ""
    chain: str = ""

    def names(self) -> tuple[str, ...]:
        """The declared parameter names."""
        return tuple(n for n in (self.one, self.chain) if n)

    def requested(self, params: dict) -> list[str]:
        """The low operators ``params`` (a solver's parameter values) name, in order."""
        one = params.get(self.one) if self.one else None
        names = [one] if isinstance(one, str) and one else []
        chain = params.get(self.chain) if self.chain else None
        if isinstance(chain, (list, tuple)):
            names += [str(x) for x in chain]
        return names

    def one_per_low(self, params: dict) -> bool:
        """True when ``params`` leave the low operator to choose (run once per low)."""
        return bool(self.one) and self.one in params and not params[self.one] \
            and not (self.chain and params.get(self.chain))


@dataclass(frozen=True)
class SolverInfo:
    """A registered solver.

    Attributes
    ----------
    name : str
        Kebab-case registry name.
    func : callable
        ``func(ctx, params) -> SolveResult``.
    params : type
        Frozen dataclass of parameters.
    needs_dense : bool
        True when the solver needs the explicit matrix (the framework forms it
        once, uncounted, and the run is flagged as not MVP-only).
    reference : bool
        True for the reference QP solvers (ground truth, not benchmarked on MVPs).
    multifidelity : bool
        True when the solver uses low-fidelity operators.
    lows : LowOperators
        Which of its parameters name low operators (none for a mono-fidelity solver).
    summary : str
        First line of the docstring.
    listed : bool
        False for solvers that exist only to exercise the framework (test doubles):
        runnable by name, but left out of ``lcpbench list``, the default sweep and
        ``lcpbench check``.
    """

    name: str
    func: Callable
    params: type
    needs_dense: bool = False
    reference: bool = False
    multifidelity: bool = False
    summary: str = ""
    listed: bool = True
    lows: LowOperators = LowOperators()

    @property
    def mvp_only(self) -> bool:
        return not self.needs_dense


@dataclass(frozen=True)
class ProblemInfo:
    """A registered problem family: ``func(params) -> list[LCP]``.

    ``estimate(params) -> lcpbench.core.guards.Estimate`` (optional) says what building
    the instances costs before any is built; the command line refuses work over the
    limits of :mod:`lcpbench.core.guards` with it.
    """

    name: str
    func: Callable
    params: type
    summary: str = ""
    default: bool = False
    estimate: Optional[Callable] = None


_SOLVERS: dict[str, SolverInfo] = {}
_PROBLEMS: dict[str, ProblemInfo] = {}
_SCENES: dict[str, SceneInfo] = {}
_SETS: dict[str, SetInfo] = {}
_LOADED = {"lcpbench.solvers": False, "lcpbench.problems": False, "lcpbench.scenes": False}
#: True once the modules named in ``LCPBENCH_PLUGINS`` were imported (with the first group).
_ENV_LOADED = False


def _check_name(name: str) -> None:
    if not name or name.lower() != name or " " in name or "_" in name or ":" in name:
        raise ValueError(f"registry name {name!r} must be kebab-case (lower case, '-')")


def _check_params(name: str, params: type) -> None:
    frozen = getattr(getattr(params, "__dataclass_params__", None), "frozen", False)
    if not (dataclasses.is_dataclass(params) and frozen):
        raise TypeError(f"parameters of {name!r} must be a frozen dataclass")
    for f in dataclasses.fields(params):
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise TypeError(f"parameter {f.name!r} of {name!r} needs a default")


def _registrar(kind: str, table: dict, name: str, params: type, make_info: Callable):
    """The decorator behind ``register_solver/problem/scene``: checks, then stores the info.

    The same function registered again (a module imported twice) replaces its entry; a
    different function under a taken name is refused.
    """
    _check_name(name)
    _check_params(name, params)

    def deco(func):
        doc = (func.__doc__ or "").strip().splitlines()
        info = make_info(func, doc[0] if doc else "")
        old = table.get(name)
        if old is not None and (old.func.__module__, old.func.__qualname__) != \
                (func.__module__, func.__qualname__):
            raise ValueError(f"{kind} {name!r} is registered twice ({old.func.__module__} and "
                             f"{func.__module__}); pick another name")
        table[name] = info
        setattr(func, f"{kind}_info", info)
        return func

    return deco


def register_solver(name: str, params: type, *, needs_dense: bool = False,
                    reference: bool = False, multifidelity: Union[bool, LowOperators] = False,
                    listed: bool = True):
    """Decorator registering ``func(ctx, params)`` as solver ``name``.

    Parameters
    ----------
    name : str
        Kebab-case registry name.
    params : type
        Frozen dataclass of the solver's parameters, every field with a default.
    multifidelity : bool or LowOperators
        The solver uses low-fidelity operators; a :class:`LowOperators` also says
        which of its parameters name them (each must be a field of ``params``).
    needs_dense, reference, listed : bool
        See :class:`SolverInfo`.
    """
    lows = multifidelity if isinstance(multifidelity, LowOperators) else LowOperators()
    if dataclasses.is_dataclass(params):
        unknown = [n for n in lows.names() if n not in {f.name for f in dataclasses.fields(params)}]
        if unknown:
            raise TypeError(f"solver {name!r} declares low-operator parameter(s) "
                            f"{', '.join(unknown)} that {params.__name__} does not have")
    return _registrar("solver", _SOLVERS, name, params, lambda func, summary: SolverInfo(
        name, func, params, needs_dense, reference, bool(multifidelity), summary, listed, lows))


def register_problem(name: str, params: type, *, default: bool = False,
                     estimate: Optional[Callable] = None):
    """Decorator registering ``func(params) -> list[LCP]`` as problem family ``name``.

    ``default=True`` puts the family in the shipped default set of ``lcpbench run``.
    ``estimate(params)`` returns a :class:`lcpbench.core.guards.Estimate` of the
    instances' memory and build work, computed from the parameters alone (no matrix
    is built), so that oversized work is refused before it starts.
    """
    return _registrar("problem", _PROBLEMS, name, params, lambda func, summary: ProblemInfo(
        name, func, params, summary, default, estimate))


#: Environment variable naming extra plugin modules or ``.py`` files (comma-separated),
#: imported when the registry first loads: for solvers and problems that are not packaged
#: with entry points (a script's own solver, test doubles). Dask workers and forked
#: children inherit it, so such plugins are known wherever runs execute.
PLUGINS_ENV = "LCPBENCH_PLUGINS"


class PluginError(RuntimeError):
    """A plugin failed to load (a missing file named in ``LCPBENCH_PLUGINS``, an import error)."""


def _load_env_plugins() -> None:
    for item in filter(None, (s.strip() for s in os.environ.get(PLUGINS_ENV, "").split(","))):
        if item.endswith(".py") and not os.path.isfile(item):
            raise PluginError(f"${PLUGINS_ENV} names {item!r}, which is not a file; fix the path "
                              f"or remove it from ${PLUGINS_ENV}")
        try:
            if item.endswith(".py"):
                path = os.path.abspath(item)
                name = os.path.splitext(os.path.basename(path))[0]
                loaded = sys.modules.get(name)
                if loaded is not None and os.path.abspath(getattr(loaded, "__file__", "") or "") \
                        == path:
                    continue                       # this very file is loaded already
                if loaded is not None:             # a module of that name exists: own name
                    name = "lcpbench_plugin_" + name
                spec = importlib.util.spec_from_file_location(name, path)
                if spec is None or spec.loader is None:
                    raise ImportError(f"cannot import {path}")
                mod = importlib.util.module_from_spec(spec)
                sys.modules[name] = mod
                spec.loader.exec_module(mod)
            else:
                importlib.import_module(item)
        except SystemExit as exc:     # sys.exit() at import must not end the command
            raise PluginError(f"plugin {item!r} named in ${PLUGINS_ENV} called "
                              f"sys.exit({exc.code!r}) while it was imported; a plugin module "
                              "must only register its solvers, problems and scenes") from None
        except Exception as exc:
            raise PluginError(f"plugin {item!r} named in ${PLUGINS_ENV} failed to load: "
                              f"{type(exc).__name__}: {exc}") from exc


def _load(group: str) -> None:
    if _LOADED[group]:
        return
    _LOADED[group] = True
    global _ENV_LOADED
    if not _ENV_LOADED:        # once, whichever group is asked for first: a plugin file may
        _ENV_LOADED = True     # register solvers, problems and scenes alike
        _load_env_plugins()
    eps = entry_points(group=group)
    if not eps:
        raise RuntimeError(
            f"no plugins found in entry-point group {group!r}: lcpbench is not installed. "
            "Install it with `pip install -e .` from the repository root")
    for ep in eps:
        try:
            ep.load()
        except (Exception, SystemExit) as exc:     # sys.exit() at import included
            raise PluginError(f"plugin {ep.name!r} ({ep.value}) of {group!r} failed to "
                              f"load: {type(exc).__name__}: {exc}") from None


def solvers() -> dict[str, SolverInfo]:
    """All registered solvers, loading entry points on first use."""
    _load("lcpbench.solvers")
    return dict(sorted(_SOLVERS.items()))


def problems() -> dict[str, ProblemInfo]:
    """All registered problem families, loading entry points on first use."""
    _load("lcpbench.problems")
    return dict(sorted(_PROBLEMS.items()))


def scenes() -> dict[str, SceneInfo]:
    """All registered scene families, loading entry points on first use."""
    _load("lcpbench.scenes")
    return dict(sorted(_SCENES.items()))


def stored_sets() -> dict[str, SetInfo]:
    """All stored sets announced by problem plugins (``{name: SetInfo}``), natural order."""
    _load("lcpbench.problems")
    return dict(_SETS)


def _unknown(kind: str, name: str, known) -> KeyError:
    close = difflib.get_close_matches(name, list(known), n=3)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    return KeyError(f"unknown {kind} {name!r}.{hint} Known: {', '.join(known)} "
                    f"(`lcpbench list` shows them with their parameters)")


def _lookup(kind: str, registered: dict, name: str):
    if name not in registered:
        raise _unknown(kind, name, registered)
    return registered[name]


def get_solver(name: str) -> SolverInfo:
    """The registered solver ``name`` (KeyError naming the known ones otherwise)."""
    return _lookup("solver", solvers(), name)


def get_problem(name: str) -> ProblemInfo:
    """The registered problem family ``name`` (KeyError naming the known ones otherwise)."""
    return _lookup("problem", problems(), name)


def problem_estimate(name: str, params: Any):
    """The registered estimate of building problem ``name`` with ``params``, or None.

    None when the family registers no estimate (its cost is then not checked).
    """
    info = get_problem(name)
    return info.estimate(params) if info.estimate is not None else None


# ---------------------------------------------------------------------- scenes
@dataclass(frozen=True)
class SceneInfo:
    """A registered scene family: ``func(params) -> scene``.

    A scene is an online problem: each time step poses one LCP whose solution moves
    the particles. The object returned by ``func`` meets the Protocol
    :class:`lcpbench.core.scene.Scene` (``params``, ``M``, ``radii``, ``step_index``,
    ``fidelity_axes``, ``build``, ``advance``, ``carry_memory``, ``keep_memory``,
    ``fidelity_knobs``, ``get_state``, ``set_state``); ``tests/test_layering.py`` checks
    every registered scene against it, and :func:`lcpbench.core.scene.step_scene` is the
    step that ``simulate`` and ``generate`` make with it.
    """

    name: str
    func: Callable
    params: type
    summary: str = ""
    #: ``estimate(params) -> lcpbench.core.guards.Estimate`` of making the scene and a
    #: step's LCP (optional; checked by ``lcpbench simulate`` before the scene is made).
    estimate: Optional[Callable] = None

    def fidelity_axes(self):
        """The fidelity knobs the scene declares (a :class:`lcpbench.core.scene.FidelityAxes`),
        read from a scene made with the default parameters."""
        return self.func(self.params()).fidelity_axes


def register_scene(name: str, params: type, *, estimate: Optional[Callable] = None):
    """Decorator registering ``func(params) -> scene`` as scene family ``name``.

    Parameters
    ----------
    name : str
        Kebab-case registry name (``lattice``).
    params : type
        Frozen dataclass of the scene's parameters, every field with a default.
    estimate : callable, optional
        ``estimate(params) -> lcpbench.core.guards.Estimate``: the memory and work of
        making the scene and one step's LCP, so that ``lcpbench simulate`` refuses
        oversized parameters before it makes anything.
    """
    return _registrar("scene", _SCENES, name, params, lambda func, summary: SceneInfo(
        name, func, params, summary, estimate))


def scene_estimate(spec: str):
    """The registered estimate of scene ``spec`` (``NAME:key=value,...``), or None when the
    scene registers none. Raises as :func:`make_scene` for an unknown scene or parameter."""
    name, raw = parse_spec(spec)
    info = get_scene(name)
    params = make_params(name, info.params, raw)
    return info.estimate(params) if info.estimate is not None else None


def get_scene(name: str) -> SceneInfo:
    """The registered scene family ``name`` (KeyError naming the known ones otherwise)."""
    return _lookup("scene", scenes(), name)


def make_scene(spec: Any) -> Any:
    """A scene from ``NAME:key=value,...`` (``lattice:m=3,model=rpy``) or a params object.

    Raises
    ------
    KeyError
        Unknown scene name (the known ones are listed).
    TypeError, ValueError
        Unknown or invalid parameter (named).
    """
    if dataclasses.is_dataclass(spec) and not isinstance(spec, type):
        for info in scenes().values():
            if isinstance(spec, info.params):
                return info.func(spec)
        raise TypeError(f"no registered scene takes parameters of type {type(spec).__name__}")
    name, raw = parse_spec(spec)
    info = get_scene(name)
    return info.func(make_params(name, info.params, raw))


# ---------------------------------------------------------------------- stored sets
@dataclass(frozen=True)
class SetInfo:
    """A stored set (HDF5 file) that a plugin ships.

    Attributes
    ----------
    name : str
        The set's name (the file stem, ``lattice-bim-m3``).
    path : pathlib.Path
        The ``.h5`` file.
    problem : str
        The problem family that reads it (``set-lattice-bim-m3``).
    baselines : pathlib.Path or None
        The E-MVP baseline file ``lcpbench check`` compares with.
    """

    name: str
    path: Any
    problem: str
    baselines: Any = None


def register_set(name: str, path: Any, *, problem: str, baselines: Any = None) -> None:
    """Announce a stored set shipped by a plugin (read by ``lcpbench check`` and the report)."""
    old = _SETS.get(name)
    if old is not None and str(old.path) != str(path):
        raise ValueError(f"stored set {name!r} is registered twice ({old.path} and {path}); "
                         "rename one of the files")
    _SETS[name] = SetInfo(name, path, problem, baselines)
