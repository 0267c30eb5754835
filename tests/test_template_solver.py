"""The documented solver template is a working plugin: through lcpbench.solve and lcpbench run."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd

TEMPLATE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "solver_template.py"


def _env():
    return {**os.environ, "LCPBENCH_PLUGINS": str(TEMPLATE)}


def test_template_solver_through_solve():
    code = (
        "import json, numpy as np, lcpbench\n"
        "rng = np.random.default_rng(3)\n"
        "Q = rng.standard_normal((40, 40)); A = Q @ Q.T / 40 + np.eye(40)\n"
        "b = rng.standard_normal(40)\n"
        "op = lcpbench.Operator(A, cost=1.0)\n"
        "res = lcpbench.solve(op, b, solver='template-pgd:max_iter=500', tol=1e-8)\n"
        "ref = lcpbench.reference(lcpbench.LCP(A, b))\n"
        "print(json.dumps({'status': res.status.value, 'solved': bool(res.solved),\n"
        "                  'mvps': res.mvps, 'emvps': res.emvps, 'iters': res.iterations,\n"
        "                  'err': float(np.max(np.abs(res.w - ref.w)))}))\n")
    out = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["status"] == "converged" and got["solved"]
    # one counted product for w0, then one per iteration (the template's own account)
    assert got["mvps"] >= 2 and got["emvps"] == got["mvps"]
    assert got["mvps"] in (got["iters"], got["iters"] + 1)
    assert got["err"] < 1e-6                                    # the reference's w


def test_template_solver_through_lcpbench_run(tmp_path):
    out_dir = tmp_path / "run"
    cmd = [sys.executable, "-m", "lcpbench.cli", "run", "--solver", "template-pgd",
           "--solver", "bb-pgd", "--problem", "random-spd:count=2,n_min=30,n_max=40",
           "--out", str(out_dir), "--quiet"]
    done = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    rows = pd.read_csv(out_dir / "results.csv")
    mine = rows[rows["solver_name"] == "template-pgd"]
    assert len(mine) == 2 and mine["solved"].all()
    assert (mine["mvps"] > 0).all()
    assert "template-pgd" in (out_dir / "report.html").read_text()
