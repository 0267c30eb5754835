"""Tests of the exact two-sphere Stokes drag series in ``tests/stokes_series.py``.

Each series is checked against an independent result: published tables, the far-field
method-of-reflections expansion, the lubrication limit, and a numerically exact method of
reflections built on Sampson's stream-function expansion (no bispherical coordinates).
"""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest
from stokes_series import (
    alpha_from_distance,
    brenner_lambda,
    distance_from_alpha,
    far_field_coefficients,
    far_field_lambda,
    mobility_functions_along_axis,
    reflection_lambda,
    stimson_jeffery_lambda,
    two_sphere_mobility_along_axis,
)

EXACT = {"together": stimson_jeffery_lambda, "apart": brenner_lambda}


# ---------------------------------------------------------------- coordinates and input checks


@pytest.mark.parametrize("d", [2.0 + 1e-9, 2.001, 2.5, 3.0, 10.0, 1e6])
def test_alpha_round_trip(d: float) -> None:
    assert distance_from_alpha(alpha_from_distance(d)) == pytest.approx(d, rel=1e-12)


def test_alpha_near_contact_is_accurate() -> None:
    # d/a = 2 + h with small h: cosh(alpha) = 1 + h/2, alpha = sqrt(h) (1 - h/24 + ...)
    h = 1e-10
    assert alpha_from_distance(2.0 + h) == pytest.approx(math.sqrt(h), rel=1e-6)


@pytest.mark.parametrize("bad", [2.0, 1.5, -3.0, float("nan"), float("inf")])
def test_rejects_touching_or_invalid_distance(bad: float) -> None:
    for f in (stimson_jeffery_lambda, brenner_lambda, two_sphere_mobility_along_axis):
        with pytest.raises(ValueError, match="d_over_a"):
            f(bad)


@pytest.mark.parametrize("bad", [0, -1, 2.5, True])
def test_rejects_bad_term_count(bad) -> None:
    with pytest.raises(ValueError, match="terms"):
        stimson_jeffery_lambda(3.0, terms=bad)


def test_rejects_unknown_mode() -> None:
    with pytest.raises(ValueError, match="mode"):
        reflection_lambda(3.0, "sideways")
    with pytest.raises(ValueError, match="mode"):
        far_field_lambda(3.0, "sideways")
    with pytest.raises(ValueError, match="order"):
        far_field_lambda(3.0, "together", order=9)


# --------------------------------------------------------------------------- convergence


@pytest.mark.parametrize("mode", ["together", "apart"])
@pytest.mark.parametrize("d", [2.05, 3.0, 10.0])
def test_partial_sums_converge_geometrically(mode: str, d: float) -> None:
    f = EXACT[mode]
    full = f(d)
    alpha = alpha_from_distance(d)
    errors = [abs(f(d, terms=k) - full) for k in (2, 4, 8, 16, 32)]
    nonzero = [e for e in errors if e > 1e-15]
    assert all(b < a for a, b in pairwise(nonzero))
    # terms decay like n^2 exp(-2 n alpha): the error after k terms is below ~k^2 exp(-2 k alpha)
    for k, e in zip((2, 4, 8, 16, 32), errors):
        assert e <= 10.0 * full * k * k * math.exp(-2.0 * k * alpha) + 1e-15


@pytest.mark.parametrize("mode", ["together", "apart"])
def test_automatic_truncation_matches_long_sum(mode: str) -> None:
    f = EXACT[mode]
    for d in (2.01, 2.5, 6.0):
        assert f(d) == pytest.approx(f(d, terms=20_000), rel=1e-14, abs=0)


def test_no_overflow_far_apart() -> None:
    for d in (1e3, 1e8, 1e15):
        assert stimson_jeffery_lambda(d) == pytest.approx(
            1.0 - 1.5 / d, abs=3.0 / d**2 + 1e-15
        )
        assert brenner_lambda(d) == pytest.approx(1.0 + 1.5 / d, abs=3.0 / d**2 + 1e-15)


# ----------------------------------------------------------------------- published values


# Stimson & Jeffery (1926), Proc. R. Soc. A 111, 110, table of lambda against alpha
# (alpha = 0.5 ... 3, three decimals), also reproduced in Happel & Brenner, Low Reynolds Number
# Hydrodynamics (1965), ch. 6. The contact value 0.645 is Cooley & O'Neill's (1969, Proc.
# Camb. Phil. Soc. 66, 407) exact result for two touching spheres, the alpha -> 0 limit.
STIMSON_JEFFERY_TABLE = [
    (0.5, 0.660),
    (1.0, 0.702),
    (1.5, 0.768),
    (2.0, 0.836),
    (2.5, 0.892),
    (3.0, 0.931),
]


