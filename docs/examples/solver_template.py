"""A solver plugin in one file: projected gradient with the exact step of the quadratic.

Copy this file, rename the solver and its parameters, and change the loop. Load it
without packaging through ``LCPBENCH_PLUGINS=path/to/this_file.py`` (the CLI, the
library, worker processes and dask workers all read that variable), or package it with
an entry point in the group ``lcpbench.solvers``::

    [project.entry-points."lcpbench.solvers"]
    my-solvers = "my_package.my_solver"

The rules the framework relies on:

* touch ``A`` only through ``ctx.A`` (every product is counted there; ``A @ 0`` is free);
* report every iterate with ``ctx.report(x, w)``; it returns True when the stop rule is
  met or the budget is spent, and then the solver returns ``ctx.finish(x, w)``;
* optionally offer directions whose products were computed anyway,
  ``ctx.offer_direction(d, Ad)`` (no product): when the solve does not converge the
  framework looks among them for evidence that the LCP has no solution;
* keep the parameters in a frozen dataclass whose fields all have defaults: the
  registry parses ``template-pgd:max_iter=50`` into it and rejects unknown keys.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lcpbench import SolverContext, SolveResult, Status, register_solver
from lcpbench.toolkit.steps import exact_step


@dataclass(frozen=True)
class TemplatePGDParams:
    """Parameters of template-pgd.

    Parameters
    ----------
    max_iter : int
        Iterations before the solver gives up with status ``max_iter``.
    """

    max_iter: int = 1000


@register_solver("template-pgd", TemplatePGDParams)
def template_pgd(ctx: SolverContext, p: TemplatePGDParams) -> SolveResult:
    """Projected gradient descent along the projected direction, with the exact step.

    One MVP per iteration: ``A d`` gives the exact step along the projected direction
    ``d = max(x - w, 0) - x``, and the new gradient follows from ``w + t A d`` without
    another product.
    """
    x = np.maximum(ctx.x0, 0.0)
    w = ctx.A @ x + ctx.b
    for _ in range(p.max_iter):
        if ctx.report(x, w):
            return ctx.finish(x, w)
        d = np.maximum(x - w, 0.0) - x
        Ad = ctx.A @ d
        t = exact_step(w, d, Ad)
        if not np.isfinite(t) or t <= 0.0:
            return ctx.finish(x, w, Status.stagnated, "no descent along the projected direction")
        t = min(t, 1.0)                     # d already ends on the feasible set at t = 1
        x, w = x + t * d, w + t * Ad
    return ctx.finish(x, w, Status.max_iter, f"max_iter = {p.max_iter} reached")
