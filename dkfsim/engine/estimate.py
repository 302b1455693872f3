"""What one run will need, from its estimators' own estimates, before it starts.

The run's shared state (truth, measurements, information contributions,
the network) plus the scenario's anti-delay DKF plus every listed
estimator's :meth:`~dkfsim.estimators.base.Estimator.cost`.  On a large
graph that is not a tree, the exact diameter (for ``flood``'s buffer) or
the spanning tree's centre costs a search per node; the estimate then uses
a cheap lower bound of the diameter and adds that search to the time.
"""

from __future__ import annotations

from dkfsim.components import topology as topo
from dkfsim.components.estimators import AntiDelayParams
from dkfsim.core.registry import ESTIMATORS
from dkfsim.core.resources import B_FLOAT, C_VISIT, CHEAP_VISITS, Cost, check
from dkfsim.engine.results import resolve_save_mode
from dkfsim.estimators.anti_delay import AntiDelayDKF


def exchange_shape(scenario) -> tuple[int, int, float]:
    """``(L, arcs, seconds)``: the buffer length, the number of links of the exchange
    graph and the time to find them, without an all-pairs search on a large graph
    that is not a tree (whose diameter is then estimated from below)."""
    graph = scenario.graph()
    if topo.is_tree(graph) or not (scenario.protocol_graph == "digraph" or scenario.spanning_tree) \
            or topo.all_pairs_work(graph) <= CHEAP_VISITS:
        return scenario.resolved_buffer_length(), len(scenario.exchange().arcs), 0.0
    L, _ = scenario.buffer_length_bound()
    arcs = 2 * (scenario.n - 1) if scenario.spanning_tree else \
        graph.number_of_edges() * (1 if graph.is_directed() else 2)
    return L, arcs, topo.all_pairs_work(graph) * C_VISIT


def estimate_run(scenario, save: str = "auto") -> Cost:
    """Memory and time of one run of ``scenario`` (its DKF and every listed estimator)."""
    n, nx, K = scenario.n, scenario.nx, int(scenario.steps)
    L, arcs, search = exchange_shape(scenario)
    mode = resolve_save_mode(save, n, K)
    m_total = sum(s.m for s in scenario.sensors)
    varying = any(s.kind != "linear" for s in scenario.sensors)
    total = Cost(f"{scenario.name}: a run of {K} ticks on {n} nodes")
    total.memory["truth and measurements"] = K * (nx + m_total) * B_FLOAT
    total.memory["information contributions"] = K * n * nx * B_FLOAT * (1 + (nx if varying else 0))
    total.memory["graph and bookkeeping"] = (n + arcs) * 200 + min(L, K) * (n + 3 * arcs) * 40
    total.seconds = search
    parts = [AntiDelayDKF.cost(AntiDelayParams(), scenario, L=L, arcs=arcs, save=mode)]
    for p in scenario.estimators:
        parts.append(ESTIMATORS.get(p.kind).implementation.cost(p, scenario, L=L, arcs=arcs, save=mode))
    for part in parts:
        total.seconds += part.seconds
        for key, size in part.memory.items():
            total.memory[f"{key} ({part.what})" if key in total.memory else key] = size
    return total


def check_run(scenario, *, save: str = "auto", yes: bool = False) -> Cost:
    """:func:`~dkfsim.core.resources.check` one run; returns its estimate."""
    est = estimate_run(scenario, save)
    check(est, yes=yes, hint="fewer steps or nodes, a shorter buffer_length, fusion: none, "
                             "or --save estimates (no n x n x K arrival log)")
    return est
