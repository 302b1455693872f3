"""What one run will need, from its estimators' own estimates, before it starts.

The run's shared state (truth, measurements, information contributions,
the network) plus the scenario's anti-delay DKF plus every listed
estimator's :meth:`~dkfsim.estimators.base.Estimator.cost`, all read from the run's
:class:`~dkfsim.config.plan.RunPlan`.  On a large graph that is not a tree, the exact
diameter (for ``flood``'s buffer) or the spanning tree's centre costs a search per node;
the plan then gives a cheap lower bound of the buffer length and the estimate adds that
search to the time (:attr:`RunPlan.search_seconds <dkfsim.config.plan.RunPlan.search_seconds>`).

That time is an analytic guess (each node re-running its whole window every tick, a fixed number
of packets per link and tick): right within a factor of a few, enough to know that a run is
short.  Where it is not short (above :data:`TRIAL_ABOVE_S`), the commands measure the run's
events on a trial (:func:`dkfsim.engine.driver.trial_events`) and :func:`estimate_run` turns
those into seconds (:func:`~dkfsim.core.resources.event_seconds`).
"""

from __future__ import annotations

from dkfsim.components.estimators import AntiDelayParams
from dkfsim.components.medium import Sps
from dkfsim.components.traffic import background_packets
from dkfsim.config.plan import RunPlan
from dkfsim.config.schema import named
from dkfsim.core.registry import ESTIMATORS
from dkfsim.core.resources import B_FLOAT, C_PACKET, C_RADIO_MEMBER, EVENT_KINDS, Cost, check, event_seconds
from dkfsim.estimators.anti_delay import AntiDelayDKF
from dkfsim.network.radio_kernels import WINDOW_SF

#: Above this many seconds of the analytic guess, a command measures its events on a trial.
TRIAL_ABOVE_S = 30.0
#: The scenario keys that make one run smaller, besides its steps (every refusal's hint names them).
SMALLER_RUN = "nodes or medium.bystanders, a shorter buffer_length, fusion: none"
#: The refusal's hint of ``dkfsim run`` (every option it names applies to the command).
RUN_HINT = (f"fewer steps (--steps), {SMALLER_RUN}, less background load, or --save estimates "
            "(no n x n x K arrival log)")
#: The refusal's hint of ``dkfsim validate`` (which takes only the scenario's keys).
VALIDATE_HINT = (f"fewer steps, {SMALLER_RUN}, or less background load (dkfsim run --save estimates keeps "
                 "no n x n x K arrival log)")


def smaller_run_hint(steps: str = "--steps") -> str:
    """What makes each run of many smaller (a memory refusal's hint: ``steps`` names how the
    command sets the ticks)."""
    return f"a smaller run (fewer {steps}, {SMALLER_RUN})"


#: Bytes a spatial radio (``medium.radio``) keeps per tick and vehicle on it: the plan's places of
#: every vehicle, nodes and bystanders (:attr:`RunPlan.radio_places <dkfsim.config.plan.RunPlan.radio_places>`:
#: x and y, float64, and whether it is on the road);
RADIO_PLACES_BYTES = 2 * B_FLOAT + 1
#: each copy of the channel (:class:`~dkfsim.network.media.radio.SpatialChannel`): its own positions
#: of its members, their x and y apart, whether each is off the road and its busy ns;
RADIO_COPY_BYTES = 2 * B_FLOAT + 2 * B_FLOAT + 1 + 8
#: and the channel busy ratio per tick and member of ``run.npz`` (``cbr``) with the busy rows it
#: is computed from.
RADIO_SERIES_BYTES = 2 * B_FLOAT


def channel_copies(scenario) -> int:
    """How many copies of each medium (the shared channel, a rate-limited link) a run makes: the
    DKF's and one per listed estimator that has a network and media of its own
    (:attr:`~dkfsim.estimators.base.Estimator.network_model`,
    :attr:`~dkfsim.estimators.base.Estimator.own_media`); one with ``links.shared_queues``."""
    if scenario.links.shared_queues:
        return 1
    return 1 + sum(bool(getattr(impl, "network_model", True) and getattr(impl, "own_media", True))
                   for impl in (ESTIMATORS.get(p.kind).implementation for p in scenario.estimators))


