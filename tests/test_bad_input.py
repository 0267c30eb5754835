"""Bad input gets a clear error that says what was wrong and what to do."""

import builtins
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

import lcpbench
from lcpbench import LCP, Operator

A2 = np.array([[2.0, 1.0], [1.0, 2.0]])
B2 = np.array([-1.0, 1.0])


@pytest.mark.parametrize("A, b, exc, words", [
    (np.array([[np.nan, 0.0], [0.0, 1.0]]), B2, ValueError, ["A", "finite"]),
    (np.array([[np.inf, 0.0], [0.0, 1.0]]), B2, ValueError, ["A", "finite"]),
    (A2, np.array([np.nan, 1.0]), ValueError, ["b", "entry 0", "finite"]),
    (A2, np.array([1.0, np.inf]), ValueError, ["b", "entry 1"]),
    (A2, np.ones(3), ValueError, ["b", "length 3", "n = 2"]),
    (np.ones((2, 3)), np.ones(2), ValueError, ["square"]),
    (np.ones(4), np.ones(2), ValueError, ["2-D"]),
    (np.array([[2.0, 1.0], [0.0, 2.0]]), B2, ValueError, ["symmetric"]),
    (-A2, B2, ValueError, ["semidefinite"]),
    (A2.astype(complex), B2, TypeError, ["real"]),
    (np.array([["a", "b"], ["c", "d"]]), B2, TypeError, ["not real"]),
    (A2, np.array(["x", "y"]), TypeError, ["b", "numeric"]),
    (A2, np.ones((2, 2)), ValueError, ["b", "vector"]),
    (np.array([[1.0, 0], [0, 1]], dtype=object), B2, TypeError, ["object"]),
    (sp.csr_matrix(np.array([[2.0, 1.0], [0.0, 2.0]])), B2, ValueError, ["symmetric"]),
])
def test_lcp_rejects_bad_data_with_a_helpful_message(A, b, exc, words):
    with pytest.raises(exc) as err:
        LCP(A, b)
    msg = str(err.value)
    for word in words:
        assert word in msg, (word, msg)


def test_bad_warm_start_and_low_operator():
    with pytest.raises(ValueError, match="x0.*negative.*np.maximum"):
        LCP(A2, B2, x0=[-1.0, 0.0])
    with pytest.raises(ValueError, match="x0.*length"):
        LCP(A2, B2, x0=[1.0])
    with pytest.raises(ValueError, match=r"low\['p4'\].*shape"):
        LCP(A2, B2, low={"p4": np.eye(3)})
    with pytest.raises(ValueError, match="x0"):
        lcpbench.solve(A2, B2, x0=[np.nan, 0.0])


def test_indefinite_low_operator_is_allowed():
    lcp = LCP(A2, B2, low={"bad": -A2})             # a legitimate, if poor, model
    assert lcp.low["bad"].shape == (2, 2)


def test_operator_construction_errors():
    with pytest.raises(ValueError, match="shape"):
        Operator(lambda v: v)
    with pytest.raises(TypeError, match="cannot make an operator"):
        Operator("matrix")
    with pytest.raises(ValueError, match="cost"):
        Operator(A2, cost=-1.0)
    with pytest.raises(ValueError, match="cost"):
        Operator(A2, cost=float("nan"))


