"""The set-up a Monte Carlo shares across its runs gives the runs a fresh set-up would.

A Monte Carlo validates its (topology-pinned) scenario and builds its run plan and system
once (:class:`~dkfsim.experiments.montecarlo.Template`); run ``r`` is a copy with the seed
replaced, run on the shared plan (``RunPlan.with_seed``).  The independent truth here is the path without any sharing: the scenario
re-validated from scratch with ``--set seed=S`` (what each run did before), a fresh
:class:`~dkfsim.engine.driver.Run`, and its rows and per-tick curves computed from the
run's arrays with the plain metric functions.  Several runs go through one template in
sequence, so a run that changed the shared system would show in the next one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dkfsim import load_scenario
from dkfsim.analysis.metrics import nees_per_tick, squared_error
from dkfsim.config.plan import RunPlan
from dkfsim.engine.driver import Run
from dkfsim.experiments.montecarlo import Template, derive_seed, pinned_topology, run_rows

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


def _random_tree_case():
    """paper_case1 on a random tree drawn from the scenario seed (so it must be pinned)."""
    d = load_scenario(CASE1, overrides=["steps=60"]).to_dict()
    d["topology"] = {"directed": False, "generator": "random_tree"}
    d["seed"] = 7
    d["estimators"] = [{"kind": "centralized"}, {"kind": "local_only"}]
    return load_scenario(d)


def test_a_run_of_the_template_is_the_revalidated_scenario_with_its_seed():
    sc = _random_tree_case()
    tpl = Template(sc)
    for r in range(3):
        seed = derive_seed(sc.seed, r)
        fresh = load_scenario(sc, overrides=pinned_topology(sc) + [f"seed={seed}"])
        copy = tpl.scenario_for(seed)
        assert copy.seed == seed
        assert copy.to_dict() == fresh.to_dict()
        shared, own = tpl.plan_for(copy), RunPlan(fresh, "estimates")
        assert shared.scenario is copy and shared.exchange is tpl.plan.exchange     # worked out once
        assert sorted(shared.graph.edges()) == sorted(own.graph.edges())
        assert shared.arcs == own.arcs and shared.exchange.arcs == own.exchange.arcs
        assert shared.buffer_length() == own.buffer_length() and shared.d_t == own.d_t
        assert shared.save == own.save == "estimates"


def test_shared_setup_gives_the_rows_and_curves_of_a_fresh_run():
    sc = _random_tree_case()
    tpl = Template(sc)
    burn = 6
    for r in range(3):                         # in sequence, on the one template and system
        seed = derive_seed(sc.seed, r)
        rows, curves = run_rows(tpl, seed, burn)
        fresh = Run(load_scenario(sc, overrides=pinned_topology(sc) + [f"seed={seed}"]),
                    save="estimates").run()
        expect = [{**row, "seed": seed} for row in fresh.rows(burn)]
        assert repr(rows) == repr(expect)              # repr: NaN == NaN, exact floats
        truth = fresh["truth"]
        assert curves["estimates"] == fresh.estimates
        for a, name in enumerate(fresh.estimates):
            x = fresh[f"x_{name}"]
            np.testing.assert_array_equal(curves["se"][a], squared_error(x, truth))
            if f"P_{name}" in fresh:
                np.testing.assert_array_equal(curves["nees"][a],
                                              nees_per_tick(x, fresh[f"P_{name}"], truth))
            else:
                assert np.isnan(curves["nees"][a]).all()
    # the runs differ (the seed reached the draws) while the graph is the base seed's
    rows0, _ = run_rows(tpl, derive_seed(sc.seed, 0), burn)
    rows1, _ = run_rows(tpl, derive_seed(sc.seed, 1), burn)
    assert [r["mse"] for r in rows0] != [r["mse"] for r in rows1]


def test_run_rows_without_curves_gives_the_same_rows():
    sc = load_scenario(CASE1, overrides=["steps=40", "fusion=diagonal"])
    with_curves, curves = run_rows(sc, 5)
    alone, none = run_rows(sc, 5, curves=False)
    assert none is None and curves is not None
    assert repr(alone) == repr(with_curves)


def test_a_plan_for_another_seed_redraws_an_unpinned_random_graph_only():
    # a plan shared across seeds follows the seed the graph is drawn from: a stale graph would be wrong
    sc = _random_tree_case()                      # random_tree drawn from the scenario seed
    plan = RunPlan(sc).resolve()
    before = sorted(plan.graph.edges())
    copy = sc.model_copy(update={"seed": 8})
    fresh = load_scenario(sc, overrides=["seed=8"])
    moved = plan.with_seed(copy)
    assert sorted(moved.graph.edges()) == sorted(RunPlan(fresh).graph.edges()) != before
    assert moved.exchange.arcs == RunPlan(fresh).exchange.arcs
    pinned = RunPlan(load_scenario(sc, overrides=pinned_topology(sc))).resolve()
    kept = pinned.with_seed(pinned.scenario.model_copy(update={"seed": 8}))
    assert kept.graph is pinned.graph and sorted(kept.graph.edges()) == before
