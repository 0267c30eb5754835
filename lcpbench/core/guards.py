"""Estimates before the work: memory, build time and sweep size, refused past stated limits.

A problem family may register an estimate of what building its instances costs
(``register_problem(..., estimate=fn)``, ``fn(params) -> Estimate``): how many
instances, their largest n, the bytes alive once they are built and the
floating-point work of building them. The command line checks that estimate
before a single matrix is allocated and refuses, with the estimate and the
limit in one line, work that would not fit in memory, would run for a long time
without a word, or would make a sweep of more runs than a machine gets through;
``--force`` lifts the limits. ``lcpbench.solve`` checks the dense copy of A a
solver that needs the explicit matrix would get the same way, and returns a
``failed`` result instead of raising (``force=True`` lifts the limit, not the
available memory).

The limits (module constants, so a site or a test can change them):

* memory: :data:`MEMORY_FRACTION` of the memory available when the check runs;
* time: :data:`TIME_LIMIT_S` seconds of building or planning, estimated from the
  floating-point work at the speed this machine multiplies matrices (measured
  once per process, in about 20 ms);
* sweep size: :data:`MAX_RUNS` runs;
* dense conversion inside a solve: :data:`DENSE_LIMIT_BYTES`, and never more than
  the memory limit.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import Optional

import numpy as np

from lcpbench.core.defaults import DEFAULT_SOLVER

__all__ = ["Estimate", "TooLarge", "MEMORY_FRACTION", "TIME_LIMIT_S", "MAX_RUNS",
           "DENSE_LIMIT_BYTES", "NOTE_AFTER_S", "FORCE_ENV", "available_memory", "memory_limit",
           "seconds_for", "format_bytes", "format_seconds", "refusal", "check", "dense_refusal",
           "forced", "dense_family"]

#: Share of the available memory that one command may plan to use.
MEMORY_FRACTION = 0.5
#: Longest estimated build or planning time accepted without ``--force`` (seconds).
TIME_LIMIT_S = 300.0
#: Largest number of runs a sweep may plan without ``--force``.
MAX_RUNS = 100_000
#: Largest dense copy of A a solve makes for a solver that needs the explicit matrix.
DENSE_LIMIT_BYTES = 2 * 2**30
#: Estimated times above this are announced before the work starts (seconds).
NOTE_AFTER_S = 10.0
#: Environment variable that lifts the limits in runs of a sweep started with ``--force``
#: (worker processes inherit it).
FORCE_ENV = "LCPBENCH_FORCE"
#: Bytes a built instance holds beside its matrices (the LCP, its operators, meta).
INSTANCE_OVERHEAD = 2048


class TooLarge(ValueError):
    """Work refused before it starts: an estimate over a stated limit."""


@dataclass(frozen=True)
class Estimate:
    """What building the instances of a problem spec costs, before building them.

    Attributes
    ----------
    instances : int
        Number of instances.
    n : int
        Largest n among them.
    bytes : float
        Memory held once all instances are built, plus the temporaries of building one.
    flops : float
        Floating-point work of building them, counted as matrix-product operations.
    """

    instances: int
    n: int
    bytes: float
    flops: float = 0.0


def dense_family(count: int, n: int, *, matrices: int = 1, temporaries: int = 4,
                 flops_each: float = 0.0) -> Estimate:
    """The estimate of ``count`` instances, each with ``matrices`` dense n x n matrices.

    Parameters
    ----------
    count, n : int
        Number of instances and their largest size.
    matrices : int
        Dense n x n float64 matrices each instance keeps (A, its low fidelities).
    temporaries : int
        Further n x n matrices alive while one instance is built.
    flops_each : float
        Floating-point work of building one instance.
    """
    square = 8.0 * float(n) * float(n)
    held = count * (matrices * square + 8.0 * 4 * n + INSTANCE_OVERHEAD)
    return Estimate(int(count), int(n), held + temporaries * square, count * flops_each)


#: Seconds a reading of the available memory is reused: a reading costs about 0.1 ms
#: (``/proc/meminfo``), which a small solve (n = 100 in a few milliseconds) paid twice per
#: call; memory that frees or fills within this interval is seen at the next reading.
MEMORY_READING_SECONDS = 0.5

_memory_reading: list[float] = []            # [time of the reading, bytes available]


def available_memory() -> float:
    """Bytes of memory available now (psutil if installed, else /proc/meminfo or sysconf).

    A reading is reused for :data:`MEMORY_READING_SECONDS`.
    """
    now = time.monotonic()
    if _memory_reading and now - _memory_reading[0] < MEMORY_READING_SECONDS:
        return _memory_reading[1]
    avail = _read_available_memory()
    _memory_reading[:] = [now, avail]
    return avail


def _read_available_memory() -> float:
    """One reading of the available memory, in bytes (inf when it cannot be read)."""
    try:
        import psutil

        return float(psutil.virtual_memory().available)
    except ImportError:
        pass
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return float("inf")                       # unknown: no memory limit


def memory_limit() -> float:
    """The memory limit in bytes: :data:`MEMORY_FRACTION` of the available memory."""
    return MEMORY_FRACTION * available_memory()


@lru_cache(maxsize=1)
def _flop_rate() -> float:
    """Matrix-product speed of this machine (flop/s), best of three 384 x 384 products."""
    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((384, 384)), rng.standard_normal((384, 384))
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - t0)
    return 2.0 * 384 ** 3 / max(best, 1e-6)


def seconds_for(flops: float) -> float:
    """Estimated seconds of ``flops`` matrix-product operations on this machine."""
    if flops <= 1e8:                              # a fraction of a second anywhere
        return flops / 1e9
    return flops / _flop_rate()


def format_bytes(nbytes: float) -> str:
    """``"74.5 GiB"``: bytes in binary units, three significant figures."""
    value = float(nbytes)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if value < 1024 or unit == "PiB":
            return f"{value:.3g} {unit}" if unit != "B" else f"{value:.0f} B"
        value /= 1024.0
    return f"{value:.3g} PiB"                     # pragma: no cover - loop always returns


def format_seconds(seconds: float) -> str:
    """``"42 s"``, ``"6.5 min"``, ``"1.5 h"``, ``"3.2 days"``."""
    s = float(seconds)
    if s < 90:
        return f"{s:.2g} s"
    if s < 5400:
        return f"{s / 60:.2g} min"
    if s < 2 * 86400:
        return f"{s / 3600:.2g} h"
    return f"{s / 86400:.2g} days"


def refusal(label: str, est: Estimate, *, seconds: Optional[float] = None,
            what: str = "lower n or count") -> Optional[str]:
    """The one-line reason ``est`` is over a limit, or None when it is within them.

    Parameters
    ----------
    label : str
        What the estimate is of (a problem spec).
    est : Estimate
    seconds : float, optional
        Estimated seconds (default: from ``est.flops``).
    what : str
        What the user can lower, named in the message.
    """
    sizes = f"{est.instances} instance(s) of n up to {est.n}"
    limit = memory_limit()
    if est.bytes > limit:
        return (f"{label}: {sizes} need about {format_bytes(est.bytes)} of memory; {what}, or "
                f"pass --force (limit: {format_bytes(limit)}, {MEMORY_FRACTION:.0%} of the "
                "available memory)")
    secs = seconds_for(est.flops) if seconds is None else seconds
    if secs > TIME_LIMIT_S:
        return (f"{label}: {sizes} take about {format_seconds(secs)} to build; {what}, or pass "
                f"--force (limit: {format_seconds(TIME_LIMIT_S)} at this machine's "
                f"{_flop_rate() / 1e9:.3g} GFLOP/s)")
    return None


def check(label: str, est: Optional[Estimate], *, force: bool = False) -> None:
    """Raise :class:`TooLarge` with :func:`refusal`'s message unless ``force`` or within limits."""
    if est is None or force:
        return
    msg = refusal(label, est)
    if msg:
        raise TooLarge(msg)


