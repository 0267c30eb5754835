"""PQN's own work per iteration: the compact BFGS memory and the Gram-form
prox give the same model, steps and iterates as the unrolled formulas, without n x r arrays.

The ``_old_*`` functions below are the formulas of the code before the change (unrolled
factors rebuilt column by column, the two-loop recursion over vectors, the prox's Newton
system built from row-masked copies of U and V), kept here as the reference.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import scipy.sparse as sp

import lcpbench
from lcpbench.core.registry import get_problem
from lcpbench.core.specs import make_params, parse_spec
from lcpbench.solvers.pqn.mono import level_model, mono_level
from lcpbench.solvers.pqn.products import DirectionProducts
from lcpbench.solvers.pqn.state import Counters
from lcpbench.toolkit.prox import compact_prox
from lcpbench.toolkit.quasinewton import DiagonalBFGS, ModelPairs, Rank2


# ------------------------------------------------------------------ the old formulas
def _old_factors(S, Y, d):
    """Unrolled BFGS factors, one column at a time (restart from d I on breakdown)."""
    n = S[0].shape[0]
    U, V = np.zeros((n, 0)), np.zeros((n, 0))
    for s, y in zip(S, Y):
        Bs = d * s + U @ (U.T @ s) - V @ (V.T @ s)
        sBs, sy = float(s @ Bs), float(s @ y)
        if sBs <= 0 or sy <= 0:
            return np.zeros((n, 0)), np.zeros((n, 0))
        U = np.column_stack([U, y / np.sqrt(sy)])
        V = np.column_stack([V, Bs / np.sqrt(sBs)])
    return U, V


def _old_apply_H(S, Y, d, g):
    q = np.array(g, dtype=float)
    rho = [1.0 / float(s @ y) for s, y in zip(S, Y)]
    alpha = [0.0] * len(S)
    for i in range(len(S) - 1, -1, -1):
        alpha[i] = rho[i] * float(S[i] @ q)
        q -= alpha[i] * Y[i]
    r = q / d
    for i in range(len(S)):
        r += (alpha[i] - rho[i] * float(Y[i] @ r)) * S[i]
    return r


def _old_prox(y, d, U, V, tol=1e-12, max_iter=100):
    """The old semi-smooth Newton on explicit factors (returns z, Newton iterations)."""
    n = y.shape[0]
    d = np.broadcast_to(np.asarray(d, dtype=float), (n,)).copy()
    r1, r2 = U.shape[1], V.shape[1]
    if r1 + r2 == 0 or np.all(y >= 0):
        return np.maximum(y, 0.0), 0
    DiU = U / d[:, None]
    K = np.eye(r1) + U.T @ DiU
    CiV = V / d[:, None] - DiU @ np.linalg.solve(K, U.T @ (V / d[:, None]))
    scale = 1.0 + np.linalg.norm(y)

    def L_of(a):
        al, at = a[:r1], a[r1:]
        t = y - DiU @ al + CiV @ at
        x = np.maximum(t, 0.0)
        return np.concatenate([U.T @ (y + CiV @ at - x) + al, V.T @ (y - x) + at]), t

    a = np.zeros(r1 + r2)
    Lv, t = L_of(a)
    res, its = np.linalg.norm(Lv), 0
    while res > tol * scale and its < max_iter:
        its += 1
        m = t > 0
        J = np.eye(r1 + r2)
        J[:r1, :r1] += U[m].T @ DiU[m]
        J[:r1, r1:] += U[~m].T @ CiV[~m]
        J[r1:, :r1] += V[m].T @ DiU[m]
        J[r1:, r1:] -= V[m].T @ CiV[m]
        step = -np.linalg.solve(J, Lv)
        lam = 1.0
        while True:
            a_new = a + lam * step
            L_new, t_new = L_of(a_new)
            r_new = np.linalg.norm(L_new)
            if r_new <= (1 - 1e-4 * lam) * res or lam < 1e-10:
                break
            lam *= 0.5
        delta = np.linalg.norm(a_new - a)
        a, Lv, t, res = a_new, L_new, t_new, r_new
        if delta <= tol * (1.0 + np.linalg.norm(a)):
            break
    return np.maximum(t, 0.0), its


def _pairs(rng, n, r, cond=1e3):
    """r secant pairs of a random SPD matrix (every pair passes the curvature test)."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = (Q * np.geomspace(1.0, cond, n)) @ Q.T
    S = [rng.standard_normal(n) for _ in range(r)]
    return A, S, [A @ s for s in S]


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


