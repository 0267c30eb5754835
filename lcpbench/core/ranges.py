"""Index selections written as text: ``"31-50"``, ``"0,3,5-7"`` (inclusive ranges)."""

from __future__ import annotations

import re
from collections.abc import Iterable

__all__ = ["parse_ranges", "format_ranges"]

_PART = re.compile(r"(\d+)(?:\s*-\s*(\d+))?")


def parse_ranges(spec: str, what: str, example: str = "0-9 or 0,3,5-7") -> list[int]:
    """Non-negative indices from comma-separated numbers and inclusive ranges.

    Parameters
    ----------
    spec : str
        E.g. ``"31-50"`` or ``"0,3,5-7"``; blanks around items are ignored.
    what : str
        Name used in error messages (``"--steps"``, ``"instances"``).
    example : str
        Example shown in error messages.

    Returns
    -------
    list of int
        In the order written, without repeats.

    Raises
    ------
    ValueError
        An item that is not a number or range, or a reversed range.
    """
    out: list[int] = []
    for part in spec.split(","):
        part = part.strip()
        m = _PART.fullmatch(part)
        if not m:
            raise ValueError(f"{what}: cannot parse {part!r}; use indices and inclusive ranges "
                             f"like {example}")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) else lo
        if hi < lo:
            raise ValueError(f"{what}: range {part!r} is reversed; write it as {hi}-{lo}")
        out.extend(i for i in range(lo, hi + 1) if i not in out)
    return out


def format_ranges(indices: Iterable[int], sep: str = ",") -> str:
    """The inverse of :func:`parse_ranges`: ``[0, 1, 2, 5]`` -> ``"0-2,5"`` (sorted,
    consecutive runs as ranges, parts joined by ``sep``)."""
    parts: list[str] = []
    run: list[int] = []
    for k in sorted(indices):
        if run and k == run[-1] + 1:
            run.append(k)
            continue
        if run:
            parts.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
        run = [k]
    if run:
        parts.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
    return sep.join(parts)
