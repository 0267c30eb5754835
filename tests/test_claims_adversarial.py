"""A small slice of benchmarks/adversarial.py: no refuted ``converged``, no false ``infeasible``.

The full runs (2,000 of each group, docs/benchmarks.md) take tens of minutes; this slice
takes seconds and covers each generator kind once with two solvers each.
"""

import numpy as np
import pytest


@pytest.mark.usefixtures("one_blas_thread")
@pytest.mark.parametrize("group, solvers", [("accuracy", ("mono-pqn", "bb-pgd")),
                                            ("scaling", ("a-pgd", "mono-pqn"))])
def test_a_slice_of_the_adversarial_cases(group, solvers, benchmark_script):
    adv = benchmark_script("adversarial")
    outcomes = []
    with np.errstate(all="ignore"):
        for i in range(4):                           # one case of each kind
            outcomes += adv.run_case((i, 0, group, solvers, 200.0, 5.0))
    assert len(outcomes) == 8
    bad = [row for row in outcomes if row[2] in ("refuted", "false-infeasible", "crash")]
    assert not bad, bad


def test_the_classifier_counts_a_refuted_claim(benchmark_script):
    # the script's own residual, not the result's: a 'converged' whose x is wrong is refuted
    import lcpbench
    from lcpbench.core.result import Status

    adv = benchmark_script("adversarial")
    lcp = lcpbench.LCP(np.eye(2), np.array([-1.0, 1.0]))
    res = lcpbench.solve(lcp, solver="mono-pqn")
    assert res.status == Status.converged and adv.classify(res, lcp, True) == "converged"
    res.x = np.array([2.0, 0.0])
    assert adv.classify(res, lcp, True) == "refuted"
    res.status = Status.infeasible
    assert adv.classify(res, lcp, True) == "false-infeasible"