def radio_members(scenario) -> int:
    """The vehicles on a spatial radio (``medium.radio``: nodes and bystanders); 0 without one."""
    medium = scenario.medium
    if medium is None or medium.radio is None or scenario.mobility is None:
        return 0
    return len(medium.members(scenario.n))


def radio_memory(plan: RunPlan) -> dict[str, float]:
    """The memory of a spatial radio, by item: every vehicle's position at every tick
    (:data:`RADIO_PLACES_BYTES`, :data:`RADIO_COPY_BYTES` in each copy of the channel,
    :data:`RADIO_SERIES_BYTES`) -- ``medium.bystanders`` of 10 000 over 100 000 ticks are tens of
    GiB -- and the sidelink's (``access: sps``) state per pair of vehicles and its sensing window
    per vehicle (:mod:`~dkfsim.network.media.sidelink`).  Empty without ``medium.radio``."""
    sc = plan.scenario
    medium = sc.medium
    members = radio_members(sc)
    if not members:
        return {}
    ticks = int(sc.steps) + 1
    bystanders = medium.bystanders.n if medium.bystanders is not None else 0
    copies = channel_copies(sc)
    what = f"positions of {members} vehicles on the radio" + (f" ({bystanders} medium.bystanders)" if bystanders else "")
    times = f" in {copies} copies of the channel" if copies > 1 else ""
    out: dict[str, float] = {
        f"{what} at {ticks} ticks{times}":
            float(ticks) * ((sc.n + bystanders) * RADIO_PLACES_BYTES
                            + members * (copies * RADIO_COPY_BYTES + RADIO_SERIES_BYTES))}
    if isinstance(medium.access, Sps):
        pairs = float(members) * members * (4 * 8 + B_FLOAT)        # what each heard of each, its power
        window = float(members) * WINDOW_SF * (medium.access.subchannels * B_FLOAT + 1)
        out[f"the sidelink's state per pair of its {members} vehicles{times}"] = \
            copies * (pairs + window)
    return out


def radio_seconds(plan: RunPlan) -> float:
    """CPU seconds a spatial radio spends at its members: every frame on the air visits every
    vehicle on it (:data:`~dkfsim.core.resources.C_RADIO_MEMBER` each), so the time grows with
    the square of the vehicles (3,000 ``medium.bystanders`` beaconing for 3 s of simulated time:
    about 35 s of CPU).  Frames: the background's, and one per node and tick for the estimators'
    (a flush per tick), in each copy of the channel.  Zero without ``medium.radio``; added to the
    analytic guess and to a trial's events alike (they count frames, not the vehicles each one
    visits)."""
    sc = plan.scenario
    medium = sc.medium
    members = radio_members(sc)
    if not members:
        return 0.0
    steps = int(sc.steps)
    frames = float(sc.n) * steps
    if medium.background is not None:
        frames += medium.background.packets_per_second * members * steps * float(sc.model.T)
    return channel_copies(sc) * frames * members * C_RADIO_MEMBER


def trial_ticks(plan: RunPlan) -> int:
    """The ticks of a trial: twice the buffer and 20 more (the window's re-runs reach their
    steady depth after ``L`` ticks), at most the run's."""
    return int(min(int(plan.scenario.steps), 2 * min(plan.L_estimate, 10**6) + 20))


def trial_is_short(plan: RunPlan, guess: Cost) -> bool:
    """Whether a trial of ``plan`` (:func:`trial_ticks`) is short by the analytic ``guess`` of
    the whole run: at most :data:`TRIAL_ABOVE_S`.  A longer trial is not run -- the guess
    stands, and an absurd load (a background of 1e9 packets/s) is refused on it instead of
    being measured for hours."""
    K = max(1, int(plan.scenario.steps))
    return guess.seconds * trial_ticks(plan) / K <= TRIAL_ABOVE_S


def scaled_events(events: dict, ticks: int, K: int) -> dict[str, float]:
    """The events of a trial of ``ticks`` ticks scaled to a run of ``K``."""
    return {k: float(events[k]) * K / ticks for k in EVENT_KINDS}