@pytest.mark.parametrize("kwargs, exc, words", [
    (dict(solver="no-such-solver"), KeyError, ["no-such-solver", "bb-pgd", "lcpbench list"]),
    (dict(solver="bb-pgd:nonsense=1"), TypeError, ["nonsense", "Valid", "variant"]),
    (dict(solver="bb-pgd:variant=bb7"), ValueError, ["bb7"]),
    (dict(solver="mono-pqn:memory=many"), TypeError, ["memory", "integer", "many"]),
    (dict(solver="mono-pqn:memory=1.5"), TypeError, ["memory", "integer"]),
    (dict(solver="bb-pgd", nonsense=3), TypeError, ["nonsense"]),
    (dict(solver="bb-pgd:variant"), ValueError, ["variant"]),
    (dict(solver=""), ValueError, ["NAME"]),
    (dict(tol=-1.0), ValueError, ["tol"]),
    (dict(tol=float("nan")), ValueError, ["tol"]),
    (dict(stop="fast"), ValueError, ["stop", "paper", "kkt"]),
    (dict(max_emvps=0), ValueError, ["max_emvps"]),
    (dict(max_iter=0), ValueError, ["max_iter"]),
])
def test_solve_rejects_bad_arguments(kwargs, exc, words):
    with pytest.raises(exc) as err:
        lcpbench.solve(A2, B2, **kwargs)
    for word in words:
        assert word in str(err.value), (word, str(err.value))


def test_missing_low_operator_is_a_failed_row_not_a_crash():
    res = lcpbench.solve(A2, B2, solver="bi-pqn:low=p4")
    assert res.status == lcpbench.Status.failed
    assert "low-fidelity" in res.message and "LCP(A, b, low=" in res.message


def test_b_required_and_not_duplicated():
    with pytest.raises(ValueError, match="b is required"):
        lcpbench.solve(A2)
    with pytest.raises(ValueError, match="inside the LCP"):
        lcpbench.solve(LCP(A2, B2), B2)


def test_unknown_problem_and_bad_problem_parameter():
    with pytest.raises(KeyError, match="no-such-problem"):
        lcpbench.get_problem("no-such-problem")
    from lcpbench.core.specs import make_params
    info = lcpbench.get_problem("random-spd")
    with pytest.raises((TypeError, ValueError), match="count"):
        make_params("problem random-spd", info.params, {"count": "many"})
    with pytest.raises(ValueError, match="n_min"):
        info.params(n_min=10, n_max=5)


# ------------------------------------------------------------------ docs/errors.md, API table
DOC = Path(__file__).resolve().parents[1] / "docs" / "errors.md"


def _api_rows() -> list[tuple[str, str, str]]:
    """``(call, outcome, message)`` of the API rows of docs/errors.md."""
    rows = []
    for line in DOC.read_text().splitlines():
        if not re.match(r"\| `(lcpbench\.|LCP\(|Operator\()", line):
            continue
        cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        rows.append((cells[0].strip("`"), cells[1].strip("`"), cells[2]))
    return rows


@pytest.mark.parametrize("call, outcome, message", _api_rows())
def test_documented_api_error(call, outcome, message):
    env = {"lcpbench": lcpbench, "LCP": LCP, "Operator": Operator, "np": np, "sp": sp,
           "A": A2, "b": B2}
    documented = message[:-3] if message.endswith("...") else message
    if outcome.startswith("status="):
        res = eval(call, env)                     # noqa: S307 - the documented call
        assert res.status.value == outcome.split("=", 1)[1]
        assert res.message.startswith(documented), res.message
        return
    exc = getattr(builtins, outcome)
    with pytest.raises(exc) as err:
        eval(call, env)                           # noqa: S307 - the documented call
    text = err.value.args[0] if isinstance(err.value, KeyError) else str(err.value)
    assert text.startswith(documented) if message.endswith("...") else text == documented, text


@pytest.mark.parametrize("solver", ["mono-pqn", "bi-pqn", "a-pgd", "minmap-newton", "bb-pgd"])
def test_operator_nan_is_failed_not_infeasible(solver):
    rng = np.random.default_rng(1)
    M = rng.standard_normal((30, 30))
    A = M @ M.T / 30 + np.eye(30)
    calls = [0]

    def broken(v):
        calls[0] += 1
        return A @ v if calls[0] < 4 else np.full(30, np.nan)

    low = {"l": 1.01 * A} if solver == "bi-pqn" else None
    res = lcpbench.solve(broken, rng.standard_normal(30), solver=solver, low=low,
                         low_cost=0.5 if low else None)
    assert res.status == lcpbench.Status.failed
    assert res.message == "operator returned non-finite values at product 4"
