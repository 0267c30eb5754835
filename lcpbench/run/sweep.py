"""Sweep plans: solver and problem specs expanded to the list of runs.

A spec is ``name[:key=value,...]``. A value in brackets sweeps:
``bi-pqn:low=[p3,p4,p6]`` is three solvers, and several swept keys expand to
their Cartesian product. A parameter whose type is itself a list (e.g.
``multi-pqn:lows=[p6,p3]``) takes the bracketed list as one value; sweep it
with nested brackets, ``lows=[[p6,p3],[p4,p3]]``.

A sweep can also come from a TOML file (``--config``)::

    solvers = ["bb-pgd", "mono-pqn", "bi-pqn:low=[p3,p4]"]
    problems = ["random-spd:count=4", "planted"]
    tol = 1e-8
    stop = "paper"
    repeat = 1
    seed = 0
    timeout = 60
    max_emvps = 5000

Every run of the plan has a stable id (a hash of what defines it), which is what
lets an interrupted sweep resume without redoing or duplicating rows.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import json
import math
import sys
import typing
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Optional

from lcpbench.core import guards
from lcpbench.core.registry import get_problem, get_solver, problem_estimate, problems, solvers
from lcpbench.core.residuals import STOP_RULES
from lcpbench.core.specs import make_params, parse_spec, split_top_level

__all__ = ["Spec", "RunSpec", "Sweep", "expand", "per_low", "load_config", "default_sweep",
           "spec_count", "SweepEstimate", "estimate_sweep"]


@dataclass(frozen=True)
class Spec:
    """One solver or problem with concrete parameters.

    Attributes
    ----------
    name : str
        Registry name.
    given : tuple of (str, str)
        The parameters as the user wrote them (for labels).
    params : dict
        All parameters after validation (defaults filled in), JSON-ready.
    """

    name: str
    given: tuple
    params: dict = field(hash=False, compare=False)

    @property
    def label(self) -> str:
        """``name:k=v,...`` with only the parameters the user set."""
        if not self.given:
            return self.name
        return self.name + ":" + ",".join(f"{k}={v}" for k, v in self.given)

    def values(self) -> dict:
        return dict(self.given)



def per_low(spec: Spec, lows: Iterable[str]) -> list[Spec]:
    """A multi-fidelity solver spec that names no low operator, once per low in ``lows``.

    ``bi-pqn`` needs one low operator; on an instance with several (a stored
    set with p3, p4 and RPY fidelities) the sweep runs it at each, as the
    paper's table reports Bi-PQN per low fidelity. The solver's registered
    :class:`~lcpbench.core.registry.LowOperators` says which parameter names
    that operator. Specs that name their low operator (or a chain), solvers
    without such a parameter and instances with fewer than two lows give ``[spec]``.
    """
    lows = sorted(lows)
    declared = get_solver(spec.name).lows
    if not declared.one_per_low(spec.params) or len(lows) < 2:
        return [spec]
    key = declared.one
    given = tuple(kv for kv in spec.given if kv[0] != key)
    return [Spec(spec.name, given + ((key, k),), {**spec.params, key: k}) for k in lows]

def _is_list_type(tp: Any) -> bool:
    origin = typing.get_origin(tp)
    if origin is typing.Union:
        return any(_is_list_type(a) for a in typing.get_args(tp))
    return origin in (list, tuple)


def _items(value: str) -> Optional[list[str]]:
    v = value.strip()
    if v.startswith("[") and v.endswith("]"):
        return [s.strip() for s in split_top_level(v[1:-1])]
    return None


@functools.lru_cache(maxsize=256)
def _registered(kind: str, name: str) -> tuple[Any, dict]:
    """The registry info of a solver or problem and its parameters' type hints."""
    info = get_solver(name) if kind == "solver" else get_problem(name)
    return info, typing.get_type_hints(info.params)


