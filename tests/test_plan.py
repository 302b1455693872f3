"""The run plan: what a scenario implies for a run, worked out once and read by every part.

Validation, ``cost()``, the engine and the estimators' ``start()`` read one
:class:`~dkfsim.config.plan.RunPlan`; these tests hold it to hand-worked facts, to the graphs
themselves, and to its promise that a run meets no error its validation did not raise.
"""

from __future__ import annotations

import ast
from pathlib import Path

import networkx as nx
import pytest
from conftest import scc_digraph_edges, scenario, tree_edges

import dkfsim
from dkfsim.config.plan import RunPlan
from dkfsim.core.errors import DkfsimError

ROOT = Path(__file__).resolve().parents[1]
CASE1 = ROOT / "scenarios" / "paper_case1.yaml"


def test_paper_case1_facts_by_hand():
    """12 sensors on a tree of diameter 4, uniform_steps latency with d_t = 4: L = 4 * 4 + 1."""
    plan = RunPlan(dkfsim.load_scenario(CASE1))
    assert plan.d_t == 4 and plan.exchange.d_g == 4 and plan.buffer_length() == 17
    assert plan.buffer_length("paper") == 4 and plan.buffer_length(5) == 5
    assert len(plan.arcs) == 2 * 11 and plan.n_exchange_links == 22
    assert plan.save == "full" and RunPlan(plan.scenario, "estimates").save == "estimates"
    assert plan.dkf().buffer_length == "auto" and plan.dkf().fusion == plan.scenario.fusion


@pytest.mark.parametrize("case", [
    dict(n=8, edges=tree_edges(8, 3)),                                             # tree on a tree
    dict(n=7, directed=True, edges=scc_digraph_edges(7, 3), protocol="flood"),     # flood on a digraph
    dict(n=9, generator="ring", edges=None, protocol="flood"),                     # flood on a cycle
    dict(n=9, generator="ring", edges=None, protocol="tree", spanning_tree=True),  # a spanning tree
    dict(n=9, generator="ring", edges=None, protocol="flood", spanning_tree=True),
])
def test_the_number_of_exchange_links_is_the_exchange_graphs(case):
    """The count cost() uses without building the exchange graph equals the graph's own."""
    spanning = case.pop("spanning_tree", False)
    d = scenario(**case)
    d["spanning_tree"] = spanning
    if case.get("generator") == "ring":
        d["topology"].pop("edges", None)
    plan = RunPlan(dkfsim.load_scenario(d))
    g = plan.exchange.graph
    assert plan.n_exchange_links == len(plan.exchange.arcs) == (g.number_of_edges() * (1 if g.is_directed() else 2))
    assert nx.is_tree(g.to_undirected() if g.is_directed() else g) == (plan.protocol_graph == "tree" or spanning)


def test_the_scenario_keeps_no_derived_state():
    """The plan holds the graphs; a scenario is its configuration only, before and after a run."""
    sc = dkfsim.load_scenario(CASE1, overrides=["steps=5"])
    assert set(sc.__pydantic_private__) == {"_source", "_base_dir"}
    dkfsim.run(sc)
    assert set(sc.__pydantic_private__) == {"_source", "_base_dir"}


def test_a_bad_save_mode_is_refused_when_the_run_is_planned():
    sc = dkfsim.load_scenario(CASE1, overrides=["steps=5"])
    with pytest.raises(DkfsimError, match="--save: unknown mode 'most'"):
        RunPlan(sc, "most")


def _raises_in(func: ast.FunctionDef) -> list[int]:
    return [n.lineno for n in ast.walk(func) if isinstance(n, ast.Raise)]


def test_no_estimator_raises_at_its_start():
    """What validation can check it checks: an estimator's ``start()`` (and the set-up of a run)
    raises nothing; the errors it raised before are raised when the scenario is validated."""
    found = []
    for path in sorted((ROOT / "dkfsim" / "estimators").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and node.name in ("start", "setup", "__init__"):
                found += [f"{path.name}:{line} ({node.name})" for line in _raises_in(node)]
    driver = ast.parse((ROOT / "dkfsim" / "engine" / "driver.py").read_text())
    for node in ast.walk(driver):
        if isinstance(node, ast.ClassDef) and node.name == "Run":
            for f in node.body:
                if isinstance(f, ast.FunctionDef) and f.name == "__init__":
                    found += [f"driver.py:{line} (Run.__init__)" for line in _raises_in(f)]
    assert not found, found
