"""The user-facing defaults that name plugins: the one place the framework does.

Everything else in the framework reaches plugins through the registries. These are
choices a user sees (what ``lcpbench.solve(A, b)`` runs, what the report divides by),
kept here so that a distribution without these plugins changes one module, and so that
a test can check that no other framework module names a plugin.
"""

from __future__ import annotations

__all__ = ["DEFAULT_SOLVER", "BASELINE_SOLVER", "SIMULATE_SOLVER", "EXAMPLE_PROBLEM",
           "EXAMPLE_SCENE"]

#: The solver ``lcpbench.solve``, ``lcpbench solve`` and ``lcpbench generate`` use when
#: none is named: Mono-PQN, the method paper's mono-fidelity method.
DEFAULT_SOLVER = "mono-pqn"
#: The solver ratios and speedups are measured against, as in the paper's tables: BB-PGD.
BASELINE_SOLVER = "bb-pgd"
#: The solver of ``lcpbench simulate`` when none is named (the paper's online baseline).
SIMULATE_SOLVER = BASELINE_SOLVER
#: The problem family of ``lcpbench solve`` when none is named.
EXAMPLE_PROBLEM = "random-spd"
#: The scene of ``lcpbench simulate`` and ``lcpbench generate`` when none is named.
EXAMPLE_SCENE = "lattice:m=3,model=rpy"


PAPER_ONLINE_FAMILIES = {"Mono-PQN": "mono-pqn", "Bi-PQN": "bi-pqn"}
"""The method paper's online solvers by the names of their solver families: the report sets
the first measured solver of each family (``bi-pqn:low=p8f6e3``) beside the paper's row."""
