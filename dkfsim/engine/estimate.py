"""What one run will need, from its estimators' own estimates, before it starts.

The run's shared state (truth, measurements, information contributions,
the network) plus the scenario's anti-delay DKF plus every listed
estimator's :meth:`~dkfsim.estimators.base.Estimator.cost`, all read from the run's
:class:`~dkfsim.config.plan.RunPlan`.  On a large graph that is not a tree, the exact
diameter (for ``flood``'s buffer) or the spanning tree's centre costs a search per node;
the plan then gives a cheap lower bound of the buffer length and the estimate adds that
search to the time (:attr:`RunPlan.search_seconds <dkfsim.config.plan.RunPlan.search_seconds>`).
"""

from __future__ import annotations

from dkfsim.components.estimators import AntiDelayParams
from dkfsim.config.plan import RunPlan
from dkfsim.core.registry import ESTIMATORS
from dkfsim.core.resources import B_FLOAT, C_PACKET, Cost, check
from dkfsim.estimators.anti_delay import AntiDelayDKF


def estimate_run(run, save: str = "auto") -> Cost:
    """Memory and time of one run (its DKF and every listed estimator): ``run`` is its
    :class:`~dkfsim.config.plan.RunPlan`, or a scenario (planned with ``save``)."""
    plan = run if isinstance(run, RunPlan) else RunPlan.of(run, save)
    scenario = plan.scenario
    n, nx, K = scenario.n, scenario.nx, int(scenario.steps)
    L, arcs = plan.L_estimate, plan.n_exchange_links
    m_total = sum(s.m for s in scenario.sensors)
    varying = any(s.kind != "linear" for s in scenario.sensors)
    total = Cost(f"{scenario.name}: a run of {K} ticks on {n} nodes")
    total.memory["truth and measurements"] = K * (nx + m_total) * B_FLOAT
    total.memory["information contributions"] = K * n * nx * B_FLOAT * (1 + (nx if varying else 0))
    total.memory["graph and bookkeeping"] = (n + arcs) * 200 + min(L, K) * (n + 3 * arcs) * 40
    total.seconds = plan.search_seconds
    medium = scenario.medium
    if medium is not None and medium.background is not None:
        # every background frame is an event of the channel engine, in each estimator's copy
        frames = (medium.background.packets_per_second * len(medium.members(n)) * K * float(scenario.model.T))
        total.seconds += frames * (1 + len(scenario.estimators)) * C_PACKET
    parts = [AntiDelayDKF.cost(AntiDelayParams(), plan)]
    for p in scenario.estimators:
        parts.append(ESTIMATORS.get(p.kind).implementation.cost(p, plan))
    for part in parts:
        total.seconds += part.seconds
        for key, size in part.memory.items():
            total.memory[f"{key} ({part.what})" if key in total.memory else key] = size
    return total


def check_run(run, *, save: str = "auto", yes: bool = False) -> Cost:
    """:func:`~dkfsim.core.resources.check` one run (a plan, or a scenario planned with
    ``save``); returns its estimate."""
    est = estimate_run(run, save)
    check(est, yes=yes, hint="fewer steps or nodes, a shorter buffer_length, fusion: none, "
                             "less background load, or --save estimates (no n x n x K arrival log)")
    return est
