"""Which solvers share a figure panel: at most :data:`MAX_CURVES` curves in any panel.

A panel of fourteen near-identical curves cannot be read. The solvers of one set are
split into panels: the variants of one solver family (``bi-pqn:low=p3e6``,
``bi-pqn:low=p4e6``, ...) in panels of their own, with the baseline beside them as the
common reference, and the solvers without variants together; each group is cut into
panels of at most :data:`MAX_CURVES` curves, as evenly as possible.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

__all__ = ["MAX_CURVES", "family", "panel_groups"]

#: Most curves drawn in one panel.
MAX_CURVES = 7


def family(solver: str) -> str:
    """The solver family of a spec: ``bi-pqn`` of ``bi-pqn:low=p4e6``; a label's
    parenthesised suffix (``bb-pgd (cold)``) is not part of it."""
    return solver.split(" (")[0].split(":", 1)[0]


def _even_chunks(items: list[str], size: int) -> list[list[str]]:
    if not items:
        return []
    parts = math.ceil(len(items) / size)
    step = math.ceil(len(items) / parts)
    return [items[k:k + step] for k in range(0, len(items), step)]


def panel_groups(solvers: Iterable[str], baseline: str | None = None,
                 max_curves: int = MAX_CURVES) -> list[tuple[str, list[str]]]:
    """Split ``solvers`` into panels of at most ``max_curves``: ``[(title, solvers)]``.

    The first panels hold the solvers whose family has one spec (the baseline among
    them); then, per family with several specs, its specs (the baseline added to each
    such panel when it is among ``solvers``). Titles are ``""`` when everything fits in
    one panel, else the family's name or ``"single solvers"``, numbered when split.
    No solver, no panel.
    """
    names = sorted(dict.fromkeys(solvers))
    if not names:
        return []
    if len(names) <= max_curves:
        return [("", names)]
    by_family: dict[str, list[str]] = {}
    for s in names:
        by_family.setdefault(family(s), []).append(s)
    singles = [v[0] for v in by_family.values() if len(v) == 1]
    groups: list[tuple[str, list[str]]] = []
    for k, chunk in enumerate(_even_chunks(singles, max_curves)):
        groups.append((f"single solvers{_part(k, singles, max_curves)}", chunk))
    base = [baseline] if baseline is not None and baseline in names else []
    room = max_curves - len(base)
    for fam, specs in sorted(by_family.items()):
        if len(specs) < 2:
            continue
        for k, chunk in enumerate(_even_chunks(specs, room)):
            groups.append((f"{fam} variants{_part(k, specs, room)}", base + chunk))
    return groups


def _part(k: int, items: list[str], size: int) -> str:
    parts = math.ceil(len(items) / size)
    return f" ({k + 1} of {parts})" if parts > 1 else ""
