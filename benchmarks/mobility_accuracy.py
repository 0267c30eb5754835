"""Error of the boundary-integral mobility against the exact two-sphere series, versus p and gap.

Usage::

    python benchmarks/mobility_accuracy.py                   # the table of docs/mobility.md
    python benchmarks/mobility_accuracy.py --p 4 8 --gap 1 0.1

Two equal unit spheres, centres ``2 + gap`` apart on a line, with equal forces
(the pair translates together; Stimson & Jeffery 1926) and with opposite
forces (the pair approaches; Brenner 1961, the squeeze mode). Each cell is the
relative error of the mobility along the line of centres,
``|U_bim - U_exact| / |U_exact|``, for the two modes: ``together / squeeze``.
The line of centres is tilted off the grid axes (a generic orientation).
GMRES tolerance 1e-12, so the error is the discretisation's alone.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))

from stokes_series import two_sphere_mobility_along_axis  # noqa: E402

from lcpbench.problems.suspension import mobility  # noqa: E402


def errors(p: int, gap: float) -> tuple[float, float]:
    """Relative errors (together, squeeze) of the BIM mobility at order ``p``."""
    e = np.array([1.0, 0.7, 0.4])
    e /= np.linalg.norm(e)
    d = 2.0 + gap
    X = np.array([-0.5 * d * e, 0.5 * d * e])
    M = mobility(X, 1.0, model="bim", p=p, eps_gmres=1e-12)
    m_together, m_apart = two_sphere_mobility_along_axis(d)
    out = []
    for sign, exact in ((1.0, m_together), (-1.0, m_apart)):
        f = np.zeros(12)
        f[0:3] = sign * e                # sphere 0 force
        f[6:9] = e                       # sphere 1 force
        u = M @ f
        got = float(u[6:9] @ e)          # sphere 1 velocity along the line
        out.append(abs(got - exact) / abs(exact))
    return out[0], out[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--p", type=int, nargs="+", default=[3, 4, 6, 8, 12])
    ap.add_argument("--gap", type=float, nargs="+", default=[2.0, 1.0, 0.5, 0.1, 0.01])
    args = ap.parse_args()
    print("| gap / a | " + " | ".join(f"p = {p}" for p in args.p) + " |")
    print("|---|" + "---|" * len(args.p))
    for gap in args.gap:
        cells = []
        for p in args.p:
            t, s = errors(p, gap)
            cells.append(f"{t:.1e} / {s:.1e}")
        print(f"| {gap:g} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
