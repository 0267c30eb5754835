"""The Krylov rest of the boundary-integral solves (orthogonalisation, recycled-space
projections: everything but the products), this tree against an earlier commit's, side by
side in one run on the same packed configuration.

Usage::

    python benchmarks/krylov_rest.py                       # paper-lattice 4x4x4, p = 8
    python benchmarks/krylov_rest.py --m 3 --solves 6 --baseline 4c5b8bc

The ``paper-lattice`` scene of side ``m`` is packed by cheap RPY steps and its
boundary-integral mobility built at order ``--p`` (``eps_gmres`` 1e-8).  The earlier
``gmres.py`` and ``recycle.py`` are read from git at ``--baseline`` (default: the last
commit with one product of the basis per direction) and loaded beside this tree's.  Both
then solve the same traction equations ``G y = b`` with the same operator, ``b`` the
right-hand sides of ``--solves`` unit loads (a force or torque on one sphere each):

* relaxed restarted GMRES (no recycling; restart 60, the tolerance ladder of the set-up),
* recycled GCR, all solves in a row from one empty recycled space (the default capacity).

Printed per solver and version: products, thread CPU seconds in all (``time.thread_time``;
run with ``NUMBA_NUM_THREADS=1`` so that the products run on this thread), in the products,
and the rest (the Krylov rest), the rest per product, the ratio old / new of the rest, and
the largest relative difference of the solutions ``||y_new - y_old|| / ||y_old||``.  The two
versions alternate per solve (which goes first alternates too).
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import packed_lattice  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BIM = "problems/suspension/bim"
BASELINE = "4c5b8bc"
"""The commit before the block orthogonalisation (scipy's GMRES; three passes per
projection in the recycled spaces)."""


def load_old(rev: str, name: str) -> types.ModuleType:
    """Module ``bim/<name>.py`` as it was at commit ``rev`` (absolute imports only)."""
    source = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{BIM}/{name}.py"],
                            check=True, capture_output=True, text=True).stdout
    spec = importlib.util.spec_from_loader(f"_old_{name}", loader=None)
    assert spec is not None
    module = importlib.util.module_from_spec(spec)
    exec(compile(source, f"{rev}:{BIM}/{name}.py", "exec"), module.__dict__)
    return module


class Timed:
    """A product that counts itself and the thread CPU time spent in it."""

    def __init__(self, apply) -> None:
        self.apply, self.calls, self.seconds = apply, 0, 0.0

    def __call__(self, *args):
        t0 = time.thread_time()
        out = self.apply(*args)
        self.seconds += time.thread_time() - t0
        self.calls += 1
        return out


def loads(M: int, count: int) -> list[np.ndarray]:
    """``count`` unit loads spread over the spheres: force x, y, z, torque x, y, z in turn."""
    out = []
    for k in range(count):
        ft = np.zeros(6 * M)
        ft[6 * ((k * 7) % M) + k % 6] = 1.0
        out.append(ft)
    return out


def run_gmres(mod, mob, rhs: list[np.ndarray]) -> dict:
    """Relaxed GMRES (module ``mod``) on every right-hand side, as the operator solves."""
    prod = Timed(mob.apply_preconditioned)
    rungs = len(mob.plan.quadrature.dir_ranges)
    ys, t = [], 0.0
    for b in rhs:
        y0 = mob.setup.unprecondition(mob.precondition(b))
        t0 = time.thread_time()
        y, _, _ = mod.relaxed_gmres(prod, b, y0, mob.eps_gmres, 60, mob.maxiter, rungs=rungs,
                                    step=10.0)
        t += time.thread_time() - t0
        ys.append(y)
    return {"ys": ys, "total": t, "products": prod.calls, "in_products": prod.seconds}


def run_recycled(mod, mob, rhs: list[np.ndarray], capacity: int) -> dict:
    """Recycled GCR (module ``mod``) on every right-hand side in a row, one space."""
    prod = Timed(lambda v: mob.apply_preconditioned(v))
    gcr = mod.RecycledGCR(prod, mob.setup.unknowns, capacity)
    ys, t = [], 0.0
    for b in rhs:
        t0 = time.thread_time()
        y, _, _ = gcr.solve(b, mob.eps_gmres, mob.maxiter)
        t += time.thread_time() - t0
        ys.append(y)
    return {"ys": ys, "total": t, "products": prod.calls, "in_products": prod.seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--m", type=int, default=4, help="lattice side (m^3 spheres)")
    parser.add_argument("--p", type=int, default=8, help="spherical-harmonic order")
    parser.add_argument("--solves", type=int, default=8, help="right-hand sides")
    parser.add_argument("--baseline", default=BASELINE, help="git commit of the old code")
    args = parser.parse_args()

    from lcpbench.problems.suspension.bim import BimMobility
    from lcpbench.problems.suspension.bim import gmres as new_gmres
    from lcpbench.problems.suspension.bim import recycle as new_recycle
    from lcpbench.toolkit.blas import one_blas_thread

    old = {"gmres": load_old(args.baseline, "gmres"),
           "recycle": load_old(args.baseline, "recycle")}
    new = {"gmres": new_gmres, "recycle": new_recycle}
    scene = packed_lattice(args.m, scene="paper-lattice")
    centers = scene.get_state()["centers"]
    mob = BimMobility(centers, 1.0, p=args.p, eps_gmres=1e-8, recycle=0)
    rhs = [mob.rhs(ft) for ft in loads(mob.M, args.solves)]
    capacity = new_recycle.default_capacity(mob.setup.unknowns)
    print(f"paper-lattice m = {args.m} ({mob.M} spheres, packed), p = {args.p}, "
          f"{mob.setup.unknowns} unknowns, {args.solves} solves, recycled capacity "
          f"{capacity}; old = {args.baseline}")
    print("| solver | version | products | CPU s | in products | Krylov rest | rest per "
          "product (ms) | rest old/new | max rel diff |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, run in (("relaxed GMRES", run_gmres), ("recycled GCR", run_recycled)):
        extra = (capacity,) if run is run_recycled else ()
        with one_blas_thread():
            if run is run_gmres:            # alternate per solve, which goes first too
                parts: dict = {"old": [], "new": []}
                for k, b in enumerate(rhs):
                    order = ("old", "new") if k % 2 == 0 else ("new", "old")
                    for v in order:
                        parts[v].append(run((old if v == "old" else new)["gmres"], mob, [b]))
                res = {v: {"ys": [y for r in parts[v] for y in r["ys"]],
                           **{key: sum(r[key] for r in parts[v])
                              for key in ("total", "products", "in_products")}}
                       for v in parts}
            else:                           # one space per version: a sequence each
                res = {"old": run(old["recycle"], mob, rhs, *extra),
                       "new": run(new["recycle"], mob, rhs, *extra)}
        rest = {v: r["total"] - r["in_products"] for v, r in res.items()}
        diff = max(float(np.linalg.norm(yn - yo) / np.linalg.norm(yo))
                   for yn, yo in zip(res["new"]["ys"], res["old"]["ys"]))
        for v in ("old", "new"):
            r = res[v]
            print(f"| {label} | {v} | {r['products']} | {r['total']:.2f} | "
                  f"{r['in_products']:.2f} | {rest[v]:.2f} | "
                  f"{1e3 * rest[v] / max(r['products'], 1):.2f} | "
                  f"{rest['old'] / rest['new'] if v == 'new' else 1.0:.2f} | "
                  f"{diff if v == 'new' else 0.0:.1e} |")


if __name__ == "__main__":
    main()
