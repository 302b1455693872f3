"""Graph generators, connectivity checks, exchange graphs and paper weights."""

from __future__ import annotations

import itertools
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import networkx as nx
import numpy as np
import pytest

from dkfsim.components.topology import (
    GraphSpecError,
    bfs_spanning_tree,
    build_graph,
    check_connected,
    is_tree,
    make_exchange,
    paper_weights,
    pruefer_decode,
    random_tree_edges,
)
from dkfsim.config.load import load_scenario
from dkfsim.config.plan import RunPlan
from dkfsim.engine.driver import Run

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def spec(generator, params=None, directed=False, edges=None):
    return SimpleNamespace(generator=generator, params=params or {}, directed=directed,
                           edges=edges)


def small_scenario(n, topology, **top):
    """A valid scenario dict on n 1-state sensors."""
    d = {
        "name": "t",
        "model": {"kind": "linear", "T": 0.01, "Phi": [[1.0]], "Q": [[1.0]]},
        "prior": {"mean": [0.0], "cov": [[1.0]]},
        "sensors": [{"name": f"s{i}", "H": [[1.0]], "R": [[1.0]]} for i in range(n)],
        "topology": dict(topology),
    }
    d.update(top)
    return d


# --------------------------------------------------------------------------- generators
def test_path():
    g = build_graph(spec("path"), 6, 0)
    assert sorted(g.nodes) == list(range(6))
    assert sorted(g.edges) == [(i, i + 1) for i in range(5)]
    assert is_tree(g) and nx.diameter(g) == 5


def test_star_hub_is_zero():
    g = build_graph(spec("star"), 7, 0)
    assert g.number_of_nodes() == 7 and is_tree(g)
    assert g.degree(0) == 6
    assert all(g.degree(v) == 1 for v in range(1, 7))


@pytest.mark.parametrize("r, h, size", [(2, 3, 15), (3, 2, 13), (1, 4, 5), (4, 0, 1)])
def test_balanced_tree(r, h, size):
    g = build_graph(spec("balanced_tree", {"r": r, "h": h}), size, 0)
    assert g.number_of_nodes() == size and is_tree(g)
    assert nx.is_isomorphic(g, nx.balanced_tree(r, h))
    if h > 0:
        assert g.degree(0) == r


def test_balanced_tree_wrong_node_count():
    with pytest.raises(GraphSpecError) as err:
        build_graph(spec("balanced_tree", {"r": 3, "h": 2}), 12, 0)
    assert "13 nodes" in str(err.value) and "12 sensors" in str(err.value)
    assert err.value.key == "params"


@pytest.mark.parametrize("n", [1, 2, 3, 10, 57])
def test_random_tree_is_tree(n):
    g = build_graph(spec("random_tree"), n, 3)
    assert sorted(g.nodes) == list(range(n))
    assert is_tree(g)


def test_random_tree_seeding():
    a = sorted(build_graph(spec("random_tree"), 30, 1).edges)
    assert a == sorted(build_graph(spec("random_tree"), 30, 1).edges)
    assert a != sorted(build_graph(spec("random_tree"), 30, 2).edges)
    # params.seed takes precedence over the scenario seed
    b = sorted(build_graph(spec("random_tree", {"seed": 2}), 30, 1).edges)
    assert b == sorted(build_graph(spec("random_tree"), 30, 2).edges)


def test_pruefer_decode_is_a_bijection():
    n = 5
    trees = set()
    for seq in itertools.product(range(n), repeat=n - 2):
        edges = pruefer_decode(list(seq), n)
        g = nx.Graph(edges)
        g.add_nodes_from(range(n))
        assert is_tree(g)
        trees.add(frozenset(frozenset(e) for e in edges))
    assert len(trees) == n ** (n - 2)  # Cayley: 125 distinct labelled trees


def test_pruefer_decode_known_sequence():
    # sequence (3, 3, 3, 4) on 6 nodes: leaves 0, 1, 2 hang on 3, then 3 - 4, 4 - 5
    edges = {frozenset(e) for e in pruefer_decode([3, 3, 3, 4], 6)}
    assert edges == {frozenset(e) for e in [(0, 3), (1, 3), (2, 3), (3, 4), (4, 5)]}


