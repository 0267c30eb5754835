"""The measured quadrature-error tables are kept on disk, validated on read."""

from __future__ import annotations

import numpy as np
import pytest

from lcpbench.problems.suspension.bim import sphere_vsh


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty cache folder and an empty in-process memo."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    sphere_vsh._error_table.cache_clear()
    yield tmp_path / "lcpbench" / "quadrature"
    sphere_vsh._error_table.cache_clear()


def _count_measurements(monkeypatch) -> list:
    calls: list = []
    real = sphere_vsh.quadrature_errors

    def counted(*args, **kwargs):
        calls.append(args[:2])
        return real(*args, **kwargs)

    monkeypatch.setattr(sphere_vsh, "quadrature_errors", counted)
    return calls


def test_a_new_process_reads_the_table_from_disk(fresh_cache, monkeypatch):
    calls = _count_measurements(monkeypatch)
    first = sphere_vsh.quadrature_radius(3, 4, 1e-8)
    table = sphere_vsh._error_table(3, 4).copy()
    assert calls == [(3, 4)]
    files = sorted(fresh_cache.glob("*.npz"))
    assert len(files) == 1 and "p3-q4-seed0" in files[0].name
    assert not list(fresh_cache.glob("*.tmp"))            # the temporary file was renamed
    sphere_vsh._error_table.cache_clear()                  # as a new process would start
    assert sphere_vsh.quadrature_radius(3, 4, 1e-8) == first
    assert calls == [(3, 4)]                               # read, not measured again
    np.testing.assert_array_equal(sphere_vsh._error_table(3, 4), table)


@pytest.mark.parametrize("damage", ["garbage", "other_grid", "other_key"])
def test_a_damaged_or_foreign_table_is_rebuilt_with_a_warning(fresh_cache, monkeypatch, damage):
    calls = _count_measurements(monkeypatch)
    good = sphere_vsh._error_table(2, 4).copy()
    path = next(fresh_cache.glob("*.npz"))
    if damage == "garbage":
        path.write_bytes(b"not an npz file")
    elif damage == "other_grid":
        np.savez(path, p=2, q=4, seed=0, version=sphere_vsh.QUADRATURE_CACHE_VERSION,
                 rho=sphere_vsh.RHO_GRID * 1.01, errors=good)
    else:
        np.savez(path, p=3, q=4, seed=0, version=sphere_vsh.QUADRATURE_CACHE_VERSION,
                 rho=sphere_vsh.RHO_GRID, errors=good * 0)
    sphere_vsh._error_table.cache_clear()
    with pytest.warns(RuntimeWarning, match="not valid.*measuring it again"):
        again = sphere_vsh._error_table(2, 4)
    np.testing.assert_array_equal(again, good)
    assert len(calls) == 2
    sphere_vsh._error_table.cache_clear()                  # the rewritten file is valid
    np.testing.assert_array_equal(sphere_vsh._error_table(2, 4), good)
    assert len(calls) == 2


def test_an_unwritable_cache_warns_and_still_answers(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder would go")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    sphere_vsh._error_table.cache_clear()
    try:
        with pytest.warns(RuntimeWarning, match="cannot keep the quadrature-error table"):
            radius = sphere_vsh.quadrature_radius(2, 2, 1e-6)
    finally:
        sphere_vsh._error_table.cache_clear()
    assert np.isfinite(radius) and radius > 1
