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


PAPER_OFFLINE_TABLE: dict[str, tuple] = {
    "bb-pgd": ("BB-PGD", (11, 11, 11, 12), None),
    "a-pgd:constants=oracle": ("A-PGD", (12, 15, 15, 16), None),
    "zero-sr1": ("zeroSR1", (9, 13, 13, 15), None),
    "l-bfgs-b": ("L-BFGS-B", (10, 11, 11, 12), None),
    "minmap-newton": ("Min-Map Newton", (15, 28, 27, 47), None),
    "mono-pqn": ("Mono-PQN", (7, 8, 7.8, 8), None),
    "bi-pqn:low=p3e6": ("Bi-PQN, low p = 3, eps 1e-6", (4.7, 5.4, 5.5, 7.1), (4, 4, 4.4, 5)),
    "bi-pqn:low=p4e6": ("Bi-PQN, low p = 4, eps 1e-6", (3.8, 4.6, 4.6, 5.5), (3, 3, 3, 4)),
    "bi-pqn:low=p6e6": ("Bi-PQN, low p = 6, eps 1e-6", (3.8, 5.1, 5.4, 8.4), (2, 2, 2.1, 3)),
}
"""The method paper's offline table (its section "Offline Comparison") by the lcpbench solver
spec that runs the same method: label, E-MVPs (min, median, mean, max) and, for Bi-PQN, the
high-fidelity MVPs of the same statistics. A-PGD gets L and mu as known, as the paper grants."""

PAPER_OFFLINE_HEADLINE = ("mono-pqn", "bi-pqn:low=p4e6")
"""The rows of the paper's offline table that its text compares with BB-PGD (Mono-PQN and
Bi-PQN on the low fidelity it marks in bold)."""

