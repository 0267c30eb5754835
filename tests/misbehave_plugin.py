"""A solver that misbehaves on purpose, for the runner's fault tests.

Imported by the tests directly and, on Dask workers, through ``LCPBENCH_PLUGINS``
(which names this file), so the same ``test-misbehave`` exists everywhere.
"""

import ctypes
import faulthandler
import os
import signal
import sys
import time
from dataclasses import dataclass

import numpy as np

from lcpbench import register_solver


@dataclass(frozen=True)
class MisbehaveParams:
    """Parameters of the misbehaving test solver.

    Parameters
    ----------
    mode : str
        sleep (ignores every budget), raise, nan, die (exit code 3), exit (sys.exit(0)), kill (SIGKILL to
        itself), segv (a real segmentation fault), slow (solves after a short sleep),
        wait (solves once the file named by ``LCPBENCH_TEST_RELEASE`` exists, for tests
        that must act while runs are certainly in flight; gives up after 120 s).
    seconds : float
        Sleep of ``slow``.
    """

    mode: str = "sleep"
    seconds: float = 0.2


@register_solver("test-misbehave", MisbehaveParams, listed=False)
def misbehave(ctx, p):
    """A solver that misbehaves on purpose."""
    if p.mode == "sleep":
        time.sleep(60)
    if p.mode == "raise":
        raise RuntimeError("boom on purpose")
    if p.mode == "die":
        os._exit(3)
    if p.mode == "exit":
        sys.exit(0)
    if p.mode == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
    if p.mode == "segv":
        faulthandler.disable()          # pytest's handler would print a traceback dump
        ctypes.string_at(0)
    if p.mode == "wait":
        release = os.environ["LCPBENCH_TEST_RELEASE"]
        t0 = time.monotonic()
        while not os.path.exists(release) and time.monotonic() - t0 < 120:
            time.sleep(0.02)
    if p.mode in ("slow", "wait"):
        time.sleep(p.seconds if p.mode == "slow" else 0.0)
        x = np.zeros(ctx.n)
        w = ctx.A @ x + ctx.b
        ctx.report(x, w)
        return ctx.finish(x, w)
    x = np.full(ctx.n, np.nan)
    ctx.report(x, x)
    return ctx.finish(x, x)
