"""Problem families of lcpbench.problems.hard and lcpbench.problems.random."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
import pytest

import lcpbench
from lcpbench.core.registry import get_problem
from lcpbench.core.residuals import kkt_abs
from lcpbench.core.specs import Bounds, CheckedParams, make_params

#: Every family with small parameters (fast), and whether it is seeded.
SMALL = {
    "planted": ({"count": 2, "n_active": 6, "n_inactive": 5, "n_degenerate": 2}, True),
    "spd-cond": ({"count": 4, "n": 12}, True),
    "singular-psd": ({"count": 2, "n_independent": 8, "n_duplicate": 3, "n_combination": 3,
                      "dof": 12}, True),
    "fathi": ({"sizes": "[1,4,10]"}, False),
    "tiny": ({}, False),
    "all-inactive": ({"count": 2, "n": 10}, True),
    "bad-scale": ({"count": 2, "n": 12}, True),
    "bb-cycle": ({}, False),
    "random-spd": ({"count": 2, "n_min": 20, "n_max": 30}, True),
    "bifidelity": ({"count": 2, "n": 15}, True),
}


def generate(name: str, **extra) -> list:
    params, _ = SMALL[name]
    info = get_problem(name)
    return info.func(make_params(name, info.params, {**params, **extra}))


def planted_lcps() -> list:
    return [lcp for name in SMALL for lcp in generate(name) if lcp.reference is not None]


@pytest.mark.parametrize("name", list(SMALL))
def test_family_valid_and_deterministic(name):
    a, b = generate(name), generate(name)
    assert len(a) >= 1 and len(a) == len(b)
    assert len({lcp.name for lcp in a}) == len(a), "instance names must be unique"
    for x, y in zip(a, b):
        assert isinstance(x, lcpbench.LCP)
        assert x.name == y.name and x.n == y.n
        assert x.meta["family"] == name and x.meta["n"] == x.n and "seed" in x.meta
        np.testing.assert_array_equal(x.dense(), y.dense())
        np.testing.assert_array_equal(x.b, y.b)
        A = x.dense()
        np.testing.assert_array_equal(A, A.T)
        if x.n:
            assert np.linalg.eigvalsh(A)[0] >= -1e-10 * max(1.0, np.abs(A).max())


@pytest.mark.parametrize("name", [k for k, (_, seeded) in SMALL.items() if seeded])
def test_seed_changes_instances(name):
    a, b = generate(name, seed=0), generate(name, seed=1)
    assert any(not np.array_equal(x.b, y.b) for x, y in zip(a, b))
    assert all(x.meta["seed"] == 0 for x in a) and all(y.meta["seed"] == 1 for y in b)


@pytest.mark.parametrize("lcp", planted_lcps(), ids=lambda lcp: lcp.name)
def test_planted_reference_solves_the_lcp(lcp):
    ref = lcp.reference
    x, w = np.asarray(ref["x"]), np.asarray(ref["w"])
    scale = max(1.0, float(np.linalg.norm(lcp.b)))
    assert np.all(x >= 0) and np.all(w >= 0)
    assert float(x @ w) == 0.0                       # complementary by construction
    w_true = lcp.dense() @ x + lcp.b
    assert np.linalg.norm(w_true - w) <= 1e-12 * scale
    assert kkt_abs(x, w_true) <= 1e-12 * scale
    # the QP objective from the matrix itself, not from the planted w
    A = lcp.dense()
    assert ref["objective"] == pytest.approx(0.5 * x @ A @ x + lcp.b @ x, rel=1e-10, abs=1e-12)


@pytest.mark.parametrize("lcp", [lcp for lcp in planted_lcps() if lcp.n],
                         ids=lambda lcp: lcp.name)
def test_consensus_reference_agrees_with_planted_w(lcp):
    ref = lcpbench.reference(lcp)
    w = np.asarray(lcp.reference["w"])
    assert ref.accepted
    assert np.linalg.norm(ref.w - w) <= 1e-8 * max(1.0, np.linalg.norm(w))
    assert ref.objective == pytest.approx(lcp.reference["objective"], rel=1e-8, abs=1e-10)


def test_planted_index_sets():
    lcp = generate("planted")[0]
    x, w = lcp.reference["x"], lcp.reference["w"]
    assert np.sum(x > 0) == 6 and np.sum(w > 0) == 5 and np.sum((x == 0) & (w == 0)) == 2
    assert np.linalg.cond(lcp.dense()) == pytest.approx(lcp.meta["cond"], rel=1e-6)


def test_fathi_solution_is_e1():
    for lcp in generate("fathi"):
        e1 = np.zeros(lcp.n)
        e1[0] = 1.0
        np.testing.assert_array_equal(lcp.reference["x"], e1)
        np.testing.assert_array_equal(lcp.b, -np.ones(lcp.n))
        w = lcp.dense() @ e1 + lcp.b
        assert w[0] == 0 and np.all(w[1:] == 1)
        ref = lcpbench.reference(lcp)
        np.testing.assert_allclose(ref.x, e1, atol=1e-8)


def test_fathi_size_limit():
    with pytest.raises(ValueError, match="1..40"):
        make_params("fathi", get_problem("fathi").params, {"sizes": "[41]"})


def test_spd_cond_spans_condition_numbers():
    lcps = generate("spd-cond")
    conds = [lcp.meta["cond"] for lcp in lcps]
    assert conds[0] == pytest.approx(1e1) and conds[-1] == pytest.approx(1e10)
    assert np.all(np.diff(np.log10(conds)) == pytest.approx(3.0))
    for lcp in lcps[:3]:
        assert np.linalg.cond(lcp.dense()) == pytest.approx(lcp.meta["cond"], rel=1e-4)


def test_singular_psd_rank_and_redundancy():
    for lcp in generate("singular-psd"):
        A = lcp.dense()
        assert lcp.n == 14
        assert np.linalg.matrix_rank(A) == lcp.meta["rank"] == 8
        assert not np.isfinite(lcp.meta["cond"])


def test_tiny_cases():
    lcps = {lcp.meta["case"]: lcp for lcp in generate("tiny")}
    assert lcps["n0"].n == 0 and {lcp.n for lcp in lcps.values()} == {0, 1, 2}
    deg = lcps["n2-degenerate"]
    np.testing.assert_array_equal(deg.reference["x"], [1.0, 0.0])
    np.testing.assert_array_equal(deg.reference["w"], [0.0, 0.0])
    res = lcpbench.solve(lcps["n0"], solver="osqp")
    assert res.solved and res.mvps == 0


def test_all_inactive_solution_is_zero():
    for lcp in generate("all-inactive"):
        assert np.all(lcp.b >= 0) and np.any(lcp.b == 0)
        np.testing.assert_array_equal(lcp.reference["x"], 0.0)
        np.testing.assert_array_equal(lcp.reference["w"], lcp.b)


def test_bad_scale_magnitudes():
    for lcp in generate("bad-scale"):
        mag = np.abs(lcp.b)
        assert mag.min() == pytest.approx(1e-12) and mag.max() == pytest.approx(1e6)
        assert np.any(lcp.b < 0) and np.any(lcp.b > 0)


def test_bb_cycle_meta():
    lcps = generate("bb-cycle")
    assert 3 <= len(lcps) <= 8
    for lcp in lcps:
        assert 3 <= lcp.n <= 8
        assert lcp.meta["expect"] == {"unsafeguarded_may_fail": True}
        assert lcp.meta["kind"] in ("cycle", "divergence")
        assert np.linalg.cond(lcp.dense()) == pytest.approx(lcp.meta["cond"], rel=1e-3)


def test_random_spd_is_a_stand_in_with_mixed_solution():
    assert not get_problem("random-spd").default     # the shipped BIM set is the default now
    assert get_problem("set-lattice-bim-m3").default
    assert get_problem("set-paper-lattice-m3").default       # where the paper's result holds
    info = get_problem("random-spd")
    default = info.params()
    assert (default.n_min, default.n_max, default.cond_min, default.cond_max) == \
        (150, 300, 10.0, 100.0)
    for lcp in generate("random-spd"):
        assert 20 <= lcp.n <= 30 and 10 <= lcp.meta["cond"] <= 100
        assert np.linalg.cond(lcp.dense()) == pytest.approx(lcp.meta["cond"], rel=1e-6)
        ref = lcpbench.reference(lcp)
        active = np.sum(ref.x > 0)
        assert 0 < active < lcp.n, "b should give a mix of active and inactive contacts"


@pytest.mark.parametrize("indefinite", [False, True])
def test_bifidelity_low_operator(indefinite):
    lcps = generate("bifidelity", indefinite=indefinite, rel_error=1e-3, cost_ratio=0.25)
    for lcp in lcps:
        assert list(lcp.low) == ["low"]
        low = lcp.low["low"]
        assert low.declared_cost == 0.25 and lcp.A.declared_cost == 1.0
        A = lcp.dense()
        from lcpbench.core.operator import dense_uncounted
        A_low = dense_uncounted(low)
        assert np.linalg.eigvalsh(A)[0] > 0
        lam_low = np.linalg.eigvalsh(A_low)[0]
        rel = np.linalg.norm(A_low - A, 2) / np.linalg.norm(A, 2)
        if indefinite:
            assert lam_low < 0 and lcp.meta["lam_min_low"] < 0
            assert rel <= 1.0 / lcp.meta["cond"] + 3e-3
        else:
            assert lam_low > 0
            assert rel == pytest.approx(1e-3, rel=1e-6)


@pytest.mark.parametrize("family, values, message", [
    ("planted", {"count": 0}, "planted: count must be an integer >= 1, got 0"),
    ("planted", {"seed": -1}, "seed must be an integer >= 0, got -1"),
    ("planted", {"cond": "inf"}, "cond must be a finite number >= 1, got inf"),
    ("spd-cond", {"cond_min": 1e3, "cond_max": 10},
     r"cond_max \(10\) must be >= cond_min \(1000\)"),
    ("singular-psd", {"n_independent": 10, "dof": 5}, r"dof \(5\) must be >= n_independent"),
    ("fathi", {"sizes": "[4,41]"}, "each of sizes must be an integer in 1..40, got 41"),
    ("all-inactive", {"zero_fraction": 1.5}, "zero_fraction must be a finite number in 0..1"),
    ("bad-scale", {"n": 1}, "n must be an integer >= 2, got 1"),
    ("bifidelity", {"cost_ratio": 0}, "cost_ratio must be a finite number > 0, got 0.0"),
    ("random-spd", {"n_min": 40, "n_max": 30}, "need n_min <= n_max"),
    ("siconos", {"path": "x.dat", "symmetrize_rtol": -1}, "symmetrize_rtol must be a number >= 0"),
])
def test_bad_params_rejected(family, values, message):
    with pytest.raises(ValueError, match=message):
        make_params(family, get_problem(family).params, values)


def test_declared_bounds_hold_for_direct_construction():
    params = get_problem("planted").params
    with pytest.raises(ValueError, match="count must be an integer >= 1, got 2.5"):
        params(count=2.5)
    with pytest.raises(ValueError, match="n_active must be an integer >= 0, got True"):
        params(n_active=True)
    assert params(count=np.int64(2), cond=1).count == 2
    assert get_problem("siconos").params(path="x", symmetrize_rtol=np.inf).symmetrize_rtol \
        == np.inf


def test_checked_params_hold_literal_choices_and_strict_bounds():
    @dataclass(frozen=True)
    class Params(CheckedParams):
        mode: Literal["a", "b"] = "a"
        k: Annotated[int, Bounds(ge=0, lt=5)] = 1

    assert make_params("x", Params, {"mode": "b", "k": "4"}) == Params("b", 4)
    with pytest.raises(ValueError, match="mode must be one of 'a', 'b', got 'c'"):
        Params(mode="c")
    with pytest.raises(ValueError, match="k must be an integer >= 0 and < 5, got 5"):
        Params(k=5)


def _low_errors(lcp, names) -> dict:
    """Relative 2-norm error of each named low against the instance's high matrix."""
    A = lcp.dense()
    nA = np.linalg.norm(A, 2)
    return {k: np.linalg.norm(np.column_stack([lcp.low[k] @ e for e in np.eye(lcp.n)]) - A, 2)
            / nA for k in names}


@pytest.mark.parametrize("name, lows, spheres", [
    ("paper-lattice-m3", ("p8f6e3", "p8f6r3e3"), 27),
    ("paper-lattice-m4", ("p8f6e3",), 64),
    ("paper-lattice-m5", ("p8f6e3",), 125)])
def test_paper_lattice_sets_hold_the_split_lows_within_their_accuracy(name, lows, spheres):
    """The shipped 0.3a sets: 20 packed instances at BIM p = 8 whose distance-split lows are
    within 3e-3 of the high matrix (relative 2-norm) on every instance, and closer than
    p = 4 at eps 1e-6."""
    info = get_problem(f"set-{name}")
    # the default run holds the 27-sphere set beside the 0.1a one, not the larger ones
    assert info.default == (name == "paper-lattice-m3")
    lcps = list(info.func(make_params(info.name, info.params, {})))
    assert len(lcps) == 20
    for lcp in lcps:
        assert (lcp.meta["M"], lcp.meta["p"], lcp.meta["eps_gmres"]) == (spheres, 8, 1e-8)
        err = _low_errors(lcp, lows + ("p4e6",))
        for k in lows:
            assert err[k] < 3e-3 < err["p4e6"]
            assert 0 < lcp.low[k].cost < 1
