"""The shape of the code, checked on the source tree (AST, no imports): no import circle,
no module over 600 lines, no function body over 80 lines (docstring excluded) and no
function with more than 8 positional parameters outside numba kernels.

The EXEMPT tables below are empty: a new offender must be fixed, not listed (nothing under
``problems/suspension/`` nor ``lcpbench/workflows/simulate.py`` / ``generate.py`` may ever be
listed). An entry that no longer offends fails the test, so the tables only shrink.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Source folders and the package each is installed as (pyproject.toml's package-dir).
PACKAGES = {"lcpbench": "lcpbench", "problems": "lcpbench.problems",
            "solvers": "lcpbench.solvers"}

MAX_MODULE_LINES = 600
MAX_BODY_LINES = 80
MAX_POSITIONAL = 8

#: Files that may never be exempt.
NEVER_EXEMPT = ("problems/suspension/", "lcpbench/workflows/simulate.py",
                "lcpbench/workflows/generate.py")

#: Functions whose body is longer than MAX_BODY_LINES: "path::qualified name".
EXEMPT_LONG: set = set()

#: Functions with more than MAX_POSITIONAL positional parameters.
EXEMPT_POSITIONAL: set = set()

#: Modules longer than MAX_MODULE_LINES.
EXEMPT_MODULES: set = set()


def _sources() -> list[Path]:
    return sorted(p for top in PACKAGES for p in (ROOT / top).rglob("*.py"))


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    parts[0] = PACKAGES[parts[0]]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _functions(tree: ast.AST, prefix: str = ""):
    """``(qualified name, node)`` of every function, methods and nested ones included."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            name = f"{prefix}{node.name}"
            yield name, node
            yield from _functions(node, name + ".")
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, f"{prefix}{node.name}.")
        else:
            yield from _functions(node, prefix)


def _body_lines(node: ast.FunctionDef) -> int:
    """Lines of a function's body from its first statement after the docstring."""
    body = node.body
    if (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)):
        body = body[1:]
    if not body:
        return 0
    return body[-1].end_lineno - body[0].lineno + 1


def _is_numba(node: ast.FunctionDef) -> bool:
    """Decorated by a numba compiler (``@njit``, ``@numba.jit(...)``, ``@_kernel(...)``
    aliases that call ``njit``)."""
    for dec in node.decorator_list:
        target = dec.func if isinstance(dec, ast.Call) else dec
        text = ast.unparse(target)
        if any(k in text for k in ("njit", "jit", "numba", "_kernel", "vectorize")):
            return True
    return False


def _positional(node: ast.FunctionDef) -> int:
    args = node.args
    names = [a.arg for a in args.posonlyargs + args.args]
    if names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names)


def _imports(path: Path, tree: ast.AST) -> set[str]:
    """Every module this file imports, at any level (type-checking imports included)."""
    me = _module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)   # from pkg import module
    return out


def _graph() -> dict[str, set[str]]:
    trees = {p: ast.parse(p.read_text(), filename=str(p)) for p in _sources()}
    names = {_module_name(p): p for p in trees}
    graph = {}
    for path, tree in trees.items():
        me = _module_name(path)
        graph[me] = {m for m in _imports(path, tree) if m in names and m != me}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_exempt_tables_name_no_protected_file():
    for key in EXEMPT_LONG | EXEMPT_POSITIONAL | EXEMPT_MODULES:
        assert not key.startswith(NEVER_EXEMPT), key


def test_no_import_circle():
    cycles = _cycles(_graph())
    assert not cycles, "modules that import each other in a circle: " + "; ".join(
        ", ".join(c) for c in cycles)


def test_the_circle_check_sees_a_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]


def _module_map(package: Path) -> list[str]:
    """The modules a package docstring's map names (``* :mod:`.name```, in order)."""
    doc = ast.get_docstring(ast.parse((package / "__init__.py").read_text())) or ""
    out: list[str] = []
    for line in doc.splitlines():
        if line.startswith("* "):
            for part in line[2:].split(": ", 1)[0].split(", "):
                if part.startswith(":mod:`.") and part.endswith("`"):
                    out.append(part[len(":mod:`."):-1])
    return out


def test_the_bim_module_map_matches_the_code():
    """The boundary-integral package's one module map (its docstring) names every module
    once, and every import between them points further down the map."""
    package = ROOT / "problems/suspension/bim"
    order = _module_map(package)
    modules = sorted(p.stem for p in package.glob("*.py") if p.stem != "__init__")
    assert sorted(order) == modules, (sorted(order), modules)
    graph = _graph()
    prefix = "lcpbench.problems.suspension.bim."
    up = [(a, b) for a in order for b in sorted(graph[prefix + a])
          if b.startswith(prefix) and order.index(b[len(prefix):]) <= order.index(a)]
    assert not up, f"imports up the module map: {up}"


def test_modules_are_at_most_600_lines():
    long = {_rel(p): len(p.read_text().splitlines()) for p in _sources()}
    bad = {k: v for k, v in long.items() if v > MAX_MODULE_LINES and k not in EXEMPT_MODULES}
    assert not bad, bad
    stale = {k for k in EXEMPT_MODULES if long.get(k, 0) <= MAX_MODULE_LINES}
    assert not stale, f"no longer too long, remove from EXEMPT_MODULES: {stale}"


def _compiled_names(tree: ast.AST) -> set[str]:
    """Functions compiled by a call such as ``njit(parallel=True)(_kernel_impl)`` or
    ``parallel_and_serial(_kernel_impl)`` (``bim/jit.py``, which calls ``njit``)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and (
                (isinstance(node.func, ast.Call) and "jit" in ast.unparse(node.func.func))
                or (isinstance(node.func, ast.Name) and node.func.id == "parallel_and_serial")):
            out.update(a.id for a in node.args if isinstance(a, ast.Name))
    return out


#: Generated modules (their generator is the source to read and is held to the rules):
#: the pair frame's inner loops, one statement per column of a panel.
GENERATED = {"problems/suspension/bim/panel_kernels.py"}


def _offenders(check) -> set[str]:
    out = set()
    for path in _sources():
        if _rel(path) in GENERATED:
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        compiled = _compiled_names(tree)
        for name, node in _functions(tree):
            if check(node, name in compiled):
                out.add(f"{_rel(path)}::{name}")
    return out


@pytest.mark.parametrize("rule", ["body", "positional"])
def test_functions_are_short_and_take_few_positional_parameters(rule):
    if rule == "body":
        found = _offenders(lambda n, compiled: _body_lines(n) > MAX_BODY_LINES)
        exempt = EXEMPT_LONG
    else:
        found = _offenders(lambda n, compiled: _positional(n) > MAX_POSITIONAL
                           and not (compiled or _is_numba(n)))
        exempt = EXEMPT_POSITIONAL
    bad = sorted(found - exempt)
    assert not bad, f"{rule}: {bad}"
    stale = sorted(exempt - found)
    assert not stale, f"{rule}: no longer offending, remove from the exempt table: {stale}"