@pytest.mark.parametrize("alpha, published", STIMSON_JEFFERY_TABLE)
def test_stimson_jeffery_table(alpha: float, published: float) -> None:
    lam = stimson_jeffery_lambda(distance_from_alpha(alpha))
    assert round(lam, 3) == pytest.approx(published, abs=1e-12)


def test_stimson_jeffery_contact_limit() -> None:
    assert stimson_jeffery_lambda(2.0 + 1e-8) == pytest.approx(0.645, abs=5e-4)
    # monotone: shielding grows as the spheres approach
    ds = [2.001, 2.1, 2.5, 3.0, 4.0, 6.0, 10.0, 100.0]
    lam = [stimson_jeffery_lambda(d) for d in ds]
    assert all(b > a for a, b in pairwise(lam))
    assert all(0.6 < v < 1.0 for v in lam)


def test_brenner_is_above_one_and_decreasing() -> None:
    ds = [2.001, 2.1, 2.5, 3.0, 4.0, 6.0, 10.0, 100.0]
    lam = [brenner_lambda(d) for d in ds]
    assert all(b < a for a, b in pairwise(lam))
    assert all(v > 1.0 for v in lam)


# ------------------------------------------------------------------- near-contact (lubrication)


def test_brenner_lubrication_leading_order() -> None:
    # lambda ~ a / (2 h): F = 6 pi mu (a/2)^2 (2U) / h from Reynolds lubrication, reduced
    # radius a/2 and approach speed 2U.
    for h in (1e-3, 1e-4):
        lam = brenner_lambda(2.0 + h)
        assert lam * 2.0 * h == pytest.approx(1.0, abs=5.0 * h * math.log(1.0 / h))


def test_brenner_lubrication_log_term() -> None:
    # next order: + (9/20) log(a/h) + O(1)  (Jeffrey & Onishi 1984: X11A - X12A for equal
    # spheres, g1 = 1/4 and g2 = 9/40 per sphere-pair function). Differences cancel the O(1).
    h1, h2 = 1e-3, 1e-4
    r1 = brenner_lambda(2.0 + h1) - 0.5 / h1
    r2 = brenner_lambda(2.0 + h2) - 0.5 / h2
    assert (r2 - r1) / math.log(h1 / h2) == pytest.approx(9.0 / 20.0, abs=0.02)


def test_stimson_jeffery_regular_at_contact() -> None:
    # same-velocity motion has no lubrication singularity: lambda is smooth in the gap
    vals = [stimson_jeffery_lambda(2.0 + h) for h in (1e-2, 1e-4, 1e-6)]
    assert abs(vals[0] - vals[1]) < 2e-3 and abs(vals[1] - vals[2]) < 2e-4


# ----------------------------------------------------------------------- far-field asymptotics


@pytest.mark.parametrize("d", [20.0, 50.0, 100.0])
def test_point_force_expansion(d: float) -> None:
    """Rotne-Prager (Stokeslet + degenerate quadrupole) gives A11 = 1, A12 = 3/(2s) - 1/s^3.

    Then 1/lambda = 1 +- A12 exactly up to the stresslet reflection -(15/4) (a/d)^4; the
    remainder is (11/2) x^6 +- (75/4) x^7 + ..., below 8 x^6 for d >= 20.
    """
    x = 1.0 / d
    a12_rp = 1.5 * x - x**3
    assert 1.0 / stimson_jeffery_lambda(d) - (1.0 + a12_rp) == pytest.approx(
        -3.75 * x**4, abs=8.0 * x**6
    )
    assert 1.0 / brenner_lambda(d) - (1.0 - a12_rp) == pytest.approx(
        -3.75 * x**4, abs=8.0 * x**6
    )
    # first order (Oseen / Stokeslet): lambda ~ 1 -+ 3a/(2d)
    assert stimson_jeffery_lambda(d) == pytest.approx(1.0 - 1.5 * x, abs=2.5 * x**2)
    assert brenner_lambda(d) == pytest.approx(1.0 + 1.5 * x, abs=2.5 * x**2)


def test_far_field_coefficients_match_happel_brenner() -> None:
    from fractions import Fraction as Fr

    together = far_field_coefficients("together", 5)
    assert together == [
        Fr(1),
        Fr(-3, 2),
        Fr(9, 4),
        Fr(-19, 8),
        Fr(93, 16),
        Fr(-387, 32),
    ]
    apart = far_field_coefficients("apart", 7)
    # A11 is even and A12 odd in a/d, so the two modes are mirror series in a/d
    assert apart == [
        c * (-1) ** k for k, c in enumerate(far_field_coefficients("together", 7))
    ]


