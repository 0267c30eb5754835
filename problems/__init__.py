"""Built-in problem plugins (installed as ``lcpbench.problems``).

Each module registers problem families with :func:`lcpbench.register_problem`
and is listed under the ``lcpbench.problems`` entry-point group.
"""