# ------------------------------------------------------------------ model and prox
@pytest.mark.parametrize("scaling", ["bb", "identity"])
@pytest.mark.parametrize("seed", range(4))
def test_compact_model_equals_the_unrolled_factors_and_two_loop(seed, scaling):
    rng = np.random.default_rng(seed)
    n, r = 40, int(rng.integers(1, 12))
    _, S, Y = _pairs(rng, n, r)
    model = DiagonalBFGS(n, scaling=scaling)
    model.set_pairs(S, Y)
    d = model.d
    U, V = _old_factors(S, Y, d)
    d2, U2, V2 = model.factors()
    assert d2 == d
    assert _rel(U2, U) < 1e-12 and _rel(V2, V) < 1e-12
    g = rng.standard_normal(n)
    assert _rel(model.apply_H(g), _old_apply_H(S, Y, d, g)) < 1e-12


def test_memory_limit_drops_the_oldest_pairs_like_a_rebuild():
    rng = np.random.default_rng(5)
    n = 30
    _, S, Y = _pairs(rng, n, 9)
    model = DiagonalBFGS(n, memory=4)
    for s, y in zip(S, Y):
        model.add_pair(s, y)
    fresh = DiagonalBFGS(n, memory=4)
    fresh.set_pairs(S[-4:], Y[-4:])
    assert model.rank == 4
    np.testing.assert_array_equal(np.array(model.S), np.array(S[-4:]))
    g = rng.standard_normal(n)
    assert _rel(model.apply_H(g), fresh.apply_H(g)) < 1e-12
    assert _rel(model.factors()[2], fresh.factors()[2]) < 1e-12


@pytest.mark.parametrize("seed", range(6))
def test_prox_sequence_with_kept_active_set_equals_the_old_prox(seed):
    """Several proxes of one growing model (the active-set Gram carried between them)."""
    rng = np.random.default_rng(10 + seed)
    n = 60
    A, S, Y = _pairs(rng, n, 10, cond=1e2)
    model = DiagonalBFGS(n)
    for k in range(10):
        model.add_pair(S[k], Y[k])
        d, W, P, N, G = model.compact()
        y = rng.standard_normal(n) * 2
        z, info = compact_prox(y, d, W, P, N, G, active=model.active)
        U, V = _old_factors(S[:k + 1], Y[:k + 1], d)
        z_old, its = _old_prox(y, d, U, V)
        assert _rel(z, z_old) < 1e-10
        # the active-set predictor (the previous prox's set) may cost passes here, where the
        # points are unrelated; on real solves it saves them (test_shipped_set_... below)
        assert info.newton_iters <= its + 3 and not info.fallback
        mask = model.active.mask                 # the carried Gram is the active set's
        np.testing.assert_allclose(model.active.gram, (W * mask) @ W.T, rtol=0, atol=1e-10
                                   * np.max(np.abs(G)))


def _grown_model(rng, n, r):
    """A model given ``r`` pairs of a random SPD matrix (condition 1e2), and the pairs."""
    _, S, Y = _pairs(rng, n, r, cond=1e2)
    model = DiagonalBFGS(n)
    for k in range(r):
        model.add_pair(S[k], Y[k])
    return model, S, Y


