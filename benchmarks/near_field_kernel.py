"""The near field's table pairs: the pair-frame kernel against the per-pair rotated one,
side by side on one packed configuration, with this machine's memory roof measured in
the same run.

Usage::

    python benchmarks/near_field_kernel.py            # paper-lattice 5x5x5, p = 8
    python benchmarks/near_field_kernel.py --m 3 --repeat 9

The ``paper-lattice`` scene of side ``m`` is packed by cheap RPY steps (as the shipped
sets' instances are) and its boundary-integral set-up built at order ``--p``.  Printed:

* one inner application (forward, and forward + transposed together) of the table pairs
  with each kernel, serial and on every thread: the minimum of ``--repeat`` runs, their
  ratio, the bytes each kernel's per-pair data occupies (streamed once per application),
  the achieved bytes per second and multiply-adds per second;
* the STREAM triad bandwidth (compiled, serial and parallel) on arrays far larger than the
  caches, and each kernel's time against its roof ``bytes / triad``;
* one full product of the mobility (``M v``, cold: no recycled directions) with each
  kernel, its time ratio and the relative difference of the two products.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from numba import get_num_threads, njit, prange

sys.path.insert(0, str(Path(__file__).parent))
from common import packed_lattice  # noqa: E402


@njit(parallel=True, cache=True)
def _triad_parallel(a, b, c, s):
    for i in prange(a.size):
        a[i] = b[i] + s * c[i]


@njit(cache=True)
def _triad_serial(a, b, c, s):
    for i in range(a.size):
        a[i] = b[i] + s * c[i]


def triad(parallel: bool, n: int = 40_000_000, repeat: int = 5) -> float:
    """STREAM triad bandwidth in bytes per second (three arrays of ``n`` doubles)."""
    a, b, c = np.zeros(n), np.ones(n), np.full(n, 2.0)
    fn = _triad_parallel if parallel else _triad_serial
    fn(a, b, c, 3.0)
    best = min(_timed(lambda: fn(a, b, c, 3.0)) for _ in range(repeat))
    return 3 * 8 * n / best


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def best_of(fn, repeat: int) -> float:
    fn()
    return min(_timed(fn) for _ in range(repeat))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--m", type=int, default=5, help="lattice side (default 5: 125 spheres)")
    ap.add_argument("--p", type=int, default=8, help="spherical-harmonic order")
    ap.add_argument("--pack", type=int, default=40, help="RPY steps that pack the lattice")
    ap.add_argument("--repeat", type=int, default=5, help="timed runs per figure")
    args = ap.parse_args()

    from lcpbench.problems.suspension.bim import kernels_rotated as kr
    from lcpbench.problems.suspension.bim.operator import BimMobility

    scene = packed_lattice(args.m, args.pack, "paper-lattice")
    mob = BimMobility(scene.get_state()["centers"], 1.0, p=args.p, eps_gmres=1e-8, recycle=0)
    near, frame, plan = mob.near, mob.near.frame, mob.plan
    if frame is None:
        raise SystemExit("this configuration has no table pairs")
    part, rot = near._rot, near.rotated
    M, nv = plan.M, frame.nv
    rng = np.random.default_rng(0)
    coef, x = rng.standard_normal((2, M, nv))
    print(f"paper-lattice {args.m}x{args.m}x{args.m} ({M} spheres), p = {args.p}: "
          f"{frame.n_pairs} table pairs; {get_num_threads()} threads\n")

    def old(parallel, both):
        fwd = kr.rotated_forward if parallel else kr.rotated_forward_serial
        tr = kr.rotated_both if parallel else kr.rotated_both_serial

        def run():
            acc = np.zeros((M, nv))
            if both:
                bar = np.empty((part.src.size, nv))
                tr(part.blocks, part.ptr, part.src, coef, acc, x, bar)
                _ = part.by_source @ bar
            else:
                fwd(part.blocks, part.ptr, part.src, coef, acc)
        return run

    def new(parallel, both):
        def run():
            acc = np.zeros((M, nv))
            if both:
                frame.both(coef, acc, x, np.zeros((M, nv)), parallel=parallel)
            else:
                frame.forward(coef, acc, parallel=parallel)
        return run

    bw = {False: triad(False), True: triad(True)}
    old_bytes, new_bytes = rot.nbytes, frame.nbytes
    print(f"triad bandwidth: serial {bw[False] / 1e9:.1f} GB/s, parallel "
          f"{bw[True] / 1e9:.1f} GB/s")
    print(f"per-pair data streamed per application: rotated {old_bytes / 1e6:.0f} MB, "
          f"pair frame {new_bytes / 1e6:.0f} MB\n")
    print("| application | threads | rotated s | pair frame s | ratio | pair frame GB/s | "
          "of triad | roof time / time | rotated GB/s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for both in (False, True):
        for parallel in (False, True):
            t_old = best_of(old(parallel, both), args.repeat)
            t_new = best_of(new(parallel, both), args.repeat)
            b = bw[parallel]
            print(f"| {'forward + transposed' if both else 'forward'} | "
                  f"{get_num_threads() if parallel else 1} | {t_old:.4f} | {t_new:.4f} | "
                  f"{t_old / t_new:.2f} | {new_bytes / t_new / 1e9:.2f} | "
                  f"{new_bytes / t_new / b:.0%} | {new_bytes / b / t_new:.0%} | "
                  f"{old_bytes / t_old / 1e9:.2f} |", flush=True)

    v = rng.standard_normal(6 * M)
    with_frame = best_of(lambda: mob.matvec(v), max(1, args.repeat // 2))
    y_new = mob.matvec(v)
    near.frame = None
    without = best_of(lambda: mob.matvec(v), max(1, args.repeat // 2))
    y_old = mob.matvec(v)
    near.frame = frame
    print(f"\nfull product M v (GMRES 1e-8, no recycling): rotated {without:.2f} s, pair "
          f"frame {with_frame:.2f} s, ratio {without / with_frame:.2f}; relative "
          f"difference {np.linalg.norm(y_new - y_old) / np.linalg.norm(y_old):.1e}")


if __name__ == "__main__":
    main()
