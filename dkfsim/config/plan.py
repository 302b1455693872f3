"""What a scenario implies for a run, worked out once: the run plan.

A validated :class:`~dkfsim.config.schema.Scenario` is configuration.  What follows from it
is derived here, in one :class:`RunPlan` per run, and read by every part that needs it:
validation checks it (``Scenario._check_consistency`` builds one and raises at the key
that is wrong), :meth:`Estimator.cost <dkfsim.estimators.base.Estimator.cost>` estimates
from it, the engine builds the network from it, and the estimators' ``start()`` follow it
(``ctx.plan``) -- so no error can surface there that validation did not raise.  A fact
costly on a large graph (the exchange graph's centre, its diameter) is computed when first
asked for and kept; checks that must answer in seconds use cheap bounds
(:meth:`RunPlan.buffer_length_bound`).  The scenario no longer keeps any of it.

The plan has one section per kind of fact, so that later work extends one place:

* the network: the topology graph, its arcs (one link each) and the per-hop delay bound
  (links with rates and queues add their settings here);
* the exchange: the protocol, the graph it runs on and that graph's diameter; with
  ``mobility:`` the per-tick link schedule (:attr:`RunPlan.link_schedule`) and the window
  ``B`` of the finite-time result on a changing graph;
* the buffer: ``L`` for any ``buffer_length``, exact or bounded (a rule for changing graphs
  goes into :meth:`RunPlan.buffer_length`);
* the anti-delay DKF instances: the scenario's own and every listed one, their settings
  resolved against the scenario's (:class:`DKFSettings`), and the memory of their fusion;
* the output: the save mode.

A Monte Carlo shares one plan between its runs (:meth:`RunPlan.with_seed`): nothing in it
depends on the seed but a random topology, which the Monte Carlo pins.
"""

from __future__ import annotations

import copy
import functools
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from dkfsim.components import topology as topo
from dkfsim.components.estimators import AntiDelayParams, NoBufferParams
from dkfsim.components.mobility import LinkSchedule
from dkfsim.core.resources import B_FLOAT, C_VISIT, CHEAP_VISITS, SaveMode, resolve_save_mode

if TYPE_CHECKING:
    import networkx

#: The plans the last validations worked out, newest last, as ``(scenario, plan)``: the command
#: that validated a scenario runs the plan it checked (:meth:`RunPlan.of`).  A scenario keeps
#: no derived state, and the list is short, so a sweep's thousands of scenarios keep no plan
#: alive (docs/decisions.md, "The plan once per command").
_WORKED_OUT: deque[tuple[Any, RunPlan]] = deque(maxlen=8)


def remember(scenario: Any, plan: RunPlan) -> None:
    """``plan`` is what validating ``scenario`` worked out (:meth:`RunPlan.of` finds it)."""
    _WORKED_OUT.append((scenario, plan))


def worked_out(scenario: Any) -> RunPlan:
    """The plan validating ``scenario`` worked out, if it is among the last few; else a new
    one (remembered)."""
    for known, plan in reversed(_WORKED_OUT):
        if known is scenario:
            return plan
    plan = RunPlan(scenario)
    remember(scenario, plan)
    return plan


@dataclass(frozen=True)
class DKFSettings:
    """One anti-delay DKF's settings, its unset keys taken from the scenario's: where they are
    given (``key``: ``""`` for the scenario's own, ``estimators.<i>`` for a listed one)."""

    key: str
    buffer_length: str | int
    fusion: str
    weights: str


