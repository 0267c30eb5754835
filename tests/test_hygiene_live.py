"""Memory and set-up hygiene of the live boundary-integral backend.

One Krylov budget per time step, the previous step's operator released before the next is
built, the non-collisional solve warm-started from the previous step's density, costs
priced by the step's own counted products (no timing products), and ``far="auto"``.
"""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from lcpbench import LCP, Operator
from lcpbench.core.api import run_solver
from lcpbench.core.registry import make_scene
from lcpbench.problems.suspension.bim import BimMobility, fmm
from lcpbench.problems.suspension.bim import operator as bim_operator
from lcpbench.problems.suspension.bim.recycle import (
    BUDGET_FLOOR,
    DEFAULT_KRYLOV_MB,
    KrylovBudget,
    RecycledGCR,
)
from lcpbench.problems.suspension.problem import ContactOptions, build_contact_problem

# three spheres, two near contact, pushed together: a small live contact problem
CENTERS = np.array([[0.0, 0.0, 0.0], [2.25, 0.0, 0.0], [1.1, 1.98, 0.0]])
LOADS = 100.0 * (CENTERS.mean(axis=0) - CENTERS)      # a pull towards the centroid
STEP = {"dt": 1.0, "delta": 0.4}                      # long enough for the contacts to act


def _matrix(n: int, seed: int = 0) -> np.ndarray:
    """A nonsymmetric second-kind matrix I + K with ||K|| < 1, like the traction operator."""
    rng = np.random.default_rng(seed)
    K = rng.standard_normal((n, n))
    return np.eye(n) + 0.95 * K / np.linalg.norm(K, 2)


# ------------------------------------------------------------------ one budget
def test_spaces_sharing_a_budget_stop_growing_together_and_still_solve():
    n = 400
    G = _matrix(n)
    directions = 100                                  # the budget, in directions of length n
    budget = KrylovBudget(16 * n * directions / 1e6)
    a = RecycledGCR(lambda v: G @ v, n, capacity=n, budget=budget)
    b = RecycledGCR(lambda v: G.T @ v, n, capacity=n, budget=budget)
    rng = np.random.default_rng(3)
    for _ in range(12):
        rhs = rng.standard_normal(n)
        for space, M in ((a, G), (b, G.T)):
            y, _, res = space.solve(rhs, 1e-10, 400)
            assert np.linalg.norm(rhs - M @ y) <= 1.01e-10 * np.linalg.norm(rhs)
    # alone, each space would keep every direction it built (hundreds); together they keep
    # the budget, plus at most the floor of the one that found it full
    assert a.size + b.size <= directions + BUDGET_FLOOR
    assert budget.used <= budget.nbytes + 16 * n * BUDGET_FLOOR
    assert min(a.size, b.size) >= BUDGET_FLOOR
    alone = RecycledGCR(lambda v: G @ v, n, capacity=n)
    for _ in range(12):
        alone.solve(rng.standard_normal(n), 1e-10, 400)
    assert alone.size > directions


@pytest.mark.parametrize("low", ["p3e4", "p3f2e4", "p2e4"])
def test_one_step_shares_one_budget_across_the_high_and_its_lows(low):
    # a twin at another tolerance, a distance-split low, a low of another order
    prob = build_contact_problem(CENTERS, 1.0, LOADS, None, **STEP, model="bim",
                                 p=3, eps_gmres=1e-8, low=[low], krylov_mb=3.0)
    budget = prob.mobility.krylov
    assert isinstance(budget, KrylovBudget) and budget.megabytes == 3.0
    res = run_solver(prob.lcp, f"bi-pqn:low={low}", tol=1e-8)
    assert res.solved and res.lofi_mvps[low] > 0
    assert budget.members == 4                        # forward and adjoint of both
    spaces = [s for s in list(budget._members) if s.size]
    assert len(spaces) == 2 and budget.used == sum(16 * s.n * s.size for s in spaces)
    assert DEFAULT_KRYLOV_MB == ContactOptions().krylov_mb


def test_a_bad_krylov_budget_is_refused_with_the_rule():
    with pytest.raises(ValueError, match="krylov_mb = -1.* >= 0"):
        ContactOptions(krylov_mb=-1)
    with pytest.raises(ValueError, match="Krylov budget .* >= 0"):
        KrylovBudget(float("nan"))


# ------------------------------------------------------------------ released
def _track_mobilities(monkeypatch) -> list:
    """Weak references to every BimMobility built, and whether the earlier ones (and their
    set-ups and blocks) were still alive when each new one started building."""
    refs: list = []
    alive_at_build: list = []
    real = bim_operator.BimMobility.__init__

    def init(self, *args, **kwargs):
        alive_at_build.append([r() is not None for trio in refs for r in trio])
        real(self, *args, **kwargs)
        refs.append((weakref.ref(self), weakref.ref(self.setup), weakref.ref(self.near)))

    monkeypatch.setattr(bim_operator.BimMobility, "__init__", init)
    return alive_at_build


