"""The core model: LCP, counted operators, residuals and stop rules, results, registry, solve API.

Nothing here imports a plugin. Solver plugins see this package through ``SolverContext``; the
public names are re-exported by ``lcpbench`` itself.
"""
