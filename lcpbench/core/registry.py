"""Registries of solvers and problems, with typed parameters parsed from strings.

A solver plugin is a function ``solve(ctx, params) -> SolveResult`` decorated
with :func:`register_solver`; its parameters are a frozen dataclass. A problem
plugin is a function ``generate(params) -> list[LCP]`` decorated with
:func:`register_problem`. Built-in plugins (``lcpbench.solvers.*``,
``lcpbench.problems.*``) and third-party packages are found the same way, through
the entry-point groups ``lcpbench.solvers`` and ``lcpbench.problems``; the core
never imports a plugin by name.

The CLI form of a choice is ``name:key=value,key=value``; a value in brackets is
a list (``low=[p3,p4]``).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import sys
import difflib
import typing
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, Callable, Optional

__all__ = [
    "SolverInfo", "ProblemInfo", "register_solver", "register_problem", "get_solver",
    "get_problem", "solvers", "problems", "parse_spec", "make_params", "split_top_level",
]


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
    summary : str
        First line of the docstring.
    """

    name: str
    func: Callable
    params: type
    needs_dense: bool = False
    reference: bool = False
    multifidelity: bool = False
    summary: str = ""

    @property
    def mvp_only(self) -> bool:
        return not self.needs_dense


@dataclass(frozen=True)
class ProblemInfo:
    """A registered problem family: ``func(params) -> list[LCP]``."""

    name: str
    func: Callable
    params: type
    summary: str = ""
    default: bool = False


_SOLVERS: dict[str, SolverInfo] = {}
_PROBLEMS: dict[str, ProblemInfo] = {}
_LOADED = {"lcpbench.solvers": False, "lcpbench.problems": False}


def _check_name(name: str) -> None:
    if not name or name.lower() != name or " " in name or "_" in name or ":" in name:
        raise ValueError(f"registry name {name!r} must be kebab-case (lower case, '-')")


def _check_params(name: str, params: type) -> None:
    if not (dataclasses.is_dataclass(params) and params.__dataclass_params__.frozen):
        raise TypeError(f"parameters of {name!r} must be a frozen dataclass")
    for f in dataclasses.fields(params):
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise TypeError(f"parameter {f.name!r} of {name!r} needs a default")


def register_solver(name: str, params: type, *, needs_dense: bool = False,
                    reference: bool = False, multifidelity: bool = False):
    """Decorator registering ``func(ctx, params)`` as solver ``name``."""
    _check_name(name)
    _check_params(name, params)

    def deco(func):
        doc = (func.__doc__ or "").strip().splitlines()
        info = SolverInfo(name, func, params, needs_dense, reference, multifidelity,
                          doc[0] if doc else "")
        old = _SOLVERS.get(name)
        if old is not None and (old.func.__module__, old.func.__qualname__) != \
                (func.__module__, func.__qualname__):
            raise ValueError(f"solver {name!r} is registered twice ({old.func.__module__} and "
                             f"{func.__module__}); pick another name")
        _SOLVERS[name] = info
        func.solver_info = info
        return func

    return deco


def register_problem(name: str, params: type, *, default: bool = False):
    """Decorator registering ``func(params) -> list[LCP]`` as problem family ``name``.

    ``default=True`` puts the family in the shipped default set of ``lcpbench run``.
    """
    _check_name(name)
    _check_params(name, params)

    def deco(func):
        doc = (func.__doc__ or "").strip().splitlines()
        info = ProblemInfo(name, func, params, doc[0] if doc else "", default)
        old = _PROBLEMS.get(name)
        if old is not None and (old.func.__module__, old.func.__qualname__) != \
                (func.__module__, func.__qualname__):
            raise ValueError(f"problem {name!r} is registered twice; pick another name")
        _PROBLEMS[name] = info
        func.problem_info = info
        return func

    return deco


#: Environment variable naming extra plugin modules or ``.py`` files (comma-separated),
#: imported when the registry first loads: for solvers and problems that are not packaged
#: with entry points (a script's own solver, test doubles). Dask workers and forked
#: children inherit it, so such plugins are known wherever runs execute.
PLUGINS_ENV = "LCPBENCH_PLUGINS"


