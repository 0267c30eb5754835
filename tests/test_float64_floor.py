"""A tolerance below the rounding floor eps (||A x|| + ||b||): the claim is reported as
reaching the float64 floor, never as converged to the tolerance."""

from __future__ import annotations

import numpy as np
import pytest

import lcpbench
from lcpbench.core.residuals import rounding_floor


@pytest.mark.parametrize("solver", ["bb-pgd", "pgs", "mono-pqn"])
def test_entries_of_b_spanning_1e30_reach_the_floor_not_the_tolerance(solver):
    A = np.array([[2.0, 1.0], [1.0, 2.0]])
    b = np.array([-1e30, -1.0])
    res = lcpbench.solve(A, b, solver=solver, tol=1e-8)
    floor = res.verified["float64_floor"]
    assert floor == pytest.approx(rounding_floor(A @ res.x, b)) and floor > 1e13
    assert not res.solved and res.status.value in ("converged", "stagnated")
    if res.status.value == "converged":        # mono-pqn stops on its relative measure
        assert res.message.startswith("reached the float64 floor, not the tolerance")


@pytest.mark.parametrize("solver", ["bb-pgd", "pgs", "mono-pqn"])
def test_a_well_scaled_problem_converges_to_its_tolerance(solver):
    A = np.array([[2.0, 1.0], [1.0, 2.0]])
    b = np.array([-1.0, -1.0])
    res = lcpbench.solve(A, b, solver=solver, tol=1e-8)
    assert res.status.value == "converged" and res.solved
    assert "float64_floor" not in res.verified and "floor" not in res.message


def test_the_run_store_records_the_floor(tmp_path):
    import pandas as pd

    from lcpbench.run.runner import result_fields

    A = np.diag([1.0, 1.0])
    at_floor = lcpbench.solve(A, np.array([-1e30, -1.0]), solver="bb-pgd")
    plain = lcpbench.solve(A, np.array([-1.0, -1.0]), solver="bb-pgd")
    assert result_fields(at_floor)["float64_floor"] is True
    assert result_fields(plain)["float64_floor"] is False
    assert "float64_floor" in pd.Index(lcpbench.run.store.RESULT_COLUMNS)