def forced() -> bool:
    """True when :data:`FORCE_ENV` is set (a sweep started with ``--force``)."""
    return os.environ.get(FORCE_ENV, "") not in ("", "0")


def dense_refusal(solver: str, n: int, *, matrix_free: bool, force: bool = False
                  ) -> Optional[str]:
    """Why the dense copy of an n x n A for ``solver`` is refused, or None.

    The copy takes ``8 n^2`` bytes (twice that for a matrix-free A, applied to the
    columns of the identity). Refused past :data:`DENSE_LIMIT_BYTES` or the memory
    limit unless ``force``; past the available memory even with ``force``.
    """
    need = 8.0 * n * n * (2 if matrix_free else 1)
    avail = available_memory()
    head = (f"{solver} needs A as a dense matrix: n = {n} takes about {format_bytes(need)}")
    if need > avail:
        return (f"{head}, more than the {format_bytes(avail)} of memory available; use an "
                f"MVP-only solver such as {DEFAULT_SOLVER}")
    limit = min(DENSE_LIMIT_BYTES, memory_limit())
    if need > limit and not (force or forced()):
        return (f"{head}, over the limit of {format_bytes(limit)}; use an MVP-only solver such "
                f"as {DEFAULT_SOLVER}, or pass force=True (lcpbench run/solve --force)")
    return None