def _axes(spec: str, kind: str, seed: Optional[int] = None, *, cached: bool = False
          ) -> tuple[str, Any, list]:
    """``(name, registry info, axes)`` of a spec: one list of ``(key, value)`` per key.

    ``cached``: look the name up in a cache (for counting many specs; the registry as it
    was at the first lookup of that name).
    """
    name, values = parse_spec(spec)
    if cached:
        info, types = _registered(kind, name)
    else:
        info = get_solver(name) if kind == "solver" else get_problem(name)
        types = typing.get_type_hints(info.params)
    if kind == "problem" and seed is not None and "seed" in types and "seed" not in values:
        values["seed"] = str(seed)
    axes = []
    for key, value in values.items():
        items = _items(value)
        if items is None:
            axes.append([(key, value)])
        elif key in types and _is_list_type(types[key]):
            nested = [_items(i) for i in items]
            if items and all(n is not None for n in nested):
                axes.append([(key, i) for i in items])      # [[a,b],[c]]: sweep over lists
            else:
                axes.append([(key, value)])                  # [a,b]: one list value
        else:
            if not items:
                raise ValueError(f"{spec!r}: {key}=[] sweeps over no value, so the spec would "
                                 f"make no run; give the values to sweep, e.g. {key}=[a,b]")
            axes.append([(key, i) for i in items])
    return name, info, axes


def spec_count(spec: str, kind: str) -> int:
    """How many specs :func:`expand` makes of ``spec``, by arithmetic on its brackets.

    Nothing is validated or built: ``bi-pqn:low=[p3,p4],memory=[5,10,20]`` is 6.
    """
    if isinstance(spec, str) and "[" not in spec:
        return 1
    return math.prod(len(axis) for axis in _axes(spec, kind, cached=True)[2])


def expand(spec: str, kind: str, seed: Optional[int] = None) -> list[Spec]:
    """Expand ``name:k=[a,b],...`` into validated :class:`Spec` objects.

    Parameters
    ----------
    spec : str
    kind : {"solver", "problem"}
    seed : int, optional
        For problems: the value of a ``seed`` parameter the spec leaves unset.

    Raises
    ------
    KeyError, ValueError, TypeError
        Unknown name or parameter, or a value of the wrong type, with the
        registry's message (nothing is run before the whole plan is valid).
    """
    name, info, axes = _axes(spec, kind, seed)
    out = []
    for combo in itertools.product(*axes) if axes else [()]:
        given = tuple(sorted(combo))
        params = make_params(name, info.params, dict(given))
        out.append(Spec(name, given, _jsonable(dataclasses.asdict(params))))
    return out


def _jsonable(d: dict) -> dict:
    return json.loads(json.dumps(d, default=str))


@dataclass(frozen=True)
class RunSpec:
    """One solve of the plan."""

    problem: Spec
    instance: int
    instance_name: str
    solver: Spec
    repeat: int
    tol: float
    stop: str
    max_emvps: float

    @property
    def run_id(self) -> str:
        key = json.dumps({"problem": [self.problem.name, self.problem.params],
                          "instance": self.instance_name, "index": self.instance,
                          "solver": [self.solver.name, self.solver.params],
                          "repeat": self.repeat, "tol": self.tol, "stop": self.stop,
                          "max_emvps": self.max_emvps}, sort_keys=True)
        return hashlib.sha1(key.encode()).hexdigest()[:16]