class RunPlan:
    """The facts of one run of ``scenario`` (see the module); ``save`` is ``--save``."""

    def __init__(self, scenario: Any, save: str = "auto"):
        self.scenario = scenario
        #: what the run keeps (``auto`` resolved)
        self.save: SaveMode = resolve_save_mode(save, scenario.n, int(scenario.steps))

    @classmethod
    def of(cls, scenario: Any, save: str = "auto") -> RunPlan:
        """The plan of ``scenario`` its validation worked out (:func:`worked_out`), with the
        save mode ``save``: every fact already derived is shared, so a command builds the graphs
        and the trajectories once."""
        plan = worked_out(scenario)
        mode = resolve_save_mode(save, scenario.n, int(scenario.steps))
        if mode == plan.save:
            return plan
        copied = copy.copy(plan)        # shares the cached graphs and bounds
        copied.save = mode
        return copied

    def with_seed(self, scenario: Any) -> RunPlan:
        """The plan of ``scenario``, this plan's scenario with another seed: the facts already
        worked out are shared when the topology does not depend on the seed (a pinned or
        unseeded topology), else a new plan."""
        old = self.scenario
        if topo.graph_seed(old.topology, old.seed) != topo.graph_seed(scenario.topology, scenario.seed):
            return RunPlan(scenario, self.save)
        plan = copy.copy(self)          # shares the cached graphs and bounds
        plan.scenario = scenario
        return plan

    def resolve(self) -> RunPlan:
        """Work out now every fact a run reads (the graphs, the exchange graph's diameter, the
        delay bound), so that the copies :meth:`with_seed` makes share them; returns the plan."""
        _ = self.arcs, self.exchange.d_g, self.d_t, self.latency_bound, self.connect_window, self.tree_schedule
        return self

    # -- the network ------------------------------------------------------------------
    @functools.cached_property
    def graph(self) -> networkx.Graph | networkx.DiGraph:
        """The topology graph (nodes ``0..n-1``); raises
        :class:`~dkfsim.components.topology.GraphSpecError` for one that cannot be built."""
        sc = self.scenario
        return topo.build_graph(sc.topology, sc.n, sc.seed)

    @functools.cached_property
    def arcs(self) -> list[tuple[int, int]]:
        """Every directed link of the topology (an undirected edge both ways), sorted: the
        run's network has one link per arc."""
        return topo.topology_arcs(self.graph)

    @functools.cached_property
    def link_schedule(self) -> LinkSchedule | None:
        """Which links (:attr:`arcs`) are up at each tick ``0 .. K``, from the vehicles'
        positions and the range (``mobility:``); None without ``mobility``."""
        sc = self.scenario
        if sc.mobility is None or self.positions is None:
            return None
        schedule = LinkSchedule.from_positions(self.positions, self.arcs, sc.mobility.range,
                                               sc.mobility.links)
        for i in range(sc.n):
            fn = sc.mobility.sinr_at(i)
            if fn is not None:
                schedule.sinr[i] = fn
        return schedule

    @functools.cached_property
    def positions(self):
        """Every vehicle's position (m) at ticks ``0 .. K``, ``(K + 1, n, 2)``
        (:meth:`~dkfsim.components.mobility.Mobility.positions`); None without ``mobility``."""
        sc = self.scenario
        if sc.mobility is None:
            return None
        return sc.mobility.positions(sc.n, int(sc.steps), sc.model.T)

    @functools.cached_property
    def radio_places(self):
        """What a spatial radio (``medium.radio``) places: the nodes' positions then its bystanders'
        (``medium.bystanders``), ``(K + 1, n + count, 2)``, and whether each is on the road at each
        tick (None: every one always; the nodes always are); None without a radio."""
        sc = self.scenario
        if sc.medium is None or sc.medium.radio is None or self.positions is None:
            return None
        if sc.medium.bystanders is None:
            return self.positions, None
        speed = sc.mobility.speed if sc.mobility is not None else 1.0
        others, present = sc.medium.bystanders.positions(int(sc.steps), sc.model.T, speed)
        nodes = np.ones(self.positions.shape[:2], dtype=bool)
        return np.concatenate([self.positions, others], axis=1), np.concatenate([nodes, present], axis=1)

    @property
    def graph_changes(self) -> bool:
        """Whether some link is down at some tick (a schedule that never changes runs as the
        fixed graph, bit for bit)."""
        schedule = self.link_schedule
        return schedule is not None and schedule.changes

    @functools.cached_property
    def connect_window(self) -> int | None:
        """``B`` of the finite-time result on a changing graph (docs/design.md §6): the
        shortest length such that every interval of ``B`` ticks has a strongly connected union
        of the exchange graph's links; None without a changing graph, or when none exists."""
        schedule = self.link_schedule
        if schedule is None or not schedule.changes:
            return None
        index = {arc: i for i, arc in enumerate(self.arcs)}
        return schedule.connect_window(self.scenario.n, [index[a] for a in self.exchange_arcs])

    @functools.cached_property
    def tree_schedule(self) -> dict[int, list[tuple[int, int]]] | None:
        """``tree`` on a graph that changes: tick -> the arcs of the spanning forest from that
        tick on (a BFS tree of each component of the links up then, as ``spanning_tree``
        builds, :func:`~dkfsim.components.topology.bfs_spanning_forest`), at tick 1 and at
        every tick whose graph differs from the tick before.  None otherwise."""
        schedule = self.link_schedule
        if schedule is None or not schedule.changes or self.protocol_graph != "tree":
            return None
        out: dict[int, list[tuple[int, int]]] = {}
        seen: dict[bytes, list[tuple[int, int]]] = {}      # link sets recur: one forest each
        prev = None
        for k in range(1, schedule.K + 1):
            key = schedule.up[k].tobytes()
            if key == prev:
                continue
            prev = key
            arcs = seen.get(key)
            if arcs is None:
                forest = topo.bfs_spanning_forest(
                    self.scenario.n, [a for a, on in zip(self.arcs, schedule.up[k].tolist()) if on])
                arcs = seen[key] = sorted(forest + [(v, u) for u, v in forest])
            out[k] = arcs
        return out

    @property
    def exchange_arcs(self) -> list[tuple[int, int]]:
        """The arcs the protocol may use: the exchange graph's, or, for ``tree`` on a graph
        that changes (whose tree is rebuilt from the links up, :attr:`tree_schedule`), every
        arc of the topology."""
        if self.protocol_graph == "tree" and self.graph_changes:
            return self.arcs
        return self.exchange.arcs

    @functools.cached_property
    def latency_bound(self) -> int | None:
        """The largest per-hop delay in steps the links the protocol uses can produce (None if
        unbounded), whatever ``links.d_t`` assumes.  Without overrides every link has the
        default settings, so the exchange graph is not built."""
        sc = self.scenario
        T_ns = int(sc.T_ns)
        # a packet leaves only while its pair is in range: at most latency_per_m x radius more
        extra = self.distance_latency_ns()
        bound = -(-extra // T_ns)
        for u, v in (self.exchange_arcs if sc.links.overrides else [(-1, -1)]):
            spec = sc.link_spec(u, v)
            if extra:
                sup = spec.sup_ns(T_ns)
                b = None if sup is None else -(-(sup + extra) // T_ns)
            else:
                b = spec.bound_steps(T_ns)
            if b is None:
                return None
            bound = max(bound, b)
        return bound

    def distance_latency_ns(self) -> int:
        """The most ``mobility.links.latency_per_m`` adds to a packet (ns): at the range's radius."""
        mob = self.scenario.mobility
        if mob is None or mob.links is None or not mob.links.latency_per_m > 0:
            return 0
        return int(round(mob.links.latency_per_m * mob.range.radius * 1e9))

    @functools.cached_property
    def rate_limited(self) -> bool:
        """True when a link the protocol uses has a ``rate``: its packets queue, so an arrival
        has no bound however bounded the latency models are (``d_t`` ignores it)."""
        sc = self.scenario
        if sc.medium is not None or (sc.mobility is not None and sc.mobility.rate_from_distance):
            return True
        if not sc.links.overrides:
            return sc.link_spec(-1, -1).rate is not None
        return any(sc.link_spec(u, v).rate is not None for u, v in self.exchange_arcs)

    @property
    def arrival_bound(self) -> int | None:
        """The most ticks a packet of the exchange can take to arrive, per hop: the links'
        :attr:`latency_bound`, or None when nothing bounds it -- an unbounded latency model, a
        rate-limited link or a shared channel (queueing has no bound), or a graph that changes
        (a link that comes up resends old rows)."""
        if self.rate_limited or self.graph_changes:
            return None
        return self.latency_bound

    def late_horizon(self, L: int, n: int | None = None) -> int:
        """How many final rows a DKF of buffer length ``L`` on ``n`` nodes (None: the
        scenario's) keeps the holdings of, so that a late contribution counts once (the arrival
        log).  Nothing is sent for a final row, so with :attr:`arrival_bound` ``d`` a late packet
        arrives at most ``d + 1`` rows after its row became final: keep that many.  Unbounded:
        4096 rows, fewer on large networks so that the holdings (``n`` masks of ``n`` bits per
        row) stay near 64 MB.  (A run keeps at most its own rows: :meth:`kept_final_rows`.)"""
        bound = self.arrival_bound
        if bound is not None:
            return bound + 2
        n = self.scenario.n if n is None else n
        per_row = n * (n // 8 + 32)
        return int(max(L + 2, min(4096, (64 << 20) // per_row)))

    def kept_final_rows(self, L: int) -> int:
        """:meth:`late_horizon`, but never more rows than the run has (and two): a latency of
        years gives a horizon of billions of rows, of which a run of ``steps`` ticks holds
        ``steps``."""
        return min(self.late_horizon(L), int(self.scenario.steps) + 2)

    @functools.cached_property
    def d_t(self) -> int | None:
        """The delay bound in steps the buffer is sized for: ``links.d_t`` if set, else
        :attr:`latency_bound` (None if unbounded)."""
        d_t = self.scenario.links.d_t
        return d_t if d_t is not None else self.latency_bound

    def unbounded_models(self) -> list[str]:
        """The unbounded latency models of the links the protocol uses (sorted names)."""
        sc = self.scenario
        return sorted({name for u, v in self.exchange_arcs for name in sc.link_spec(u, v).unbounded_models(sc.T_ns)})

    # -- the exchange ----------------------------------------------------------------------
    @property
    def protocol(self) -> str:
        return str(self.scenario.protocol)

    @functools.cached_property
    def protocol_graph(self) -> str:
        """``"tree"`` or ``"digraph"``: what the protocol runs on."""
        return topo.protocol_graph(self.protocol)

    @functools.cached_property
    def exchange(self) -> topo.ExchangeGraph:
        """The graph the protocol runs on (its diameter ``d_g`` computed when first asked for)."""
        return topo.make_exchange(self.graph, self.protocol, self.scenario.spanning_tree)

    @property
    def n_exchange_links(self) -> int:
        """How many links the exchange graph has (without building it): a spanning tree's
        ``2 (n - 1)``, else every arc of the topology."""
        if self.scenario.spanning_tree:
            return 2 * (self.scenario.n - 1)
        return len(self.arcs)

    @functools.cached_property
    def diameter_is_costly(self) -> bool:
        """Whether the exchange graph's exact diameter (or the spanning tree's centre) needs a
        search from every node of a large graph that is not a tree."""
        graph, sc = self.graph, self.scenario
        return ((self.protocol_graph == "digraph" or sc.spanning_tree) and not topo.is_tree(graph)
                and topo.all_pairs_work(graph) > CHEAP_VISITS)

    @property
    def search_seconds(self) -> float:
        """CPU time of that search when it is costly (0 otherwise), for resource estimates."""
        return topo.all_pairs_work(self.graph) * C_VISIT if self.diameter_is_costly else 0.0

    @functools.cached_property
    def diameter_bounds(self) -> tuple[int, int]:
        """Cheap ``(lower, upper)`` bounds of the exchange graph's diameter: the topology's own
        (a spanning tree's is at least the graph's, and at most twice its radius)."""
        lower, upper = topo.diameter_bounds(self.graph)
        if self.scenario.spanning_tree:
            upper = 2 * upper
        return lower, min(upper, max(self.scenario.n - 1, 0))

    # -- the buffer --------------------------------------------------------------------------
    def buffer_length(self, spec: str | int | None = None) -> int:
        """``L`` for ``buffer_length`` ``spec`` (default: the scenario's), docs/design.md §4:
        ``auto`` -> ``d_t d_g + 1``, on a changing graph ``(n - 1)(B + d_t) + 1``
        (:attr:`connect_window`), ``paper`` -> ``max(d_t, 1)``, an integer -> itself."""
        spec = self.scenario.buffer_length if spec is None else spec
        if isinstance(spec, int):
            return spec
        d_t = self.d_t
        if d_t is None:
            raise ValueError(f"buffer_length {spec!r} needs a delay bound (validation refuses this scenario)")
        if spec == "paper":
            return max(d_t, 1)
        if self.graph_changes:
            B = self.connect_window
            if B is None:
                raise ValueError("buffer_length 'auto' needs a window B (validation refuses this scenario)")
            return (self.scenario.n - 1) * (B + d_t) + 1
        return d_t * self.exchange.d_g + 1

    def buffer_length_bound(self, spec: str | int | None = None) -> tuple[int, bool]:
        """``(L, exact)``: :meth:`buffer_length`, or, when ``auto`` would need the diameter of
        a large graph that is not a tree (:attr:`diameter_is_costly`), the cheap lower bound
        ``d_t * lower + 1`` with ``exact`` false.  For checks that must answer in seconds."""
        spec = self.scenario.buffer_length if spec is None else spec
        if spec == "auto" and self.diameter_is_costly and not self.graph_changes:
            return (self.d_t or 0) * self.diameter_bounds[0] + 1, False
        return self.buffer_length(spec), True

    @property
    def L_estimate(self) -> int:
        """The scenario's buffer length as resource estimates use it: exact, or on a large graph
        the cheap lower bound of :meth:`buffer_length_bound`."""
        return self.buffer_length_bound()[0]

    # -- the anti-delay DKF instances --------------------------------------------------------
    def dkf(self, params: AntiDelayParams | None = None, key: str = "") -> DKFSettings:
        """The settings of the DKF instance ``params`` (None: the scenario's own), unset keys
        taken from the scenario's."""
        sc = self.scenario
        if params is None:
            return DKFSettings(key, sc.buffer_length, sc.fusion, sc.weights)
        return DKFSettings(key, sc.buffer_length if params.buffer_length is None else params.buffer_length,
                           params.fusion or sc.fusion, params.weights or sc.weights)

    def dkfs(self) -> list[DKFSettings]:
        """Every anti-delay DKF of the run: the scenario's own, then each listed instance
        (``no_buffer`` is one with ``L = 1``)."""
        out = [self.dkf()]
        for i, p in enumerate(self.scenario.estimators):
            if isinstance(p, NoBufferParams):
                out.append(self.dkf(AntiDelayParams(name=p.label, buffer_length=1), f"estimators.{i}"))
            elif isinstance(p, AntiDelayParams):
                out.append(self.dkf(p, f"estimators.{i}"))
        return out

    def fusion_bytes(self, L: int) -> int:
        """Memory of the fusion's cross-covariance ring with buffer length ``L``:
        ``(min(L, K) + 1) (n nx)^2`` floats."""
        sc = self.scenario
        return (min(L, int(sc.steps)) + 1) * (sc.n * sc.nx) ** 2 * B_FLOAT

    def fusion_overflow(self, dkf: DKFSettings, limit: int) -> tuple[int, int, bool] | None:
        """None when ``dkf``'s fusion ring fits in ``limit`` bytes, else ``(L, bytes, exact)``
        for the message (``exact`` false: at least that much).  Cheap bounds decide when they
        can; the exact ``L`` is computed only when the lower bound fits and the upper does not."""
        if dkf.fusion == "none":
            return None
        L, exact = self.buffer_length_bound(dkf.buffer_length)
        if self.fusion_bytes(L) > limit:
            return L, self.fusion_bytes(L), exact
        if exact or self.fusion_bytes((self.d_t or 0) * self.diameter_bounds[1] + 1) <= limit:
            return None
        L = self.buffer_length(dkf.buffer_length)
        return (L, self.fusion_bytes(L), True) if self.fusion_bytes(L) > limit else None
