"""The multi-fidelity capability is declared: the framework asks the registry which
parameters name low-fidelity operators, whatever those parameters are called."""

from dataclasses import dataclass

import numpy as np
import pytest

import lcpbench
from lcpbench import LowOperators, register_solver
from lcpbench.core.api import requested_lows
from lcpbench.run.sweep import expand, per_low


@dataclass(frozen=True)
class _LadderParams:
    coarse: str = ""
    ladder: tuple[str, ...] = ()
    low: str = ""            # an ordinary parameter here: it names no operator


@register_solver("test-ladder", _LadderParams, listed=False,
                 multifidelity=LowOperators(one="coarse", chain="ladder"))
def _ladder(ctx, p):
    """A test double: records the low operators its parameters name; x = 0 solves (b >= 0)."""
    names = requested_lows({"coarse": p.coarse, "ladder": list(p.ladder)}, "test-ladder")
    ctx.info["used"] = names or sorted(ctx.low)
    x = np.zeros(ctx.n)
    w = ctx.A @ x + ctx.b
    return ctx.finish(x, w)


def test_the_sweep_runs_a_spec_once_per_low_through_the_declared_parameter():
    spec = expand("test-ladder", "solver")[0]
    out = per_low(spec, ["fine", "rough"])
    assert [s.label for s in out] == ["test-ladder:coarse=fine", "test-ladder:coarse=rough"]
    assert [s.params["coarse"] for s in out] == ["fine", "rough"]
    named = expand("test-ladder:coarse=fine", "solver")[0]
    assert per_low(named, ["fine", "rough"]) == [named]
    chain = expand("test-ladder:ladder=[fine,rough]", "solver")[0]
    assert per_low(chain, ["fine", "rough"]) == [chain]


def test_requested_lows_reads_the_declared_parameters_only():
    params = {"coarse": "fine", "ladder": ["rough", "rougher"], "low": "not-an-operator"}
    assert requested_lows(params, "test-ladder") == ["fine", "rough", "rougher"]
    assert requested_lows({"low": "p4"}, "mono-pqn") == []
    assert requested_lows({"low": "p4"}, "bi-pqn") == ["p4"]
    assert requested_lows({"lows": ["p6", "p3"]}, "multi-pqn") == ["p6", "p3"]


def test_the_solver_runs_with_its_named_low():
    lcp = lcpbench.LCP(np.eye(2), np.array([1.0, 2.0]), low={"fine": np.eye(2)})
    res = lcpbench.solve(lcp, solver="test-ladder:coarse=fine")
    assert res.solved and res.info["used"] == ["fine"]


def test_a_declared_parameter_the_solver_lacks_is_refused_at_registration():
    with pytest.raises(TypeError, match="nowhere"):
        register_solver("test-bad-ladder", _LadderParams,
                        multifidelity=LowOperators(one="nowhere"))(lambda ctx, p: None)
