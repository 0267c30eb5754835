"""``lcpbench generate``: a dense stored set from a live suspension scene.

The scene (e.g. ``lattice:m=3,model=rpy``) is simulated with one solver, one
LCP per forward Euler step, exactly as ``lcpbench simulate`` does. For every
chosen step the instance is written to an HDF5 set (layout of
:mod:`lcpbench.sets`):

* ``A``: the high-fidelity ``D' M D`` formed densely by ``n`` uncounted MVPs
  and symmetrised, ``(A + A') / 2`` (the boundary-integral mobility is only
  symmetric to about 1e-3; the measured asymmetry ``max|A - A'| / max|A|`` is
  kept as instance attr ``asymmetry``);
* ``b`` and the warm start ``x0`` the online solver got (previous step's
  forces carried by pair identity), when there is one;
* ``low/<name>/A`` for every requested fidelity, formed and symmetrised the
  same way, with ``cost_ratio = t_low / t_high`` (seconds per MVP measured on
  this instance with :func:`~lcpbench.core.probes.measure_cost`)
  and the fidelity knobs (``model``, ``p``, ``eps_gmres``, ``t_mvp``);
* ``reference``: the consensus of the QP solvers (:func:`lcpbench.reference`)
  on the dense ``A``, with its ``accepted`` flag;
* provenance: root attrs ``generator`` (the command line), ``name``,
  ``scene``, ``scene_params``, ``solver``, ``steps``, ``lows``, ``versions``;
  instance attrs ``step``, ``M``, ``n``, ``t_mvp_high``, ``scene``.

Step numbers are the scene's 0-based step indices. Steps before the first
chosen one (and between chosen ones) are simulated but not stored. The scene is
deterministic, so a run into an existing file skips the instances the file
already holds (after verifying them): an interrupted run resumes, and a longer
``--steps`` range appends. The simulation never depends on what is stored: it
always solves the matrix-free LCP, so a resumed file holds the same instances
as one written in a single run.

Resuming does not re-simulate the steps already done: after every step the
scene's state (positions, orientations, the previous contacts and forces) is
checkpointed atomically to ``<out stem>.checkpoint.npz`` beside the set (format
of :mod:`lcpbench.workflows.checkpoint`), and a rerun starts from it when its
settings (scene, solver, stop rule, tolerance, budget) are the same and no step
still to be stored lies before it. Otherwise the rerun says why and simulates
from step 0. The checkpoint stays after the run, so a longer ``--steps`` range
appends without re-simulating either; delete it to reclaim its few kilobytes.

A write that fails (disk full, I/O error) leaves the set as it was before that
instance (:class:`~lcpbench.sets.SetWriter` replaces the file atomically after
each instance) and the checkpoint at the step before it, and raises
:class:`~lcpbench.sets.StoredSetError` (``OSError`` for the checkpoint) with one
line saying so; with space again the same command resumes. Only one run writes a
set at a time.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import platform
import re
import shlex
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Optional, Union

import numpy as np
import scipy.sparse as sp

from lcpbench import __version__
from lcpbench.core.context import Budget
from lcpbench.core.defaults import DEFAULT_SOLVER
from lcpbench.core.lcp import LCP
from lcpbench.core.operator import Operator, apply_uncounted, dense_uncounted
from lcpbench.core.probes import measure_cost
from lcpbench.core.ranges import format_ranges, parse_ranges
from lcpbench.core.reference import reference as consensus
from lcpbench.core.registry import get_solver, make_scene
from lcpbench.core.scene import step_scene
from lcpbench.core.specs import make_params, parse_spec
from lcpbench.sets import SetWriter, instance_ids, read_instance
from lcpbench.workflows.checkpoint import Checkpoint, load_checkpoint, save_checkpoint

__all__ = ["generate", "parse_steps", "parse_lows", "instance_id", "default_cache_dir",
           "portable_command", "checkpoint_file", "GenerateSummary"]

_P_LIST = re.compile(r"^p\s*=\s*(.+)$")


# ----------------------------------------------------------------------------- parsing


def parse_steps(spec: Union[str, int, Iterable[int]]) -> list[int]:
    """Step indices from ``"31-50"``, ``"0,3,5-7"``, ``"7"`` or an iterable of ints.

    Ranges are inclusive; the result is sorted and without repeats.

    Raises
    ------
    ValueError
        Malformed text, a reversed range or a negative step.
    """
    if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool):
        items = [int(spec)]
    elif isinstance(spec, str):
        if not spec.strip():
            raise ValueError("--steps is empty; give step indices like 31-50 or 0,3,5-7")
        items = parse_ranges(spec, "--steps", "31-50 or 0,3,5-7 (0-based steps)")
    elif isinstance(spec, bool):
        raise TypeError(f"--steps: expected step indices, got {spec!r}; give e.g. 31-50")
    else:
        items = [int(s) for s in spec]
    if any(s < 0 for s in items):
        raise ValueError(f"--steps: step indices are 0-based and non-negative; got {items}")
    if not items:
        raise ValueError("--steps selects no step; give step indices like 31-50")
    return sorted(set(items))


def _eps_suffix(eps: float) -> str:
    e = -math.log10(eps)
    k = int(round(e))
    if not (0 < eps < 1) or abs(e - k) > 1e-9:
        raise ValueError(f"--eps {eps:g}: GMRES tolerances must be powers of ten below 1 "
                         "(1e-6, 1e-8, ...), so the fidelity can be named p<k>e<j>")
    return f"e{k}"


def parse_lows(lows: Sequence[str], eps: Sequence[float] = ()) -> list[str]:
    """Fidelity names from ``--low`` and ``--eps`` values.

    Parameters
    ----------
    lows : list of str
        Each item is ``p=3,4`` (boundary integral at orders 3 and 4), a fidelity
        name (``rpy``, ``self``, ``bim``, ``p4``, ``p4e6``) or a comma-separated
        list of names.
    eps : list of float
        GMRES tolerances; every ``p=`` order is generated at each of them
        (``p=4`` with ``eps = 1e-6, 1e-8`` gives ``p4e6`` and ``p4e8``). Without
        ``eps`` the order takes the scene's ``eps_gmres`` (name ``p4``).

    Returns
    -------
    list of str
        Low-fidelity names in the given order, without repeats (the scene validates
        them: ``fidelity_knobs`` of its scene plugin).
    """
    suffixes = [_eps_suffix(float(e)) for e in eps]
    out: list[str] = []
    for item in lows:
        item = str(item).strip()
        m = _P_LIST.match(item)
        if m:
            orders = [t.strip() for t in m.group(1).split(",") if t.strip()]
            bad = [t for t in orders if not t.isdigit() or int(t) < 1]
            if bad or not orders:
                raise ValueError(f"--low {item!r}: orders must be positive integers, e.g. "
                                 "--low p=3,4")
            names = [f"p{int(t)}{s}" for t in orders for s in (suffixes or [""])]
        else:
            names = [t.strip() for t in item.split(",") if t.strip()]
            if not names:
                raise ValueError("--low is empty; use e.g. --low p=3,4 or --low rpy")
        for name in names:
            if name not in out:
                out.append(name)
    return out


def instance_id(step: int) -> str:
    """The instance id of a step: ``step00031``."""
    return f"step{int(step):05d}"


def default_cache_dir() -> Path:
    """Folder for generated sets: ``$LCPBENCH_CACHE/sets`` or ``~/.cache/lcpbench/sets``."""
    import os

    root = os.environ.get("LCPBENCH_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "lcpbench") / "sets"


# ----------------------------------------------------------------------------- generation


@dataclasses.dataclass
class GenerateSummary:
    """What :func:`generate` did.

    Attributes
    ----------
    path : Path
        The set file.
    written, kept : list of str
        Instance ids written by this run, and those already in the file.
    simulated : int
        Time steps simulated.
    references_rejected : list of str
        Written instances whose QP reference was not accepted (backends disagreed).
    seconds : float
        Wall time.
    """

    path: Path
    written: list
    kept: list
    simulated: int
    references_rejected: list
    seconds: float


def _versions() -> dict:
    import h5py
    import scipy

    return {"lcpbench": __version__, "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy.__version__, "h5py": h5py.__version__}


#: Columns of an implicit operator formed per progress update of :func:`_dense_sym`.
_COLUMNS_PER_UPDATE = 4
#: Seconds of forming before its progress bar shows.
_PROGRESS_DELAY = 2.0


def _dense_sym(op: Operator, desc: str = "", progress: bool = False
               ) -> tuple[np.ndarray, float]:
    """The operator as a symmetrised dense matrix and its relative asymmetry.

    An implicit operator is applied to the columns of the identity in order, a few at a
    time, under a progress bar (shown once forming has taken 2 s: at 125 spheres and
    p = 8 one matrix is minutes of mobility solves)."""
    impl = op._impl
    if isinstance(impl, np.ndarray) or sp.issparse(impl):
        A = np.asarray(dense_uncounted(op), dtype=np.float64)
    else:
        from tqdm.auto import tqdm

        n = op.shape[1]
        A = np.empty((n, n))
        eye = np.eye(n)
        with tqdm(total=n, desc=desc, unit="column", leave=False, delay=_PROGRESS_DELAY,
                  disable=not progress, file=sys.stderr) as bar:
            for j in range(0, n, _COLUMNS_PER_UPDATE):
                cols = slice(j, min(j + _COLUMNS_PER_UPDATE, n))
                A[:, cols] = apply_uncounted(op, eye[:, cols])
                bar.update(cols.stop - cols.start)
    scale = float(np.max(np.abs(A))) if A.size else 0.0
    asym = float(np.max(np.abs(A - A.T)) / scale) if scale > 0 else 0.0
    return 0.5 * (A + A.T), asym


def _cost(op: Operator) -> float:
    """Declared seconds per product, else timed on a cold product (an operator whose
    products reuse earlier work offers ``cold_products``, e.g. a live boundary-integral low)."""
    cold = getattr(op._impl, "cold_products", None)
    return float(op.cost) if op.cost else float(measure_cost(op, cold=cold))


def _check_resume(f, path: Path, config: dict) -> None:
    """Refuse to append to a file generated with another scene, solver or fidelities."""
    for key in ("scene_params", "solver", "lows"):
        if key not in f.attrs:
            continue
        old = f.attrs[key]
        old = old.decode() if isinstance(old, bytes) else str(old)
        if old != config[key]:
            raise ValueError(f"{path} was generated with {key} = {old}, this run has "
                             f"{config[key]}; resume with the same --scene, --solver, --low and "
                             "--eps, or write to another --out")


def portable_command(argv: Sequence[str]) -> str:
    """The command line as stored in a set's ``generator``, without machine-specific paths.

    Every absolute path (``--out /home/me/sets/x.h5``, ``--baseline=/tmp/b.json``) is
    replaced by its file name, so the command reads the same on every machine.
    """
    out = []
    for arg in argv:
        key, eq, value = arg.partition("=") if arg.startswith("--") and "=" in arg \
            else ("", "", arg)
        if Path(value).is_absolute():
            value = Path(value).name
        out.append(f"{key}={value}" if eq else value)
    return shlex.join(out)


def generate(scene_spec: str, steps: Union[str, Iterable[int]], out: Union[str, Path], *,
             solver: str = DEFAULT_SOLVER, lows: Sequence[str] = (), name: Optional[str] = None,
             title: Optional[str] = None, description: Optional[str] = None,
             tol: float = 1e-8, stop: str = "paper", max_emvps: float = 5000.0,
             progress: bool = True, argv: Optional[Sequence[str]] = None,
             compression: Optional[str] = None) -> GenerateSummary:
    """Simulate ``scene_spec`` and store the dense LCPs of the chosen ``steps``.

    Parameters
    ----------
    scene_spec : str
        Scene, e.g. ``lattice:m=3,model=rpy`` or ``lattice:m=3,model=bim,p=6``.
        Do not put ``low=`` in it; pass the fidelities as ``lows``.
    steps : str or iterable of int
        0-based steps to store (``"31-50"``); earlier steps are only simulated.
    out : str or Path
        The ``.h5`` file; created, or resumed when it exists.
    solver : str
        Solver that advances the simulation (``mono-pqn``; a multi-fidelity
        solver gets the ``lows`` at every step).
    lows : list of str
        Low fidelities to store (``p3e6``, ``rpy``, ``self``; see :func:`parse_lows`).
    name, title, description : str, optional
        Set name (default: the file stem) and the set's root attrs.
    tol, stop, max_emvps
        Stop rule and E-MVP budget of each simulation solve.
    progress : bool
        tqdm progress bar on stderr.
    argv : list of str, optional
        The command line stored as ``generator``.
    compression : str, optional
        h5py compression of the matrices (e.g. ``gzip``).

    Returns
    -------
    GenerateSummary

    Raises
    ------
    KeyError, TypeError, ValueError
        Bad scene, solver, step or fidelity; a file generated with other settings.
    lcpbench.sets.StoredSetError
        The existing file is truncated or corrupted (names instance and dataset), another
        run writes it, or an instance could not be written (the set keeps every finished
        instance; rerun to resume).
    OSError
        The checkpoint could not be written (the previous one is kept; rerun to resume).
    """
    import time

    t_start = time.perf_counter()
    wanted = parse_steps(steps)
    lows = list(dict.fromkeys(str(x) for x in lows))
    scene = make_scene(scene_spec)
    base = scene.params
    if base.low:
        raise ValueError(f"scene {scene_spec!r} sets low={list(base.low)}; pass the "
                         "fidelities with --low instead (they are stored per instance)")
    sname, sraw = parse_spec(solver)
    sinfo = get_solver(sname)
    make_params(sname, sinfo.params, sraw)
    if sinfo.multifidelity and not lows:
        raise ValueError(f"solver {solver!r} needs low-fidelity operators; add --low (e.g. "
                         "--low rpy) or simulate with mono-pqn")
    with_lows = dataclasses.replace(base, low=tuple(lows))    # validates the names
    sim_params = with_lows if sinfo.multifidelity else base
    out = Path(out)
    name = name or out.stem
    params_json = json.dumps(dataclasses.asdict(base), sort_keys=True, default=str)
    config = {"scene_params": params_json, "solver": solver, "lows": json.dumps(lows)}
    generator, title, description = _texts(
        scene_spec, scene.M, solver=solver, lows=lows, wanted=wanted, out=out, name=name,
        stop=stop, tol=tol, argv=argv, title=title, description=description)
    if out.exists() and out.stat().st_size > 0:   # verify what a resume would keep
        have = set(instance_ids(out))
        for s in wanted:
            if instance_id(s) in have:
                read_instance(out, instance_id(s))
    job = _Job(scene_spec=scene_spec, solver=solver, lows=lows, stop=stop, tol=float(tol),
               budget=Budget(max_emvps=max_emvps), with_lows=with_lows,
               sim_params=sim_params, ckpt_path=checkpoint_file(out), ckpt_config={
                   "scene": parse_spec(scene_spec)[0], "scene_params": json.dumps(
                       dataclasses.asdict(sim_params), sort_keys=True, default=str),
                   "solver": solver, "stop": stop, "tol": float(tol),
                   "max_emvps": float(max_emvps)}, progress=progress)
    with SetWriter(out, title=title, description=description, generator=generator,
                   compression=compression) as w:
        f = w.file
        _check_resume(f, out, config)
        job.kept = [instance_id(s) for s in wanted if w.has(instance_id(s))]
        if "scene" not in f.attrs:
            f.attrs.update({"name": name, "scene": scene_spec, "solver": solver,
                            "versions": json.dumps(_versions(), sort_keys=True),
                            "stop": stop, "tol": float(tol), **config})
        steps_text = format_ranges(sorted(set(wanted) | _stored_steps(w.ids())))
        old = f.attrs.get("steps")
        if (old.decode() if isinstance(old, bytes) else old) != steps_text:
            f.attrs["steps"] = steps_text        # unchanged, the set needs no rewrite
        todo = [s for s in wanted if instance_id(s) not in job.kept]
        if todo:
            _resume_scene(scene, job.ckpt_path, job.ckpt_config, todo[0])
        try:
            simulated = _simulate(w, scene, job, todo, desc=f"generate {name}",
                                  progress=progress)
        finally:
            scene.params = base
    return GenerateSummary(path=out, written=job.written, kept=job.kept, simulated=simulated,
                           references_rejected=job.rejected,
                           seconds=time.perf_counter() - t_start)


def _texts(scene_spec: str, M: int, *, solver: str, lows: Sequence[str], wanted: list,
           out: Path, name: str, stop: str, tol: float, argv: Optional[Sequence[str]],
           title: Optional[str], description: Optional[str]) -> tuple[str, str, str]:
    """The set's ``generator``, ``title`` and ``description`` (given ones kept)."""
    generator = portable_command(argv) if argv else (
        f"lcpbench generate --scene {shlex.quote(scene_spec)} --solver {shlex.quote(solver)} "
        f"--steps {format_ranges(wanted)} " + "".join(f"--low {x} " for x in lows)
        + f"--name {shlex.quote(name)} --out {shlex.quote(out.name)}")
    title = title or f"{name}: dense LCPs of {scene_spec}, steps {format_ranges(wanted)}"
    description = description or (
        f"Scene {scene_spec} ({M} particles) simulated with "
        f"{solver} (stop {stop}, tol {tol:g}); for each stored step the dense high-fidelity "
        f"A = D'MD (n MVPs, symmetrised), b, the warm start, the low fidelities "
        f"{', '.join(lows) or 'none'} with cost_ratio = t_low / t_high measured on the "
        "instance, and the QP consensus reference.")
    return generator, title, description


