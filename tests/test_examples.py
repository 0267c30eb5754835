"""The documented examples run: the solve() doctest and the README's time-stepper snippet."""

import doctest
import re
from pathlib import Path

import numpy as np

import lcpbench.core.api
from lcpbench.problems.hard import random_spd_matrix
from lcpbench.problems.random import symmetric_perturbation

README = Path(__file__).resolve().parents[1] / "README.md"


def test_api_doctests():
    failed, attempted = doctest.testmod(lcpbench.core.api, optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0


def test_readme_time_stepper_snippet_runs_for_several_steps():
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    rng = np.random.default_rng(0)
    A = random_spd_matrix(rng, 80, 30.0)
    A_low = A + symmetric_perturbation(rng, A, 1e-2)
    env = {"A": A, "A_low": (A_low + A_low.T) / 2, "x_prev": None, "state": None}
    for _ in range(3):
        env["b"] = rng.standard_normal(80)
        exec(code, env)                                   # asserts res.solved itself
        env["x_prev"] = env["x"]
        assert env["res"].status.value == "converged"
        assert env["res"].lofi_mvps["coarse"] > 0
        assert env["res"].framework_mvps >= 1     # the verification's product, at least
    assert env["state"] is not None