def _load_env_plugins() -> None:
    for item in filter(None, (s.strip() for s in os.environ.get(PLUGINS_ENV, "").split(","))):
        try:
            if item.endswith(".py"):
                path = os.path.abspath(item)
                name = os.path.splitext(os.path.basename(path))[0]
                if name in sys.modules:
                    continue
                spec = importlib.util.spec_from_file_location(name, path)
                if spec is None or spec.loader is None:
                    raise ImportError(f"cannot import {path}")
                mod = importlib.util.module_from_spec(spec)
                sys.modules[name] = mod
                spec.loader.exec_module(mod)
            else:
                importlib.import_module(item)
        except Exception as exc:
            raise RuntimeError(f"plugin {item!r} named in ${PLUGINS_ENV} failed to load: "
                               f"{exc}") from exc


def _load(group: str) -> None:
    if _LOADED[group]:
        return
    _LOADED[group] = True
    if group == "lcpbench.solvers":
        _load_env_plugins()
    eps = entry_points(group=group)
    if not eps:
        raise RuntimeError(
            f"no plugins found in entry-point group {group!r}: lcpbench is not installed. "
            "Install it with `pip install -e .` from the repository root")
    for ep in eps:
        try:
            ep.load()
        except Exception as exc:
            raise RuntimeError(f"plugin {ep.name!r} ({ep.value}) of {group!r} failed to "
                               f"load: {exc}") from exc


def solvers() -> dict[str, SolverInfo]:
    """All registered solvers, loading entry points on first use."""
    _load("lcpbench.solvers")
    return dict(sorted(_SOLVERS.items()))


def problems() -> dict[str, ProblemInfo]:
    """All registered problem families, loading entry points on first use."""
    _load("lcpbench.problems")
    return dict(sorted(_PROBLEMS.items()))


def _unknown(kind: str, name: str, known) -> KeyError:
    close = difflib.get_close_matches(name, list(known), n=3)
    hint = f" Did you mean {', '.join(close)}?" if close else ""
    return KeyError(f"unknown {kind} {name!r}.{hint} Known: {', '.join(known)} "
                    f"(`lcpbench list` shows them with their parameters)")


def get_solver(name: str) -> SolverInfo:
    """The registered solver ``name`` (KeyError naming the known ones otherwise)."""
    all_ = solvers()
    if name not in all_:
        raise _unknown("solver", name, all_)
    return all_[name]


def get_problem(name: str) -> ProblemInfo:
    """The registered problem family ``name``."""
    all_ = problems()
    if name not in all_:
        raise _unknown("problem", name, all_)
    return all_[name]


# ---------------------------------------------------------------------- parsing
def split_top_level(text: str, sep: str = ",") -> list[str]:
    """Split on ``sep`` outside brackets: ``"a=1,b=[x,y]"`` -> ``["a=1", "b=[x,y]"]``."""
    out, depth, cur = [], 0, []
    for ch in text:
        if ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
            if depth < 0:
                raise ValueError(f"unbalanced bracket in {text!r}")
        if ch == sep and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    if depth != 0:
        raise ValueError(f"unbalanced bracket in {text!r}")
    out.append("".join(cur))
    return [s.strip() for s in out if s.strip()]


