"""The solver toolkit: numerical pieces that solver plugins import.

Weighted proximal operators (``prox``), quasi-Newton models (``quasinewton``), step rules
(``steps``), convergence-claim confirmation (``confirm``) and QP helpers (``qp``). A solver plugin
is one file that imports what it needs from here and touches ``A`` only through its
``SolverContext`` (see docs/architecture.md, "Adding a solver").
"""
