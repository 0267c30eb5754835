"""Tests of the generalised Rotne-Prager-Yamakawa mobility and of ``mobility()``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.linalg import LinearOperator
from scipy.special import spherical_jn
from scipy.stats import special_ortho_group

from lcpbench.problems.suspension import mobility, rpy_matrix

PI = np.pi


def pair_blocks(r: float, a: float, b: float, mu: float = 1.0) -> dict[str, np.ndarray]:
    """Blocks of sphere 0 (radius a, at r x) with sphere 1 (radius b, at 0)."""
    K = rpy_matrix([[r, 0.0, 0.0], [0.0, 0.0, 0.0]], [a, b], mu=mu)
    return {"tt": K[0:3, 6:9], "tr": K[0:3, 9:12], "rt": K[3:6, 6:9], "rr": K[3:6, 9:12]}


def coefficients(r: float, a: float, b: float) -> np.ndarray:
    """Scalar functions of a pair with rhat = x: tt (I, rr), rr (I, rr), rt, tr."""
    B = pair_blocks(r, a, b)
    return np.array([B["tt"][1, 1], B["tt"][0, 0] - B["tt"][1, 1],
                     B["rr"][1, 1], B["rr"][0, 0] - B["rr"][1, 1],
                     B["rt"][1, 2], B["tr"][1, 2]])


def random_overlapping(rng: np.random.Generator, M: int) -> tuple[np.ndarray, np.ndarray]:
    """A clustered polydisperse configuration forced to contain overlapping
    pairs and one sphere inside another."""
    radii = rng.uniform(0.3, 1.2, M)
    centers = rng.normal(scale=1.0, size=(M, 3))
    # sphere 1 inside sphere 0, sphere 3 partly overlapping sphere 2
    radii[0], radii[1] = 1.5, 0.4
    u = rng.normal(size=(2, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    centers[1] = centers[0] + 0.5 * u[0]
    radii[2], radii[3] = 0.8, 0.7
    centers[3] = centers[2] + 1.0 * u[1]
    return centers, radii


def pair_regimes(centers: np.ndarray, radii: np.ndarray) -> set[str]:
    i, j = np.triu_indices(len(radii), 1)
    r = np.linalg.norm(centers[i] - centers[j], axis=1)
    out = set()
    if np.any(r <= np.abs(radii[i] - radii[j])):
        out.add("inside")
    if np.any((r > np.abs(radii[i] - radii[j])) & (r < radii[i] + radii[j])):
        out.add("overlap")
    if np.any(r >= radii[i] + radii[j]):
        out.add("far")
    return out


# --------------------------------------------------------------------------- one sphere

@pytest.mark.parametrize("a", [0.1, 1.0, 3.7])
@pytest.mark.parametrize("mu", [0.5, 1.0, 2.3])
def test_single_sphere_exact(a: float, mu: float) -> None:
    K = rpy_matrix([[0.3, -1.0, 2.0]], a, mu=mu)
    expected = np.diag([1 / (6 * PI * mu * a)] * 3 + [1 / (8 * PI * mu * a ** 3)] * 3)
    np.testing.assert_allclose(K, expected, rtol=1e-14, atol=0)
    F, T = np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.0, -1.1])
    UW = mobility([[0.3, -1.0, 2.0]], [a], model="rpy", mu=mu) @ np.concatenate([F, T])
    np.testing.assert_allclose(UW[:3], F / (6 * PI * mu * a), rtol=1e-14)
    np.testing.assert_allclose(UW[3:], T / (8 * PI * mu * a ** 3), rtol=1e-14)


# --------------------------------------------------------------------- matrix properties

@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_symmetric_positive_definite_for_overlapping_polydisperse(seed: int) -> None:
    rng = np.random.default_rng(seed)
    centers, radii = random_overlapping(rng, 40)
    assert pair_regimes(centers, radii) == {"inside", "overlap", "far"}
    K = rpy_matrix(centers, radii)
    assert np.abs(K - K.T).max() <= 1e-13 * np.abs(K).max()
    assert np.linalg.eigvalsh(K).min() > 0


def test_positive_definite_dense_cluster_and_nested_spheres() -> None:
    rng = np.random.default_rng(7)
    # 60 spheres squeezed into a ball of radius 1: almost every pair overlaps
    centers = rng.uniform(-1, 1, size=(60, 3))
    radii = rng.uniform(0.2, 1.5, 60)
    assert {"inside", "overlap"} <= pair_regimes(centers, radii)
    lam = np.linalg.eigvalsh(rpy_matrix(centers, radii))
    assert lam.min() > 0
    # a chain of concentric-ish nested spheres, each inside the previous one
    radii = np.array([2.0, 1.5, 1.0, 0.6, 0.3])
    centers = np.array([[0.0, 0, 0], [0.2, 0, 0], [0.3, 0.1, 0], [0.35, 0.1, 0.1],
                        [0.4, 0.15, 0.1]])
    assert pair_regimes(centers, radii) == {"inside"}
    assert np.linalg.eigvalsh(rpy_matrix(centers, radii)).min() > 0


@pytest.mark.parametrize("a, b", [(1.0, 1.0), (1.0, 0.4), (0.4, 1.0), (2.5, 1.7)])
def test_blocks_continuous_at_contact_and_at_internal_tangency(a: float, b: float) -> None:
    h = 1e-10
    for r0 in (a + b, abs(a - b)):
        if r0 == 0.0:
            continue
        below = coefficients(r0 * (1 - h), a, b)
        above = coefficients(r0 * (1 + h), a, b)
        scale = np.abs(np.concatenate([below, above])).max()
        np.testing.assert_allclose(below, above, rtol=0, atol=1e-8 * scale)


@pytest.mark.parametrize("r, a, b", [
    (3.0, 1.0, 1.3),   # disjoint
    (1.5, 1.0, 1.0),   # equal spheres overlapping
    (1.2, 1.0, 0.7),   # overlap, r > a
    (0.8, 1.0, 0.5),   # overlap, r < a
    (0.8, 0.5, 1.0),   # same pair seen from the small sphere
    (0.3, 1.0, 0.5),   # small sphere inside: the rotating sphere is the big one
    (0.3, 0.5, 1.0),   # rotating sphere inside the big one
])
def test_blocks_equal_the_fourier_definition(r: float, a: float, b: float) -> None:
    """Independent check of every formula against the definition of the
    generalised RPY tensor: the Oseen kernel averaged over sphere surfaces
    (forces) and volumes (torques), evaluated as a 1-D Fourier integral."""
    k = np.linspace(1e-9, 1500.0, 600_001)
    x = k * r
    ang_I = spherical_jn(0, x) - spherical_jn(1, x) / x      # angular mean of e^{ik.r}(I - kk)
    ang_R = spherical_jn(2, x)
    sa, sb = spherical_jn(0, k * a), spherical_jn(0, k * b)  # surface weights
    va, vb = 3 * spherical_jn(1, k * a) / (k * a), 3 * spherical_jn(1, k * b) / (k * b)  # volume

    def integral(f: np.ndarray) -> float:
        return float(np.trapezoid(f, k))

    ref = np.array([
        integral(ang_I * sa * sb) / (2 * PI ** 2), integral(ang_R * sa * sb) / (2 * PI ** 2),
        integral(k ** 2 * ang_I * va * vb) / (8 * PI ** 2),
        integral(k ** 2 * ang_R * va * vb) / (8 * PI ** 2),
        integral(k * spherical_jn(1, x) * sb * va) / (4 * PI ** 2),   # sphere 0 rotates
        integral(k * spherical_jn(1, x) * sa * vb) / (4 * PI ** 2),   # sphere 1 rotates
    ])
    got = coefficients(r, a, b)
    np.testing.assert_allclose(got, ref, rtol=0, atol=2e-6 * np.abs(ref).max())


def test_nested_sphere_blocks() -> None:
    a_big, a_small, r = 1.3, 0.5, 0.4
    B = pair_blocks(r, a_big, a_small, mu=2.0)
    np.testing.assert_allclose(B["tt"], np.eye(3) / (6 * PI * 2.0 * a_big), rtol=1e-14)
    np.testing.assert_allclose(B["rr"], np.eye(3) / (8 * PI * 2.0 * a_big ** 3), rtol=1e-14)
    # a force F on the small sphere turns the big one as the torque r x F would
    F = np.array([0.0, 1.0, 0.0])
    lever = np.array([0.0, 0.0, 0.0]) - np.array([r, 0.0, 0.0])   # small - big centre
    np.testing.assert_allclose(B["rt"] @ F, np.cross(lever, F) / (8 * PI * 2.0 * a_big ** 3),
                               rtol=1e-14)
    # and a force on the big sphere does not turn the small one
    np.testing.assert_allclose(pair_blocks(r, a_small, a_big)["rt"], 0.0, atol=0)


# ------------------------------------------------------------------------ far field

@pytest.mark.parametrize("a, b", [(1.0, 1.0), (0.3, 2.0)])
def test_far_field_tends_to_oseen(a: float, b: float) -> None:
    rng = np.random.default_rng(11)
    for r in (1e2, 1e4):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        K = rpy_matrix([r * n, [0.0, 0.0, 0.0]], [a, b])
        oseen = (np.eye(3) + np.outer(n, n)) / (8 * PI * r)
        rel = np.abs(K[0:3, 6:9] - oseen).max() / np.abs(oseen).max()
        assert rel <= 2 * (a * a + b * b) / r ** 2
    assert rel < 1e-7


def test_two_equal_spheres_leading_terms() -> None:
    """Far-field series of the exact two-sphere mobility functions (Jeffrey &
    Onishi 1984): x12a = 3/(2 rho) - 1/rho^3, y12a = 3/(4 rho) + 1/(2 rho^3),
    x12c = 1/rho^3, y12c = -1/(2 rho^3); RPY reproduces exactly these terms."""
    a, mu = 0.7, 1.9
    for rho in (2.5, 4.0, 10.0):
        B = pair_blocks(rho * a, a, a, mu=mu)
        t0, r0 = 1 / (6 * PI * mu * a), 1 / (8 * PI * mu * a ** 3)
        np.testing.assert_allclose(B["tt"][0, 0] / t0, 3 / (2 * rho) - 1 / rho ** 3, rtol=1e-13)
        np.testing.assert_allclose(B["tt"][1, 1] / t0, 3 / (4 * rho) + 1 / (2 * rho ** 3),
                                   rtol=1e-13)
        np.testing.assert_allclose(B["rr"][0, 0] / r0, 1 / rho ** 3, rtol=1e-13)
        np.testing.assert_allclose(B["rr"][1, 1] / r0, -1 / (2 * rho ** 3), rtol=1e-13)
        # vorticity of a Stokeslet: W_0 = F x rhat / (8 pi mu r^2)
        F = np.array([0.0, 1.0, 0.0])
        np.testing.assert_allclose(B["rt"] @ F,
                                   np.cross(F, [1.0, 0, 0]) / (8 * PI * mu * (rho * a) ** 2),
                                   rtol=1e-13)
        np.testing.assert_allclose(B["tr"], B["rt"], rtol=1e-13)


def test_two_unequal_spheres_faxen_form() -> None:
    """Disjoint spheres: tt = (1 + (a^2 + b^2)/6 lap) Oseen, so the Oseen part
    plus (a^2 + b^2)/(24 pi mu r^3) (I - 3 rhat rhat)."""
    a, b, r = 0.4, 1.3, 2.0
    n = np.array([0.0, 0.6, 0.8])
    K = rpy_matrix([r * n, [0, 0, 0]], [a, b])
    expect = ((np.eye(3) + np.outer(n, n)) / (8 * PI * r)
              + (a * a + b * b) / (24 * PI * r ** 3) * (np.eye(3) - 3 * np.outer(n, n)))
    np.testing.assert_allclose(K[0:3, 6:9], expect, rtol=1e-13)


# ------------------------------------------------------------------------- symmetries

def test_translation_invariance_and_rotation_covariance() -> None:
    rng = np.random.default_rng(5)
    centers, radii = random_overlapping(rng, 12)
    K = rpy_matrix(centers, radii)
    np.testing.assert_allclose(rpy_matrix(centers + [3.0, -7.0, 0.25], radii), K,
                               rtol=0, atol=1e-13 * np.abs(K).max())
    Q = special_ortho_group.rvs(3, random_state=6)
    P = Q @ np.diag([1.0, 1.0, -1.0])                 # improper: a rotation times a mirror
    for R in (Q, P):
        det = np.linalg.det(R)
        # torques and angular velocities are pseudo-vectors: they pick up det(R)
        D = np.kron(np.eye(len(radii)), np.block([[R, np.zeros((3, 3))],
                                                  [np.zeros((3, 3)), det * R]]))
        np.testing.assert_allclose(rpy_matrix(centers @ R.T, radii), D @ K @ D.T,
                                   rtol=0, atol=1e-12 * np.abs(K).max())


def test_scalar_and_array_radii_agree() -> None:
    centers = np.random.default_rng(9).normal(size=(8, 3))
    np.testing.assert_array_equal(rpy_matrix(centers, 0.45), rpy_matrix(centers, [0.45] * 8))
    np.testing.assert_allclose(rpy_matrix(centers, 0.45, mu=3.0), rpy_matrix(centers, 0.45) / 3.0,
                               rtol=1e-15)


# ------------------------------------------------------------------------- mobility()

def test_mobility_rpy_is_a_linear_operator_of_the_matrix() -> None:
    rng = np.random.default_rng(3)
    centers, radii = random_overlapping(rng, 9)
    K = rpy_matrix(centers, radii, mu=0.8)
    op = mobility(centers, radii, model="rpy", mu=0.8)
    assert isinstance(op, LinearOperator)
    assert op.shape == (54, 54)
    x = rng.normal(size=54)
    X = rng.normal(size=(54, 4))
    np.testing.assert_allclose(op.matvec(x), K @ x, rtol=1e-14, atol=0)
    np.testing.assert_allclose(op @ x, K @ x, rtol=1e-14, atol=0)
    np.testing.assert_allclose(op.matmat(X), K @ X, rtol=1e-14, atol=0)
    np.testing.assert_allclose(op.rmatvec(x), K.T @ x, rtol=1e-14, atol=0)


GOOD = {"centers": [[0.0, 0, 0], [3.0, 0, 0]], "radii": [1.0, 1.0]}


@pytest.mark.parametrize("model", ["rpy", "bim"])
@pytest.mark.parametrize("change, message", [
    ({"centers": [[0.0, 0, 0], [np.nan, 0, 0]]}, r"centers\[1\].*not finite"),
    ({"centers": [[0.0, 0, 0], [np.inf, 0, 0]]}, r"not finite"),
    ({"centers": [[1.0, 2, 3], [1.0, 2, 3]]}, r"coincident centres"),
    ({"centers": [[0.0, 0], [1.0, 0]]}, r"shape \(M, 3\)"),
    ({"radii": [1.0, 0.0]}, r"radii\[1\].*finite positive"),
    ({"radii": [-1.0, 1.0]}, r"radii\[0\].*finite positive"),
    ({"radii": [1.0, 1.0, 1.0]}, r"radii must be a scalar or have shape"),
    ({"p": 0}, r"p = 0 must be an integer spherical-harmonic order >= 1"),
    ({"p": -3}, r"order >= 1"),
    ({"p": 2.5}, r"must be an integer"),
    ({"p": True}, r"must be an integer"),
    ({"eps_gmres": 0.0}, r"eps_gmres = 0.0 must be a finite number in \(0, 1\)"),
    ({"eps_gmres": -1e-6}, r"eps_gmres.*in \(0, 1\)"),
    ({"eps_gmres": float("nan")}, r"eps_gmres.*finite"),
    ({"eps_gmres": "1e-8"}, r"eps_gmres = '1e-8' must be a finite number"),
    ({"mu": 0.0}, r"mu = 0.0 must be a finite positive viscosity"),
    ({"mu": -2.0}, r"positive viscosity"),
])
def test_mobility_bad_input_raises_helpful_value_error(model: str, change: dict,
                                                       message: str) -> None:
    kwargs = {**GOOD, "model": model}
    kwargs.update(change)
    with pytest.raises(ValueError, match=message):
        mobility(**kwargs)


@pytest.mark.parametrize("model", ["RPY", "stokesian", "", None])
def test_mobility_unknown_model_lists_the_choices(model) -> None:
    with pytest.raises(ValueError, match=r"unknown mobility model.*'rpy'.*'bim'"):
        mobility(**GOOD, model=model)


def test_rpy_matrix_validates_its_input() -> None:
    with pytest.raises(ValueError, match="coincident"):
        rpy_matrix([[0.0, 0, 0], [0.0, 0, 0]], [1.0, 0.5])
    with pytest.raises(ValueError, match="viscosity"):
        rpy_matrix([[0.0, 0, 0]], 1.0, mu=float("nan"))
