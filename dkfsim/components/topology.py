"""Communication graphs: generators, checks, and the graph each protocol runs on.

Nodes are always ``0..n-1``, node ``i`` being the ``i``-th sensor of the
scenario.

Generators (``topology.generator``) and their ``topology.params``:

=================  ==================  ===============================================
generator          params              graph
=================  ==================  ===============================================
``path``           --                  0 - 1 - ... - n-1
``star``           --                  node 0 is the hub, joined to every other node
``balanced_tree``  ``r``, ``h``        every internal node has ``r`` children, height
                                       ``h``; it has ``(r^(h+1) - 1)/(r - 1)`` nodes
                                       (``h + 1`` for ``r = 1``), which must equal n
``random_tree``    ``seed``?           uniform random labelled tree: a random Pruefer
                                       sequence of length n-2 decoded here
``ring``           --                  the cycle 0 - 1 - ... - n-1 - 0 (n >= 3)
``random_regular`` ``d``, ``seed``?    random d-regular graph (``n*d`` even, d < n)
``erdos_renyi``    ``p``, ``seed``?    G(n, p)
``edges``          --                  ``topology.edges`` as listed
=================  ==================  ===============================================

The node count is always the number of sensors, so no generator takes ``n``.

Seeds.  A seeded generator uses ``params.seed`` if given, else the scenario
seed, and draws from ``dkfsim.core.streams.stream(seed, "topology")``.  The
networkx generators get an integer seed drawn from that stream (integer seeds
of networkx are stable across versions as long as the algorithm is).

Directed topologies (``topology.directed: true``):

* ``edges``: the arcs ``u -> v`` exactly as listed;
* ``ring``: the one-way cycle ``0 -> 1 -> ... -> n-1 -> 0`` (the sparsest
  strongly connected digraph, the usual directed test case);
* ``erdos_renyi``: the directed G(n, p), each ordered pair an arc with
  probability p (``networkx.gnp_random_graph(directed=True)``);
* every other generator: both arcs of each undirected edge (a symmetric
  digraph -- a directed tree or path would never be strongly connected).

Exchange graph (:func:`make_exchange`, ``RunPlan.exchange``), the graph a protocol actually uses:

* ``tree``: the undirected topology when it is a tree.  With
  ``spanning_tree: true`` on a graph with cycles, a breadth-first spanning
  tree rooted at the graph centre of lowest index, neighbours visited in
  increasing order (deterministic).  Rooting at a centre keeps the tree's
  depth equal to the graph radius, so its diameter ``d_g <= 2 * radius <=
  2 * diameter`` -- ``d_g`` sets the buffer length ``d_t * d_g + 1`` and the
  number of hops information needs.
* ``flood``: a DiGraph; an undirected topology becomes the symmetric digraph.
  ``spanning_tree: true`` (undirected topologies only) makes flood run on
  the same BFS spanning tree, so both protocols can be compared on the same
  links.
"""

from __future__ import annotations

import functools
import heapq
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from dkfsim.core.files import clip
from dkfsim.core.params import suggest
from dkfsim.core.registry import GENERATORS, PROTOCOLS
from dkfsim.core.streams import stream

if TYPE_CHECKING:
    import networkx as nx


@dataclass(frozen=True)
class Generator:
    """A graph generator's parameters (``topology.params``): required and optional names."""

    required: tuple[str, ...] = ()
    optional: tuple[str, ...] = ()


for _name, _gen, _doc in (
        ("path", Generator(), "the path 0 - 1 - ... - n-1"),
        ("star", Generator(), "node 0 joined to every other node"),
        ("balanced_tree", Generator(("r", "h")), "r children per internal node, height h (r^(h+1)-1)/(r-1) nodes"),
        ("random_tree", Generator((), ("seed",)), "a uniform random labelled tree (random Pruefer sequence)"),
        ("ring", Generator(), "the cycle 0 - 1 - ... - n-1 - 0 (directed: one way)"),
        ("random_regular", Generator(("d",), ("seed",)), "a random d-regular graph"),
        ("erdos_renyi", Generator(("p",), ("seed",)), "G(n, p): each pair an edge with probability p"),
        ("edges", Generator(), "topology.edges exactly as listed")):
    GENERATORS.add(_name, implementation=_gen, description=_doc)