@dataclass
class Sweep:
    """What ``lcpbench run`` does: solvers x problems x repeats at one stop rule."""

    solvers: list[str]
    problems: list[str]
    tol: float = 1e-8
    stop: str = "paper"
    repeat: int = 1
    seed: int = 0
    timeout: Optional[float] = None
    max_emvps: float = 5000.0

    def __post_init__(self) -> None:
        if not self.solvers:
            raise ValueError("the sweep has no solver; give --solver NAME (see `lcpbench list`)")
        if not self.problems:
            raise ValueError("the sweep has no problem; give --problem NAME (see `lcpbench list`)")
        if self.stop not in STOP_RULES:
            raise ValueError(f"stop must be one of {', '.join(STOP_RULES)}, got {self.stop!r}")
        if not self.tol > 0:
            raise ValueError(f"tol must be > 0, got {self.tol}")
        if self.repeat < 1:
            raise ValueError(f"repeat must be >= 1, got {self.repeat}")
        if self.timeout is not None and not self.timeout > 0:
            raise ValueError(f"timeout must be > 0 seconds, got {self.timeout}")
        if self.timeout is not None and not self.timeout <= MAX_TIMEOUT_S:
            raise ValueError(f"timeout {self.timeout:g} s is over the longest per-run limit of "
                             f"{MAX_TIMEOUT_S:g} s (30 days); leave --timeout out for no limit")
        if not (isinstance(self.max_emvps, (int, float)) and math.isfinite(self.max_emvps)):
            raise ValueError(f"budget max_emvps must be a finite number, got {self.max_emvps}; "
                             "give a large budget instead (e.g. 1e9)")

    def solver_specs(self) -> list[Spec]:
        return _unique(s for spec in self.solvers for s in expand(spec, "solver"))

    def problem_specs(self) -> list[Spec]:
        return _unique(p for spec in self.problems for p in expand(spec, "problem", self.seed))

    def config(self) -> dict:
        """The configuration that defines the rows (stored in ``meta.json``)."""
        return {"solvers": list(self.solvers), "problems": list(self.problems), "tol": self.tol,
                "stop": self.stop, "repeat": self.repeat, "seed": self.seed,
                "max_emvps": self.max_emvps}


def _unique(specs) -> list[Spec]:
    seen, out = set(), []
    for s in specs:
        key = (s.name, json.dumps(s.params, sort_keys=True))
        if key not in seen:
            seen.add(key)
            out.append(s)
    return out


#: The longest per-run time limit a sweep accepts (30 days): beyond it the platform's
#: timers and timestamps overflow; no limit at all is no ``timeout``.
MAX_TIMEOUT_S = 30 * 86400.0

_CONFIG_KEYS = {"solvers", "problems", "tol", "stop", "repeat", "seed", "timeout", "max_emvps"}