@dataclasses.dataclass
class _Job:
    """What the step loop of :func:`generate` needs, and what it reports back."""

    scene_spec: str
    solver: str
    lows: list
    stop: str
    tol: float
    budget: Budget
    with_lows: object                    # scene parameters with the lows (stored steps)
    sim_params: object                   # scene parameters of the simulation
    ckpt_path: Path
    ckpt_config: dict
    progress: bool = False
    kept: list = dataclasses.field(default_factory=list)
    written: list = dataclasses.field(default_factory=list)
    rejected: list = dataclasses.field(default_factory=list)


def _simulate(w: SetWriter, scene, job: _Job, todo: list, *, desc: str,
              progress: bool) -> int:
    """Simulate up to the last step of ``todo``, writing those steps; the steps simulated."""
    from tqdm.auto import tqdm

    last_needed = todo[-1] if todo else -1
    bar = tqdm(total=last_needed + 1, initial=min(scene.step_index, last_needed + 1),
               desc=desc, unit="step", disable=not progress, file=sys.stderr)
    simulated = 0
    try:
        while scene.step_index <= last_needed:
            k = scene.step_index
            store = k in todo
            scene.params = job.with_lows if store else job.sim_params
            # forward operator only: the stored matrices are (A + A')/2 of n forward
            # products (the live symmetrised operator would cost 2n solves)
            rec = step_scene(scene, job.solver, tol=job.tol, stop=job.stop, budget=job.budget,
                             symmetrize=False, before_solve=(
                                 functools.partial(_write_step, w, scene, k=k, job=job)
                                 if store else None))
            save_checkpoint(job.ckpt_path, Checkpoint(step=k, config=job.ckpt_config,
                                                      scene_state=scene.get_state(),
                                                      row={"step": k}))
            simulated += 1
            bar.set_postfix(step=k, n=rec.n, stored=len(job.written) + len(job.kept))
            bar.update(1)
    finally:
        bar.close()
    return simulated


