"""What the framework costs around a solve, and lcpbench's Lemke against quantecon's.

Usage::

    pip install -e ".[bench]"                  # quantecon, for the Lemke comparison
    python benchmarks/framework_cost.py        # both parts, one run
    python benchmarks/framework_cost.py --repeat 7 --sizes 100 1500

Part 1, the framework around a small and a large solve: BB-PGD on a dense SPD matrix
(eigenvalues spread evenly over [1, 100], ``b`` normal so that about half the entries end
active) at each ``--sizes`` n. For each way of calling ``lcpbench.solve`` the script prints
the call's wall time, the solver's own iteration time (``SolveResult.time_s``: the
solver's loop, the framework's bookkeeping excluded) and their ratio, with the products
the framework made (``framework_mvps``). The ways: a bare array (checked on every call:
symmetry, then the definiteness test), an :class:`lcpbench.Operator` made once and
passed to every call (checked once, on the first), ``psd=True`` (no definiteness test)
and ``psd=True, verify=False`` (what a time stepper that trusts the confirmed claim
needs). Each time is the best of ``--repeat`` calls; the first call of each way is made
before and not timed (compilation, caches), except that the reused operator's first
check is timed once and shown apart.

Part 2, Lemke: every instance of the shipped stored sets solved by lcpbench's ``lemke``
(through ``lcpbench.solve``) and by quantecon's ``lcp_lemke`` on the same ``(A, b)``.
Per set the script prints the geometric mean of the ratio ``lemke / lcp_lemke`` for the
solver's own time (``time_s``) and for the whole ``lcpbench.solve`` call (the reused
operator, ``psd=True``, verified), with the pivots of each and the largest difference
of the two solutions. Times are the best of ``--repeat`` calls.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from functools import partial

import numpy as np

import lcpbench
from lcpbench.problems.stored import StoredParams, shipped_sets, stored


def spd(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A dense SPD matrix with eigenvalues evenly spread over [1, 100], and a normal ``b``."""
    rng = np.random.default_rng(seed)
    Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    A = (Q * np.linspace(1.0, 100.0, n)) @ Q.T
    A = (A + A.T) / 2
    return A, rng.standard_normal(n)


def best(call: Callable[[], lcpbench.SolveResult], repeat: int
         ) -> tuple[float, lcpbench.SolveResult]:
    """The best wall time of ``repeat`` calls and the result of the best one."""
    out: tuple[float, lcpbench.SolveResult] | None = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = call()
        wall = time.perf_counter() - t0
        if out is None or wall < out[0]:
            out = (wall, res)
    assert out is not None
    return out


def framework_part(sizes: list[int], repeat: int) -> None:
    print("## lcpbench.solve around BB-PGD on a dense SPD matrix")
    print()
    print("| n | call | wall (ms) | solver's iterations (ms) | wall / iterations "
          "| iterations | framework products |")
    print("|---|---|---|---|---|---|---|")
    lcpbench.solve(*spd(5), solver="bb-pgd")         # imports and compilation, not timed
    for n in sizes:
        A, b = spd(n)
        op = lcpbench.Operator(A)
        t0 = time.perf_counter()
        first = lcpbench.solve(op, b, solver="bb-pgd")
        first_wall = time.perf_counter() - t0
        ways: list[tuple[str, Callable[[], lcpbench.SolveResult]]] = [
            ("bare array", partial(lcpbench.solve, A, b, solver="bb-pgd")),
            ("Operator reused", partial(lcpbench.solve, op, b, solver="bb-pgd")),
            ("psd=True", partial(lcpbench.solve, A, b, solver="bb-pgd", psd=True)),
            ("psd=True, verify=False",
             partial(lcpbench.solve, A, b, solver="bb-pgd", psd=True, verify=False)),
        ]
        print(f"| {n} | Operator, first call (checked) | {1e3 * first_wall:.2f} | "
              f"{1e3 * first.time_s:.2f} | {first_wall / first.time_s:.2f} | "
              f"{first.iterations} | {first.framework_mvps} |")
        for label, call in ways:
            call()
            wall, res = best(call, repeat)
            assert res.status is lcpbench.Status.converged, res.summary()
            print(f"| {n} | {label} | {1e3 * wall:.2f} | {1e3 * res.time_s:.2f} | "
                  f"{wall / res.time_s:.2f} | {res.iterations} | {res.framework_mvps} |")
    print()


def _geomean(v: list[float]) -> float:
    return float(np.exp(np.mean(np.log(v))))


def lemke_part(repeat: int) -> None:
    from quantecon.optimize import lcp_lemke  # the bench extra

    print("## lcpbench's lemke against quantecon's lcp_lemke on the shipped sets")
    print()
    print("| set | instances | n | pivots (lcpbench / quantecon) | lcp_lemke (ms) "
          "| lemke's own time / lcp_lemke | lcpbench.solve / lcp_lemke | max abs x diff |")
    print("|---|---|---|---|---|---|---|---|")
    own_all, call_all = [], []
    for stem, path in shipped_sets().items():
        own, whole, qe_t, piv, qpiv, ns, diff = [], [], [], [], [], [], 0.0
        for lcp in stored(StoredParams(path=str(path))):
            A, b = np.asarray(lcp.A._impl, dtype=np.float64), lcp.b
            op = lcpbench.Operator(A)
            lcp_lemke(A, b)
            lcpbench.solve(op, b, solver="lemke", psd=True)
            q_wall = min(_timed(partial(lcp_lemke, A, b)) for _ in range(repeat))
            call = partial(lcpbench.solve, op, b, solver="lemke", psd=True)
            wall, res = best(call, repeat)
            own_t = min(call().time_s for _ in range(repeat))
            qe = lcp_lemke(A, b)
            assert res.solved and qe.success, (res.summary(), qe.status)
            own.append(own_t / q_wall)
            whole.append(wall / q_wall)
            qe_t.append(q_wall)
            piv.append(res.info["pivots"])
            qpiv.append(qe.num_iter)
            ns.append(len(b))
            diff = max(diff, float(np.max(np.abs(res.x - qe.z))))
        own_all += own
        call_all += whole
        print(f"| {stem} | {len(own)} | {min(ns)}-{max(ns)} | {np.median(piv):.0f} / "
              f"{np.median(qpiv):.0f} | {1e3 * np.median(qe_t):.3f} | {_geomean(own):.2f} | "
              f"{_geomean(whole):.2f} | {diff:.1e} |")
    print(f"| all | {len(own_all)} | | | | {_geomean(own_all):.2f} | {_geomean(call_all):.2f} "
          "| |")
    print()
    print("Ratios are geometric means over the instances of the best-of-repeat times.")


def _timed(call: Callable[[], object]) -> float:
    t0 = time.perf_counter()
    call()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1500])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--skip-lemke", action="store_true", help="only the framework part")
    args = ap.parse_args()
    framework_part(args.sizes, args.repeat)
    if not args.skip_lemke:
        lemke_part(args.repeat)


if __name__ == "__main__":
    main()
