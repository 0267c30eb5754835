"""Online runs: one simulation of a scene per solver, a result row per time step.

The solution of step ``k`` moves the spheres and so defines the LCP of step
``k + 1``; each solver therefore runs its own simulation from the same initial
configuration. Every step is written to the run store as soon as it is done
(``results.csv`` with ``kind = "online"``, its iterates to ``history.csv``), so
``lcpbench report DIR`` shows the paper's online table: total and
collision-resolution seconds per scene and solver, E-MVPs per step.

Row columns specific to online runs: ``step``; ``time_s`` the collision
resolution seconds (the solve); ``sim_total_s`` the whole step (contacts,
mobility, ``U_nc``, fidelity cost timing, solve, verification, update);
``max_overlap`` the largest overlap of two spheres after the step; a run
without warm start is labelled ``"<solver> (cold)"`` so the online table keeps
it apart from the warm-started one. ``info``
holds the rest (setup and update seconds, mobility solves outside the counted
MVPs, warm-start entries, overlap check, ``qn_memory``: whether the solve
started from the previous step's secant pairs, ``qn_pairs``: how many of them
survived the mapping onto the step's contacts).

Resuming: after every step the simulation's state is checkpointed (see
:mod:`lcpbench.workflows.checkpoint`) before its row is written, so rerunning the same
command after a kill continues each simulation from its last finished step, and every
step appears exactly once in ``results.csv``; a larger ``steps`` extends finished
simulations. SIGTERM stops the run with :class:`Interrupted` once the step under way is
written (a solve cut short would be stored as a failed step).

Physical sanity: a step whose overlap exceeds ``overlap_tol`` (a fraction of
the smallest radius) is flagged in ``message`` and ``info``; for frictionless
spheres the linearised constraint is conservative (the true gap is at least
its linearisation), so overlap only appears when a pair outside the candidate
set closes more than ``delta`` in one step: a sign that ``dt`` is too large.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Optional, Union

import numpy as np
import pandas as pd

from lcpbench.core.api import requested_lows
from lcpbench.core.clock import utc_now
from lcpbench.core.context import Budget
from lcpbench.core.registry import SolverInfo, get_solver
from lcpbench.core.residuals import make_stop_rule
from lcpbench.core.scene import Scene, StepRecord, step_scene
from lcpbench.core.specs import make_params, parse_spec
from lcpbench.run.runner import machine_info, result_fields
from lcpbench.run.store import RunStore, refuse_link
from lcpbench.workflows.checkpoint import (
    Checkpoint,
    checkpoint_path,
    load_checkpoint,
    save_checkpoint,
)
from lcpbench.workflows.cost_model import CostModel
from lcpbench.workflows.regimes import DEFAULT_REGIME, REGIMES, apply_regime

__all__ = ["simulate", "DEFAULT_OVERLAP_TOL", "DEFAULT_QN_MEMORY", "Interrupted"]


class Interrupted(RuntimeError):
    """The simulation was stopped by SIGTERM; every finished step is stored and resumable."""

#: Default overlap tolerance, as a fraction of the smallest radius.
DEFAULT_OVERLAP_TOL = 1e-2

#: Default of ``qn_memory`` (see docs/benchmarks.md, "Quasi-Newton memory across time steps").
DEFAULT_QN_MEMORY = REGIMES[DEFAULT_REGIME].qn_memory


def _check_solver(spec: str, lows: Sequence[str], scene_spec: str):
    name, raw = parse_spec(spec)
    info = get_solver(name)
    params = make_params(name, info.params, raw)
    missing = [n for n in requested_lows(dataclasses.asdict(params), name) if n not in lows]
    if lows and missing:
        raise ValueError(f"solver {spec!r}: no low fidelity {missing[0]!r} in scene "
                         f"{scene_spec!r} (it has: {', '.join(lows)})")
    if info.multifidelity and not lows:
        raise ValueError(f"solver {spec!r} needs low-fidelity operators but scene {scene_spec!r} "
                         "has none; add low=[...] to the scene, e.g. "
                         f"{scene_spec.split(':')[0]}:...,low=[self]")
    if info.needs_dense:
        print(f"lcpbench simulate: note: {name} forms A densely (n uncounted mobility solves "
              "per step); its E-MVPs are not comparable to MVP-only solvers", file=sys.stderr)
    return name, info


def _run_id(scene: str, solver: str, warm: bool, step: int) -> str:
    return f"online|{scene}|{solver}|warm={int(warm)}|step={step:05d}"


def _sim_key(scene: str, solver: str, warm: bool) -> str:
    return f"online|{scene}|{solver}|warm={int(warm)}"


#: Set by SIGTERM; the step loop stops at the next step boundary (a solve is never cut
#: short: an exception raised inside it would be recorded as a failed solve).
_TERM = threading.Event()


def _request_stop(signum, frame):
    _TERM.set()


def simulate(scene_spec: str, solver_spec: Union[str, Sequence[str]], steps: int,
             out_dir: Union[str, Path], *, warm_start: bool = True,
             qn_memory: Optional[bool] = None, regime: str = DEFAULT_REGIME,
             progress: bool = True,
             tol: float = 1e-8, stop: str = "paper", max_emvps: float = 5000.0,
             max_seconds: Optional[float] = None,
             overlap_tol: float = DEFAULT_OVERLAP_TOL,
             argv: Optional[Sequence[str]] = None) -> pd.DataFrame:
    """Simulate ``scene_spec`` once per solver and store a row per step.

    Parameters
    ----------
    scene_spec : str
        Scene, e.g. ``lattice:m=3,model=rpy,low=[self]`` (see
        the scene's parameters, ``lcpbench list scenes``).
    solver_spec : str or list of str
        One or more solver specs (``bi-pqn:low=self``, ``bb-pgd``); each runs
        its own simulation. The simulations take their steps in turn (one step
        each, round robin), so that their wall times are measured under the same
        machine load; each builds only the low fidelities it uses.
    steps : int
        Time steps per simulation (>= 1).
    out_dir : str or Path
        Run-store folder (created if missing). Several scenes may be simulated
        into one folder. A scene/solver pair already in it resumes from its last
        finished step (same settings required; a larger ``steps`` extends it).
    warm_start : bool
        Start each solve from the previous step's forces matched by pair identity.
    qn_memory : bool, optional
        Start each PQN solve's quasi-Newton model from the previous step's
        secant pairs, mapped onto the new contacts by pair identity (the
        scene's ``carry_memory``); other solvers ignore it. ``None`` takes the
        regime's (on in ``default``: what it saves is in docs/benchmarks.md,
        "Quasi-Newton memory across time steps"; off in ``paper``).
        Part of the simulation's settings:
        a resume with the other choice is refused (simulations stored before
        the switch existed ran without the memory).
    regime : str
        ``default`` or ``paper`` (:mod:`lcpbench.workflows.regimes`): ``paper`` runs
        without Krylov recycling (``krylov_mb=0`` is added to the scene spec), without
        memory across steps, and refuses solvers with other than the paper's products.
        Recorded in ``meta.json`` and in every row's ``info``.
    progress : bool
        Show a tqdm progress bar per simulation (on stderr).
    tol, stop : stop rule of every solve (``paper`` or ``kkt``).
    max_emvps, max_seconds : budget of each solve.
    overlap_tol : float
        Largest acceptable overlap after a step, as a fraction of the smallest radius.
    argv : list of str, optional
        Command line recorded in ``meta.json``.

    Returns
    -------
    pandas.DataFrame
        The rows written (one per step and solver).

    Raises
    ------
    KeyError, TypeError, ValueError
        Unknown scene or solver, bad parameter, ``steps < 1``, a solver that
        needs low-fidelity operators on a scene without them, or a scene/solver
        pair stored in ``out_dir`` with other settings. All checked before any step runs.
    Interrupted
        SIGTERM arrived; the finished steps are stored, the same call resumes.
    """
    from lcpbench.core.registry import make_scene

    specs = _check_inputs(solver_spec, steps, overlap_tol)
    make_stop_rule(stop, tol)
    chosen = apply_regime(regime, str(scene_spec), specs, qn_memory)
    run = SimSettings(scene_spec=chosen.scene_spec, tol=tol, stop=stop,
                      warm_start=warm_start, qn_memory=chosen.qn_memory, max_emvps=max_emvps,
                      max_seconds=max_seconds, overlap_tol=float(overlap_tol),
                      regime=chosen.regime)
    run.budget()                                   # a bad budget is refused before any write
    if not np.isfinite(float(max_emvps)):          # meta.json is JSON: no Infinity
        raise ValueError(f"budget max_emvps must be a finite number, got {max_emvps}; give a "
                         "large budget instead (e.g. 1e9)")
    _check_not_offline(Path(out_dir))
    probe = make_scene(run.scene_spec)             # validates the scene before any work
    infos = {s: _check_solver(s, [str(x) for x in probe.params.low], run.scene_spec)
             for s in specs}
    store = RunStore(out_dir)
    with store.lock():
        resumed = {s: _resume_point(store, run, s) for s in specs}
        meta = _start_meta(store, run, specs, int(steps), probe, argv)
        costs = _cost_model(store, meta, run.scene_spec)
        in_main = threading.current_thread() is threading.main_thread()
        _TERM.clear()
        previous = signal.signal(signal.SIGTERM, _request_stop) if in_main else None
        try:
            sims = []
            for k, spec in enumerate(specs):
                scene = probe if spec == specs[0] else make_scene(run.scene_spec)
                name, info = infos[spec]
                path, ckpt = resumed[spec]
                sims.append(_one_simulation(SimulationJob(
                    store=store, scene=scene, run=run, spec=spec, name=name, info=info,
                    steps=int(steps), progress=progress, ckpt_path=path, ckpt=ckpt,
                    lows=_lows_for(spec, info, scene.params.low), position=k,
                    costs=costs)))
            frames = _round_robin(sims)
        except Interrupted:
            raise Interrupted(f"stopped by SIGTERM; every finished step is in {store.path}, "
                              "run the same command again to resume") from None
        finally:
            if in_main:
                signal.signal(signal.SIGTERM, previous)
        meta["finished"] = utc_now()
        meta["load_average_finished"] = _load_average()
        store.write_meta(meta)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _check_not_offline(folder: Path) -> None:
    """Refuse a run store that ``lcpbench run`` wrote: online rows are not added to it.

    Raises
    ------
    ValueError
        Naming the folder and what to do.
    """
    path = folder / "meta.json"
    try:
        meta = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None
    except (OSError, ValueError):   # an unreadable meta.json is the store's own error, later
        return
    if isinstance(meta, dict) and meta.get("command") != "simulate":
        raise ValueError(f"--out {folder} holds an offline run store (written by lcpbench "
                         "run); give lcpbench simulate its own --out")


@dataclasses.dataclass(frozen=True)
class SimSettings:
    """The settings every simulation of one :func:`simulate` call shares."""

    scene_spec: str
    tol: float
    stop: str
    warm_start: bool
    qn_memory: bool
    max_emvps: float
    max_seconds: Optional[float]
    overlap_tol: float
    regime: str = DEFAULT_REGIME

    @property
    def scene_name(self) -> str:
        """The registered scene name of ``scene_spec``."""
        return parse_spec(self.scene_spec)[0]

    def budget(self) -> Budget:
        """The budget of every solve."""
        return Budget(max_emvps=self.max_emvps, max_seconds=self.max_seconds)

    def for_solver(self, spec: str) -> dict:
        """What a resumed simulation must share with the one it continues (not the step
        count)."""
        return {"scene": self.scene_spec, "solver": spec, "tol": float(self.tol),
                "stop": self.stop, "warm_start": bool(self.warm_start),
                "qn_memory": bool(self.qn_memory), "max_emvps": self.max_emvps,
                "max_seconds": self.max_seconds, "overlap_tol": float(self.overlap_tol),
                "regime": self.regime}


@dataclasses.dataclass
class SimulationJob:
    """One simulation: a scene stepped with one solver (:func:`_one_simulation`)."""

    store: RunStore
    scene: Scene
    run: SimSettings
    spec: str
    name: str
    info: SolverInfo
    steps: int
    progress: bool
    ckpt_path: Path
    ckpt: Optional[Checkpoint]
    lows: tuple
    position: int
    costs: CostModel


def _check_inputs(solver_spec, steps, overlap_tol) -> list:
    """The solver specs, after the checks of the solver list, ``steps`` and ``overlap_tol``."""
    if isinstance(solver_spec, str):
        solver_spec = [solver_spec]
    specs = [str(s).strip() for s in solver_spec]
    if not specs:
        raise ValueError("no solver given; pass at least one --solver NAME[:k=v,...]")
    if len(set(specs)) != len(specs):
        raise ValueError(f"solver list {specs} repeats a spec; each solver runs one simulation")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"steps = {steps!r} must be an integer >= 1")
    tol = float(overlap_tol)
    if not (np.isfinite(tol) and tol >= 0):
        raise ValueError(f"overlap_tol = {tol} must be a finite non-negative fraction "
                         "of the radius")
    return specs


def _resume_point(store: RunStore, run: SimSettings, spec: str
                  ) -> tuple[Path, Optional[Checkpoint]]:
    """The checkpoint path of one simulation and its checkpoint when it resumes (refused
    when it was stored with other settings, or has rows but no checkpoint)."""
    settings = run.for_solver(spec)
    path = checkpoint_path(store.path, _sim_key(run.scene_spec, spec, run.warm_start))
    if path.exists():
        ckpt = load_checkpoint(path)
        # checkpoints from before the switches existed ran without the memory, and in
        # lcpbench's default regime
        ckpt.config = {"qn_memory": False, "regime": DEFAULT_REGIME, **ckpt.config}
        if ckpt.config != settings:
            changed = sorted(k for k in settings if settings[k] != ckpt.config.get(k))
            raise ValueError(f"{store.path} holds the simulation of {run.scene_spec!r} with "
                             f"{spec!r} under other settings ({', '.join(changed)}); rerun "
                             "with the same settings to resume, or choose another --out")
        return path, ckpt
    if _run_id(run.scene_spec, spec, run.warm_start, 0) in store.done_ids():
        raise ValueError(f"{store.path} holds rows of the simulation of {run.scene_spec!r} "
                         f"with {spec!r} but no checkpoint to resume from; choose another "
                         "--out")
    return path, None


def _cost_model(store: RunStore, meta: dict, scene_spec: str) -> CostModel:
    """The run's cost model of the low fidelities (:mod:`lcpbench.workflows.cost_model`):
    the constants an earlier run of this store recorded in ``meta.json``, new ones
    written there as soon as they are calibrated."""
    recorded = dict((meta.get("cost_model") or {}).get(scene_spec) or {})
    machine = machine_info()

    def persist(entries: dict) -> None:
        meta.setdefault("cost_model", {})[scene_spec] = dict(entries)
        store.write_meta(meta)

    return CostModel(scene_spec, entries=recorded,
                     machine={k: machine.get(k) for k in ("cpu", "cpu_count", "threads")},
                     persist=persist)


def _start_meta(store: RunStore, run: SimSettings, specs: list, steps: int, probe,
                argv: Optional[Sequence[str]]) -> dict:
    """Writes ``meta.json`` at the start of the run (this simulation's configuration added
    to those already stored) and returns it."""
    from lcpbench.run.runner import git_commit, machine_info

    old = store.read_meta() or {}
    config = {"scene": run.scene_spec, "solvers": specs, "steps": steps, "tol": run.tol,
              "stop": run.stop, "warm_start": bool(run.warm_start),
              "qn_memory": bool(run.qn_memory), "max_emvps": run.max_emvps,
              "max_seconds": run.max_seconds, "overlap_tol": run.overlap_tol,
              "regime": run.regime, "scene_params": dataclasses.asdict(probe.params)}
    meta = dict(old)
    meta.update({"argv": list(argv) if argv is not None else meta.get("argv", []),
                 "command": "simulate", "started": utc_now(), "finished": None,
                 "machine": machine_info(), "git_commit": git_commit(),
                 "load_average": _load_average(), "load_average_finished": None})
    meta.setdefault("config", config)
    sims = list(meta.get("simulations", []))
    if json.dumps(config, sort_keys=True, default=str) not in \
            {json.dumps(c, sort_keys=True, default=str) for c in sims}:
        sims.append(config)
    meta["simulations"] = sims
    store.write_meta(meta)
    return meta


def _load_average() -> Optional[list]:
    """The machine's 1, 5 and 15 minute load averages (``None`` where the system has none),
    recorded beside the run so a reader knows what else was running."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def _lows_for(spec: str, info, scene_lows: Sequence[str]) -> tuple:
    """The scene's low fidelities a solver uses: those it names, all for a multi-fidelity
    solver that names none, none for a single-fidelity one (each low costs a mobility
    set-up and a timed product per step, which would burden the others' total time)."""
    if not info.multifidelity:
        return ()
    name, raw = parse_spec(spec)
    named = requested_lows(dataclasses.asdict(make_params(name, info.params, raw)), name)
    return tuple(named) if named else tuple(scene_lows)


def _round_robin(sims: list) -> list:
    """Advance every simulation one step in turn until all have finished, so that the
    solvers' wall times are measured under the same machine load; returns each
    simulation's rows."""
    frames: list = [None] * len(sims)
    active = list(range(len(sims)))
    while active:
        for k in list(active):
            try:
                next(sims[k])
            except StopIteration as done:
                frames[k] = done.value
                active.remove(k)
    return frames


def _one_simulation(job: SimulationJob):
    """One simulation as a generator: it yields after every stored step and returns its
    rows (:func:`_round_robin` interleaves several)."""
    from tqdm.auto import tqdm

    store, scene, run, spec = job.store, job.scene, job.run, job.spec
    rule = make_stop_rule(run.stop, run.tol)
    limit = run.overlap_tol * float(np.min(scene.radii))
    base = _RowBase(job, rule.kind)
    budget = run.budget()
    prefix = _sim_key(run.scene_spec, spec, run.warm_start) + "|"
    if job.ckpt is not None:
        ckpt = job.ckpt
        if ckpt.row["run_id"] not in store.done_ids():   # killed between checkpoint and row
            store.append(ckpt.row, ckpt.history)
        scene.set_state(ckpt.scene_state)
        if ckpt.finished:
            print(f"lcpbench simulate: {spec}: the simulation stopped at step {ckpt.step} "
                  f"({ckpt.row.get('message', '')}); nothing to resume", file=sys.stderr)
            return _stored_rows(store, prefix)

    def commit(row: dict, history, finished: bool) -> None:
        refuse_link(job.ckpt_path)       # checkpoints/ inside the store, never through a link
        save_checkpoint(job.ckpt_path, Checkpoint(step=int(row["step"]),
                                                  config=run.for_solver(spec),
                                                  scene_state=scene.get_state(), row=row,
                                                  history=history, finished=finished))
        store.append(row, history)

    bar = tqdm(total=job.steps, initial=min(scene.step_index, job.steps),
               desc=f"{run.scene_spec} | {spec}", disable=not job.progress, file=sys.stderr,
               leave=False, position=job.position)
    try:
        while scene.step_index < job.steps:
            if _TERM.is_set():
                raise Interrupted("stopped by SIGTERM")
            started = utc_now()
            k = scene.step_index
            try:
                rec = step_scene(scene, spec, tol=run.tol, stop=run.stop, budget=budget,
                                 warm_start=run.warm_start, qn_memory=run.qn_memory,
                                 lows=job.lows)
            except ValueError as exc:  # diverged forces or a configuration the model rejects
                row = base.row(k)
                row.update({"status": "failed", "message": f"simulation stopped: {exc}",
                            "solved": False, "started": started, "finished": utc_now()})
                commit(row, None, finished=True)
                print(f"lcpbench simulate: {spec}: {exc}", file=sys.stderr)
                break
            job.costs.observe(rec.result, f"step {rec.step} of {spec}")
            row = _step_row(base.row(rec.step), rec, limit, run.regime)
            row["model_emvps"] = job.costs.emvps(rec.result)
            row.update({"started": started, "finished": utc_now()})
            commit(row, rec.result.history, finished=False)
            bar.set_postfix(n=rec.n, emvps=f"{rec.result.emvps:.1f}",
                            status=rec.result.status.value)
            bar.update(1)
            yield
    finally:
        bar.close()
    return _stored_rows(store, prefix)


def _step_row(row: dict, rec: StepRecord, limit: float, regime: str) -> dict:
    """The result row of a finished step (``row`` holds the simulation's columns): status,
    counts, times, and the overlap check against ``limit``."""
    res = rec.result
    over = rec.max_overlap > limit
    message = res.message or ""
    if over:
        message = (f"{message}; " if message else "") + (
            f"overlap {rec.max_overlap:.3g} after the step exceeds the tolerance "
            f"{limit:.3g}: reduce dt or raise delta")
    extra = {"setup_s": rec.setup_s, "update_s": rec.update_s,
             "setup_solves": rec.setup_solves, "update_solves": rec.update_solves,
             "warm_entries": rec.warm_entries,
             "min_gap": rec.min_gap, "overlap_ok": not over, "overlap_tol": limit,
             **(res.info or {}), "qn_memory": rec.qn_memory, "qn_pairs": rec.qn_pairs,
             "regime": regime, "load_1min": (_load_average() or [None])[0],
             "lofi_applications": dict(res.lofi_applications or {})}
    row.update({
        "n": rec.n, "status": res.status.value, "message": message,
        **result_fields(res), "sim_total_s": rec.total_s,
        "max_overlap": rec.max_overlap,
        "info": json.dumps(extra, sort_keys=True, default=str)})
    return row


def _stored_rows(store: RunStore, prefix: str) -> pd.DataFrame:
    """Every stored row of one simulation, in step order (resumed runs included)."""
    res = store.results()
    if res.empty:
        return res
    mine = res[res["run_id"].astype(str).str.startswith(prefix)]
    return mine.sort_values("step").reset_index(drop=True)


class _RowBase:
    """The columns every row of one simulation shares."""

    def __init__(self, job: SimulationJob, stop_kind: str) -> None:
        self.job, self.stop_kind = job, stop_kind
        self.solver_params = json.dumps(parse_spec(job.spec)[1], sort_keys=True)
        self.problem_params = json.dumps(dataclasses.asdict(job.scene.params),
                                         sort_keys=True, default=str)

    def row(self, step: int) -> dict:
        """The shared columns of step ``step``'s row (``n`` 0 until the step is done)."""
        job, run = self.job, self.job.run
        info = job.info
        return {"run_id": _run_id(run.scene_spec, job.spec, run.warm_start, step),
                "kind": "online", "problem": run.scene_spec,
                "problem_params": self.problem_params, "family": run.scene_name,
                "instance": f"step{step}", "instance_index": step, "n": 0,
                "solver": job.spec if run.warm_start else f"{job.spec} (cold)",
                "solver_name": job.name, "solver_params": self.solver_params,
                "mvp_only": info.mvp_only, "multifidelity": info.multifidelity,
                "reference_solver": info.reference, "tol": run.tol, "stop": self.stop_kind,
                "repeat": 0, "step": step}
