"""Wall-clock timestamps as the run store and stored sets write them."""

from __future__ import annotations

from datetime import datetime, timezone

__all__ = ["utc_now"]


def utc_now() -> str:
    """The current UTC time as ISO 8601 to the second (``2026-11-23T23:15:22+00:00``)."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")
