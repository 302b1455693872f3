"""One set of keywords across ``dkfsim.run``, ``montecarlo``, ``sweep`` and ``maxdelay`` (issue 34
§8): each takes ``seed``, ``steps``, ``overrides`` (``--set``), ``progress`` and ``yes``; the three
that make many runs also ``jobs``, ``executor`` and ``burn_in``; and each applies them as
``load_scenario(..., overrides=[...])`` would."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest

import dkfsim
from dkfsim.experiments.montecarlo import derive_seed
from dkfsim.experiments.sweep import load_sweep
from dkfsim.experiments.sweep.results import read_results

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"
EVERY = {"seed", "steps", "overrides", "progress", "yes"}
MANY_RUNS = {"jobs", "executor", "burn_in"}


@pytest.mark.parametrize("name", ["run", "montecarlo", "sweep", "maxdelay"])
def test_every_entry_point_takes_the_shared_keywords(name):
    params = set(inspect.signature(getattr(dkfsim, name)).parameters)
    want = EVERY | (MANY_RUNS if name != "run" else set())
    if name == "maxdelay":              # jobs and burn_in are settings of the search (its **settings)
        params |= set(dkfsim.experiments.maxdelay.Settings.__dataclass_fields__)
    assert want <= params, f"dkfsim.{name} lacks {sorted(want - params)}"


def test_montecarlo_takes_steps_seed_and_overrides_as_run_does():
    keywords = {"steps": 30, "seed": 5, "overrides": ["fusion=diagonal"]}
    mc = dkfsim.montecarlo(CASE1, runs=2, jobs=1, **keywords)
    assert (mc.scenario.steps, mc.scenario.seed, mc.scenario.fusion) == (30, 5, "diagonal")
    same = dkfsim.montecarlo(dkfsim.load_scenario(CASE1, overrides=["fusion=diagonal", "seed=5", "steps=30"]),
                             runs=2, jobs=1)
    assert mc.rows == same.rows
    one = dkfsim.run(CASE1, **keywords)
    assert (one.scenario.steps, one.scenario.seed, one.scenario.fusion) == (30, 5, "diagonal")


def test_maxdelay_takes_steps_and_seed():
    res = dkfsim.maxdelay(CASE1, steps=40, seed=3, overrides=["estimators=[]"], relative=1.5, jobs=1,
                          max_delay=2, batch=2, max_runs=2)
    assert (res.md.sc.steps, res.md.sc.seed) == (40, 3)


def test_sweep_takes_steps_seed_overrides_and_burn_in(tmp_path):
    spec = {"scenario": str(CASE1), "grid": {"fusion": ["matrix", "diagonal"]}, "runs": 1,
            "output": str(tmp_path / "s.sqlite")}
    rep = dkfsim.sweep(spec, steps=20, seed=9, overrides=["estimators=[]"], burn_in=3, jobs=1, progress=False)
    columns, table = read_results(rep.db)
    rows = [dict(zip(columns, row)) for row in table]
    assert rep.computed == 2
    assert {r["seed"] for r in rows} == {derive_seed(9, 0)}                  # seed=9
    assert {r["estimate"] for r in rows} == {"fused", "local"}               # estimators=[]
    sweep = load_sweep(spec, overrides=["estimators=[]", "seed=9", "steps=20"], burn_in=3)
    assert {p.scenario.steps for p in sweep.parameter_sets} == {20} and sweep.burn_in == 3
    again = dkfsim.sweep(spec, steps=20, seed=9, overrides=["estimators=[]"], burn_in=3, jobs=1, progress=False)
    assert again.skipped == 2 and again.computed == 0                       # the same sweep: resumed
    with pytest.raises(dkfsim.DkfsimError, match="not a loaded Sweep"):
        dkfsim.sweep(sweep, steps=10)
