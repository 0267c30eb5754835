"""Solver, problem and scene specs: ``name:key=value,...`` strings and typed parameters.

The CLI form of a choice is ``name:key=value,key=value``; a value in brackets is
a list (``low=[p3,p4]``). :func:`parse_spec` splits a spec into its name and raw
string values; :func:`make_params` converts them by the types of the plugin's frozen
parameter dataclass (``int``, ``float``, ``bool``, ``str``, ``Literal[...]``,
``Optional``, ``list``/``tuple``) and reports an unknown key or a bad value by name.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import typing
from dataclasses import dataclass
from typing import Any, Optional

__all__ = ["split_top_level", "parse_spec", "make_params", "describe_params", "Bounds", "Doc",
           "CheckedParams", "check_bounds"]


def split_top_level(text: str, sep: str = ",", *, keep_empty: bool = False) -> list[str]:
    """Split on ``sep`` outside brackets: ``"a=1,b=[x,y]"`` -> ``["a=1", "b=[x,y]"]``.

    Empty pieces are dropped unless ``keep_empty``.
    """
    out: list[str] = []
    cur: list[str] = []
    depth = 0
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
    if keep_empty:
        return [s.strip() for s in out] if text.strip() else []
    return [s.strip() for s in out if s.strip()]


def parse_spec(spec: str) -> tuple[str, dict[str, str]]:
    """``"bi-pqn:low=p4,memory=10"`` -> ``("bi-pqn", {"low": "p4", "memory": "10"})``.

    Values stay strings here; :func:`make_params` converts them by type.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"empty solver/problem spec {spec!r}; use NAME[:key=value,...]")
    name, _, rest = spec.strip().partition(":")
    if "," in name:
        raise ValueError(f"spec {spec!r}: a comma in the name {name.strip()!r}; give one spec "
                         "per option (repeat --solver/--problem), parameters after ':'")
    if len(split_top_level(rest)) != len(split_top_level(rest, keep_empty=True)):
        raise ValueError(f"spec {spec!r}: an empty parameter (a stray comma); remove it, "
                         "e.g. NAME:key=value,key2=value2")
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
                raise TypeError(f"{what} expects a number, got {value!r}") from None
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


# ---------------------------------------------------------------------- declared bounds
@dataclass(frozen=True)
class Doc:
    """The documentation of a parameter, declared in its type hint beside its bounds.

    ``n: Annotated[int, Bounds(ge=1), Doc("Size of every instance.")]``: a type alias
    that several parameter classes share documents the parameter once. An entry of
    the class's own ``Parameters`` docstring section takes precedence.
    """

    text: str


@dataclass(frozen=True)
class Bounds:
    """Allowed values of a numeric parameter, declared in its type hint.

    ``count: Annotated[int, Bounds(ge=1)] = 5`` declares an integer >= 1. A
    parameter dataclass that derives from :class:`CheckedParams` checks every
    declared bound when it is built (from the CLI, a sweep or Python), and the
    error names the parameter, what it accepts and the value given. In
    ``tuple[Annotated[int, Bounds(...)], ...]`` the bound applies to every item;
    ``Literal`` fields are held to their choices the same way. String conversion
    ignores the annotation: it sees the plain type.

    Attributes
    ----------
    ge, gt, le, lt : float, optional
        Inclusive (``ge``, ``le``) and strict (``gt``, ``lt``) limits.
    finite : bool
        Refuse inf (nan is always refused; default True).
    """

    ge: Optional[float] = None
    gt: Optional[float] = None
    le: Optional[float] = None
    lt: Optional[float] = None
    finite: bool = True

    def admits(self, value: float) -> bool:
        """True when ``value`` lies within the bounds."""
        v = float(value)
        if math.isnan(v) or (self.finite and math.isinf(v)):
            return False
        return ((self.ge is None or v >= self.ge) and (self.gt is None or v > self.gt)
                and (self.le is None or v <= self.le) and (self.lt is None or v < self.lt))

    def describe(self, integer: bool) -> str:
        """``"an integer in 1..40"``, ``"a finite number >= 0"``: what the bounds accept."""
        kind = "an integer" if integer else ("a finite number" if self.finite else "a number")
        if self.ge is not None and self.le is not None:
            return f"{kind} in {self.ge:g}..{self.le:g}"
        limits = [f"{op} {lim:g}" for op, lim in ((">=", self.ge), (">", self.gt),
                                                  ("<=", self.le), ("<", self.lt))
                  if lim is not None]
        return " ".join([kind, " and ".join(limits)]).strip()