def test_prox_starts_from_the_previous_active_set():
    """A prox of a slightly moved point, whose active set is the previous prox's: one Newton
    pass (the predicted step lands on the root), the same point as a cold start, which needs
    more passes; a point with another active set still gets its exact prox."""
    rng = np.random.default_rng(4)
    n = 80
    model, S, Y = _grown_model(rng, n, 8)
    d, W, P, N, G = model.compact()
    y = rng.standard_normal(n) * 2
    z0, info0 = compact_prox(y, d, W, P, N, G, active=model.active)
    assert info0.newton_iters >= 2                # cold: the active set at y is wrong
    y1 = y + 1e-6 * rng.standard_normal(n)
    z1, info1 = compact_prox(y1, d, W, P, N, G, active=model.active)
    cold, cold_info = compact_prox(y1, d, W, P, N, G)
    assert info1.newton_iters == 1 and cold_info.newton_iters >= 2
    assert _rel(z1, cold) < 1e-12
    y2 = -y                                       # another active set: the predictor misses
    z2, _ = compact_prox(y2, d, W, P, N, G, active=model.active)
    U, V = _old_factors(S, Y, d)
    assert _rel(z2, _old_prox(y2, d, U, V)[0]) < 1e-10


def test_rank_two_correction_equals_corrected_pairs_rebuilt():
    """The carried inner model corrected in place = a model rebuilt from Y + (uu' - vv') S."""
    rng = np.random.default_rng(3)
    n = 50
    _, S, Y = _pairs(rng, n, 8)
    u, v = rng.standard_normal(n), 0.3 * rng.standard_normal(n)
    model = DiagonalBFGS(n)
    model.set_pairs(S, Y)
    d0, W0, *_ = model.compact()
    model.active.mask = rng.random(n) < 0.5          # a kept active set, corrected too
    model.active.gram = (W0 * model.active.mask) @ W0.T
    model.correct(u, v)
    Yc = [y + u * (u @ s) - v * (v @ s) for s, y in zip(S, Y)]
    keep = [i for i in range(8) if S[i] @ Yc[i] > 1e-12 * np.linalg.norm(S[i])
            * np.linalg.norm(Yc[i])]
    rebuilt = DiagonalBFGS(n)
    rebuilt.set_pairs([S[i] for i in keep], [Yc[i] for i in keep])
    assert model.rank == rebuilt.rank == len(keep)
    assert _rel(np.array(model.Y), np.array(rebuilt.Y)) < 1e-12
    d, W, P, N, G = model.compact()
    assert _rel(G, W @ W.T) < 1e-12
    assert _rel(model.active.gram, (W * model.active.mask) @ W.T) < 1e-12
    g = rng.standard_normal(n)
    assert _rel(model.apply_H(g), rebuilt.apply_H(g)) < 1e-12
    (d1, U1, V1), (d2, U2, V2) = model.factors(), rebuilt.factors()
    assert abs(d1 - d2) <= 1e-12 * d2 and _rel(U1 @ U1.T - V1 @ V1.T, U2 @ U2.T - V2 @ V2.T) < 1e-12
    assert len(ModelPairs(model).corrected(Rank2(u, v))) == rebuilt.rank


# ------------------------------------------------------------------ no n x r arrays
def test_an_iteration_allocates_no_n_by_r_array():
    """Five Mono-PQN iterations at rank 24 allocate a few n-vectors, not n x r arrays.

    The old code rebuilt the n x r factors U, V every iteration and copied the rows
    of U and V in the active set in every Newton step of the prox.
    """
    n = 20_000
    rng = np.random.default_rng(0)
    i, j = rng.integers(0, n, n), rng.integers(0, n, n)
    cols = np.r_[np.arange(n), np.arange(n)]
    D = sp.csr_matrix((np.r_[np.ones(n), -np.ones(n)], (np.r_[i, j], cols)), shape=(n, n))
    A = (D.T @ D + sp.identity(n)).tocsr()
    b = rng.standard_normal(n)
    peaks = {}
    calls = [0]

    def stop(z, G):
        calls[0] += 1
        if calls[0] == 20:
            tracemalloc.start()
        elif calls[0] == 25:
            peaks["bytes"] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            return True
        return False

    out = mono_level(DirectionProducts(lambda v: A @ v), np.zeros(n), b.copy(), stop, 100,
                     level_model(n, 0, "bb"), Counters())
    assert len(out.pairs) >= 24
    assert peaks["bytes"] < 12 * n * 8        # the n x r factors alone are 2 * 24 * n * 8