def checkpoint_file(out: Union[str, Path]) -> Path:
    """The simulation checkpoint that :func:`generate` keeps beside the set ``out``."""
    out = Path(out)
    return out.with_name(f"{out.stem}.checkpoint.npz")


def _resume_scene(scene, path: Path, config: dict, first_todo: int) -> None:
    """Restore the scene from the checkpoint at ``path`` when it can serve this run."""
    if not path.exists():
        return
    why = None
    try:
        ckpt = load_checkpoint(path)
    except ValueError as exc:
        why = str(exc)
    else:
        changed = sorted(k for k in config if ckpt.config.get(k) != config[k])
        if changed:
            why = f"it was written with other settings ({', '.join(changed)})"
        elif ckpt.step >= first_todo:
            why = (f"it is after step {ckpt.step}, and step {first_todo} still has to be "
                   "stored")
        else:
            try:
                scene.set_state(ckpt.scene_state)
                return
            except (KeyError, ValueError) as exc:
                why = f"its state does not fit this scene ({exc})"
    print(f"lcpbench generate: not resuming from {path.name}: {why}; simulating from "
          "step 0 (the checkpoint will be overwritten)", file=sys.stderr)


def _stored_steps(ids: Iterable[str]) -> set:
    out = set()
    for iid in ids:
        m = re.fullmatch(r"step(\d+)", iid)
        if m:
            out.add(int(m.group(1)))
    return out


