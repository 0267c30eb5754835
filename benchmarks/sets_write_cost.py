"""Seconds and bytes that writing a stored set instance by instance costs, per shipped set.

Usage::

    python benchmarks/sets_write_cost.py                  # every shipped set, into a temp folder
    python benchmarks/sets_write_cost.py --dir /data/tmp  # on another disk
    python benchmarks/sets_write_cost.py --read           # also the verified read of each set

Each shipped set is read (verified) and written again into a fresh file with ``SetWriter``,
one ``write_instance`` per instance, as ``lcpbench generate`` writes it. Prints, per set, the
number of instances, the final file size, the total and the median and largest seconds of one
``write_instance`` (the dense matrices are already formed, so this is the writing alone), and
the peak Python memory of the writing (tracemalloc: the image in memory and the copy written).
With ``--read`` it also times ``read_set`` of the written file. Run it against another
checkout (``PYTHONPATH=that/checkout``) to compare two versions of the writer.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path

from lcpbench.sets import SetWriter, instance_ids, read_set


def _write(path: Path, lcps) -> list[float]:
    seconds = []
    with SetWriter(path, title="bench", description="rewrite of a shipped set",
                   generator="benchmarks/sets_write_cost.py") as w:
        for lcp in lcps:
            low = {name: (op._impl, op.declared_cost, {}) for name, op in lcp.low.items()}
            t0 = time.perf_counter()
            w.write_instance(lcp.meta["instance"], lcp.A._impl, lcp.b, low=low, x0=lcp.x0,
                             reference=lcp.reference)
            seconds.append(time.perf_counter() - t0)
    return seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", default=None, help="folder for the written files (default: temp)")
    ap.add_argument("--read", action="store_true", help="also time read_set of each file")
    args = ap.parse_args()
    from lcpbench.problems.stored import shipped_sets

    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        print(f"{'set':18s} {'inst':>4s} {'MB':>6s} {'total s':>8s} {'median ms':>10s} "
              f"{'max ms':>8s} {'peak MB':>8s}" + (f" {'read s':>7s}" if args.read else ""))
        for name, src in shipped_sets().items():
            lcps = read_set(src, psd_check=False)
            out = Path(tmp) / f"{name}.h5"
            tracemalloc.start()
            seconds = _write(out, lcps)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            line = (f"{name:18s} {len(seconds):4d} {out.stat().st_size / 1e6:6.2f} "
                    f"{sum(seconds):8.3f} {1e3 * statistics.median(seconds):10.1f} "
                    f"{1e3 * max(seconds):8.1f} {peak / 1e6:8.1f}")
            if args.read:
                t0 = time.perf_counter()
                assert len(read_set(out, psd_check=False)) == len(instance_ids(out))
                line += f" {time.perf_counter() - t0:7.3f}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
