"""``lcpbench list``: the registered solvers, problem families and scenes (``--full``: with
their parameters)."""

from __future__ import annotations

import argparse
import json
import textwrap

import numpy as np

from lcpbench.core.registry import problems, scenes, solvers
from lcpbench.core.specs import describe_params

__all__ = ["add_list_parser", "cmd_list"]


_LIST_DESCRIPTION = """
List every registered solver, problem family and scene, one line each; --full adds every
parameter with its type, default and documentation.
"""


def add_list_parser(sub) -> None:
    """Add ``lcpbench list`` to the subcommands ``sub``."""
    p = sub.add_parser("list", help="registered solvers, problem families and scenes",
                       description=_LIST_DESCRIPTION)
    p.add_argument("what", nargs="?", choices=("solvers", "problems", "scenes", "all"),
                   default="all")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--full", action="store_true",
                   help="every parameter with its type, default and documentation")
    # The listing is brief by default; --brief stays accepted for scripts that pass it.
    p.add_argument("--brief", action="store_true", help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_list)


def _entry(info, kind: str) -> dict:
    out = {"name": info.name, "kind": kind, "summary": info.summary,
           "params": [{"name": n, "type": t, "default": _jsonable(d), "doc": doc}
                      for n, t, d, doc in describe_params(info.params)]}
    if kind == "solver":
        out.update(needs_dense=info.needs_dense, reference=info.reference,
                   multifidelity=info.multifidelity)
    elif kind == "problem":
        out["default"] = info.default
    return out


def _jsonable(v):
    if isinstance(v, (tuple, list)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


def _tags(e: dict) -> str:
    tags = []
    if e["kind"] == "solver":
        if e["reference"]:
            tags.append("reference")
        if e["needs_dense"]:
            tags.append("needs dense A")
        if e["multifidelity"]:
            tags.append("multi-fidelity")
    elif e.get("default"):
        tags.append("default set")
    return f"  [{', '.join(tags)}]" if tags else ""


def cmd_list(args: argparse.Namespace) -> int:
    entries = []
    if args.what in ("solvers", "all"):
        entries += [_entry(i, "solver") for _, i in sorted(solvers().items())
                    if i.listed]
    if args.what in ("problems", "all"):
        entries += [_entry(i, "problem") for _, i in sorted(problems().items())]
    if args.what in ("scenes", "all"):
        entries += [_entry(i, "scene") for _, i in sorted(scenes().items())]
    if args.json:
        print(json.dumps(entries, indent=2, default=str))
        return 0
    kind = None
    for e in entries:
        if e["kind"] != kind:
            kind = e["kind"]
            title = {"solver": "Solvers", "problem": "Problem families",
                     "scene": "Scenes (lcpbench simulate / generate --scene)"}[kind]
            print(f"\n{title}:")
        print(f"  {e['name']:<16} {e['summary']}{_tags(e)}")
        if not args.full:
            continue
        for prm in e["params"]:
            print(f"      {prm['name']}: {prm['type']} = {prm['default']!r}")
            if prm["doc"]:
                print(textwrap.fill(prm["doc"], width=100, initial_indent=" " * 10,
                                    subsequent_indent=" " * 10, break_on_hyphens=False))
    print("\nUse as NAME:key=value,...  e.g.  bi-pqn:low=p4,inner_rtol=0.01")
    if not args.full:
        print("Every parameter: lcpbench list --full [solvers|problems|scenes]")
    return 0
