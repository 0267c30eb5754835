"""Sphere configurations shared by the boundary-integral tests."""

import numpy as np


def packed(n_side=3, spacing=2.35, jitter=0.1, seed=5):
    """Centres of an ``n_side^3`` cubic lattice of unit spheres ``spacing`` apart (gaps about
    0.35a), each moved by uniform jitter of width ``jitter``."""
    rng = np.random.default_rng(seed)
    ax = np.arange(n_side) * spacing
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    c = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    return c + rng.uniform(-jitter / 2, jitter / 2, c.shape)