def generator_params(generator: str) -> tuple[tuple[str, ...], tuple[str, ...]] | None:
    """``(required, optional)`` parameter names of ``generator``, None when it is not registered.

    Read from the registry when asked, never at import: a registry read may load the
    installed plugins, which import dkfsim themselves (docs/decisions.md, #72).
    """
    if generator not in GENERATORS:
        return None
    gen = GENERATORS.get(generator).implementation
    return gen.required, gen.optional


#: Largest number of edges a random generator may produce (expected count, checked before).
MAX_EDGES = 5_000_000


class GraphSpecError(ValueError):
    """A topology cannot be built or does not suit the protocol.

    ``key`` is the offending key path relative to the scenario's
    ``topology`` mapping (e.g. ``params.r``, ``edges.3``), or ``""``.
    """

    def __init__(self, message: str, key: str = ""):
        super().__init__(message)
        self.key = key
        self.reason = message


# --------------------------------------------------------------------------- params
def _is_int(x: Any) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool)


def _int_param(params: dict, name: str, minimum: int) -> int:
    value = params[name]
    if not _is_int(value) or value < minimum:
        raise GraphSpecError(f"must be an integer >= {minimum}, got {clip(value)}", f"params.{name}")
    return int(value)


def balanced_tree_size(r: int, h: int) -> int:
    """Number of nodes of the balanced tree with branching ``r`` and height ``h``."""
    return h + 1 if r == 1 else (r ** (h + 1) - 1) // (r - 1)


def check_params(generator: str, params: dict, n: int) -> None:
    """Check ``params`` for ``generator`` on ``n`` nodes; raise :class:`GraphSpecError`."""
    names = generator_params(generator)
    if names is None:
        raise GraphSpecError(GENERATORS.unknown(generator), "generator")
    required, optional = names
    allowed = required + optional
    for key in params:
        if key not in allowed:
            hint = suggest(key, allowed)
            if key == "n":
                hint += "; the node count is the number of sensors"
            what = ", ".join(allowed) if allowed else "none"
            raise GraphSpecError(f"unknown parameter for {generator}{hint}; allowed: {what}",
                                 f"params.{key}")
    for key in required:
        if key not in params:
            raise GraphSpecError(f"required by generator {generator}", f"params.{key}")
    if "seed" in params:
        _int_param(params, "seed", 0)
    if generator == "balanced_tree":
        r = _int_param(params, "r", 1)
        h = _int_param(params, "h", 0)
        size = balanced_tree_size(r, h)
        if size != n:
            raise GraphSpecError(
                f"balanced_tree with r={r}, h={h} has {size} nodes but there are {n} sensors "
                "(the node count must equal the number of sensors)", "params")
    elif generator == "ring":
        if n < 3:
            raise GraphSpecError(f"ring needs at least 3 nodes, there are {n} sensors", "generator")
    elif generator == "random_regular":
        d = _int_param(params, "d", 0)
        if d >= n:
            raise GraphSpecError(f"degree must be < number of nodes ({n}), got {d}", "params.d")
        if (n * d) % 2:
            raise GraphSpecError(f"n*d must be even (n={n}, d={d})", "params.d")
        if n * d // 2 > MAX_EDGES:
            raise GraphSpecError(f"{n} nodes of degree {d} make {n * d // 2:,} edges, more than the "
                                 f"{MAX_EDGES:,} a topology may have", "params.d")
    elif generator == "erdos_renyi":
        p = params["p"]
        if not _is_number(p) or not 0.0 <= float(p) <= 1.0:
            raise GraphSpecError(f"must be a probability in [0, 1], got {clip(p)}", "params.p")
        edges = float(p) * n * (n - 1) / 2          # expected edges (half the arcs of a digraph)
        if edges > MAX_EDGES:
            raise GraphSpecError(f"G({n}, {float(p):g}) has about {edges:.3g} edges, more than the "
                                 f"{MAX_EDGES:,} a topology may have; use a smaller p", "params.p")