def test_random_tree_is_uniform_over_labelled_trees():
    n, draws = 4, 16_000  # 4^2 = 16 labelled trees, 1000 expected each
    gen = np.random.default_rng(2024)
    counts = Counter(frozenset(frozenset(e) for e in random_tree_edges(n, gen))
                     for _ in range(draws))
    assert len(counts) == 16
    expected = draws / 16
    sd = np.sqrt(expected * (1 - 1 / 16))
    assert all(abs(c - expected) < 5 * sd for c in counts.values()), counts


def test_ring():
    g = build_graph(spec("ring"), 8, 0)
    assert g.number_of_edges() == 8 and nx.is_connected(g)
    assert all(d == 2 for _, d in g.degree)
    assert not is_tree(g)


def test_ring_needs_three_nodes():
    with pytest.raises(GraphSpecError):
        build_graph(spec("ring"), 2, 0)


def test_random_regular():
    g = build_graph(spec("random_regular", {"d": 3}), 10, 5)
    assert g.number_of_nodes() == 10
    assert all(d == 3 for _, d in g.degree)
    assert sorted(g.edges) == sorted(build_graph(spec("random_regular", {"d": 3}), 10, 5).edges)


@pytest.mark.parametrize("params, n", [({"d": 3}, 9), ({"d": 10}, 10), ({}, 10), ({"d": -1}, 10)])
def test_random_regular_bad_params(params, n):
    with pytest.raises(GraphSpecError):
        build_graph(spec("random_regular", params), n, 0)


def test_erdos_renyi_extremes_and_seed():
    assert build_graph(spec("erdos_renyi", {"p": 1.0}), 6, 0).number_of_edges() == 15
    assert build_graph(spec("erdos_renyi", {"p": 0.0}), 6, 0).number_of_edges() == 0
    a = sorted(build_graph(spec("erdos_renyi", {"p": 0.4, "seed": 9}), 20, 0).edges)
    assert a == sorted(build_graph(spec("erdos_renyi", {"p": 0.4}), 20, 9).edges)
    with pytest.raises(GraphSpecError):
        build_graph(spec("erdos_renyi", {"p": 1.5}), 6, 0)


def test_unknown_param_suggests():
    with pytest.raises(GraphSpecError) as err:
        build_graph(spec("balanced_tree", {"r": 2, "hh": 1}), 3, 0)
    assert "did you mean 'h'" in str(err.value)
    assert err.value.key == "params.hh"


# --------------------------------------------------------------------------- directed
def test_directed_ring_is_one_way_cycle():
    g = build_graph(spec("ring", directed=True), 5, 0)
    assert g.is_directed()
    assert sorted(g.edges) == [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0)]
    assert nx.is_strongly_connected(g)


@pytest.mark.parametrize("generator, params, n", [
    ("path", {}, 5), ("star", {}, 5), ("balanced_tree", {"r": 2, "h": 2}, 7),
    ("random_tree", {}, 9), ("random_regular", {"d": 2}, 6)])
def test_directed_named_generators_are_symmetric(generator, params, n):
    und = build_graph(spec(generator, params), n, 4)
    dig = build_graph(spec(generator, params, directed=True), n, 4)
    assert dig.is_directed()
    assert dig.number_of_edges() == 2 * und.number_of_edges()
    assert all(dig.has_edge(v, u) for u, v in dig.edges)
    assert all(dig.has_edge(u, v) and dig.has_edge(v, u) for u, v in und.edges)


def test_directed_erdos_renyi():
    g = build_graph(spec("erdos_renyi", {"p": 1.0}, directed=True), 5, 0)
    assert g.is_directed() and g.number_of_edges() == 20
    g = build_graph(spec("erdos_renyi", {"p": 0.3}, directed=True), 30, 0)
    assert any(not g.has_edge(v, u) for u, v in g.edges)  # not forced symmetric


def test_directed_edges_as_listed():
    g = build_graph(spec("edges", directed=True, edges=[(0, 1), (1, 2), (2, 0)]), 3, 0)
    assert sorted(g.edges) == [(0, 1), (1, 2), (2, 0)]