def _check_value(label: str, tp: Any, value: Any) -> None:
    origin = typing.get_origin(tp)
    if origin is typing.Annotated:
        base, *extras = typing.get_args(tp)
        for bound in (e for e in extras if isinstance(e, Bounds)):
            integer = base is int
            number = isinstance(value, numbers.Integral if integer else numbers.Real)
            if isinstance(value, bool) or not number or not bound.admits(value):
                raise ValueError(f"{label} must be {bound.describe(integer)}, got {value!r}")
        _check_value(label, base, value)
    elif origin is typing.Literal and value not in typing.get_args(tp):
        raise ValueError(f"{label} must be one of "
                         f"{', '.join(map(repr, typing.get_args(tp)))}, got {value!r}")
    elif origin in (tuple, list) and isinstance(value, (tuple, list)):
        item_t = typing.get_args(tp)[0] if typing.get_args(tp) else Any
        for item in value:
            _check_value(f"each of {label}", item_t, item)


@functools.cache
def _type_hints(cls: type, extras: bool) -> dict[str, Any]:
    """``typing.get_type_hints`` of a parameter class, resolved once (a resolution takes
    about a millisecond, as much as a small solve)."""
    return typing.get_type_hints(cls, include_extras=extras)


def check_bounds(params: Any) -> None:
    """Check the fields of parameter dataclass ``params``: :class:`Bounds`, ``Literal`` choices.

    Raises
    ------
    ValueError
        Naming the first field outside its bounds, what it accepts and its value.
    """
    hints = _type_hints(type(params), True)  # type: ignore[arg-type]
    for f in dataclasses.fields(params):
        _check_value(f.name, hints[f.name], getattr(params, f.name))


class CheckedParams:
    """Base of parameter dataclasses that declare :class:`Bounds` in their type hints.

    Its ``__post_init__`` runs :func:`check_bounds`; a subclass with checks that
    relate several fields defines its own ``__post_init__`` and calls
    ``super().__post_init__()`` first.
    """

    def __post_init__(self) -> None:
        check_bounds(self)


def make_params(owner: str, cls: type, values: Optional[dict] = None):
    """Build the frozen parameter dataclass ``cls`` from ``values``.

    Strings are converted by the field's type hint; unknown keys and values of
    the wrong type raise errors naming the parameter and the accepted values.
    Fields may declare :class:`Bounds` (checked by :class:`CheckedParams`) and validate
    themselves further in ``__post_init__``.
    """
    values = dict(values or {})
    hints = _type_hints(cls, False)
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
    """``(name, type, default, doc)`` for every parameter.

    The docs come from the ``Parameters`` sections of the class's docstring and of its
    bases', so parameters declared once in a base class are documented once there.
    """
    hints = typing.get_type_hints(cls)
    declared = typing.get_type_hints(cls, include_extras=True)
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):   # a subclass documents its own and overrides
        docs.update({k: v for k, v in _param_docs(klass.__dict__.get("__doc__") or "").items()
                     if v})
    out = []
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        tp = hints[f.name]
        if typing.get_origin(tp) is typing.Literal:
            tname = "one of " + "|".join(str(c) for c in typing.get_args(tp))
        else:
            tname = getattr(tp, "__name__", None) or str(tp).replace("typing.", "")
        out.append((f.name, tname, default, docs.get(f.name) or _declared_doc(declared[f.name])))
    return out


def _declared_doc(tp: Any) -> str:
    """The text of a :class:`Doc` in an ``Annotated`` type hint ("" without one)."""
    if typing.get_origin(tp) is typing.Annotated:
        return next((m.text for m in tp.__metadata__ if isinstance(m, Doc)), "")
    return ""


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