def parse_spec(spec: str) -> tuple[str, dict[str, str]]:
    """``"bi-pqn:low=p4,memory=10"`` -> ``("bi-pqn", {"low": "p4", "memory": "10"})``.

    Values stay strings here; :func:`make_params` converts them by type.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"empty solver/problem spec {spec!r}; use NAME[:key=value,...]")
    name, _, rest = spec.strip().partition(":")
    raw: dict[str, str] = {}
    for item in split_top_level(rest):
        key, eq, val = item.partition("=")
        key = key.strip().replace("-", "_")
        if not eq or not key:
            raise ValueError(f"malformed parameter {item!r} in {spec!r}; use key=value")
        if key in raw:
            raise ValueError(f"parameter {key!r} given twice in {spec!r}")
        raw[key] = val.strip()
    return name.strip(), raw


_TRUE = {"true", "1", "yes", "on"}
_FALSE = {"false", "0", "no", "off"}


def _convert(owner: str, key: str, tp: Any, value: Any) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    what = f"parameter {key!r} of {owner!r}"
    if origin is typing.Union:
        non_none = [a for a in args if a is not type(None)]
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null", "")):
            if type(None) in args:
                return None
        errors = []
        for a in non_none:
            try:
                return _convert(owner, key, a, value)
            except (TypeError, ValueError) as exc:
                errors.append(str(exc))
        raise TypeError(f"{what}: {value!r} matches none of {tp}: {'; '.join(errors)}")
    if origin is typing.Literal:
        for a in args:
            if value == a or (isinstance(value, str) and str(a) == value):
                return a
        raise ValueError(f"{what} must be one of {', '.join(map(repr, args))}, got {value!r}")
    if origin in (tuple, list):
        item_t = args[0] if args else str
        if isinstance(value, str):
            s = value.strip()
            if s.startswith("[") and s.endswith("]"):
                s = s[1:-1]
            items = split_top_level(s) if s else []
        elif isinstance(value, (list, tuple)):
            items = list(value)
        else:
            items = [value]
        return tuple(_convert(owner, key, item_t, v) for v in items)
    if tp is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in _TRUE | _FALSE:
            return value.lower() in _TRUE
        raise TypeError(f"{what} expects true/false, got {value!r}")
    if tp is int:
        if isinstance(value, bool):
            raise TypeError(f"{what} expects an integer, got {value!r}")
        if isinstance(value, int):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, str):
            try:
                return int(value)
            except ValueError:
                try:
                    f = float(value)
                except ValueError:
                    f = None
                if f is not None and f.is_integer():
                    return int(f)
        raise TypeError(f"{what} expects an integer, got {value!r}")
    if tp is float:
        if isinstance(value, bool):
            raise TypeError(f"{what} expects a number, got {value!r}")
        if isinstance(value, (int, float)):
            return float(value)
        if isinstance(value, str):
            try:
                return float(value)
            except ValueError:
                pass
        raise TypeError(f"{what} expects a number, got {value!r}")
    if tp is str:
        if isinstance(value, str):
            return value
        raise TypeError(f"{what} expects a string, got {value!r}")
    if tp is Any or tp is object:
        return value
    if isinstance(value, tp):
        return value
    raise TypeError(f"{what}: cannot convert {value!r} to {tp}")


def make_params(owner: str, cls: type, values: Optional[dict] = None):
    """Build the frozen parameter dataclass ``cls`` from ``values``.

    Strings are converted by the field's type hint; unknown keys and values of
    the wrong type raise errors naming the parameter and the accepted values.
    Fields may validate themselves further in ``__post_init__``.
    """
    values = dict(values or {})
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, val in values.items():
        k = key.replace("-", "_")
        if k not in fields:
            close = difflib.get_close_matches(k, list(fields), n=2)
            hint = f" Did you mean {', '.join(close)}?" if close else ""
            valid = ", ".join(fields) or "(none)"
            raise TypeError(f"unknown parameter {key!r} for {owner!r}.{hint} Valid: {valid}")
        kwargs[k] = _convert(owner, k, hints[k], val)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise type(exc)(f"{owner}: {exc}") from None


def describe_params(cls: type) -> list[tuple[str, str, Any, str]]:
    """``(name, type, default, doc)`` for every parameter (docs from the class docstring)."""
    hints = typing.get_type_hints(cls)
    docs = _param_docs(cls.__doc__ or "")
    out = []
    for f in dataclasses.fields(cls):
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        tp = hints[f.name]
        tname = getattr(tp, "__name__", None) or str(tp).replace("typing.", "")
        out.append((f.name, tname, default, docs.get(f.name, "")))
    return out


def _param_docs(doc: str) -> dict[str, str]:
    """Parse a numpy-style ``Parameters`` section into ``{name: whole description}``."""
    lines = doc.splitlines()
    out: dict[str, str] = {}
    in_params = False
    cur = None
    for i, line in enumerate(lines):
        s = line.strip()
        if s in ("Parameters", "Attributes"):
            in_params = True
            continue
        if in_params and set(s) == {"-"}:
            continue
        if in_params and s and i + 1 < len(lines) and set(lines[i + 1].strip()) == {"-"} \
                and len(lines[i + 1].strip()) > 2:
            break
        if not in_params:
            continue
        indent = len(line) - len(line.lstrip())
        if s and ":" in s and indent <= 4:
            names = s.split(":")[0]
            cur = [n.strip() for n in names.split(",")]
            for n in cur:
                out.setdefault(n, "")
        elif s and cur:
            for n in cur:
                out[n] = f"{out[n]} {s}".strip()
    return out
