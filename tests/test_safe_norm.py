"""safe_norm: one pass for ordinary vectors, the scaled passes near overflow and underflow."""

import math

import numpy as np

from lcpbench.core.probes import safe_norm


def test_an_ordinary_vector_gets_its_two_norm():
    v = np.random.default_rng(0).standard_normal(100)
    assert safe_norm(v) == np.float64(np.sqrt(v @ v))
    assert math.isclose(safe_norm(v), float(np.linalg.norm(v)), rel_tol=1e-15)


def test_huge_and_tiny_entries_neither_overflow_nor_underflow():
    assert math.isclose(safe_norm(np.full(4, 1e300)), 2e300, rel_tol=1e-15)
    assert math.isclose(safe_norm(np.full(4, 1e-300)), 2e-300, rel_tol=1e-15)
    assert math.isclose(safe_norm(np.array([3e-170, 4e-170])), 5e-170, rel_tol=1e-15)


def test_infinite_nan_and_empty_vectors():
    assert safe_norm(np.array([1.0, np.inf])) == np.inf
    assert math.isnan(safe_norm(np.array([1.0, np.nan])))
    assert safe_norm(np.zeros(0)) == 0.0
    assert safe_norm(np.zeros(3)) == 0.0
