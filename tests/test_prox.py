"""The weighted prox of Proposition prop-nnProx against independent solvers."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lcpbench.toolkit.prox import weighted_prox
from lcpbench.toolkit.qp import polish_active_set, solve_nonneg_qp


def _metric(rng, n, r1, r2):
    d = rng.uniform(0.1, 10.0, n)
    U = rng.standard_normal((n, r1))
    V = rng.standard_normal((n, r2))
    if r2:
        # keep B = D + UU' - VV' positive definite: scale V below the smallest eigenvalue of C
        C = np.diag(d) + U @ U.T
        lam = np.linalg.eigvalsh(C)[0]
        V *= np.sqrt(0.9 * lam) / np.linalg.norm(V, 2)
    return d, U, V


def _qp_prox(y, d, U, V, backend):
    B = np.diag(d) + U @ U.T - V @ V.T
    B = (B + B.T) / 2
    x, msg = solve_nonneg_qp(B, -B @ y, backend, tol=1e-10)
    assert x is not None, msg
    # interior-point answers sit ~1e-9 off the boundary: one active-set solve on the
    # backend's support makes them exact (kept only if it lowers the KKT residual)
    return polish_active_set(B, -B @ y, x)


def test_rank_zero_is_projection():
    y = np.array([-1.0, 0.0, 2.5])
    z, info = weighted_prox(y, np.ones(3), np.zeros((3, 0)), np.zeros((3, 0)))
    assert np.array_equal(z, [0.0, 0.0, 2.5])
    assert info.newton_iters == 0


@pytest.mark.parametrize("seed", range(12))
def test_matches_clarabel_up_to_rank_10(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 60))
    r = int(rng.integers(1, 11))
    d, U, V = _metric(rng, n, r, r)
    y = rng.standard_normal(n) * 3
    z, info = weighted_prox(y, d, U, V)
    ref = _qp_prox(y, d, U, V, "clarabel")
    assert np.max(np.abs(z - ref)) <= 1e-9 * max(1.0, np.max(np.abs(ref)))
    assert not info.fallback
    B = np.diag(d) + U @ U.T - V @ V.T      # and the KKT conditions hold on their own
    assert np.linalg.norm(np.minimum(z, B @ (z - y))) <= 1e-10 * max(1.0, np.linalg.norm(B @ y))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 25), r1=st.integers(0, 6),
       r2=st.integers(0, 6))
def test_property_matches_proxqp(seed, n, r1, r2):
    rng = np.random.default_rng(seed)
    d, U, V = _metric(rng, n, r1, r2)
    y = rng.standard_normal(n)
    y[rng.random(n) < 0.3] = 0.0          # ties at the boundary
    z, _ = weighted_prox(y, d, U, V)
    ref = _qp_prox(y, d, U, V, "proxqp")
    assert np.all(z >= 0)
    assert np.max(np.abs(z - ref)) <= 1e-8 * max(1.0, np.max(np.abs(ref)))


@pytest.mark.parametrize("sigma", [1.0, -1.0])
@pytest.mark.parametrize("seed", range(6))
def test_rank_one_equals_zero_sr1_prox(seed, sigma):
    from lcpbench.solvers.zerosr1 import prox_rank1_nonneg

    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(3, 80))
    d = rng.uniform(0.5, 5.0, n)
    u = rng.standard_normal(n)
    if sigma < 0:  # D - uu' positive definite
        u *= np.sqrt(0.8 / float(u @ (u / d)))
    y = rng.standard_normal(n) * 2
    U = u[:, None] if sigma > 0 else np.zeros((n, 0))
    V = u[:, None] if sigma < 0 else np.zeros((n, 0))
    z, _ = weighted_prox(y, d, U, V)
    z1 = prox_rank1_nonneg(y, d, u, sigma)
    assert np.max(np.abs(z - z1)) <= 1e-12 * max(1.0, np.max(np.abs(z1)))


def test_fallback_is_reported_and_correct():
    rng = np.random.default_rng(7)
    d, U, V = _metric(rng, 40, 5, 5)
    y = rng.standard_normal(40) * 3
    z, info = weighted_prox(y, d, U, V, max_iter=1)
    ref = _qp_prox(y, d, U, V, "clarabel")
    assert info.fallback
    assert np.max(np.abs(z - ref)) <= 1e-7 * max(1.0, np.max(np.abs(ref)))
