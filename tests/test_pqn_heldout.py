"""Bi-PQN's defaults on a packed configuration none of the shipped sets holds.

The shipped sets were all generated with seed 0; ``benchmarks/pqn_heldout.py`` checks the
defaults on other seeds and both lattice scenes (docs/benchmarks.md, "Bi-PQN's defaults on
held-out configurations"). This is its smallest case: 8 spheres, seed 3, BIM p = 4.
"""

from __future__ import annotations

import warnings

import pytest


@pytest.mark.slow
def test_bi_pqn_defaults_reach_the_oracle_on_a_held_out_configuration(benchmark_script):
    heldout = benchmark_script("pqn_heldout")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lcp, A, lows = heldout.heldout_lcp("lattice", 2, 3, 4, 12, 1e-3)
    assert lcp.n > 5
    for d in heldout.measure(lcp, A, lows):
        assert d["solved"] and d["bi"] <= d["oracle"], heldout.row(d)
