"""Small LCPs with a known complementary solution, shared by the solver tests."""

import numpy as np


def planted(n, rank=None, seed=0, cond=100.0, solution=False):
    """A PSD LCP ``(A, b)`` with a planted complementary solution (SPD when ``rank`` is None).

    SPD: eigenvalues log-spaced over ``[1, cond]`` in a random basis; PSD: ``B B' / rank``
    with ``B`` of shape ``(n, rank)``. About half the indices are active (``x > 0 = w``).
    With ``solution=True`` returns ``(A, b, x)``.
    """
    rng = np.random.default_rng(seed)
    if rank is None:
        Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
        A = (Q * np.logspace(0, np.log10(cond), n)) @ Q.T
    else:
        B = rng.standard_normal((n, rank))
        A = B @ B.T / rank
    A = (A + A.T) / 2
    act = rng.random(n) < 0.5
    xs = np.where(act, rng.random(n) + 0.1, 0.0)
    ws = np.where(act, 0.0, rng.random(n) + 0.1)
    b = ws - A @ xs
    return (A, b, xs) if solution else (A, b)
