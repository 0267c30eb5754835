"""Where the time of one live boundary-integral time step goes, per solver, and the peak
memory of the process.

Usage::

    python benchmarks/step_budget.py                               # m = 3 and 4, p = 8
    python benchmarks/step_budget.py --m 3 --steps 3 --solvers bb-pgd bi-pqn:low=p4e6
    python benchmarks/step_budget.py --nc --m 3 --steps 10 --solvers mono-pqn

For every lattice side ``m`` the ``paper-lattice`` scene is stepped with RPY until it has
packed (:func:`common.packed_lattice`, as the shipped sets' instances are), and from that
state each solver runs ``--steps`` time steps of the boundary-integral scene (order
``--p``, ``eps_gmres`` 1e-8) in a fresh process of its own, after one warm-up step that is
not measured (it loads the compiled kernels and the cached tables, as the report's online
table leaves each simulation's first step out), so that each process's peak
resident memory is its own.  Explicit timers (the code's own wall-time records and
wrappers around its parts, exclusive of each other) split every step into:

* set-up: the boundary-integral set-ups of the step's mobilities (grids, pair plan and
  near-field pair blocks; ``BimMobility`` and the distance-split lows' construction);
* nc solve: the non-collisional solve ``U_nc = M [F; T]``;
* cost-ratio products: products made only to time a fidelity's cost (none since the
  costs are priced by the step's own products; an older tree shows them here);
* LCP products: every product of the step's LCP operators during the solve (counted,
  and the framework's confirmation and verification products);
* solver overhead: the rest of the solve (the solver's own algebra, the framework's
  bookkeeping);
* other: the rest of the step (contacts, loads, the position update).

The columns are percentages of the mean step; ``step s`` is the mean step in seconds,
``peak RSS`` the process's maximum resident set size.

``--nc`` measures instead what the warm-started non-collisional solve saves: three copies of
the scene take their steps in turn from the same packed state with the first solver, one
starting ``U_nc`` from the two previous steps' densities extrapolated (the default), one from
the previous step's density and one from zero; per step it prints the inner applications of
the non-collisional solve of each (the guess's residual included) and of the whole step's
forward solves.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import packed_lattice

PARTS = ("setup", "nc", "cost", "products", "overhead", "other")
HEADS = ("set-up", "nc solve", "cost-ratio products", "LCP products", "solver overhead",
         "other")


class Timers:
    """Exclusive wall-time accounts: time inside an inner account is not its outer's."""

    def __init__(self) -> None:
        self.total = dict.fromkeys(PARTS, 0.0)
        self.stack: list = []

    def wrap(self, owner, name: str, part: str) -> None:
        """Charge the calls of ``owner.name`` to ``part`` (nothing when it does not exist)."""
        fn = getattr(owner, name, None)
        if fn is None:
            return
        timers = self

        def timed(*args, **kwargs):
            if part == "products" and (not timers.stack or timers.stack[-1][0] != "solve"):
                return fn(*args, **kwargs)          # only products made inside the solve
            timers.stack.append([part, time.perf_counter(), 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                _, t0, inner = timers.stack.pop()
                dt = time.perf_counter() - t0
                if part != "solve":
                    timers.total[part] += dt - inner
                if timers.stack:
                    timers.stack[-1][2] += dt
                if part == "solve":
                    timers.total["overhead"] += dt - inner

        setattr(owner, name, timed)


def _install(timers: Timers) -> None:
    import lcpbench.core.api as api
    import lcpbench.core.operator as core_operator
    import lcpbench.problems.suspension.bim.operator as bim_operator
    import lcpbench.problems.suspension.bim.split as split
    import lcpbench.problems.suspension.fidelity as fidelity
    import lcpbench.problems.suspension.problem as problem

    timers.wrap(bim_operator.BimMobility, "__init__", "setup")
    timers.wrap(split.SplitMobility, "__init__", "setup")
    timers.wrap(bim_operator.BimMobility, "solve_loads", "nc")
    timers.wrap(problem, "_timed", "cost")                  # an older tree's timing products
    timers.wrap(core_operator, "_checked_apply", "products")
    timers.wrap(api, "run_solver", "solve")
    fidelity.split_mobility = split.split_mobility           # the wrapped class is used


def worker(state: str, m: int, p: int, solver: str, steps: int, low: str) -> None:
    """``steps`` steps of one solver from the packed state; prints one JSON line."""
    from lcpbench.core.registry import make_scene

    timers = Timers()
    _install(timers)
    lows = f",low=[{low}]" if solver.startswith(("bi-", "multi-")) else ""
    scene = make_scene(f"paper-lattice:m={m},model=bim,p={p},eps_gmres=1e-8{lows}")
    scene.set_state(dict(np.load(state)))
    scene.step(solver, qn_memory=True)      # warm-up: loads the compiled kernels and the
    timers.total = dict.fromkeys(PARTS, 0.0)  # tables of a fresh process; not measured
    total, n, emvps = 0.0, [], []
    for _ in range(steps):
        t0 = time.perf_counter()
        rec = scene.step(solver, qn_memory=True)
        total += time.perf_counter() - t0
        n.append(rec.n)
        emvps.append(rec.result.emvps)
    timers.total["other"] = total - sum(v for k, v in timers.total.items() if k != "other")
    print(json.dumps({"m": m, "M": scene.M, "solver": solver, "step_s": total / steps,
                      "n": float(np.mean(n)), "emvps": float(np.mean(emvps)),
                      "parts": {k: v / total for k, v in timers.total.items()},
                      "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))


def nc_saving(state: Path, m: int, p: int, solver: str, steps: int) -> None:
    """Side by side: the non-collisional solve from the two previous densities
    extrapolated (the default), from the previous density, and from zero."""
    from lcpbench.core.registry import make_scene

    kinds = ("extrapolated", "previous", "cold")
    scenes = {}
    for kind in kinds:
        scenes[kind] = make_scene(f"paper-lattice:m={m},model=bim,p={p},eps_gmres=1e-8")
        scenes[kind].set_state(dict(np.load(state)))
    scenes["previous"].nc_extrapolate = False
    scenes["cold"].nc_guess = lambda: None
    print(f"paper-lattice m = {m}, p = {p}, eps_gmres 1e-8, {solver}: inner applications "
          "of the non-collisional solve and of the whole step's forward solves\n")
    print("| step | " + " | ".join(f"nc solve {k}" for k in kinds) + " | "
          + " | ".join(f"step {k}" for k in kinds) + " |")
    print("|---" * (1 + 2 * len(kinds)) + "|")
    totals = np.zeros(2 * len(kinds))
    for k in range(steps):
        row = []
        for kind in kinds:
            scene = scenes[kind]
            built = []
            real = scene.build
            scene.build = lambda *a, _real=real, _b=built, **kw: _b.append(_real(*a, **kw)) or _b[-1]
            scene.step(solver, qn_memory=True)
            del scene.build
            prob = built[0]
            row.append((prob.nc_applications or 0, sum(prob.mobility.gmres_iterations)))
        cells = [r[0] for r in row] + [r[1] for r in row]
        totals += cells
        print(f"| {k} | " + " | ".join(str(int(c)) for c in cells) + " |", flush=True)
    print("| all | " + " | ".join(str(int(c)) for c in totals) + " |")


def run(state: Path, m: int, p: int, solver: str, steps: int, low: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "--worker", str(state), str(m), str(p),
                          solver, str(steps), low], capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"m={m} {solver} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        state, m, p, solver, steps, low = sys.argv[2:8]
        worker(state, int(m), int(p), solver, int(steps), low)
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, nargs="+", default=[3, 4], help="lattice sides")
    ap.add_argument("--p", type=int, default=8, help="spherical-harmonic order")
    ap.add_argument("--steps", type=int, default=3, help="time steps per solver")
    ap.add_argument("--pack", type=int, default=40, help="RPY steps that pack the lattice")
    ap.add_argument("--low", default="p4e6", help="the low fidelity of Bi-PQN")
    ap.add_argument("--solvers", nargs="+", default=["bb-pgd", "mono-pqn", "bi-pqn"])
    ap.add_argument("--nc", action="store_true",
                    help="measure the warm-started non-collisional solve instead")
    args = ap.parse_args()
    if args.nc:
        with tempfile.TemporaryDirectory() as tmp:
            state = Path(tmp) / "state.npz"
            np.savez(state, **packed_lattice(args.m[0], args.pack, "paper-lattice").get_state())
            nc_saving(state, args.m[0], args.p, args.solvers[0], args.steps)
        return
    print(f"paper-lattice, boundary integral p = {args.p}, eps_gmres 1e-8, {args.steps} "
          f"steps from the state after {args.pack} RPY steps; Bi-PQN's low {args.low}; "
          "percent of the mean step\n")
    print("| M | solver | n | E-MVPs | step s | " + " | ".join(HEADS) + " | peak RSS MB |")
    print("|---|---|---|---|---|" + "---|" * len(HEADS) + "---|")
    with tempfile.TemporaryDirectory() as tmp:
        for m in args.m:
            state = Path(tmp) / f"m{m}.npz"
            np.savez(state, **packed_lattice(m, args.pack, "paper-lattice").get_state())
            for solver in args.solvers:
                spec = f"{solver}:low={args.low}" if solver == "bi-pqn" else solver
                r = run(state, m, args.p, spec, args.steps, args.low)
                cells = " | ".join(f"{100 * r['parts'][k]:.1f}" for k in PARTS)
                print(f"| {r['M']} | {spec} | {r['n']:.0f} | {r['emvps']:.1f} | "
                      f"{r['step_s']:.1f} | {cells} | {r['peak_rss_mb']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