def estimate_run(run, save: str = "auto", events: dict | None = None, how: str = "") -> Cost:
    """Memory and time of one run (its DKF and every listed estimator): ``run`` is its
    :class:`~dkfsim.config.plan.RunPlan`, or a scenario (planned with ``save``).  ``events``:
    the run's events measured on a trial and scaled to its ticks (``how`` says how), which
    then give the time; without them the time is the analytic guess."""
    plan = run if isinstance(run, RunPlan) else RunPlan.of(run, save)
    scenario = plan.scenario
    n, nx, K = scenario.n, scenario.nx, int(scenario.steps)
    L, arcs = plan.L_estimate, plan.n_exchange_links
    m_total = sum(s.m for s in scenario.sensors)
    varying = any(s.kind != "linear" for s in scenario.sensors)
    total = Cost(f"{named(scenario)}: a run of {K} ticks on {n} nodes")
    total.memory["truth and measurements"] = K * (nx + m_total) * B_FLOAT
    total.memory["information contributions"] = K * n * nx * B_FLOAT * (1 + (nx if varying else 0))
    total.memory["graph and bookkeeping"] = (n + arcs) * 200 + min(L, K) * (n + 3 * arcs) * 40
    total.memory.update(radio_memory(plan))
    total.seconds = plan.search_seconds + background_packets(scenario, plan.arcs, channel_copies(scenario)) * C_PACKET \
        + radio_seconds(plan)
    parts = [AntiDelayDKF.cost(AntiDelayParams(), plan)]
    for p in scenario.estimators:
        parts.append(ESTIMATORS.get(p.kind).implementation.cost(p, plan))
    for part in parts:
        total.seconds += part.seconds
        for key, size in part.memory.items():
            total.memory[f"{key} ({part.what})" if key in total.memory else key] = size
    if events is not None:
        total.events = {k: float(events[k]) for k in EVENT_KINDS}
        total.how = how
        total.seconds = plan.search_seconds + event_seconds(total.events, n * nx) + radio_seconds(plan)
    return total


def buffer_warning(plan: RunPlan) -> str | None:
    """A warning when the scenario's integer ``buffer_length`` is below the bound the plan
    computes for ``auto`` (``d_t d_g + 1``; on a changing graph ``(n - 1)(B + d_t) + 1``), else
    None.  On a changing graph a ``late`` count of 0 does not mean the final rows are exact: a
    row's information may still be on its way when the row leaves the window, unseen (docs/design.md
    §6)."""
    sc = plan.scenario
    L = sc.buffer_length
    if not isinstance(L, int) or isinstance(L, bool) or plan.d_t is None:
        return None
    if plan.graph_changes:
        B = plan.connect_window
        if B is None:
            return (f"buffer_length {L}: the links up never make a connected union over the run (no window "
                    "B), so no buffer length makes the final rows exact, and late = 0 does not say they are "
                    "(docs/mobility.md)")
        bound = (sc.n - 1) * (B + plan.d_t) + 1
        if L >= bound:
            return None
        return (f"buffer_length {L} is below (n - 1)(B + d_t) + 1 = ({sc.n} - 1)({B} + {plan.d_t}) + 1 = "
                f"{bound}, the bound for this changing graph: a final row can differ from what the "
                "centralized filter knows even when late = 0 (information still on its way when the row "
                "leaves the window is not counted as late; docs/mobility.md); buffer_length: auto uses the bound")
    bound = plan.d_t * plan.exchange.d_g + 1
    if L >= bound:
        return None
    return (f"buffer_length {L} is below d_t d_g + 1 = {plan.d_t} x {plan.exchange.d_g} + 1 = {bound}: "
            "information slower than the window arrives late (the run counts it as late) and the final "
            "rows miss it; buffer_length: auto uses the bound")


def check_run(run, *, save: str = "auto", yes: bool = False) -> Cost:
    """:func:`~dkfsim.core.resources.check` one run (a plan, or a scenario planned with
    ``save``) on its analytic guess; returns the estimate.  (``dkfsim.run`` and ``dkfsim run``
    measure a trial first when the guess is long: :func:`dkfsim.engine.driver.check_run_measured`.)"""
    est = estimate_run(run, save)
    check(est, yes=yes, hint=RUN_HINT)
    return est