@pytest.mark.parametrize("solver", ["bb-pgd", "bi-pqn:low=p2e4"])
def test_the_previous_steps_operator_is_released_before_the_next_is_built(monkeypatch, solver):
    alive_at_build = _track_mobilities(monkeypatch)
    gc.disable()                          # released by reference counting, not the collector
    try:
        scene = make_scene("paper-lattice:m=2,model=bim,p=2,eps_gmres=1e-6,low=[p2e4]")
        for _ in range(3):
            scene.step(solver, lows=["p2e4"] if "low" in solver else [])
    finally:
        gc.enable()
    assert len(alive_at_build) >= 3
    assert not any(any(alive) for alive in alive_at_build)


# ------------------------------------------------------------------ warm start
def test_the_non_collisional_solve_starts_from_a_nearby_density():
    A = BimMobility(CENTERS, 1.0, p=4, eps_gmres=1e-10)
    ft = np.concatenate([LOADS, np.zeros((3, 3))], axis=1).ravel()
    u_cold, y = A.solve_loads(ft)
    cold = A.gmres_iterations[-1]
    moved = CENTERS + 0.002 * np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    B = BimMobility(moved, 1.0, p=4, eps_gmres=1e-10)
    u_warm, _ = B.solve_loads(ft, y)
    warm = B.gmres_iterations[-1]                     # the guess's residual included
    C = BimMobility(moved, 1.0, p=4, eps_gmres=1e-10)
    u_ref = C @ ft
    assert warm < cold and warm < C.gmres_iterations[-1]
    assert np.abs(u_warm - u_ref).max() <= 1e-8 * np.abs(u_ref).max()
    assert np.abs(u_cold - u_ref).max() > 1e-6 * np.abs(u_ref).max()   # it did move
    with pytest.raises(ValueError, match="guess has 5 entries"):
        B.solve_loads(ft, np.ones(5))


def test_the_scene_carries_the_density_to_the_next_step_and_checkpoints_it():
    scene = make_scene("paper-lattice:m=2,model=bim,p=3,eps_gmres=1e-8")
    scene.step("bb-pgd")
    assert scene.nc_guess() is not None
    state = scene.get_state()
    again = make_scene("paper-lattice:m=2,model=bim,p=3,eps_gmres=1e-8")
    again.set_state(state)
    np.testing.assert_array_equal(again.nc_guess(), scene.nc_guess())
    with_guess = again.build()
    cold = make_scene("paper-lattice:m=2,model=bim,p=3,eps_gmres=1e-8")
    cold.set_state({k: v for k, v in state.items() if not k.startswith("nc_")})
    without = cold.build()
    assert with_guess.nc_applications < without.nc_applications
    # the high's cost unit stays a solve from zero: the count carried from the last one
    assert with_guess.nc_cold_applications == float(state["nc_cold"]) > 0
    assert with_guess.lcp.A.cold_applications == float(state["nc_cold"])
    assert without.lcp.A.cold_applications == without.nc_applications
    np.testing.assert_allclose(with_guess.U_nc, without.U_nc, rtol=0,
                               atol=1e-7 * np.abs(without.U_nc).max())
    # a configuration that moved too far starts cold
    again.centers = again.centers + 10.0
    assert again.nc_guess() is None


def test_the_non_collisional_guess_extrapolates_the_two_previous_densities():
    """From the third step on the guess is 2 s_1 - s_0 (two consecutive steps' densities),
    kept across a checkpoint and across a rebuild at the same step; it starts the solve
    closer than the previous density does."""
    spec = "paper-lattice:m=2,model=bim,p=3,eps_gmres=1e-8"
    scene = make_scene(spec)
    scene.step("bb-pgd")
    s0 = scene.nc_guess().copy()
    # one step kept: the guess is that density
    assert scene.get_state()["nc_before"].size == 0
    scene.step("bb-pgd")
    s1 = scene.get_state()["nc_density"]
    np.testing.assert_array_equal(scene.get_state()["nc_before"], s0)
    np.testing.assert_allclose(scene.nc_guess(), 2 * s1 - s0, rtol=0, atol=0)
    state = scene.get_state()
    again = make_scene(spec)
    again.set_state(state)
    np.testing.assert_array_equal(again.nc_guess(), scene.nc_guess())
    # building this step moves s1 back; a rebuild at the same step keeps it there and
    # starts from this step's own density
    again.build()
    np.testing.assert_array_equal(again.get_state()["nc_before"], s1)
    s2 = again.get_state()["nc_density"]
    np.testing.assert_array_equal(again.nc_guess(), s2)
    again.build()
    np.testing.assert_array_equal(again.get_state()["nc_before"], s1)
    # the previous density alone, and the extrapolated one, against the solved density
    previous = make_scene(spec)
    previous.set_state(state)
    previous.nc_extrapolate = False
    np.testing.assert_array_equal(previous.nc_guess(), s1)
    extra, prev = scene.build(), previous.build()
    assert extra.nc_applications < prev.nc_applications
    np.testing.assert_allclose(extra.U_nc, prev.U_nc, rtol=0, atol=1e-7 * np.abs(prev.U_nc).max())
    # a gap in the steps (an old checkpoint without nc_step): the previous density only
    old = make_scene(spec)
    old.set_state({k: v for k, v in state.items() if k not in ("nc_step", "nc_before")})
    np.testing.assert_array_equal(old.nc_guess(), s1)


