"""The available memory is read at most once per MEMORY_READING_SECONDS."""

import lcpbench.core.guards as guards


def test_a_memory_reading_is_reused_within_its_interval_and_renewed_after(monkeypatch):
    readings = iter([1e9, 2e9, 3e9])
    calls: list[float] = []

    def fake_read() -> float:
        calls.append(1.0)
        return next(readings)

    clock = [100.0]
    monkeypatch.setattr(guards, "_read_available_memory", fake_read)
    monkeypatch.setattr(guards.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(guards, "_memory_reading", [])
    assert guards.available_memory() == 1e9
    clock[0] += 0.5 * guards.MEMORY_READING_SECONDS
    assert guards.available_memory() == 1e9              # reused: no second reading
    assert len(calls) == 1
    clock[0] += guards.MEMORY_READING_SECONDS
    assert guards.available_memory() == 2e9              # the interval passed: read again
    assert len(calls) == 2
    assert guards.memory_limit() == guards.MEMORY_FRACTION * 2e9


def test_the_reading_itself_reports_a_positive_amount():
    assert guards._read_available_memory() > 0
