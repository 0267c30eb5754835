"""Built-in problem plugins (installed as ``lcpbench.problems``).

The modules listed under the ``lcpbench.problems`` entry-point group register
problem families with :func:`lcpbench.register_problem`. The others hold what
those share: the building blocks of the synthetic families (``synthetic``) and
the file formats that ``external`` reads (``siconos``, ``fclib``, and their
common rules in ``formats``). ``suspension`` is the live backend (mobility models, the
fidelity registry, contacts) and registers the lattice scenes (entry-point group
``lcpbench.scenes``).
"""
