"""Wall time per collision resolution of the live boundary-integral contact operator,
this tree against a checkout of an earlier one, side by side in one run.

Usage::

    python benchmarks/live_operator.py --baseline-python /path/to/old/.venv/bin/python
    python benchmarks/live_operator.py --baseline-python OLD --m 3 --solvers mono-pqn --repeat 3

``--baseline-python`` is the interpreter of an environment where the earlier lcpbench is
installed (``git worktree add ../base <commit> && cd ../base && python -m venv .venv &&
.venv/bin/pip install -e .``).  For every lattice side ``m`` the scene
``lattice:m=M,model=rpy`` is stepped ``--pack`` times (cheap) until it has packed, as
the shipped sets' instances are; that state is saved once and every solve starts from
it: the step's contact LCP with the boundary-integral mobility at order ``--p`` and
``eps_gmres`` 1e-8 (the paper's high fidelity), built and solved in a fresh process of
either tree.  The two trees alternate (which goes first alternates too), so both see the
same machine load; a cell is the median over ``--repeat`` pairs.

Columns: seconds of the collision resolution (the solver's run, ``old / new``), their
ratio, the per-step set-up (contacts, mobility set-up, the non-collisional solve), counted
MVPs, and ``dw = ||w_new - w_old|| / ||w_old||`` of the verified ``w = A x + b`` of the two
answers (the answers are unchanged when it is at the solver's tolerance).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import packed_lattice


def worker(state: str, m: int, p: int, solver: str) -> None:
    """One step's build and solve in this process's lcpbench; prints a JSON line."""
    from lcpbench.core.api import run_solver
    from lcpbench.core.specs import parse_spec
    from lcpbench.problems.suspension.scene import LatticeScene

    name, params = parse_spec(solver)
    # a multi-fidelity solver gets the low its spec names (p4e6 when it names none)
    low = [str(params.get("low", "p4e6"))] if name.startswith("bi-") else []
    scene = LatticeScene(m, model="bim", p=p, eps_gmres=1e-8, low=tuple(low))
    scene.set_state(dict(np.load(state)))
    t0 = time.perf_counter()
    prob = scene.build()
    t1 = time.perf_counter()
    res = run_solver(prob.lcp, solver, stop="paper", tol=1e-8)
    t2 = time.perf_counter()
    print(json.dumps({"setup_s": t1 - t0, "solve_s": t2 - t1, "status": str(res.status),
                      "mvps": int(res.mvps), "emvps": float(res.emvps), "n": int(prob.lcp.n),
                      "w": np.asarray(res.w, float).tolist()}))


def packed_state(m: int, steps: int, path: Path) -> None:
    """Save the state of :func:`common.packed_lattice` for the worker processes."""
    np.savez(path, **packed_lattice(m, steps).get_state())


def run(python: str, state: Path, m: int, p: int, solver: str) -> dict:
    out = subprocess.run([python, __file__, "--worker", str(state), str(m), str(p), solver],
                         capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"{python} failed on m={m} {solver}:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        state, m, p, solver = sys.argv[2:6]
        worker(state, int(m), int(p), solver)
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline-python", required=True,
                    help="python of an environment with the earlier lcpbench installed")
    ap.add_argument("--m", type=int, nargs="+", default=[3, 4], help="lattice sides (M = m^3)")
    ap.add_argument("--p", type=int, default=8)
    ap.add_argument("--solvers", nargs="+", default=["bb-pgd", "mono-pqn", "bi-pqn:low=p4e6"])
    ap.add_argument("--pack", type=int, default=40, help="RPY steps before the measurement")
    ap.add_argument("--repeat", type=int, default=1, help="pairs of solves per cell")
    args = ap.parse_args()
    print(f"{'M':>3} {'n':>4} {'solver':<16} {'solve s old/new':>16} {'ratio':>6} "
          f"{'setup s old/new':>16} {'mvps':>9} {'dw':>8}  status", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for m in args.m:
            state = Path(tmp) / f"m{m}.npz"
            packed_state(m, args.pack, state)
            for solver in args.solvers:
                pairs = []
                for k in range(args.repeat):
                    first, second = ((args.baseline_python, sys.executable) if k % 2 == 0
                                     else (sys.executable, args.baseline_python))
                    got = {first: run(first, state, m, args.p, solver)}
                    got[second] = run(second, state, m, args.p, solver)
                    pairs.append((got[args.baseline_python], got[sys.executable]))
                old, new = pairs[-1]
                ratio = float(np.median([o["solve_s"] / n["solve_s"] for o, n in pairs]))
                so = float(np.median([o["solve_s"] for o, _ in pairs]))
                sn = float(np.median([n["solve_s"] for _, n in pairs]))
                uo = float(np.median([o["setup_s"] for o, _ in pairs]))
                un = float(np.median([n["setup_s"] for _, n in pairs]))
                wo, wn = np.asarray(old["w"]), np.asarray(new["w"])
                dw = float(np.linalg.norm(wn - wo) / max(np.linalg.norm(wo), 1e-300))
                print(f"{m ** 3:>3} {new['n']:>4} {solver:<16} {so:>7.1f}/{sn:<8.1f} "
                      f"{ratio:>6.2f} {uo:>7.1f}/{un:<8.1f} {old['mvps']:>4}/{new['mvps']:<4} "
                      f"{dw:>8.1e}  {old['status']}/{new['status']}", flush=True)


if __name__ == "__main__":
    main()
