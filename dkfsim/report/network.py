"""The network drawing of a report: nodes, every link, and the graph the protocol used.

A tree protocol (or a spanning tree) is drawn top-down from its root, any other
graph on a circle (small) or a seeded spring layout (large), so the same
scenario always gives the same picture.  Every topology link is a thin grey
line, the exchange graph's links are dark (arrows on a directed graph).  Above
:data:`MAX_NODES` nodes only the nodes nearest the root (breadth-first in the
exchange graph) are drawn, and the caption says so (docs/design.md §5 for the
graphs each protocol runs on).
"""

from __future__ import annotations

import networkx as nx

from dkfsim.core.extras import pyplot
from dkfsim.report.plots.style import plain

#: At most this many nodes are drawn; a larger network is cut, and the caption says so.
MAX_NODES = 60


def _root(g) -> int:
    """The exchange graph's centre of lowest index (the spanning-tree root), node 0 if directed."""
    if g.is_directed() or g.number_of_nodes() > 2000:
        return min(g.nodes)
    return min(nx.center(g))


def _tree_positions(tree, root: int, keep: set) -> dict:
    """Top-down tidy layout: leaves left to right in depth-first order, parents centred."""
    sub = tree.subgraph(keep)
    depth = nx.single_source_shortest_path_length(sub, root)
    pos: dict[int, tuple[float, float]] = {}
    next_x = 0.0
    for v in nx.dfs_postorder_nodes(sub, root, sort_neighbors=sorted):
        kids = [u for u in sub.neighbors(v) if depth.get(u, -1) == depth[v] + 1]
        if kids:
            xs = [pos[u][0] for u in kids]
            pos[v] = ((min(xs) + max(xs)) / 2, -depth[v])
        else:
            pos[v] = (next_x, -depth[v])
            next_x += 1.0
    return pos


def draw_network(graph, exchange_graph, is_tree: bool, labels=None, title: str = "", uptime=None):
    """A matplotlib figure of the network; returns ``(figure, caption)``.  ``uptime`` (vehicles
    that move: ``{(u, v): fraction of the ticks the link was up}``, ``u < v``) draws each link by
    how long it was up, and no link never up, instead of the protocol's graph."""
    n = graph.number_of_nodes()
    root = _root(exchange_graph)
    order = list(nx.bfs_tree(exchange_graph, root)) if n > MAX_NODES else sorted(graph.nodes)
    keep = set(order[:MAX_NODES])
    g = graph.subgraph(keep)
    xg = exchange_graph.subgraph(keep)
    if is_tree:
        pos = _tree_positions(exchange_graph, root, keep)
    elif len(keep) <= 30:
        pos = nx.circular_layout(sorted(keep))
    else:
        pos = nx.spring_layout(g, seed=1)
    plt = pyplot()
    width = 7.5 if len(keep) <= 20 else 9.5
    fig, ax = plt.subplots(figsize=(width, 4.2 if is_tree else 5.2))
    if uptime is not None:                 # a changing graph: a complete graph of links used says nothing
        up = [(e, uptime.get((min(e), max(e)), 0.0)) for e in (g.to_undirected() if g.is_directed() else g).edges]
        up = [(e, f) for e, f in up if f > 0]
        if up:
            nx.draw_networkx_edges(nx.Graph([e for e, _ in up]), pos, ax=ax, edgelist=[e for e, _ in up],
                                   width=[0.4 + 3.0 * f for _, f in up],
                                   edge_color=[str(round(0.85 - 0.7 * f, 3)) for _, f in up])
    else:
        nx.draw_networkx_edges(g.to_undirected() if g.is_directed() else g, pos, ax=ax,
                               edge_color="0.75", width=0.8, style="dashed")
        nx.draw_networkx_edges(xg, pos, ax=ax, edge_color="0.15", width=1.6,
                               arrows=xg.is_directed(), arrowsize=10,
                               node_size=300 if len(keep) <= 30 else 80)
    size = 420 if len(keep) <= 20 else (260 if len(keep) <= 40 else 120)
    nx.draw_networkx_nodes(g, pos, ax=ax, node_color="#cfe2f3", edgecolors="#2a6fb0", node_size=size)
    if len(keep) <= 40:                   # the index inside the circle, the sensor's name under it
        nx.draw_networkx_labels(g, pos, labels={v: str(v) for v in keep}, ax=ax,
                                font_size=7 if len(keep) <= 20 else 6)
        if labels is not None and len(keep) <= 20:
            for v in keep:
                ax.annotate(plain(labels[v], 30), pos[v], textcoords="offset points", xytext=(0, -10),
                            ha="center", va="top", fontsize=6.5, color="0.25", zorder=5,
                            bbox=dict(boxstyle="round,pad=0.1", fc="white", ec="none", alpha=0.8))
    ax.set_axis_off()
    if title:
        ax.set_title(plain(title), fontsize=10)
    fig.tight_layout()
    if uptime is not None:
        ever = sum(1 for f in uptime.values() if f > 0)
        caption = (f"{n} vehicles; the {ever} links that were up at some tick, the thicker and darker the "
                   "longer they were up (their fraction of the ticks: the \"Link up-time\" table); links "
                   "never in range are not drawn")
    else:
        caption = (f"{n} nodes, {graph.number_of_edges()} links; dark: the links the protocol uses"
                   + (" (a tree, drawn from its root, node " + str(root) + ")" if is_tree else "")
                   + "; dashed grey: other links of the topology")
    if n > MAX_NODES:
        caption += (f". Only {MAX_NODES} of the {n} nodes are drawn (those nearest node {root} in "
                    "the exchange graph), so that the drawing stays readable")
    return fig, caption
