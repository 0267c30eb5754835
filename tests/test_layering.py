"""The framework never reaches into its plugins: no imports of them, no plugin names in its code."""

import ast
from pathlib import Path

import lcpbench
from lcpbench.core.registry import scenes, solvers

FRAMEWORK = Path(lcpbench.__file__).resolve().parent


def _modules():
    return sorted(p for p in FRAMEWORK.rglob("*.py"))


def _docstring_nodes(tree):
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def test_framework_modules_exist():
    # the package this test reads is the installed framework, and it has its parts
    names = {p.relative_to(FRAMEWORK).parts[0] for p in _modules()}
    assert {"core", "toolkit", "run", "report", "cli", "workflows", "sets"} <= names


def test_no_framework_module_imports_a_plugin():
    bad = []
    for path in _modules():
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                mods = [node.module or ""]
                if node.module == "lcpbench":
                    mods += [f"lcpbench.{a.name}" for a in node.names]
            else:
                continue
            for m in mods:
                if m.split(".")[0] in ("problems", "solvers") or \
                        m.startswith(("lcpbench.problems", "lcpbench.solvers")):
                    bad.append(f"{path.relative_to(FRAMEWORK)}:{node.lineno} imports {m}")
    assert not bad, "\n".join(bad)


def test_no_framework_code_names_a_plugin():
    """Solver and scene names appear in framework code only in ``core/defaults.py``.

    (The QP back-ends of qpsolvers, such as ``clarabel``, are library names: the framework
    calls qpsolvers with them for its consensus references.)
    """
    import qpsolvers

    plugin_names = set(solvers()) | set(scenes())
    assert {"mono-pqn", "bi-pqn", "bb-pgd", "lattice"} <= plugin_names   # plugins are loaded
    plugin_names -= set(qpsolvers.available_solvers)
    bad = []
    for path in _modules():
        if path.relative_to(FRAMEWORK).as_posix() == "core/defaults.py":
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        docs = _docstring_nodes(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and id(node) not in docs:
                text = node.value.strip()
                name = text.split(":", 1)[0]
                if name in plugin_names and (text == name or ":" in text) and " " not in text:
                    bad.append(f"{path.relative_to(FRAMEWORK)}:{node.lineno} names {text!r}")
    assert not bad, "\n".join(bad)


def test_an_unlisted_solver_runs_by_name_but_joins_no_default(capsys):
    from dataclasses import dataclass

    import numpy as np

    from lcpbench import register_solver
    from lcpbench.cli import main
    from lcpbench.run.sweep import default_sweep
    from lcpbench.workflows.check import default_specs

    @dataclass(frozen=True)
    class _Params:
        """No parameters."""

    @register_solver("test-unlisted", _Params, listed=False)
    def _unlisted(ctx, p):
        """Returns the start."""
        x = np.zeros(ctx.n)
        return ctx.finish(x, ctx.A @ x + ctx.b)

    res = lcpbench.solve(np.eye(2), np.ones(2), solver="test-unlisted")
    assert res.solved                                  # runnable by name
    assert "test-unlisted" not in default_sweep()[0]
    assert not any(s.startswith("test-unlisted") for s in default_specs(["low"]))
    assert main(["list", "solvers"]) == 0
    assert "test-unlisted" not in capsys.readouterr().out


def test_every_shipped_scene_meets_the_scene_protocol():
    """The scene contract is code (lcpbench.core.scene): every registered scene provides
    the members of ``Scene`` with the documented signatures, declares its fidelity knobs,
    and its ``build`` returns a ``SceneProblem``."""
    import inspect

    from lcpbench.core.registry import make_scene
    from lcpbench.core.scene import FidelityAxes, Scene, SceneProblem

    members = [n for n in dir(Scene) if not n.startswith("_")]
    assert {"build", "advance", "get_state", "set_state", "fidelity_knobs", "carry_memory",
            "keep_memory", "M", "radii", "step_index", "params",
            "fidelity_axes"} <= set(members) | set(Scene.__annotations__)
    for name in scenes():
        scene = make_scene(f"{name}:m=2,model=rpy")
        assert isinstance(scene, Scene), name
        for member in members:
            want = getattr(Scene, member)
            if callable(want) and not isinstance(want, property):
                got = inspect.signature(getattr(scene, member)).parameters
                assert list(inspect.signature(want).parameters)[1:] == list(got)[:len(
                    inspect.signature(want).parameters) - 1], (name, member)
        assert isinstance(scene.fidelity_axes, FidelityAxes)
        knobs = scene.fidelity_knobs("rpy")
        assert {scene.fidelity_axes.rows, scene.fidelity_axes.columns,
                scene.fidelity_axes.model_knob} <= set(knobs)
        problem = scene.build()
        assert isinstance(problem, SceneProblem), name
        assert len(problem.pairs) == problem.lcp.n
        # the framework reads the declared knobs from the registry, without a spec
        from lcpbench.core.registry import get_scene
        assert get_scene(name).fidelity_axes() == scene.fidelity_axes