# ------------------------------------------------------------------ cost ratio
def test_no_product_is_made_to_time_the_fidelities():
    prob = build_contact_problem(CENTERS, 1.0, LOADS, None, **STEP, model="bim",
                                 p=3, eps_gmres=1e-8, low=["p3e4", "p2e4"])
    assert len(prob.mobility.gmres_iterations) == 1           # the non-collisional solve
    assert prob.setup_solves == 1
    lcp = prob.lcp
    assert all(op.declared_cost is None for op in lcp.operators().values())
    res = run_solver(lcp, "bi-pqn:low=p2e4", tol=1e-8)
    assert res.solved and res.lofi_mvps["p2e4"] > 0
    # priced by the solve's own products: E-MVPs are high products plus the seconds spent
    # in low products in units of the mean high product
    assert res.emvps > res.mvps


def test_undeclared_costs_never_buy_a_high_product_to_set_the_unit():
    """A solve whose first products are low-fidelity ones (start=low from x0 = 0) with no
    declared costs: the budget check waits for the solver's own first high product instead
    of making a counted one (it did: one extra high MVP)."""
    rng = np.random.default_rng(0)
    Q = rng.standard_normal((30, 30))
    A = Q @ Q.T + 30 * np.eye(30)
    L = A + 0.05 * np.diag(rng.standard_normal(30))
    b = -rng.standard_normal(30)
    clocked = LCP(Operator(A), b, low={"L": Operator(L)})
    declared = LCP(Operator(A, cost=1.0), b, low={"L": Operator(L, cost=0.1)})
    spec = "bi-pqn:low=L,start=low"
    r_clocked = run_solver(clocked, spec, tol=1e-10)
    r_declared = run_solver(declared, spec, tol=1e-10)
    assert r_clocked.solved and r_declared.solved
    assert r_clocked.lofi_mvps["L"] == r_declared.lofi_mvps["L"] > 0
    assert r_clocked.mvps == r_declared.mvps


# ------------------------------------------------------------------ far = auto
def test_far_auto_takes_the_fmm_from_the_measured_crossover(monkeypatch):
    M = fmm.FAR_CROSSOVER_M
    monkeypatch.setattr(fmm, "fmm_available", lambda: True)
    assert fmm.resolve_far("auto", M) == "fmm"
    assert fmm.resolve_far("auto", M - 1) == "direct"
    assert fmm.resolve_far("direct", 10 * M) == "direct"
    monkeypatch.setattr(fmm, "fmm_available", lambda: False)
    assert fmm.resolve_far("auto", 10 * M) == "direct"
    with pytest.raises(ValueError, match="use 'direct'.* 'fmm' .* or 'auto'"):
        fmm.resolve_far("tree", 8)


def test_the_lattice_scene_builds_with_far_auto(monkeypatch):
    pytest.importorskip("fmm3dpy")
    monkeypatch.setattr(fmm, "FAR_CROSSOVER_M", 8)         # this 8-sphere scene takes the FMM
    scene = make_scene("paper-lattice:m=2,model=bim,p=3,eps_gmres=1e-9")
    assert scene.far == "auto"
    prob = scene.build()
    assert prob.mobility.setup.far == "fmm"
    scene.far = "direct"
    ref = scene.build()
    assert ref.mobility.setup.far == "direct"
    np.testing.assert_allclose(prob.U_nc, ref.U_nc, rtol=0,
                               atol=1e-8 * np.abs(ref.U_nc).max())


def test_a_hooked_operator_is_priced_at_its_cold_product(monkeypatch):
    """Seconds per inner application times the cold applications: a first product of 10
    applications in 10 s and a recycled one of 1 application in 1 s price the operator at
    10 s a product (the cold one), not at their mean of 5.5 s."""
    import types

    import lcpbench.core.operator as core_operator

    clock = iter([0.0, 10.0, 20.0, 21.0])
    monkeypatch.setattr(core_operator, "time",
                        types.SimpleNamespace(perf_counter=lambda: next(clock)))
    work = {"forward": 0}
    steps = iter([10, 1])

    def product(v):
        work["forward"] += next(steps)
        return 2.0 * v

    op = Operator(product, shape=(3, 3), work=lambda: dict(work))
    op @ np.ones(3)
    op @ np.arange(1.0, 4.0)
    assert op.count == 2 and op.applications == 11 and op.cold_applications == 10
    assert op.measured_cost == pytest.approx(10.0)
    plain = Operator(lambda v: v, shape=(3, 3))             # no hook: the mean product time
    clock = iter([0.0, 4.0, 5.0, 7.0])
    monkeypatch.setattr(core_operator, "time",
                        types.SimpleNamespace(perf_counter=lambda: next(clock)))
    plain @ np.ones(3)
    plain @ np.ones(3)
    assert plain.measured_cost == pytest.approx(3.0)