def load_config(path: str) -> dict:
    """Read a sweep TOML file into keyword arguments of :class:`Sweep`."""
    if sys.version_info >= (3, 11):
        import tomllib
    else:   # Python 3.10: tomli is the package tomllib was taken from
        import tomli as tomllib

    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise FileNotFoundError(f"sweep config {path!r} not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"sweep config {path!r} is not valid TOML: {exc}") from None
    if not data:
        raise ValueError(f"sweep config {path!r} is empty; give at least solvers = [...] and "
                         "problems = [...] (see sweeps/ for examples)")
    unknown = set(data) - _CONFIG_KEYS
    if unknown:
        raise ValueError(f"sweep config {path!r}: unknown key(s) {', '.join(sorted(unknown))}; "
                         f"allowed: {', '.join(sorted(_CONFIG_KEYS))}")
    for key in ("solvers", "problems"):
        if key in data and (not isinstance(data[key], list) or
                            not all(isinstance(s, str) for s in data[key])):
            raise ValueError(f"sweep config {path!r}: {key} must be a list of strings")
    return data


def default_sweep() -> tuple[list[str], list[str]]:
    """Every listed MVP-only solver and reference solver, on the default problems."""
    sv = [name for name, info in sorted(solvers().items())
          if info.listed and (info.mvp_only or info.reference)]
    pb = [name for name, info in sorted(problems().items()) if info.default]
    return sv, pb


# ----------------------------------------------------------------------------- sweep size
#: Planning seconds per problem spec (parameters checked, instances listed), per instance
#: beside its matrix work and per run (its spec and id): measured on a 2-core machine.
PLAN_S_PER_SPEC, PLAN_S_PER_INSTANCE, PLAN_S_PER_RUN = 1e-3, 2e-3, 4e-5
#: Bytes a planned run holds (its spec, its id, its row of bookkeeping).
PLAN_BYTES_PER_RUN = 1024


@dataclass(frozen=True)
class SweepEstimate:
    """What planning a sweep costs, estimated before it is planned.

    Attributes
    ----------
    runs : int
        Runs of the plan (multi-fidelity solvers count once per instance).
    instances : int
        Instances built (a family without a registered estimate counts as one).
    bytes : float
        Memory of the instances and the plan.
    seconds : float
        Planning time (building the instances, expanding the specs).
    """

    runs: int
    instances: int
    bytes: float
    seconds: float


def _over(what: str, limit: str) -> str:
    return f"{what}; make the sweep smaller, or pass --force (limit: {limit})"


def estimate_sweep(sweep: Sweep, *, force: bool = False, progress: bool = False
                   ) -> SweepEstimate:
    """Count and price the sweep's runs before planning it; refuse it past the limits.

    The number of specs comes first, by arithmetic on the brackets (a sweep of a million
    specs is refused in milliseconds); then each problem spec's registered estimate
    (:func:`lcpbench.core.registry.problem_estimate`) gives its instances, memory and
    build work.

    Raises
    ------
    lcpbench.core.guards.TooLarge
        More than :data:`~lcpbench.core.guards.MAX_RUNS` runs, more memory than the
        limit or more planning time than :data:`~lcpbench.core.guards.TIME_LIMIT_S`,
        unless ``force``; the message gives the estimate.
    """
    from tqdm.auto import tqdm

    n_solvers = sum(spec_count(s, "solver") for s in sweep.solvers)
    n_problems = sum(spec_count(p, "problem") for p in sweep.problems)
    floor = n_solvers * n_problems * sweep.repeat
    if force and floor > guards.MAX_RUNS:         # forced: no second pass over the specs
        return SweepEstimate(floor, n_problems, float("nan"), float("nan"))
    if floor > guards.MAX_RUNS:
        raise guards.TooLarge(_over(
            f"the sweep makes at least {floor:,} runs ({n_solvers:,} solver spec(s) x "
            f"{n_problems:,} problem spec(s) x {sweep.repeat} repeat(s))",
            f"{guards.MAX_RUNS:,} runs"))
    instances, nbytes, flops = 0, 0.0, 0.0
    specs = tqdm(sweep.problem_specs(), desc="estimating", unit="spec", file=sys.stderr,
                 disable=not progress, delay=2.0)
    for ps in specs:
        info = get_problem(ps.name)
        est = problem_estimate(ps.name, make_params(ps.name, info.params, ps.values()))
        if est is None:
            instances += 1
            continue
        guards.check(ps.label, est, force=force)
        instances, nbytes, flops = instances + est.instances, nbytes + est.bytes, flops + est.flops
    runs = n_solvers * instances * sweep.repeat
    nbytes += runs * PLAN_BYTES_PER_RUN
    seconds = (guards.seconds_for(flops) + n_problems * PLAN_S_PER_SPEC
               + instances * PLAN_S_PER_INSTANCE + runs * PLAN_S_PER_RUN)
    out = SweepEstimate(runs, instances, nbytes, seconds)
    if force:
        return out
    if runs > guards.MAX_RUNS:
        raise guards.TooLarge(_over(f"the sweep makes about {runs:,} runs ({instances:,} "
                                    f"instance(s) x {n_solvers:,} solver spec(s) x "
                                    f"{sweep.repeat} repeat(s))", f"{guards.MAX_RUNS:,} runs"))
    limit = guards.memory_limit()
    if nbytes > limit:
        raise guards.TooLarge(_over(
            f"planning the sweep holds about {guards.format_bytes(nbytes)} ({instances:,} "
            f"instance(s), {runs:,} runs)", f"{guards.format_bytes(limit)}, "
            f"{guards.MEMORY_FRACTION:.0%} of the available memory"))
    if seconds > guards.TIME_LIMIT_S:
        raise guards.TooLarge(_over(
            f"planning the sweep takes about {guards.format_seconds(seconds)} before its first "
            f"run ({n_problems:,} problem spec(s), {instances:,} instance(s), {runs:,} runs)",
            guards.format_seconds(guards.TIME_LIMIT_S)))
    return out
