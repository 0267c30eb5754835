"""A wall-time limit that reaches a solver's inner loops, not only its products.

The budget's ``max_seconds`` is checked at every counted product and every
reported iterate. A solver can still spend long stretches between the two (a
prox subproblem, a dense factorisation, a library call); :class:`Deadline`
covers those with a ``SIGALRM`` timer that raises
:class:`~lcpbench.core.operator.BudgetExhausted` (kind ``"time"``) in the
solver's own Python code, so the solve ends as ``timeout`` at its last
reported iterate. The timer is set a little after the budget so that the
ordinary checks win when they can. Only in the main thread, and only when no
other interval timer is running (it is never taken from its owner); elsewhere
the runner's process timeout is the backstop.

The timer reaches Python code only: a compiled loop that never returns to the
interpreter (a QP backend such as ProxQP) does not see it. Such calls run in a
forked child killed at the limit instead (:func:`lcpbench.toolkit.qp.solve_nonneg_qp`
with ``max_seconds``, through :func:`lcpbench.core.forked.call_with_deadline`),
and end before this timer would fire.
"""

from __future__ import annotations

import signal
import threading
from typing import Any, Optional

from lcpbench.core.operator import BudgetExhausted

__all__ = ["Deadline", "DEADLINE_SLACK"]

#: The timer fires at ``max_seconds * (1 + DEADLINE_SLACK) + DEADLINE_SLACK`` seconds.
DEADLINE_SLACK = 0.1


class Deadline:
    """Context manager: raise ``BudgetExhausted(kind="time")`` once ``seconds`` are over.

    Parameters
    ----------
    seconds : float or None
        The budget's ``max_seconds``; None disables the timer.
    """

    def __init__(self, seconds: Optional[float]):
        self.seconds = seconds
        self.armed = False
        self._old_handler: Any = None   # what signal.signal returned

    def _fire(self, signum, frame) -> None:
        raise BudgetExhausted(f"time budget of {self.seconds:g} s exhausted (inside the solver's "
                              "own computation)", kind="time")

    def __enter__(self) -> Deadline:
        if self.seconds is None or not hasattr(signal, "setitimer") \
                or threading.current_thread() is not threading.main_thread() \
                or signal.getitimer(signal.ITIMER_REAL)[0] > 0:
            return self
        try:
            self._old_handler = signal.signal(signal.SIGALRM, self._fire)
        except ValueError:          # not the main thread of the main interpreter
            return self
        delay = self.seconds * (1 + DEADLINE_SLACK) + DEADLINE_SLACK
        signal.setitimer(signal.ITIMER_REAL, delay)
        self.armed = True
        return self

    def __exit__(self, *exc) -> None:
        if self.armed:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, self._old_handler)
            self.armed = False
