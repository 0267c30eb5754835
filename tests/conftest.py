"""Fixtures shared by several test files."""

import importlib.util
import pathlib

import numpy as np
import pytest
from threadpoolctl import threadpool_limits


# ---------------------------------------------------------------------- shared helpers
@pytest.fixture
def one_blas_thread():
    """Run the test with one BLAS thread.

    The LCPs of the solver tests are small (n <= 300): a threaded BLAS gains nothing on
    them, and on a machine whose cores are busy its spinning threads make each product
    5-20 times slower (the hard-case test took minutes instead of seconds). One thread
    also makes the rounding of every product independent of the machine's core count.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        yield


@pytest.fixture
def benchmark_script(monkeypatch):
    """``load(name)``: the module of ``benchmarks/NAME.py`` (the scripts are not a package;
    their folder is on ``sys.path`` for the test, as when a script runs)."""
    folder = pathlib.Path(__file__).resolve().parents[1] / "benchmarks"
    monkeypatch.syspath_prepend(str(folder))

    def load(name: str):
        path = folder / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load


@pytest.fixture
def true_residual():
    """``residual(lcp, x) = ||min(x, A x + b)||`` from the explicit matrix, outside the framework.

    Tests compare the framework's verified residual and statuses with this plain numpy
    value, so a verification that used the solver's own ``w`` (or a stale product) fails.
    """
    def residual(lcp, x) -> float:
        x = np.asarray(x, dtype=float)
        return float(np.linalg.norm(np.minimum(x, lcp.dense() @ x + lcp.b)))

    return residual


@pytest.fixture(autouse=True, scope="session")
def _user_cache_in_tmp(tmp_path_factory):
    """The user cache (``XDG_CACHE_HOME``: the report's fidelity study) in a temporary folder.

    No test writes to the real home; a test that checks the cache itself points
    ``XDG_CACHE_HOME`` at its own ``tmp_path``.
    """
    patch = pytest.MonkeyPatch()
    patch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("xdg-cache")))
    yield
    patch.undo()