@pytest.mark.parametrize("edges, key", [([(0, 1), (1, 3)], "edges.1"), ([(0, 0)], "edges.0"),
                                        ([(0, 1), (1, 0)], "edges.1"), (None, "edges")])
def test_bad_explicit_edges(edges, key):
    with pytest.raises(GraphSpecError) as err:
        build_graph(spec("edges", edges=edges), 3, 0)
    assert err.value.key == key


# --------------------------------------------------------------------------- connectivity
def test_check_connected():
    check_connected(build_graph(spec("path"), 4, 0))
    g = build_graph(spec("edges", edges=[(0, 1), (2, 3)]), 4, 0)
    with pytest.raises(GraphSpecError, match="disconnected"):
        check_connected(g)
    d = build_graph(spec("edges", directed=True, edges=[(0, 1), (1, 2)]), 3, 0)
    assert nx.is_weakly_connected(d)
    with pytest.raises(GraphSpecError, match="not strongly connected"):
        check_connected(d)
    check_connected(build_graph(spec("ring", directed=True), 4, 0))


# --------------------------------------------------------------------------- spanning tree
def grid(rows, cols):
    return nx.convert_node_labels_to_integers(nx.grid_2d_graph(rows, cols), ordering="sorted")


@pytest.mark.parametrize("graph", [
    nx.cycle_graph(12), grid(5, 5), grid(3, 7), nx.complete_graph(6),
    nx.convert_node_labels_to_integers(nx.lollipop_graph(5, 6)),
    nx.convert_node_labels_to_integers(nx.petersen_graph())])
def test_bfs_spanning_tree_diameter(graph):
    tree = bfs_spanning_tree(graph)
    assert is_tree(tree)
    assert sorted(tree.nodes) == sorted(graph.nodes)
    assert all(graph.has_edge(u, v) for u, v in tree.edges)
    radius = nx.radius(graph)
    assert nx.diameter(tree) <= 2 * radius
    root = min(nx.center(graph))
    # BFS from the root keeps the root's distances
    assert nx.eccentricity(tree, root) == radius
    assert sorted(tree.edges) == sorted(bfs_spanning_tree(graph).edges)  # deterministic


def test_spanning_tree_of_lollipop_roots_at_centre():
    # clique 0..4, path 5..10 attached at 4: the centre is on the path, not node 0
    g = nx.convert_node_labels_to_integers(nx.lollipop_graph(5, 6))
    root = min(nx.center(g))
    assert root != 0
    tree = bfs_spanning_tree(g)
    naive = nx.bfs_tree(g, 0).to_undirected()
    assert nx.diameter(tree) <= nx.diameter(naive)
    assert nx.diameter(tree) == nx.diameter(g)


def test_spanning_tree_of_a_tree_is_itself():
    g = build_graph(spec("random_tree"), 20, 5)
    assert sorted(bfs_spanning_tree(g).edges) == sorted(tuple(sorted(e)) for e in g.edges)


# --------------------------------------------------------------------------- exchange graph
def test_exchange_tree_protocol():
    sc = load_scenario(small_scenario(5, {"generator": "star"}))
    xg = RunPlan(sc).exchange
    assert not xg.graph.is_directed() and is_tree(xg.graph)
    assert xg.d_g == 2
    assert xg.arcs == sorted([(0, i) for i in range(1, 5)] + [(i, 0) for i in range(1, 5)])
    assert xg.neighbors == [[1, 2, 3, 4], [0], [0], [0], [0]]
    assert xg.n == 5


def test_exchange_tree_with_spanning_tree():
    sc = load_scenario(small_scenario(8, {"generator": "ring"}, spanning_tree=True))
    xg = RunPlan(sc).exchange
    assert is_tree(xg.graph)
    assert xg.d_g == nx.diameter(xg.graph) <= 2 * nx.radius(nx.cycle_graph(8))
    assert len(xg.arcs) == 2 * 7


def test_exchange_flood_on_undirected_is_symmetric_digraph():
    sc = load_scenario(small_scenario(6, {"generator": "ring"}, protocol="flood"))
    xg = RunPlan(sc).exchange
    assert xg.graph.is_directed()
    assert xg.d_g == 3
    assert len(xg.arcs) == 12 and xg.arcs == sorted(xg.arcs)
    assert all((v, u) in xg.arcs for u, v in xg.arcs)
    assert xg.neighbors[0] == [1, 5]