@pytest.mark.parametrize("mode", ["together", "apart"])
@pytest.mark.parametrize("d", [4.0, 6.0, 10.0])
def test_method_of_reflections_to_sixth_order(mode: str, d: float) -> None:
    """Exact series minus the O((a/d)^6) reflection series is the O((a/d)^7) remainder.

    The coefficients grow like 2^k (the series converges for d > 2a), so the remainder is
    bounded by |c7| x^7 / (1 - 2x), and it carries the sign of c7.
    """
    x = 1.0 / d
    c7 = float(far_field_coefficients(mode, 7)[7])
    exact = EXACT[mode](d)
    remainder = exact - far_field_lambda(d, mode, order=6)
    bound = abs(c7) * x**7 / (1.0 - 2.0 * x)
    assert abs(remainder) <= 1.25 * bound
    assert math.copysign(1.0, remainder) == math.copysign(1.0, c7)
    # each added order of the reflection series brings the result closer
    errs = [abs(exact - far_field_lambda(d, mode, order=k)) for k in range(2, 8)]
    assert all(b < a for a, b in pairwise(errs))


@pytest.mark.parametrize("d", [10.0, 20.0])
def test_mobility_functions_far_field(d: float) -> None:
    x = 1.0 / d
    a11, a12 = mobility_functions_along_axis(d)
    assert a11 == pytest.approx(1.0 - 3.75 * x**4 + 5.5 * x**6, abs=12.0 * x**8)
    assert a12 == pytest.approx(1.5 * x - x**3 + 18.75 * x**7, abs=10.0 * x**9)


# ------------------------------------------------------ independent exact method of reflections


@pytest.mark.parametrize("d", [15.0, 25.0])
def test_reflection_solver_reproduces_far_field_coefficients(d: float) -> None:
    """The reflection solver alone (no bispherical series, no literature coefficient).

    Recovers -15/4 and 11/2 in A11 and 3/2, -1, 0 and 75/4 in A12 within the size of the next
    terms (about 10.5 x^8 in A11 and 7.5 x^9 in A12) plus round-off.
    """
    x = 1.0 / d
    m_sum = 1.0 / reflection_lambda(d, "together")
    m_diff = 1.0 / reflection_lambda(d, "apart")
    a11, a12 = 0.5 * (m_sum + m_diff), 0.5 * (m_sum - m_diff)
    assert (a11 - 1.0) / x**4 == pytest.approx(-15.0 / 4.0, abs=6.0 * x**2)
    assert (a11 - 1.0 + 3.75 * x**4) / x**6 == pytest.approx(
        11.0 / 2.0, abs=12.0 * x**2
    )
    assert (a12 - 1.5 * x) / x**3 == pytest.approx(-1.0, abs=1e-3)
    assert (a12 - 1.5 * x + x**3) / x**5 == pytest.approx(0.0, abs=20.0 * x**2)
    assert (a12 - 1.5 * x + x**3) / x**7 == pytest.approx(
        75.0 / 4.0, abs=10.0 * x**2 + 1e-2
    )


@pytest.mark.parametrize("mode", ["together", "apart"])
@pytest.mark.parametrize("d", [2.5, 3.0, 4.0, 6.0, 10.0])
def test_exact_reflections_agree_with_bispherical_series(mode: str, d: float) -> None:
    assert reflection_lambda(d, mode) == pytest.approx(EXACT[mode](d), rel=1e-12)


def test_reflections_single_sphere_limit() -> None:
    assert reflection_lambda(1e6, "together") == pytest.approx(1.0 - 1.5e-6, rel=1e-10)


# ------------------------------------------------------------------------- mobility contract


@pytest.mark.parametrize("d", [2.5, 3.0, 4.0, 6.0])
def test_mode_mobilities(d: float) -> None:
    m_together, m_apart = two_sphere_mobility_along_axis(d)
    assert m_together == pytest.approx(
        1.0 / (6.0 * math.pi * stimson_jeffery_lambda(d))
    )
    assert m_apart == pytest.approx(1.0 / (6.0 * math.pi * brenner_lambda(d)))
    a11, a12 = mobility_functions_along_axis(d)
    # e.M11.e +- e.M12.e with M in units of 1/(6 pi mu a)
    assert 6.0 * math.pi * m_together == pytest.approx(a11 + a12, rel=1e-14)
    assert 6.0 * math.pi * m_apart == pytest.approx(a11 - a12, rel=1e-14)
    # the 2x2 axial block [[A11, A12], [A12, A11]] is symmetric positive definite
    eig = np.linalg.eigvalsh(np.array([[a11, a12], [a12, a11]]))
    assert np.all(eig > 0)
    # Rotne-Prager overestimates the pair mobility of the together mode at these distances
    x = 1.0 / d
    assert 6.0 * math.pi * m_together < 1.0 + 1.5 * x - x**3
