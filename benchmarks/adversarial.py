"""Adversarial claims: refuted ``converged`` and false ``infeasible`` over every MVP-only solver.

Usage::

    python benchmarks/adversarial.py --group accuracy --cases 250      # 2,000 runs
    python benchmarks/adversarial.py --group scaling --cases 250       # 2,000 runs
    python benchmarks/adversarial.py --group operators --cases 200     # 2,000 runs
    python benchmarks/adversarial.py --group metadata --cases 2000     # 2,000 reads
    python benchmarks/adversarial.py --group accuracy --cases 4 --solvers mono-pqn  # a slice

Two groups of generators, outside ``benchmarks/fuzz.py``'s distribution:

``accuracy`` (undeclared inexact operators; case ``i`` is kind ``i mod 4``):

* ``float32``: ``A`` stored and applied in single precision, products returned as float32;
* ``mixed``: single-precision storage and product, returned as float64 (the dtype hides it);
* ``gmres``: ``A = K^-1`` applied by GMRES at an undeclared tolerance 10^U(-10, -5);
* ``cg-float32``: ``A = K^-1`` by CG at 10^U(-9, -6) on a single-precision ``K``.

``A`` is SPD (condition 10^U(0, 5)) or singular PSD, ``b`` planted (a known solution)
scaled by 10^U(-3, 4), n = 4..40. No operator declares ``rtol``.

``scaling`` (badly scaled problems that all have a solution; kind ``i mod 4``):

* ``spike``: ``A = s I + M v v'`` with ``s`` in 10^U(-2, 0) and ``M`` in 10^U(6, 11);
* ``diagonal``: ``D S D`` with ``D`` spread over 10^U(-4, 4) per entry;
* ``psd-planted``: singular ``J J'`` (null directions exist) with a planted solution;
* ``tiny-eig``: SPD with one eigenvalue 10^U(-12, -7) times the largest, random ``b``.

``operators`` (operators and matrices of the collision problems that broke claims or
escaped the framework; kind ``i mod 5``; the dense solvers ``pgs`` and ``lemke`` run too,
so the framework's dense copy of a matrix-free A is exercised):

* ``ill-definite``: SPD with condition 10^U(8, 14) whose eigenvector of the smallest
  eigenvalue is positive (the false "no solution" of a split certificate), ``b`` planted or
  random (an SPD LCP has a solution for every ``b``);
* ``nonsymmetric``: a matrix-free ``S + K`` (``S`` PSD, ``K`` skew, never checked for
  symmetry by the framework) with a planted solution;
* ``duplicated``: ``D' M D`` with contacts repeated in ``D`` (singular PSD), planted;
* ``mutating``: an SPD operator applied by ``cho_solve(..., overwrite_b=True)``, which
  writes into its input, planted;
* ``slow``: an SPD operator that sleeps 2 ms per product, planted.

``metadata`` (one flipped bit in the metadata of a stored set; kind ``i mod 3``): a small
set (two instances, a low with its ``cost_ratio``, a reference) is written with
``SetWriter`` and one bit is flipped near an attribute of the root (``root``: format,
version, title, generator, ...), of an instance or a low (``instance``: ``M``, ``step``,
``cost_ratio``, ``sha256:*``) or of the reference (``reference``: solvers, kkt_abs); the
set is then read with ``read_set``. Outcomes: ``refused`` (a ``StoredSetError``), ``silent``
(it loaded: a changed bit went unnoticed) or ``crash`` (any other exception; a crash of the
HDF5 library would end the script).

Counted besides the claims: ``crash`` (an exception escaped ``lcpbench.solve``) and
``hang`` (a solve took longer than twice its time budget plus 5 s).

Each case also draws a warm start: 0, 1e300 on one entry, 1e12 * U(0, 1), a negative
vector (projected to 0), 1e-300, or 1e150 everywhere. Every MVP-only solver runs at tol
1e-8 with the paper's stop rule; the multi-fidelity ones get explicit low fidelities
``A + E`` with declared costs.

Counted per solver: ``refuted converged`` (status ``converged`` while the framework's
verified residual, or this script's own residual of the same operator's product in float64
and in long double, exceeds the threshold) and ``false infeasible`` (status ``infeasible``:
every ``scaling`` problem has a solution). Exits 1 if any is nonzero.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from collections import Counter  # noqa: E402
from multiprocessing import Pool  # noqa: E402

import numpy as np  # noqa: E402
from common import print_outcomes, solver_names  # noqa: E402
from scipy.linalg import cho_factor, cho_solve  # noqa: E402
from scipy.sparse.linalg import LinearOperator, cg, gmres  # noqa: E402

import lcpbench  # noqa: E402
from lcpbench.core.operator import apply_uncounted  # noqa: E402
from lcpbench.problems.synthetic import random_spd_matrix  # noqa: E402

GROUPS = {"accuracy": ("float32", "mixed", "gmres", "cg-float32"),
          "scaling": ("spike", "diagonal", "psd-planted", "tiny-eig"),
          "operators": ("ill-definite", "nonsymmetric", "duplicated", "mutating", "slow"),
          "metadata": ("root", "instance", "reference")}
#: Attribute names whose neighbourhood a ``metadata`` case flips a bit in, per kind.
METADATA_NEEDLES = {"root": (b"lcpbench.set", b"version", b"title", b"generator",
                             b"cost_convention", b"created"),
                    "instance": (b"cost_ratio", b"sha256:", b"step", b"t_mvp"),
                    "reference": (b"solvers", b"kkt_abs", b"disagreement", b"accepted")}
_METADATA_SET: dict[int, bytes] = {}
#: Solvers that need the dense A, run on the ``operators`` group besides the MVP-only ones.
DENSE_EXTRA = ("pgs", "lemke")
#: Seconds a product of the ``slow`` kind sleeps.
SLOW_PRODUCT_S = 0.002
STARTS = ("zero", "one-1e300", "huge", "negative", "tiny", "all-1e150")
MULTI = {"bi-pqn": "bi-pqn:low=low", "multi-pqn": "multi-pqn:lows=[low,lower]"}


def mvp_solvers() -> list[str]:
    """Every listed MVP-only solver (not the references)."""
    return solver_names(mvp_only=True)


def _matrix(rng: np.random.Generator, n: int) -> np.ndarray:
    if rng.random() < 0.7:
        return random_spd_matrix(rng, n, float(10 ** rng.uniform(0, 5)))
    J = rng.standard_normal((n, max(1, n - int(rng.integers(1, max(2, n // 2))))))
    return (J @ J.T + (J @ J.T).T) / 2


def _planted(rng: np.random.Generator, A: np.ndarray) -> np.ndarray:
    n = A.shape[0]
    role = rng.integers(0, 3, n)                 # active, inactive, degenerate
    x = np.where(role == 0, rng.uniform(0.1, 2.0, n), 0.0)
    w = np.where(role == 1, rng.uniform(0.1, 2.0, n), 0.0)
    return w - A @ x


def _float32(A: np.ndarray, keep32: bool):
    A32 = A.astype(np.float32)
    if keep32:
        return lambda v: A32 @ np.asarray(v).astype(np.float32)
    return lambda v: (A32 @ np.asarray(v).astype(np.float32)).astype(np.float64)


def _solve_by(method, K: np.ndarray, tol: float):
    def apply(v):
        y, _ = method(K, np.asarray(v, dtype=K.dtype), rtol=tol, atol=0.0,
                      maxiter=20 * K.shape[0])
        return np.asarray(y)
    return apply


def accuracy_case(i: int, seed: int) -> tuple[lcpbench.LCP, dict]:
    """Case ``i`` of the ``accuracy`` group: an undeclared inexact high operator."""
    rng = np.random.default_rng([seed, i, 1])
    kind = GROUPS["accuracy"][i % 4]
    n = int(rng.integers(4, 41))
    if kind in ("float32", "mixed"):
        A = _matrix(rng, n)
        f = _float32(A, keep32=kind == "float32")
    else:
        K = random_spd_matrix(rng, n, float(10 ** rng.uniform(0, 3)))
        A = np.linalg.inv(K)
        A = (A + A.T) / 2
        if kind == "gmres":
            f = _solve_by(gmres, K, float(10 ** rng.uniform(-10, -5)))
        else:
            f = _solve_by(cg, K.astype(np.float32), float(10 ** rng.uniform(-9, -6)))
    b = _planted(rng, A) * 10 ** rng.uniform(-3, 4)
    high = lcpbench.Operator(LinearOperator((n, n), matvec=f, dtype=np.float64), cost=1.0)
    return _with_lows(rng, high, A, b, kind), {"kind": kind, "solvable": True}


def _with_lows(rng, high, A: np.ndarray, b: np.ndarray, kind: str) -> lcpbench.LCP:
    lows = {}
    for name, rel, cost in (("low", 1e-3, 0.1), ("lower", 1e-2, 0.01)):
        E = rng.uniform(-1, 1, A.shape) * rel * np.abs(A)
        lows[name] = lcpbench.Operator(A + (E + E.T) / 2, cost=cost, name=name)
    return lcpbench.LCP(high, b, low=lows, name=f"adversarial-{kind}", psd_check=False)


def scaling_case(i: int, seed: int) -> tuple[lcpbench.LCP, dict]:
    """Case ``i`` of the ``scaling`` group: a badly scaled problem that has a solution."""
    rng = np.random.default_rng([seed, i, 2])
    kind = GROUPS["scaling"][i % 4]
    n = int(rng.integers(3, 41))
    if kind == "spike":
        v = rng.standard_normal(n)
        v /= np.linalg.norm(v)
        A = 10 ** rng.uniform(-2, 0) * np.eye(n) + 10 ** rng.uniform(6, 11) * np.outer(v, v)
        b = _planted(rng, A) if rng.random() < 0.5 else rng.standard_normal(n)
    elif kind == "diagonal":
        S = random_spd_matrix(rng, n, float(10 ** rng.uniform(0, 3)))
        D = 10 ** rng.uniform(-4, 4, n)
        A = (D[:, None] * S) * D[None, :]
        b = _planted(rng, A) if rng.random() < 0.5 else D * rng.standard_normal(n)
    elif kind == "psd-planted":
        J = rng.standard_normal((n, max(1, n // 3))) * 10 ** rng.uniform(-3, 3)
        A = J @ J.T
        b = _planted(rng, A)
    else:
        lam = np.r_[10 ** rng.uniform(-12, -7), np.geomspace(1e-2, 1.0, n - 1)]
        Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
        A = (Q * lam) @ Q.T * 10 ** rng.uniform(-4, 6)
        b = rng.standard_normal(n)
    A = (A + A.T) / 2
    lcp = _with_lows(rng, lcpbench.Operator(A, cost=1.0), A, b, kind)
    return lcp, {"kind": kind, "solvable": True, "x0": _start(rng, n, i)}


def _positive_low_mode(rng: np.random.Generator, n: int) -> np.ndarray:
    """SPD, condition 10^U(8, 14), the smallest eigenvalue's eigenvector positive."""
    u = rng.uniform(0.5, 1.5, n)
    G = rng.standard_normal((n, n))
    G[:, 0] = u
    Q, _ = np.linalg.qr(G)
    Q[:, 0] *= np.sign(Q[0, 0])                    # the first column is u / ||u|| > 0
    lam = np.r_[1.0, np.geomspace(10 ** rng.uniform(8, 14), 1.0, n - 1)[::-1]]
    lam[1:] = np.maximum(lam[1:], 2.0)
    A = (Q * lam) @ Q.T
    return (A + A.T) / 2