def test_exchange_flood_directed_uses_directed_diameter():
    sc = load_scenario(small_scenario(5, {"generator": "ring", "directed": True},
                                      protocol="flood"))
    xg = RunPlan(sc).exchange
    assert xg.d_g == 4  # one-way ring: 0 reaches 4 in 4 hops
    assert xg.arcs == [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0)]
    assert xg.neighbors == [[1], [2], [3], [4], [0]]


def test_exchange_flood_on_spanning_tree():
    sc = load_scenario(small_scenario(6, {"generator": "ring"}, protocol="flood",
                                      spanning_tree=True))
    xg = RunPlan(sc).exchange
    assert xg.graph.is_directed() and len(xg.arcs) == 10
    assert is_tree(xg.graph.to_undirected())


def test_paper_scenarios_exchange():
    xg1 = RunPlan(load_scenario(SCENARIOS / "paper_case1.yaml")).exchange
    assert xg1.d_g == 4 and is_tree(xg1.graph) and xg1.n == 12
    xg2 = RunPlan(load_scenario(SCENARIOS / "paper_case2.yaml")).exchange
    assert xg2.graph.is_directed() and xg2.d_g == 5 and len(xg2.arcs) == 18
    assert nx.is_strongly_connected(xg2.graph)


def test_make_exchange_rejects_misuse():
    with pytest.raises(GraphSpecError):
        make_exchange(nx.cycle_graph(4), "tree")
    with pytest.raises(GraphSpecError):
        make_exchange(nx.DiGraph([(0, 1), (1, 0)]), "tree")


# --------------------------------------------------------------------------- weights
def test_paper_weights_on_4_node_path_by_hand():
    # path 0 - 1 - 2 - 3, degrees 1, 2, 2, 1.  A[i, o] = product of 1/deg(v) over the
    # nodes v on the path from o to i, v != o.
    #   A[1,0] = 1/deg1 = 1/2     A[2,0] = 1/2 * 1/2 = 1/4    A[3,0] = 1/4 * 1/1 = 1/4
    #   A[0,1] = 1/deg0 = 1       A[2,1] = 1/2                A[3,1] = 1/2 * 1 = 1/2
    #   A[0,2] = 1/2 * 1 = 1/2    A[1,2] = 1/2                A[3,2] = 1
    #   A[0,3] = 1/2*1/2*1 = 1/4  A[1,3] = 1/2 * 1/2 = 1/4    A[2,3] = 1/2
    expected = np.array([
        [1.0, 1.0, 0.5, 0.25],
        [0.5, 1.0, 0.5, 0.25],
        [0.25, 0.5, 1.0, 0.5],
        [0.25, 0.5, 1.0, 1.0],
    ])
    A = paper_weights(nx.path_graph(4))
    np.testing.assert_allclose(A, expected, rtol=0, atol=1e-15)


def test_paper_weights_star():
    A = paper_weights(nx.star_graph(3))  # hub 0 with leaves 1, 2, 3
    assert np.allclose(np.diag(A), 1.0)
    assert np.allclose(A[0, 1:], 1 / 3)   # hub divides by its degree 3
    assert np.allclose(A[1:, 0], 1.0)     # leaves divide by 1
    assert np.isclose(A[2, 1], 1 / 3)     # 1 -> 0 (1/3) -> 2 (1)


def test_paper_weights_rejects_cycles():
    with pytest.raises(ValueError):
        paper_weights(nx.cycle_graph(4))


def test_unit_weights():
    # weights: unit (the default) gives the DKF the all-ones matrix A; paper gives paper_weights
    sc = load_scenario(small_scenario(3, {"generator": "path"}, steps=3))
    assert sc.weights == "unit"
    r = Run(sc)
    r.run()
    assert np.array_equal(r.dkf.A, np.ones((3, 3)))
    r = Run(load_scenario(sc, ["weights=paper"]))
    r.run()
    np.testing.assert_array_equal(r.dkf.A, paper_weights(nx.path_graph(3)))
