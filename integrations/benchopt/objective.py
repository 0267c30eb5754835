"""The benchopt objective of lcpbench: the verified LCP residual, counted in E-MVPs.

An LCP asks for ``x >= 0`` with ``w = A x + b >= 0`` and ``x . w = 0``. Each solver of this
benchmark runs inside lcpbench, whose counted operator counts every product with ``A``; the
objective recomputes ``w`` itself (one product lcpbench does not count) and reports

* ``value``: the verified residual ``||min(x, A x + b)||_2`` (what benchopt's convergence
  curves show and its stopping criterion watches),
* ``emvps``: the effective matrix-vector products spent so far (high-fidelity products plus
  each low-fidelity product weighted by its cost), the method paper's unit of cost,
* ``mvps``: the high-fidelity products alone, and ``qp_objective``: ``x'(A x)/2 + b'x``.

``plots/residual_emvps.py`` draws ``value`` against ``emvps``: benchopt's own axes are time
and iterations, and on a suspension one product is a Stokes solve, so the products are the
cost that transfers between machines.
"""

import numpy as np
from benchopt import BaseObjective

from lcpbench.core.operator import apply_uncounted
from lcpbench.core.residuals import kkt_abs


class Objective(BaseObjective):
    name = "lcpbench"
    url = None    # the repository has no public address yet
    min_benchopt_version = "1.10"
    # lcpbench itself: `pip install "lcpbench[benchopt]"` (or `pip install -e ".[benchopt]"`
    # in a checkout) installs it with benchopt.
    requirements: list = []
    # lcpbench's stop rule (the method paper's, at this tolerance) ends a solve, unless
    # benchopt's stopping criterion ends it first (through the callback).
    parameters = {"tol": [1e-8]}
    sampling_strategy = "callback"

    test_dataset_name = "lcpbench"
    test_config = {"dataset": {"problem": "fathi", "instance": 0}}

    def set_data(self, lcp, problem):
        self.lcp = lcp
        self.problem = problem

    def get_objective(self):
        return dict(lcp=self.lcp, tol=self.tol)

    def evaluate_result(self, x, mvps, emvps):
        x = np.asarray(x, dtype=np.float64)
        w = apply_uncounted(self.lcp.A, x) + self.lcp.b
        return dict(value=kkt_abs(x, w), emvps=float(emvps), mvps=int(mvps),
                    qp_objective=float(0.5 * x @ (w - self.lcp.b) + self.lcp.b @ x))

    def get_one_result(self):
        return dict(x=np.zeros(self.lcp.n), mvps=0, emvps=0.0)
