"""Online E-MVPs from the cost model: identical runs give identical E-MVPs at every step."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from lcpbench.report import tables
from lcpbench.report.online_cost import with_model_emvps
from lcpbench.workflows.cost_model import CostModel, calibrate
from lcpbench.workflows.simulate import simulate

SCENE = "lattice:m=2,model=rpy,low=[self]"
SOLVERS = ["bi-pqn:low=self", "bb-pgd"]


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("cost")
    cache = root / "xdg"
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CACHE_HOME", str(cache))
    try:
        for k in (1, 2):
            simulate(SCENE, SOLVERS, 12, root / f"run{k}", progress=False)
    finally:
        mp.undo()
    return [(pd.read_csv(root / f"run{k}" / "results.csv"),
             json.loads((root / f"run{k}" / "meta.json").read_text())) for k in (1, 2)]


def test_two_identical_simulations_give_identical_emvps_at_every_step(two_runs):
    (a, meta_a), (b, meta_b) = two_runs
    key = ["solver", "step"]
    a, b = a.sort_values(key).reset_index(drop=True), b.sort_values(key).reset_index(drop=True)
    assert list(a["step"]) == list(b["step"]) and len(a) == 24
    assert a["model_emvps"].notna().all() and b["model_emvps"].notna().all()
    assert a["model_emvps"].tolist() == b["model_emvps"].tolist()
    # the constant was calibrated once, by the first run, and the second took it from the
    # cache; both stores record it
    ca = meta_a["cost_model"][SCENE]["self"]
    cb = meta_b["cost_model"][SCENE]["self"]
    assert ca["per_application"] == cb["per_application"] > 0
    assert ca["source"].startswith("calibrated on step") and "cached" in cb["source"]


def test_model_emvps_are_high_mvps_plus_applications_times_the_constant(two_runs):
    (a, meta), _ = two_runs
    c = meta["cost_model"][SCENE]["self"]["per_application"]
    bi = a[a["solver"] == "bi-pqn:low=self"]
    apps = [json.loads(t)["lofi_applications"].get("self", 0) for t in bi["info"]]
    assert any(apps)
    expect = bi["mvps"].to_numpy(float) + np.asarray(apps, float) * c
    assert np.allclose(bi["model_emvps"].to_numpy(float), expect, rtol=0, atol=1e-12)
    base = a[a["solver"] == "bb-pgd"]          # no low: the model is the high MVPs
    assert (base["model_emvps"] == base["mvps"]).all()


def test_report_uses_the_model_and_keeps_the_timed_figures(two_runs):
    (a, _), _ = two_runs
    paper = tables.online_paper_table(a, "bb-pgd")
    steps = tables.online_step_rows(a)
    bi = steps[steps["solver"] == "bi-pqn:low=self"]
    assert len(bi) and 0 not in set(bi["step"])      # warm-up and product-free steps apart
    row = paper.iloc[0]
    model = pd.to_numeric(a.set_index(["solver", "step"])["model_emvps"])
    timed = pd.to_numeric(a.set_index(["solver", "step"])["emvps"])
    keys = [("bi-pqn:low=self", s) for s in bi["step"]]
    assert row["bi-pqn:low=self median E-MVPs"] == pytest.approx(float(model[keys].median()))
    assert row["bi-pqn:low=self median timed E-MVPs"] == pytest.approx(
        float(timed[keys].median()))
    apart = tables.online_left_out(a)
    assert {0, 1, 2} <= {int(k) for s in apart["steps"] for k in str(s).split(",")}


def test_rows_without_the_model_keep_their_timed_emvps():
    old = pd.DataFrame({"emvps": [5.4, 5.66], "kind": "online"})
    assert with_model_emvps(old)["emvps"].tolist() == [5.4, 5.66]
    mixed = pd.DataFrame({"emvps": [5.4, 5.66], "model_emvps": [np.nan, 6.0]})
    out = with_model_emvps(mixed)
    assert out["emvps"].tolist() == [5.4, 6.0] and out["timed_emvps"].tolist() == [5.4, 5.66]


class _Result:
    def __init__(self, mvps, apps, seconds, cost):
        self.mvps, self.lofi_applications = mvps, apps
        self.info = {"operator_seconds": seconds, "operator_cost": cost}


def test_calibration_prices_an_application_in_cold_high_products(tmp_path):
    # the high costs 2 s a cold product; the low spent 3 s on 6 applications: 0.25 each
    res = _Result(4, {"p4": 6.0}, {"high": 8.0, "p4": 3.0}, {"high": 2.0, "p4": 1.0})
    assert calibrate(res) == {"p4": pytest.approx(0.25)}
    assert calibrate(_Result(0, {"p4": 6.0}, {"p4": 3.0}, {"p4": 1.0})) == {}   # no unit
    saved = []
    model = CostModel("scene", machine={"cpu": "x"}, cache_dir=tmp_path, persist=saved.append)
    assert np.isnan(model.emvps(res))                  # not calibrated yet: no number
    model.observe(res, "step 3")
    assert model.emvps(res) == pytest.approx(4 + 6 * 0.25) and saved
    # a later, slower step does not move the constant
    model.observe(_Result(4, {"p4": 6.0}, {"high": 8.0, "p4": 30.0}, {"high": 2.0}), "step 4")
    assert model.emvps(res) == pytest.approx(5.5)
    again = CostModel("scene", machine={"cpu": "x"}, cache_dir=tmp_path)
    again.observe(_Result(4, {"p4": 6.0}, {"high": 8.0, "p4": 30.0}, {"high": 2.0}), "later")
    assert again.entries["p4"]["per_application"] == pytest.approx(0.25)   # from the cache
    other = CostModel("scene", machine={"cpu": "y"}, cache_dir=tmp_path)    # another machine
    other.observe(_Result(4, {"p4": 6.0}, {"high": 8.0, "p4": 30.0}, {"high": 2.0}), "later")
    assert other.entries["p4"]["per_application"] == pytest.approx(2.5)


def test_calibration_leaves_out_each_operators_first_call():
    # the low's first call paid 50 s of one-off work; after it, 2 s on 8 applications;
    # the high's steady cold product is 0.5 s an application times 4 applications
    res = _Result(4, {"p8f6e3": 9.0}, {"high": 12.0, "p8f6e3": 52.0}, {"high": 3.0})
    res.info["operator_steady_seconds"] = {"high": 0.5, "p8f6e3": 0.25}
    res.info["operator_cold_applications"] = {"high": 4.0}
    assert calibrate(res) == {"p8f6e3": pytest.approx(0.25 / 2.0)}


def test_an_operators_steady_seconds_exclude_its_first_call(monkeypatch):
    import lcpbench
    import lcpbench.core.operator as operator

    clock = iter([0.0, 10.0, 10.0, 11.0, 11.0, 12.0])   # first call 10 s, then 1 s each
    monkeypatch.setattr(operator.time, "perf_counter", lambda: next(clock))
    op = lcpbench.Operator(np.eye(3))
    assert op.steady_application_seconds is None
    op @ np.ones(3)
    assert op.steady_application_seconds is None         # one call: nothing steady yet
    op @ np.ones(3)
    op @ np.ones(3)
    assert op.steady_application_seconds == pytest.approx(1.0)
    assert op.seconds == pytest.approx(12.0)