# --------------------------------------------------------------------------- generators
def _nx_seed(seed: int) -> int:
    return int(stream(seed, "topology").integers(0, 2**31 - 1))


def random_tree_edges(n: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Edges of a uniform random labelled tree on ``0..n-1``.

    A Pruefer sequence of ``n - 2`` labels drawn uniformly is a uniform draw
    among the ``n^(n-2)`` labelled trees (Cayley), since decoding is a bijection.
    """
    if n <= 1:
        return []
    return pruefer_decode([int(x) for x in rng.integers(0, n, size=max(n - 2, 0))], n)


def pruefer_decode(seq, n: int) -> list[tuple[int, int]]:
    """Edges of the labelled tree on ``0..n-1`` with Pruefer sequence ``seq``."""
    if n <= 1:
        return []
    if len(seq) != n - 2 or any(not 0 <= x < n for x in seq):
        raise ValueError(f"a Pruefer sequence for {n} nodes has {n - 2} labels in 0..{n - 1}")
    degree = [1] * n
    for x in seq:
        degree[x] += 1
    leaves = [v for v in range(n) if degree[v] == 1]
    heapq.heapify(leaves)
    edges = []
    for x in seq:
        leaf = heapq.heappop(leaves)
        edges.append((leaf, x))
        degree[x] -= 1
        if degree[x] == 1:
            heapq.heappush(leaves, x)
    u, v = heapq.heappop(leaves), heapq.heappop(leaves)
    edges.append((u, v))
    return edges


def _undirected_edges(generator: str, params: dict, n: int, seed: int) -> list[tuple[int, int]]:
    import networkx as nx
    if generator == "path":
        return [(i, i + 1) for i in range(n - 1)]
    if generator == "star":
        return [(0, i) for i in range(1, n)]
    if generator == "ring":
        return [(i, (i + 1) % n) for i in range(n)]
    if generator == "balanced_tree":
        r = int(params["r"])          # h only fixes n, checked with the params
        # breadth-first labelling: the children of node v are r*v+1 .. r*v+r
        return [(v, r * v + c) for v in range(n) for c in range(1, r + 1) if r * v + c < n]
    if generator == "random_tree":
        return random_tree_edges(n, stream(seed, "topology"))
    if generator == "random_regular":
        g = nx.random_regular_graph(int(params["d"]), n, seed=_nx_seed(seed))
        return list(g.edges())
    if generator == "erdos_renyi":
        g = nx.gnp_random_graph(n, float(params["p"]), seed=_nx_seed(seed))
        return list(g.edges())
    raise GraphSpecError(f"unknown generator {generator!r}", "generator")  # pragma: no cover


def _explicit_edges(edges, n: int, directed: bool) -> list[tuple[int, int]]:
    if edges is None:
        raise GraphSpecError("required with generator: edges (a list of [u, v] pairs)", "edges")
    seen = set()
    out = []
    for idx, pair in enumerate(edges):
        u, v = (int(x) for x in pair)
        for node in (u, v):
            if not 0 <= node < n:
                raise GraphSpecError(
                    f"node {node} is out of range 0..{n - 1} (there are {n} sensors)",
                    f"edges.{idx}")
        if u == v:
            raise GraphSpecError(f"self-loop [{u}, {v}]", f"edges.{idx}")
        key = (u, v) if directed else (min(u, v), max(u, v))
        if key in seen:
            raise GraphSpecError(f"[{u}, {v}] is listed twice", f"edges.{idx}")
        seen.add(key)
        out.append((u, v))
    return out


def graph_seed(topology, seed: int):
    """The seed :func:`build_graph` draws ``topology`` from: ``params.seed``, else the
    scenario's ``seed``; None for a generator that draws nothing (``edges``, ``ring``...)."""
    optional = (generator_params(topology.generator) or ((), ("seed",)))[1]
    return (topology.params or {}).get("seed", seed) if "seed" in optional else None


def build_graph(topology, n: int, seed: int) -> nx.Graph | nx.DiGraph:
    """Build the topology graph on nodes ``0..n-1``.

    ``topology`` is a scenario ``Topology`` (or anything with ``directed``,
    ``generator``, ``params`` and ``edges`` attributes); ``seed`` is the
    scenario seed, used when ``params`` has no ``seed``.  Raises
    :class:`GraphSpecError` for bad parameters; connectivity is checked by
    :func:`check_connected`.
    """
    import networkx as nx
    generator = topology.generator
    params = dict(topology.params or {})
    directed = bool(topology.directed)
    check_params(generator, params, n)
    if generator != "edges" and topology.edges is not None:
        raise GraphSpecError(f"only used with generator: edges (generator is {generator!r})",
                             "edges")
    seed = int(params.get("seed", seed))
    graph = nx.DiGraph() if directed else nx.Graph()
    graph.add_nodes_from(range(n))
    if generator == "edges":
        graph.add_edges_from(_explicit_edges(topology.edges, n, directed))
    elif directed and generator == "ring":
        graph.add_edges_from((i, (i + 1) % n) for i in range(n))
    elif directed and generator == "erdos_renyi":
        g = nx.gnp_random_graph(n, float(params["p"]), seed=_nx_seed(seed), directed=True)
        graph.add_edges_from(g.edges())
    else:
        for u, v in _undirected_edges(generator, params, n, seed):
            graph.add_edge(u, v)
            if directed:
                graph.add_edge(v, u)
    return graph


# --------------------------------------------------------------------------- checks
def _fmt_nodes(nodes, limit: int = 8) -> str:
    nodes = sorted(nodes)
    text = ", ".join(str(v) for v in nodes[:limit])
    return "{" + text + (", ..." if len(nodes) > limit else "") + "}"


def check_connected(graph: nx.Graph | nx.DiGraph) -> None:
    """Undirected: connected; directed: strongly connected.  Else GraphSpecError."""
    import networkx as nx
    if graph.number_of_nodes() <= 1:
        return
    if graph.is_directed():
        comps = sorted((sorted(c) for c in nx.strongly_connected_components(graph)),
                       key=lambda c: c[0])
        if len(comps) > 1:
            # find a concrete pair that has no directed path
            src = comps[0][0]
            reach = nx.descendants(graph, src) | {src}
            missing = [v for v in graph.nodes if v not in reach]
            if missing:
                pair = f"node {src} cannot reach node {min(missing)}"
            else:
                back = nx.ancestors(graph, src) | {src}
                pair = f"node {min(v for v in graph.nodes if v not in back)} cannot reach node {src}"
            shown = "; ".join(_fmt_nodes(c) for c in comps[:4])
            more = "; ..." if len(comps) > 4 else ""
            raise GraphSpecError(
                f"directed graph is not strongly connected ({pair}; {len(comps)} strongly "
                f"connected components: {shown}{more})")
    else:
        comps = sorted((sorted(c) for c in nx.connected_components(graph)), key=lambda c: c[0])
        if len(comps) > 1:
            shown = "; ".join(_fmt_nodes(c) for c in comps[:4])
            more = "; ..." if len(comps) > 4 else ""
            raise GraphSpecError(
                f"graph is disconnected ({len(comps)} components: {shown}{more})")


def is_tree(graph: nx.Graph) -> bool:
    """Connected undirected graph without cycles."""
    import networkx as nx
    return (not graph.is_directed() and graph.number_of_nodes() >= 1
            and graph.number_of_edges() == graph.number_of_nodes() - 1
            and nx.is_connected(graph))


def bfs_spanning_tree(graph: nx.Graph) -> nx.Graph:
    """BFS spanning tree rooted at the lowest-index centre (see module docstring)."""
    import networkx as nx
    n = graph.number_of_nodes()
    tree = nx.Graph()
    tree.add_nodes_from(sorted(graph.nodes))
    if n <= 1:
        return tree
    root = min(nx.center(graph))
    seen = {root}
    frontier = [root]
    while frontier:
        nxt = []
        for u in frontier:
            for v in sorted(graph.neighbors(u)):
                if v not in seen:
                    seen.add(v)
                    tree.add_edge(u, v)
                    nxt.append(v)
        frontier = nxt
    return tree


def bfs_spanning_forest(n: int, edges) -> list[tuple[int, int]]:
    """The edges ``(parent, child)`` of a BFS spanning tree of every connected component of
    the graph on nodes ``0 .. n-1`` with ``edges``, each rooted at its lowest-index centre,
    neighbours in increasing order: :func:`bfs_spanning_tree` of a graph that may be
    disconnected (the links up at one tick of a graph that changes), in plain Python, since a
    run may need one per tick."""
    adj: list[list[int]] = [[] for _ in range(n)]
    for u, v in edges:
        if u != v:
            adj[u].append(v)
            adj[v].append(u)
    adj = [sorted(set(a)) for a in adj]

    def bfs(root: int) -> list[int]:
        """Distances from ``root`` (-1: unreached)."""
        dist = [-1] * n
        dist[root] = 0
        frontier = [root]
        while frontier:
            nxt = []
            for u in frontier:
                for v in adj[u]:
                    if dist[v] < 0:
                        dist[v] = dist[u] + 1
                        nxt.append(v)
            frontier = nxt
        return dist

    out: list[tuple[int, int]] = []
    done = [False] * n
    for start in range(n):
        if done[start]:
            continue
        comp = [i for i, d in enumerate(bfs(start)) if d >= 0]
        for i in comp:
            done[i] = True
        if len(comp) == 1:
            continue
        ecc = {i: max(bfs(i)) for i in comp}
        radius = min(ecc.values())
        root = min(i for i in comp if ecc[i] == radius)
        seen = {root}
        frontier = [root]
        while frontier:
            nxt = []
            for u in frontier:
                for v in adj[u]:
                    if v not in seen:
                        seen.add(v)
                        out.append((u, v))
                        nxt.append(v)
            frontier = nxt
    return out


def all_pairs_work(graph: nx.Graph | nx.DiGraph) -> int:
    """Nodes and edges visited by one breadth-first search from every node: the cost
    of an exact diameter or centre of a graph that is not a tree."""
    n = graph.number_of_nodes()
    return n * (n + graph.number_of_edges())


def _farthest(graph, source) -> tuple[int, int]:
    """(a farthest node from ``source``, its distance) by breadth-first search."""
    import networkx as nx
    dist = nx.single_source_shortest_path_length(graph, source)
    far = max(dist.items(), key=lambda kv: (kv[1], -kv[0]))
    return far[0], far[1]


def diameter(graph: nx.Graph | nx.DiGraph) -> int:
    """(Directed) diameter; 0 for a single node.

    A tree takes two breadth-first searches (the farthest node from any node
    is an end of a longest path); any other graph one from every node.
    """
    import networkx as nx
    if graph.number_of_nodes() <= 1:
        return 0
    graph = _undirected_if_symmetric(graph)
    if is_tree(graph):
        end, _ = _farthest(graph, min(graph.nodes))
        return _farthest(graph, end)[1]
    return int(nx.diameter(graph))


def _undirected_if_symmetric(graph):
    """A digraph whose every arc has its reverse has the distances of its undirected view."""
    if graph.is_directed() and all(graph.has_edge(v, u) for u, v in graph.edges):
        return graph.to_undirected(as_view=True)
    return graph


def diameter_bounds(graph: nx.Graph | nx.DiGraph) -> tuple[int, int]:
    """Cheap ``(lower, upper)`` bounds of :func:`diameter` (exact for a tree).

    Lower: the eccentricity reached by two sweeps of breadth-first search;
    upper: ``ecc_out(v) + ecc_in(v)`` of a node (``2 ecc(v)`` undirected).
    """
    n = graph.number_of_nodes()
    if n <= 1:
        return 0, 0
    graph = _undirected_if_symmetric(graph)
    if is_tree(graph):
        d = diameter(graph)
        return d, d
    v0 = min(graph.nodes)
    far, e_out = _farthest(graph, v0)
    lower = max(e_out, _farthest(graph, far)[1])
    e_in = _farthest(graph.reverse(copy=False), v0)[1] if graph.is_directed() else e_out
    return lower, min(n - 1, e_out + e_in)


def topology_arcs(graph: nx.Graph | nx.DiGraph) -> list[tuple[int, int]]:
    """Every directed link of a topology, sorted: the arcs of a digraph, both directions
    of every edge of an undirected graph.  The run's network has one link per arc."""
    if graph.is_directed():
        return sorted((int(u), int(v)) for u, v in graph.edges())
    return sorted([(int(u), int(v)) for u, v in graph.edges()] + [(int(v), int(u)) for u, v in graph.edges()])


# --------------------------------------------------------------------------- exchange
@dataclass(frozen=True)
class ExchangeGraph:
    """The graph a protocol runs on.

    ``graph``: undirected tree (``tree``) or DiGraph (``flood``); ``arcs``:
    every directed link ``(u, v)`` in sorted order; ``neighbors[i]``: sorted
    out-neighbours of node ``i``; ``d_g``: its (directed) diameter, computed
    when first asked for (on a large graph that is not a tree it costs one
    search per node, see :func:`all_pairs_work`).
    """

    graph: nx.Graph | nx.DiGraph
    arcs: list[tuple[int, int]] = field(default_factory=list)
    neighbors: list[list[int]] = field(default_factory=list)

    @property
    def n(self) -> int:
        return self.graph.number_of_nodes()

    @functools.cached_property
    def d_g(self) -> int:
        return diameter(self.graph)


def protocol_graph(protocol: str) -> str:
    """``"tree"`` or ``"digraph"``: the kind of graph a registered protocol runs on."""
    return getattr(PROTOCOLS.get(protocol).implementation, "graph", "digraph")


def make_exchange(graph: nx.Graph | nx.DiGraph, protocol: str,
                  spanning_tree: bool = False) -> ExchangeGraph:
    """Exchange graph of a validated topology ``graph`` for ``protocol``."""
    import networkx as nx
    kind = protocol_graph(protocol)
    if kind == "tree":
        if graph.is_directed():
            raise GraphSpecError("protocol tree needs an undirected topology; use flood")
        used = bfs_spanning_tree(graph) if spanning_tree else graph
        if not is_tree(used):
            raise GraphSpecError("protocol tree needs a tree; set spanning_tree: true")
        used = nx.Graph(used)
    elif kind == "digraph":
        if spanning_tree:
            if graph.is_directed():
                raise GraphSpecError("spanning_tree needs an undirected topology")
            graph = bfs_spanning_tree(graph)
        used = nx.DiGraph(graph) if graph.is_directed() else graph.to_directed()
    else:
        raise GraphSpecError(f"unknown protocol {protocol!r}")
    n = used.number_of_nodes()
    if used.is_directed():
        arcs = sorted((int(u), int(v)) for u, v in used.edges())
        neighbors = [sorted(int(v) for v in used.successors(i)) for i in range(n)]
    else:
        arcs = sorted([(int(u), int(v)) for u, v in used.edges()]
                      + [(int(v), int(u)) for u, v in used.edges()])
        neighbors = [sorted(int(v) for v in used.neighbors(i)) for i in range(n)]
    return ExchangeGraph(graph=used, arcs=arcs, neighbors=neighbors)


# --------------------------------------------------------------------------- weights
def paper_weights(tree: nx.Graph) -> np.ndarray:
    """Effective origin weights for ``weights: paper`` on a tree.

    ``A[i, o]`` is the product, over the nodes ``v`` on the tree path from
    ``o`` to ``i`` other than ``o``, of ``1 / |N_v|`` (``|N_v|`` the degree of
    ``v``): each receiver ``v`` scales what it got from a neighbour by
    ``w_vl = 1/|N_v|``.  ``A[i, i] = 1``.
    """
    if not is_tree(tree):
        raise ValueError("paper_weights needs an undirected tree")
    n = tree.number_of_nodes()
    A = np.zeros((n, n))
    inv_deg = {v: 1.0 / tree.degree(v) if tree.degree(v) else 1.0 for v in tree.nodes}
    for o in range(n):
        A[o, o] = 1.0
        frontier = [o]
        while frontier:
            nxt = []
            for u in frontier:
                for v in tree.neighbors(u):
                    if v != o and A[v, o] == 0.0:
                        A[v, o] = A[u, o] * inv_deg[v]
                        nxt.append(v)
            frontier = nxt
    return A
