"""Quasi-Newton memory across time steps: the mapping by contact identity, the PQN solvers'
warm start from secant pairs, and the simulation switch."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

import lcpbench
from lcpbench import SecantMemory
from lcpbench.cli import main
from lcpbench.problems.suspension.contacts import Contacts
from lcpbench.problems.suspension.scene import LatticeScene


def _spd(n: int, cond: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.geomspace(1.0, cond, n)) @ Q.T


# ------------------------------------------------------------------ the mapping
def test_index_of_finds_each_contact_by_pair_identity_and_moves_a_vector():
    old = Contacts.from_configuration([[0, 0, 0], [2.1, 0, 0], [0, 2.2, 0], [2.1, 2.2, 0]],
                                      1.0, 0.3)
    assert old.pair_ids() == [(0, 1), (0, 2), (1, 3), (2, 3)]
    new = Contacts.from_configuration([[0, 0, 0], [2.05, 0, 0], [0, 5, 0], [2.05, 2.1, 0]],
                                      1.0, 0.3)
    assert new.pair_ids() == [(0, 1), (1, 3)]
    index = new.index_of(old.pairs)
    np.testing.assert_array_equal(index, [0, 2])
    np.testing.assert_array_equal(np.array([10.0, 20.0, 30.0, 40.0])[index], [10.0, 30.0])
    np.testing.assert_array_equal(old.index_of(new.pairs), [0, -1, 1, -1])
    np.testing.assert_allclose(new.carry(old.pairs, [1.0, 2.0, 3.0, 4.0]), [1.0, 3.0])


def test_remap_permutes_rows_zeroes_new_contacts_and_drops_what_cannot_be_mapped():
    S = np.array([[1.0, 0.0, 1.0, 1.0],     # old contact 0
                  [2.0, 0.0, 0.0, 0.0],     # old contact 1 (vanishes)
                  [3.0, 5.0, 1.0, -1.0]])   # old contact 2
    Y = np.array([[1.0, 0.0, 1.0, 1.0],
                  [2.0, 0.0, 0.0, 0.0],
                  [3.0, 9.0, 1.0, 2.0]])
    mem = SecantMemory(S, Y)
    out = mem.remap([2, -1, 0])             # new contacts: old 2, a new one, old 0
    assert out.n == 3
    # pair 1 lives on old contact 2 only: kept and moved; pair 2 on 0 and 2: kept;
    # pair 3 loses its curvature on the kept rows (s'y = 1 - 2 < 0): dropped;
    # pair 0 keeps 10/14 of ||s||^2: kept at min_kept=0.5, dropped at min_kept=0.9
    np.testing.assert_array_equal(out.S, [[3.0, 5.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 1.0]])
    np.testing.assert_array_equal(out.Y, [[3.0, 9.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 1.0]])
    strict = mem.remap([2, -1, 0], min_kept=0.9)
    np.testing.assert_array_equal(strict.S, [[5.0, 1.0], [0.0, 0.0], [0.0, 1.0]])
    only_vanished = SecantMemory(np.array([[0.0], [1.0], [0.0]]), np.array([[0.0], [2.0], [0.0]]))
    assert only_vanished.remap([2, -1, 0]).rank == 0
    with pytest.raises(ValueError, match="index entries must be -1 or rows 0..2"):
        mem.remap([3, 0])


def test_secant_memory_rejects_mismatched_or_non_finite_pairs():
    with pytest.raises(ValueError, match=r"S has shape \(3, 2\) and Y \(3, 1\)"):
        SecantMemory(np.ones((3, 2)), np.ones((3, 1)))
    with pytest.raises(ValueError, match="non-finite"):
        SecantMemory(np.ones((2, 1)), np.array([[1.0], [np.nan]]))
    one = SecantMemory(np.ones(4), 2 * np.ones(4))          # one pair as vectors
    assert (one.n, one.rank, repr(one)) == (4, 1, "SecantMemory(n=4, pairs=1)")


def test_scene_carries_its_memory_by_pair_identity():
    scene = LatticeScene(2, model="rpy", seed=1)
    for _ in range(4):
        rec = scene.step("mono-pqn", qn_memory=True)
    assert rec.qn_memory and rec.qn_pairs > 0
    old_pairs = scene._prev_pairs.copy()
    memory = scene._prev_memory
    assert memory is not None and memory.n == len(old_pairs)
    problem = scene.build()
    carried = scene.carry_memory(problem)
    assert carried is not None and carried.n == problem.contacts.n
    # the same rows by sphere pair, written out by hand: a new pair gets zero rows
    old_row = {tuple(p): k for k, p in enumerate(old_pairs.tolist())}
    S_full = np.zeros((problem.contacts.n, memory.rank))
    Y_full = np.zeros_like(S_full)
    for k, p in enumerate(problem.contacts.pairs.tolist()):
        if tuple(p) in old_row:
            S_full[k], Y_full[k] = memory.S[old_row[tuple(p)]], memory.Y[old_row[tuple(p)]]
    # the carried pairs are those columns, oldest first (some may be dropped)
    cols = [next(k for k in range(memory.rank) if np.array_equal(S_full[:, k], carried.S[:, j])
                 and np.array_equal(Y_full[:, k], carried.Y[:, j]))
            for j in range(carried.rank)]
    assert cols == sorted(cols) and len(set(cols)) == len(cols)


# ------------------------------------------------------------------ the solvers' warm start
def test_mono_pqn_from_the_exact_pairs_of_a_previous_solve_needs_fewer_mvps():
    A = _spd(30, 1e3, 2)
    b = np.random.default_rng(3).standard_normal(30)
    cold = lcpbench.solve(A, b, solver="mono-pqn", tol=1e-9)
    assert cold.solved
    memory = cold.info["secant_memory"]
    assert memory is cold.state and isinstance(memory, SecantMemory)
    assert memory.n == 30 and memory.rank == cold.info["rank"] > 0
    np.testing.assert_allclose(A @ memory.S, memory.Y, atol=1e-10)   # exact pairs of A
    warm = lcpbench.solve(A, b, solver="mono-pqn", tol=1e-9, state=memory)
    assert warm.solved and warm.info["carried_pairs"] == memory.rank
    assert warm.mvps < cold.mvps, (warm.mvps, cold.mvps)
    # a second solve's memory keeps the carried pairs (up to n) and its own
    assert warm.info["secant_memory"].rank >= memory.rank


def test_bi_pqn_keeps_carried_pairs_out_of_its_low_fidelity_model():
    A = _spd(40, 1e2, 4)
    rng = np.random.default_rng(5)
    E = 1e-3 * rng.standard_normal((40, 40))
    b = rng.standard_normal(40)
    low = {"low": A + (E + E.T) / 2}                      # a good low: B = A_low + U U' - V V'
    first = lcpbench.solve(A, b, solver="bi-pqn", tol=1e-9, low=low, low_cost=0.1)
    memory = first.state
    assert isinstance(memory, SecantMemory) and memory.rank > 0
    again = lcpbench.solve(A, b, solver="bi-pqn", tol=1e-9, low=low, low_cost=0.1,
                           state=memory)
    assert again.solved and again.info["carried_pairs"] == memory.rank
    # no low product rebuilds the carried pairs, and the bi-fidelity steps are unchanged
    assert (again.mvps, again.lofi_mvps) == (first.mvps, first.lofi_mvps)


def test_bi_pqn_with_a_useless_low_uses_carried_pairs_in_its_mono_model():
    A = _spd(40, 1e3, 7)
    b = np.random.default_rng(8).standard_normal(40)
    low = {"low": np.eye(40)}                             # judged useless: Mono-PQN takes over
    cold = lcpbench.solve(A, b, solver="bi-pqn", tol=1e-9, low=low, low_cost=0.1)
    assert cold.solved and cold.info["abandoned_low"]
    memory = cold.state
    np.testing.assert_allclose(A @ memory.S, memory.Y, atol=1e-9)
    warm = lcpbench.solve(A, b, solver="bi-pqn", tol=1e-9, low=low, low_cost=0.1, state=memory)
    assert warm.solved and warm.mvps < cold.mvps, (warm.mvps, cold.mvps)
    assert warm.lofi_mvps == cold.lofi_mvps


def test_a_wrong_memory_is_a_clear_error():
    A = _spd(5, 10.0, 6)
    b = -np.ones(5)
    res = lcpbench.solve(A, b, solver="mono-pqn", state=SecantMemory(np.ones((3, 1)),
                                                                       np.ones((3, 1))))
    assert res.status.value == "failed"
    assert res.message == ("ValueError: mono-pqn: the secant memory (state=) has 3 rows but the "
                           "LCP has n = 5 unknowns; map it to this LCP's unknowns first "
                           "(SecantMemory.remap) or pass state=None")
    res = lcpbench.solve(A, b, solver="bi-pqn", low={"c": A}, low_cost=0.1,
                         state={"pairs": []})
    assert res.status.value == "failed"
    assert "bi-pqn: state= takes the SecantMemory of a previous PQN solve" in res.message
    # solvers without a quasi-Newton memory ignore it
    assert lcpbench.solve(A, b, solver="bb-pgd", stop="kkt", state=SecantMemory(
        np.ones((3, 1)), np.ones((3, 1)))).solved


# ------------------------------------------------------------------ the simulation switch
SCENE = "lattice:m=2,model=rpy"


def _argv(out, steps, memory):
    return ["simulate", "--scene", SCENE, "--solver", "mono-pqn", "--steps", str(steps),
            "--out", str(out), "--stop", "kkt", "--quiet",
            "--qn-memory" if memory else "--no-qn-memory"]


def _info(out) -> pd.DataFrame:
    rows = pd.read_csv(out / "results.csv").sort_values("step")
    info = rows["info"].map(json.loads)
    return rows.assign(qn_memory=info.map(lambda i: i["qn_memory"]),
                       qn_pairs=info.map(lambda i: i["qn_pairs"]))


def test_simulate_switch_carries_memory_and_resume_refuses_a_change(tmp_path, capsys):
    on, off = tmp_path / "on", tmp_path / "off"
    assert main(_argv(on, 12, True)) == 0
    assert main(_argv(off, 12, False)) == 0
    with_mem, without = _info(on), _info(off)
    assert with_mem["qn_memory"].all() and not without["qn_memory"].any()
    assert (without["qn_pairs"] == 0).all()
    assert with_mem["qn_pairs"].iloc[0] == 0                 # nothing to carry at step 0
    assert (with_mem["qn_pairs"].iloc[-6:] > 0).all()         # once the spheres touch
    assert with_mem["mvps"].iloc[1:].sum() < without["mvps"].iloc[1:].sum()
    # the changed switch is refused before any step
    size = (on / "results.csv").stat().st_size
    assert main(_argv(on, 14, False)) == 2
    assert "under other settings (qn_memory)" in capsys.readouterr().err
    assert (on / "results.csv").stat().st_size == size


def test_a_resumed_simulation_continues_with_the_stored_memory(tmp_path):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    assert main(_argv(straight, 10, True)) == 0
    assert main(_argv(resumed, 5, True)) == 0
    assert main(_argv(resumed, 10, True)) == 0                # extends from the checkpoint
    a, b = _info(straight), _info(resumed)
    assert list(b["step"]) == list(range(10))
    pd.testing.assert_frame_equal(a[["step", "n", "mvps", "qn_pairs"]].reset_index(drop=True),
                                  b[["step", "n", "mvps", "qn_pairs"]].reset_index(drop=True))
