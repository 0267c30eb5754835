"""Built-in solver plugins (installed as ``lcpbench.solvers``).

One module per family; each registers its solvers with
:func:`lcpbench.register_solver` and is listed in ``pyproject.toml`` under the
``lcpbench.solvers`` entry-point group, exactly as a third-party package would.
"""
