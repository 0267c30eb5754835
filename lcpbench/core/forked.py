"""Work in a forked child with a deadline: the isolation the runner and the QP references share.

:class:`ForkedCall` runs ``fn(*args)`` in a child made by ``os.fork`` and returns its result
through a pipe (``os.fork`` works inside a daemonic Dask worker, where ``multiprocessing``
refuses to start children); :func:`call_with_deadline` waits for it and kills it at its
deadline. The runner isolates runs with it (:mod:`lcpbench.run.executors`) and the reference
QP backends their solves (:func:`lcpbench.toolkit.qp.solve_nonneg_qp`), so compiled code
that never returns to a Python-level time check is still bounded.
"""

from __future__ import annotations

import os
import pickle
import select
import signal
import time
from collections.abc import Callable
from typing import Optional

__all__ = ["ForkedCall", "call_with_deadline"]


class ForkedCall:
    """``fn(*args)`` in a forked child; the result comes back pickled through a pipe."""

    def __init__(self, fn: Callable, args: tuple, deadline: Optional[float]):
        self.deadline = deadline
        r, w = os.pipe()
        pid = os.fork()
        if pid == 0:  # child
            os.close(r)
            code = 0
            try:
                payload = pickle.dumps(("ok", fn(*args)), protocol=pickle.HIGHEST_PROTOCOL)
            except BaseException as exc:  # noqa: BLE001 - reported to the parent
                payload = pickle.dumps(("error", f"{type(exc).__name__}: {exc}"))
                code = 1
            try:
                view = memoryview(payload)
                while view:
                    n = os.write(w, view)
                    view = view[n:]
            finally:
                os._exit(code)
        os.close(w)
        self.started = time.monotonic()
        self.pid, self.fd = pid, r
        self.chunks: list[bytes] = []
        self.done = False
        self.result: Optional[tuple[str, object]] = None

    def poll(self, wait: float = 0.0) -> bool:
        """Read what the child sent; True once it has finished (or been killed)."""
        if self.done:
            return True
        ready, _, _ = select.select([self.fd], [], [], wait)
        if ready:
            data = os.read(self.fd, 1 << 20)
            if data:
                self.chunks.append(data)
                return False
            self._reap()          # EOF: the child closed its end (exited)
            return True
        if self.deadline is not None and time.monotonic() > self.deadline:
            os.kill(self.pid, signal.SIGKILL)
            self._reap(timeout=True)
            return True
        return False

    @property
    def elapsed(self) -> float:
        """Seconds from the fork to the end of the child (or to now while it runs)."""
        return getattr(self, "ended", time.monotonic()) - self.started

    def _reap(self, timeout: bool = False) -> None:
        _, status = os.waitpid(self.pid, 0)
        os.close(self.fd)
        self.ended = time.monotonic()
        self.done = True
        if timeout:
            self.result = ("timeout", None)
            return
        try:
            kind, value = pickle.loads(b"".join(self.chunks))
            self.result = (kind, value)
        except Exception:  # the child died before sending everything
            if os.WIFSIGNALED(status):
                self.result = ("died", f"worker process died (signal {os.WTERMSIG(status)})")
            else:
                self.result = ("died",
                               f"worker process died (exit code {os.waitstatus_to_exitcode(status)})")


def call_with_deadline(fn: Callable, args: tuple, timeout: Optional[float]):
    """``fn(*args)`` in a forked child killed after ``timeout`` s: ``(kind, value)``.

    ``kind`` is ``ok`` (``value`` is the result), ``error`` (the exception's
    text), ``timeout`` or ``died``. For work the parent must not wait on
    unboundedly, such as an instance's reference solve. If the wait itself is
    interrupted (Ctrl-C, a timer's exception), the child is killed before the
    exception goes on: compiled code that ignores signals is never left running.
    """
    call = ForkedCall(fn, args, None if timeout is None else time.monotonic() + timeout)
    try:
        while not call.poll(wait=0.05):
            pass
    except BaseException:
        if not call.done:
            os.kill(call.pid, signal.SIGKILL)
            call._reap(timeout=True)
        raise
    return call.result