class _Overwriting(LinearOperator):
    """``M v`` solved as ``inv(M)^-1 v`` in place: the operator overwrites its input."""

    def __init__(self, M: np.ndarray):
        super().__init__(np.float64, M.shape)
        self.factor = cho_factor(np.linalg.inv(M))

    def _matvec(self, v):
        return cho_solve(self.factor, np.ravel(v), overwrite_b=True, check_finite=False)


def _slow(M: np.ndarray):
    def apply(v):
        time.sleep(SLOW_PRODUCT_S)
        return M @ np.ravel(v)
    return apply


def operators_case(i: int, seed: int) -> tuple[lcpbench.LCP, dict]:
    """Case ``i`` of the ``operators`` group; every problem has a solution."""
    rng = np.random.default_rng([seed, i, 3])
    kind = GROUPS["operators"][i % 5]
    n = int(rng.integers(2, 31))
    op = None
    if kind == "ill-definite":
        A = _positive_low_mode(rng, n)
        b = _planted(rng, A) if rng.random() < 0.5 else rng.standard_normal(n)
    elif kind == "nonsymmetric":
        J = rng.standard_normal((n, n))
        K = rng.standard_normal((n, n)) * 10 ** rng.uniform(-2, 1)
        A = J @ J.T / n + (K - K.T)
        b = _planted(rng, A)
        op = LinearOperator((n, n), matvec=lambda v, A=A: A @ np.ravel(v), dtype=np.float64)
    elif kind == "duplicated":
        m = int(rng.integers(max(1, n // 2), n + 1))
        D = rng.standard_normal((3 * m, m))
        D = D[:, rng.integers(0, m, n)]            # n contacts, some of them the same one
        M = random_spd_matrix(rng, 3 * m, float(10 ** rng.uniform(0, 3)))
        A = D.T @ M @ D
        A = (A + A.T) / 2
        b = _planted(rng, A)
    else:
        A = random_spd_matrix(rng, n, float(10 ** rng.uniform(0, 4)))
        b = _planted(rng, A)
        op = _Overwriting(A) if kind == "mutating" else \
            LinearOperator((n, n), matvec=_slow(A), dtype=np.float64)
    high = lcpbench.Operator(A if op is None else op, cost=1.0)
    lcp = _with_lows(rng, high, (A + A.T) / 2, b, kind)     # the lows: symmetric models
    return lcp, {"kind": kind, "solvable": True, "x0": _start(rng, n, i // 5 * 4)}


def _metadata_set(seed: int) -> bytes:
    """The bytes of the small stored set the ``metadata`` cases flip bits of (made once)."""
    if seed not in _METADATA_SET:
        import tempfile

        from lcpbench.sets import SetWriter

        rng = np.random.default_rng([seed, 4])
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "meta.h5")
            with SetWriter(path, title="adversarial", description="bit flips",
                           generator="benchmarks/adversarial.py --group metadata") as w:
                for k in range(2):
                    A = random_spd_matrix(rng, 6, 100.0)
                    b = _planted(rng, A)
                    w.write_instance(f"step{k:05d}", A, b,
                                     low={"p4": (A + 1e-3 * np.eye(6), 0.1, {"p": 4})},
                                     reference={"x": np.zeros(6), "w": b, "kkt_abs": 0.0,
                                                "solvers": ["clarabel", "proxqp"]},
                                     attrs={"step": k, "M": 8, "t_mvp_high": 0.01})
            with open(path, "rb") as fh:
                _METADATA_SET[seed] = fh.read()
    return _METADATA_SET[seed]


def metadata_case(i: int, seed: int) -> tuple[str, str, str]:
    """``(kind, outcome, detail)`` of case ``i`` of the ``metadata`` group."""
    import tempfile

    from lcpbench.sets import StoredSetError, read_set

    rng = np.random.default_rng([seed, i, 5])
    kind = GROUPS["metadata"][i % 3]
    data = _metadata_set(seed)
    spots = [pos for needle in METADATA_NEEDLES[kind]
             for start in _occurrences(data, needle)
             for pos in range(max(0, start - 16), min(len(data), start + len(needle) + 16))]
    pos, bit = int(spots[int(rng.integers(len(spots)))]), int(rng.integers(8))
    flipped = bytearray(data)
    flipped[pos] ^= 1 << bit
    where = f"case {i}: byte {pos} bit {bit}"
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "flipped.h5")
        with open(path, "wb") as fh:
            fh.write(bytes(flipped))
        try:
            lcps = read_set(path)
        except StoredSetError as exc:
            text = str(exc)
            return kind, ("refused" if "\n" not in text else "crash"), f"{where}: {text[:200]}"
        except Exception:
            return kind, "crash", f"{where}: {traceback.format_exc(limit=3)}"
    return kind, "silent", f"{where}: loaded {len(lcps)} instance(s)"


def _occurrences(data: bytes, needle: bytes) -> list[int]:
    out, at = [], data.find(needle)
    while at >= 0:
        out.append(at)
        at = data.find(needle, at + 1)
    return out


def _start(rng: np.random.Generator, n: int, i: int) -> np.ndarray:
    which = STARTS[(i // 4) % len(STARTS)]
    x0 = np.zeros(n)
    if which == "one-1e300":
        x0[int(rng.integers(n))] = 1e300
    elif which == "huge":
        x0 = 1e12 * rng.random(n)
    elif which == "negative":
        x0 = -10 ** rng.uniform(0, 300, n)
    elif which == "tiny":
        x0 = np.full(n, 1e-300)
    elif which == "all-1e150":
        x0 = np.full(n, 1e150)
    return x0


def own_residuals(lcp: lcpbench.LCP, x: np.ndarray) -> tuple[float, float]:
    """``||min(x, A x + b)||`` from one more product of the operator, in float64 and long double."""
    Ax = np.asarray(apply_uncounted(lcp.A, x))
    w64 = Ax.astype(np.float64) + lcp.b
    wld = Ax.astype(np.longdouble) + lcp.b.astype(np.longdouble)
    r64 = float(np.sqrt(np.sum(np.minimum(x, w64) ** 2)))
    rld = float(np.sqrt(np.sum(np.minimum(x.astype(np.longdouble), wld) ** 2)))
    return r64, rld


def classify(res: lcpbench.SolveResult, lcp: lcpbench.LCP, solvable: bool) -> str:
    """``refuted`` / ``false-infeasible`` / ``converged`` / ``infeasible`` / ``other``."""
    if res.status.value == "converged":
        own = own_residuals(lcp, res.x)
        if not (res.verified_kkt_abs <= res.threshold and max(own) <= res.threshold):
            return "refuted"
        return "converged"
    if res.status.value == "infeasible":
        return "false-infeasible" if solvable else "infeasible"
    return "other"


def group_solvers(group: str) -> list[str]:
    """The solvers a group runs: the MVP-only ones, and the dense ones on ``operators``;
    the ``metadata`` group runs the reader only."""
    if group == "metadata":
        return ["(reader)"]
    return mvp_solvers() + (list(DENSE_EXTRA) if group == "operators" else [])


def run_case(args: tuple) -> list[tuple[str, str, str, str]]:
    """``(kind, solver, outcome, detail)`` for each solver on case ``i`` of ``group``."""
    i, seed, group, only, max_emvps, max_seconds = args
    if group == "metadata":
        t0 = time.perf_counter()
        kind, outcome, detail = metadata_case(i, seed)
        if time.perf_counter() - t0 > 2 * max_seconds + 5:
            outcome = "hang"
        return [(kind, "(reader)", outcome, detail)]
    make = {"accuracy": accuracy_case, "scaling": scaling_case, "operators": operators_case}
    try:
        lcp, meta = make[group](i, seed)
    except Exception:
        return [("?", "(generator)", "crash", traceback.format_exc(limit=3))]
    out = []
    for name in group_solvers(group):
        if only and name not in only:
            continue
        t0 = time.perf_counter()
        try:
            res = lcpbench.solve(lcp, solver=MULTI.get(name, name), tol=1e-8,
                                 max_emvps=max_emvps, max_seconds=max_seconds,
                                 x0=meta.get("x0"))
            outcome = classify(res, lcp, meta["solvable"])
            detail = f"case {i}: {res.summary()} | {res.message[:300]}"
        except Exception:
            outcome, detail = "crash", f"case {i}: {traceback.format_exc(limit=3)}"
        wall = time.perf_counter() - t0
        if wall > 2 * max_seconds + 5:
            outcome, detail = "hang", f"case {i}: {wall:.1f} s | {detail}"
        out.append((meta["kind"], name, outcome, detail))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--group", choices=sorted(GROUPS), required=True)
    ap.add_argument("--cases", type=int, default=250)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--solvers", nargs="+", metavar="NAME")
    ap.add_argument("--max-emvps", type=float, default=300.0)
    ap.add_argument("--max-seconds", type=float, default=5.0)
    args = ap.parse_args()
    if args.cases < 1 or args.jobs < 1 or args.start < 0:
        ap.error("--cases and --jobs must be >= 1, --start >= 0")
    only = tuple(args.solvers or ())
    unknown = set(only) - set(group_solvers(args.group))
    if unknown:
        ap.error(f"--solvers: {sorted(unknown)} are not solvers of group {args.group}: "
                 f"{group_solvers(args.group)}")
    work = [(i, args.seed, args.group, only, args.max_emvps, args.max_seconds)
            for i in range(args.start, args.start + args.cases)]
    counts: Counter = Counter()
    problems: list[str] = []
    with Pool(args.jobs) as pool:
        for rows in pool.imap_unordered(run_case, work, chunksize=2):
            for kind, name, outcome, detail in rows:
                counts[(name, outcome)] += 1
                counts[(kind, outcome)] += 0
                if outcome in ("refuted", "false-infeasible", "crash", "hang", "silent"):
                    problems.append(f"{name} on {kind} {detail}")
    return report(args, counts, problems)


def report(args, counts: Counter, problems: list[str]) -> int:
    """Print the table; 1 if any claim was false or a run crashed."""
    head = (f"group {args.group}, cases {args.start}..{args.start + args.cases - 1} (seed "
            f"{args.seed}), tol 1e-8, paper's stop rule, budget {args.max_emvps:g} E-MVPs and "
            f"{args.max_seconds:g} s per solve")
    outcomes = ("converged", "refuted", "infeasible", "false-infeasible", "other", "crash",
                "hang", "refused", "silent")
    names = [n for n in group_solvers(args.group) if any(counts[(n, o)] for o in outcomes)]
    return print_outcomes(head, counts, names, {o: o for o in outcomes}, problems=problems,
                          bad={"refuted": "refuted converged",
                               "false-infeasible": "false infeasible", "crash": "crashes",
                               "hang": "hangs", "silent": "silent bit flips"})


if __name__ == "__main__":
    sys.exit(main())
