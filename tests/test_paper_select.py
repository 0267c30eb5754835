"""The held-apart choice of the best regime's configurations (lcpbench paper's section)."""

from __future__ import annotations

import pytest

from lcpbench.report import paper_page, paper_select, tables
from lcpbench.run.store import RunStore
from lcpbench.workflows.simulate import simulate

SCENE = "lattice:m=2,model=rpy,low=[self]"
CANDIDATES = ["bb-pgd", "mono-pqn", "mono-pqn:products=iterate", "bi-pqn:low=self"]


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    root = tmp_path_factory.mktemp("paper")
    simulate(SCENE, CANDIDATES, 14, root / paper_select.SELECT_STORE, progress=False)
    return root


def test_each_family_gets_its_fastest_fully_solved_candidate(store):
    res = RunStore(store / paper_select.SELECT_STORE).results()
    table, chosen = paper_select.choose(res)
    steps = tables.online_step_rows(res)
    assert set(table["solver"]) == set(CANDIDATES) and len(steps)
    for fam in ("bb-pgd", "mono-pqn", "bi-pqn"):
        mine = steps[steps["solver"].str.split(":").str[0] == fam]
        sums = mine.groupby("solver")["time_s"].sum()
        assert chosen[fam] == sums.idxmin()
    # a candidate that failed one compared step is never chosen, however fast
    mono = [s for s in CANDIDATES if s.startswith("mono-pqn")]
    faster = next(s for s in mono if s != chosen["mono-pqn"])
    step = int(steps["step"].iloc[-1])
    hit = (res["solver"] == faster) & (res["step"] == step)
    res.loc[res["solver"] == faster, "time_s"] = 1e-9
    res.loc[hit, "status"] = "failed"
    res.loc[hit, "solved"] = False
    _, again = paper_select.choose(res)
    assert again["mono-pqn"] == chosen["mono-pqn"]


def test_the_page_shows_the_choice_apart_from_the_campaign(store):
    text = paper_page.render_page(store)
    section = text.split("## lcpbench's best regime")[1].split("## Online comparison")[0]
    _, chosen = paper_select.choose(RunStore(store / paper_select.SELECT_STORE).results())
    assert f'SOLVERS="{chosen["bb-pgd"]} {chosen["mono-pqn"]} {chosen["bi-pqn"]}"' in section
    online = text.split("## Online comparison")[1].split("## Offline comparison")[0]
    assert "No online store yet." in online            # the selection is not a campaign row
