"""lcpbench's registered solvers as benchopt solvers, each solve through lcpbench.

``solver`` is an lcpbench registry name (every listed solver but the reference QP solvers);
``low`` names the low-fidelity operator of a multi-fidelity solver (``bi-pqn``,
``multi-pqn``), one of the instance's (``lcpbench list`` and the set's description name them;
the method paper's is ``p4e6``). Empty, the instance's only low is used, and an instance with
several is skipped with a message naming them. Select one with
``-s "lcpbench[solver=bi-pqn,low=p4e6]"``.

Each run is :func:`lcpbench.run_solver` on a fresh copy of the instance's counted operators:
the products are counted by lcpbench, never by the solver, and benchopt's callback sees
every iterate lcpbench's solver reports. When benchopt has seen enough, the callback raises
``StopIteration``, which ends lcpbench's solve at that iterate.
"""

import numpy as np
from benchopt import BaseSolver

import lcpbench


def _registry_solvers() -> list[str]:
    """Every listed lcpbench solver except the reference QP solvers (ground truth)."""
    return sorted(name for name, info in lcpbench.list_solvers().items()
                  if info.listed and not info.reference)


class Solver(BaseSolver):
    name = "lcpbench"
    requirements: list = []
    parameters = {"solver": _registry_solvers(), "low": [""]}
    sampling_strategy = "callback"

    def skip(self, lcp, tol):
        info = lcpbench.get_solver(self.solver)
        if not info.multifidelity:
            return (True, f"{self.solver} uses no low fidelity; leave low empty") \
                if self.low else (False, None)
        lows = sorted(lcp.low)
        if not lows:
            return True, f"{lcp.name} has no low-fidelity operator for {self.solver}"
        if self.low and self.low not in lows:
            return True, f"{lcp.name} has no low {self.low!r}; it has {', '.join(lows)}"
        if not self.low and len(lows) > 1:
            return True, (f"{lcp.name} has {len(lows)} lows; name one: "
                          f"lcpbench[solver={self.solver},low=NAME], NAME in {', '.join(lows)}")
        return False, None

    def set_objective(self, lcp, tol):
        self.lcp, self.tol = lcp, tol
        info = lcpbench.get_solver(self.solver)
        low = self.low or (sorted(lcp.low)[0] if info.multifidelity else "")
        self.spec = f"{self.solver}:{info.lows.one}={low}" if low and info.lows.one \
            else self.solver
        self._x = np.zeros(lcp.n)
        self._mvps, self._emvps = 0, 0.0

    def run(self, callback):
        def seen(row, x):
            self._x, self._mvps, self._emvps = x, row["mvps"], row["emvps"]
            if not callback():
                raise StopIteration

        res = lcpbench.run_solver(self.lcp, self.spec, tol=self.tol, callback=seen)
        self._x, self._mvps, self._emvps = res.x, res.mvps, res.emvps
        self.status = res.status.value

    def get_result(self):
        return dict(x=self._x, mvps=self._mvps, emvps=self._emvps)
