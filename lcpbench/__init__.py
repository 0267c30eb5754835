"""lcpbench: benchmark suite and reference solvers for symmetric LCPs.

Find ``x >= 0`` with ``w = A x + b >= 0`` and ``x . w = 0``, where every product
with ``A`` is counted. Quick start::

    import lcpbench
    res = lcpbench.solve(A, b)                 # Mono-PQN, paper's stop rule, tol 1e-8
    res = lcpbench.solve(lcp, solver="bi-pqn:low=p4", x0=x_prev)
    print(res.summary())
"""

from .core.api import DEFAULT_SOLVER, run_solver, solve
from .core.context import Budget, Monitor, SolverContext, StopSolver
from .core.lcp import LCP
from .core.operator import BudgetExhausted, Operator
from .core.reference import Reference, reference
from .core.registry import LowOperators, get_problem, get_solver, register_problem, register_solver
from .core.registry import problems as list_problems
from .core.registry import solvers as list_solvers
from .core.residuals import StopRule
from .core.result import SolveResult, Status
from .core.specs import parse_spec
from .toolkit.quasinewton import SecantMemory

__version__ = "0.1.0"

__all__ = [
    "LCP", "Operator", "Budget", "Monitor", "SolverContext", "StopSolver", "BudgetExhausted",
    "StopRule", "SolveResult", "Status", "solve", "run_solver", "DEFAULT_SOLVER", "reference",
    "Reference", "LowOperators", "register_solver", "register_problem", "get_solver", "get_problem",
    "list_problems", "list_solvers", "parse_spec", "SecantMemory", "__version__",
]