def _write_step(w: SetWriter, scene, problem, k: int, job: _Job) -> None:
    """Form and write the dense instance of step ``k``."""
    scene_spec, lows = job.scene_spec, job.lows
    lcp = problem.lcp
    n = lcp.n
    P = scene.params
    A, asym = _dense_sym(lcp.A, f"step {k}: high", job.progress)
    t_high = _cost(lcp.A) if n else 0.0
    low = {}
    for key in lows:
        op = lcp.low[key]
        A_low, asym_low = _dense_sym(op, f"step {k}: low {key}", job.progress)
        t_low = _cost(op) if n else 0.0
        knobs = scene.fidelity_knobs(key)
        ratio = t_low / t_high if t_high > 0 else 1.0
        low[key] = (A_low, ratio, {**knobs, "t_mvp": t_low, "asymmetry": asym_low})
    ref = consensus(LCP(A, lcp.b, psd_check=False))
    size = scene.fidelity_axes.size_param          # the scene's size knob: a set attribute
    scalars = {key: v for key, v in dataclasses.asdict(P).items()
               if isinstance(v, (bool, int, float, str)) and key not in ("low", size)}
    attrs = {**scalars, "step": int(k), "M": int(scene.M), "t_mvp_high": float(t_high),
             "scene": scene_spec, "asymmetry": asym, "family": parse_spec(scene_spec)[0]}
    if lcp.meta.get("min_gap") is not None:
        attrs["min_gap"] = float(lcp.meta["min_gap"])
    x0 = lcp.x0 if lcp.x0 is not None and np.any(lcp.x0) else None
    iid = instance_id(k)
    w.write_instance(iid, A, lcp.b, low=low, x0=x0, reference=ref, attrs=attrs)
    job.written.append(iid)
    if not ref.accepted:
        job.rejected.append(iid)
