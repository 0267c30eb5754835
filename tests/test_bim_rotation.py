"""Rotations of the real VSH basis (problems/suspension/bim/rotation.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lcpbench.problems.suspension.bim.coaxial import basis_at
from lcpbench.problems.suspension.bim.rotation import (
    degree_slices,
    euler_angles,
    frame_of,
    rotate_blocks,
    vsh_rotation,
    wigner_directions,
)
from lcpbench.problems.suspension.bim.sphere_vsh import sphere_grid, vsh_basis


def _analysis(values: np.ndarray, p: int) -> np.ndarray:
    """Coefficients of a degree <= p field sampled on the grid of order p + 1 (exact
    quadrature of the orthonormal basis there)."""
    g = sphere_grid(p + 1)
    B = basis_at(g.nodes, p)                                       # (K, 3, nv)
    return np.einsum("kic,ki,k->c", B, values, g.weights)


def test_basis_at_matches_the_sampled_basis():
    p = 5
    g = sphere_grid(p)
    assert np.abs(basis_at(g.nodes, p).reshape(-1, vsh_basis(p).B.shape[1])
                  - vsh_basis(p).B).max() < 1e-14


@pytest.mark.parametrize("p", [2, 4, 7])
def test_rotation_matrix_rotates_sampled_fields(p):
    rng = np.random.default_rng(p)
    g = sphere_grid(p + 1)
    nv = vsh_basis(p).B.shape[1]
    for Q in Rotation.random(3, random_state=p).as_matrix():
        c = rng.standard_normal(nv)
        # (Q.f)(x) = Q f(Q^T x): the field sampled at the turned nodes, its vectors turned
        turned = np.einsum("kic,c->ki", basis_at(g.nodes @ Q, p), c) @ Q.T
        assert np.abs(_analysis(turned, p) - vsh_rotation(Q, p) @ c).max() < 1e-12


def test_rotation_is_an_orthogonal_representation():
    p = 6
    Q1, Q2 = Rotation.random(2, random_state=3).as_matrix()
    D1, D2 = vsh_rotation(Q1, p), vsh_rotation(Q2, p)
    assert np.abs(D1 @ D1.T - np.eye(D1.shape[0])).max() < 1e-13
    assert np.abs(vsh_rotation(Q1 @ Q2, p) - D1 @ D2).max() < 1e-13
    assert np.abs(vsh_rotation(Q1.T, p) - D1.T).max() < 1e-13


@pytest.mark.parametrize("Q", [np.eye(3), np.diag([-1.0, 1.0, -1.0]), np.diag([1.0, -1.0, -1.0]),
                               Rotation.from_euler("z", 0.7).as_matrix()])
def test_euler_angles_at_the_poles(Q):
    a, b, c = euler_angles(Q[None])
    back = Rotation.from_euler("ZYZ", [a[0], b[0], c[0]]).as_matrix()
    assert np.abs(back - Q).max() < 1e-14


def test_directions_and_batched_rotation_of_blocks():
    p = 4
    rng = np.random.default_rng(0)
    u = rng.standard_normal((5, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    u[0] = [0.0, 0.0, -1.0]                                        # the south pole
    Q = frame_of(u)
    assert np.abs(Q[:, :, 2] - u).max() < 1e-15                    # +z goes to u
    D = vsh_rotation(Q, p)
    nv = D.shape[1]
    E = rng.standard_normal((5, nv, nv))
    L = np.eye(nv)
    L[3, 7], L[7, 3] = 0.5, -0.25
    want = L @ D @ E @ np.swapaxes(D, 1, 2)
    got = rotate_blocks(E, wigner_directions(u, p), degree_slices(p), left_matrix=L)
    assert np.abs(got - want).max() < 1e-12 * np.abs(want).max()


def test_rotation_refuses_a_reflection():
    with pytest.raises(ValueError, match="rotation"):
        vsh_rotation(np.diag([1.0, 1.0, -1.0]), 3)


def test_rotation_of_masked_blocks_equals_the_dense_rotation():
    p = 3
    rng = np.random.default_rng(4)
    order = vsh_basis(p).order
    mask = order[:, None] == order[None, :]
    E = np.where(mask, rng.standard_normal((2,) + mask.shape), 0.0)
    u = rng.standard_normal((2, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    Dn = wigner_directions(u, p)
    dense = rotate_blocks(E, Dn, degree_slices(p))
    masked = rotate_blocks(E[:, mask], Dn, degree_slices(p), pattern=mask)
    assert np.abs(dense - masked).max() < 1e-14 * np.abs(dense).max()