# ------------------------------------------------------------------ shipped sets
def _instances(spec):
    name, values = parse_spec(spec)
    info = get_problem(name)
    return info.func(make_params(name, info.params, values))


#: Recorded with the code before the change (commit 10429ac): MVPs, low MVPs, iterations,
#: prox Newton iterations, support of x and sum(x), x.x, x.k, x.cos(k) (k = 1..n). The prox
#: Newton iterations since its active-set predictor are NEWTON's (same roots, fewer passes).
OLD = [
    ("set-lattice-bim-m3:instances=0", "mono-pqn", 8, 0, 7, 15,
     [0, 1, 2, 6, 7, 8, 9, 15, 16, 17, 33, 34, 39, 42],
     [67.68322993960045, 350.96405611732894, 1098.3498797808993, -21.632993668137555]),
    ("set-lattice-bim-m3:instances=0", "bi-pqn:low=p4e6", 6, 13, 5, 22,
     [0, 1, 2, 6, 7, 8, 9, 15, 16, 17, 33, 34, 39, 42],
     [67.68322975310967, 350.96405497693166, 1098.349876123009, -21.632993531683642]),
    ("set-paper-lattice-m4:instances=3", "mono-pqn", 10, 0, 9, 18,
     [7, 9, 12, 17, 18, 23, 25, 28, 29, 30, 34, 35, 36, 43, 45, 46, 48, 50, 51, 52, 66, 67,
      69, 73, 78, 79, 81, 83, 84, 86, 88, 93, 94],
     [161.79459858793908, 863.5858503445738, 8463.47274300151, 32.75597458189393]),
    ("set-paper-lattice-m4:instances=3", "bi-pqn:low=p8f6e3", 3, 12, 2, 20,
     [7, 9, 12, 17, 18, 23, 25, 28, 29, 30, 34, 35, 36, 43, 45, 46, 48, 50, 51, 52, 66, 67,
      69, 73, 78, 79, 81, 83, 84, 86, 88, 93, 94],
     [161.79459866313792, 863.5858515791807, 8463.472739978874, 32.75597463891217]),
    ("set-lattice-bim-m4:instances=5", "multi-pqn", 7, 62, 6, 100, None,
     [520.2272978451616, 3885.1994793811546, 26801.163326637714, -43.388054537385514]),
    ("set-paper-lattice-m3:instances=7", "bi-pqn:low=rpy", 9, 4, 8, 28,
     [0, 1, 2, 3, 6, 7, 8, 9, 15, 16, 17, 18, 21, 23, 34, 37, 38, 39, 40, 43, 46, 47],
     [121.84109142715522, 742.2785283526329, 2570.7758422716925, -19.90549310405935]),
]


#: Prox Newton iterations with the active-set predictor (``_NewtonSystem._predicted``), per
#: row of OLD; before it 15, 22, 18, 20, 100 and 28.
NEWTON = [8, 13, 10, 12, 85, 13]


@pytest.mark.parametrize("spec,solver,mvps,lofi,iters,newton,support,fp",
                         [c[:5] + (k,) + c[6:] for c, k in zip(OLD, NEWTON)],
                         ids=[f"{c[0].split(':')[0]}-{c[1]}" for c in OLD])
def test_shipped_set_iterates_as_before(spec, solver, mvps, lofi, iters, newton, support, fp):
    r = lcpbench.solve(_instances(spec)[0], solver=solver, tol=1e-8)
    assert (r.mvps, sum(r.lofi_mvps.values()), r.iterations) == (mvps, lofi, iters)
    assert r.info["prox_newton_iters"] == newton
    if support is not None:
        assert np.flatnonzero(r.x > 0).tolist() == support
    k = np.arange(1, r.x.size + 1)
    got = [r.x.sum(), r.x @ r.x, r.x @ k, r.x @ np.cos(k)]
    np.testing.assert_allclose(got, fp, rtol=1e-10)
