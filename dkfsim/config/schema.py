"""The scenario schema: every key of a scenario file, validated in one place.

A scenario is a YAML mapping (docs/scenarios.md, "The keys");
:func:`dkfsim.config.load.load_scenario` reads it and validates it into a
frozen :class:`Scenario`.  Field checks live in the parameter models,
cross-field checks (shapes, graph, protocol, buffer, time range, each
estimator against the scenario) in ``Scenario._check_consistency``, which reads what
the scenario implies for a run from a :class:`~dkfsim.config.plan.RunPlan` (the graph,
the delay bound, each anti-delay DKF's buffer and fusion memory): the plan a run
follows, so a run can meet no error its validation did not raise.  The scenario keeps
no derived state (no cached graph).  The
component keys -- a latency ``model``, a sensor or estimator ``kind``, a
topology ``generator``, the ``protocol`` -- are validated with the parameter
model the name has in its registry (:mod:`dkfsim.core.registry`), so this
module never imports the stages that implement them.

Decisions where docs/design.md leaves a choice:

* Matrices are lists of lists.  A scalar is a 1x1 matrix and a flat list is
  a single row (so ``H: [1, 0, 0]`` and ``R: 0.8`` work).  Vectors (the prior
  mean) are flat lists; a scalar is a 1-vector and an n x 1 column is
  flattened.  Entries must be finite and at most 1e100 in magnitude.
* R and P0 must be symmetric positive definite, Q symmetric positive
  semidefinite (tolerance ``1e-12 * max(1, max|eig|)``), symmetry exact up to
  ``1e-9`` relative.
* ``name`` defaults to the file's stem (``"unnamed"`` for a dict); sensor
  names and estimator names must be unique.  ``kind: constant_acceleration``
  must not give ``Phi``; ``kind: linear`` must.
* ``fusion: null`` means ``none``.  Integers and booleans are strict (``steps:
  3.0`` or ``directed: 1`` is an error); floats accept integers.
* ``links.d_t``, when given, is *the* delay bound used for the buffer length,
  even if the latency models have a smaller or larger one (so an
  under-estimated bound can be studied).  Otherwise ``d_t`` is the largest
  ``bound_steps`` over the links the protocol uses.  ``buffer_length: paper``
  needs a bound too.
* ``spanning_tree: true`` also applies to ``flood`` (flood then runs on the
  same BFS spanning tree); it is an error on a directed topology.
* ``estimators: [{kind: ..., name: ..., <parameters>}]`` lists the
  algorithms run beside the anti-delay DKF (default: ``centralized``); the
  old ``baselines: [kinds]`` (with ``consensus_rounds``) is still read and
  converted, ``local`` being the old name of ``local_only``.
* The source file is remembered (``scenario.source``) but is not part of
  ``to_dict``, the hash, or equality: two scenarios are equal when their
  ``to_dict`` are.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, BeforeValidator, Field, PrivateAttr, field_validator, model_validator
from pydantic_core import PydanticCustomError

from dkfsim.components import topology as topo
from dkfsim.components.estimators import BufferLength, CentralizedParams, EstimatorParams
from dkfsim.components.faults import Faults, LinkSpec, Schedule, Window
from dkfsim.components.latency import Constant, LatencyModel
from dkfsim.components.medium import Medium, smallest_frame
from dkfsim.components.mobility import SCHEDULE_LIMIT, Mobility
from dkfsim.components.sensors import SensorParams
from dkfsim.components.traffic import TRAFFIC_KEYS, TrafficKeys
from dkfsim.components.truth import TruthParams
from dkfsim.config.dynamics import Model, Prior
from dkfsim.config.plan import RunPlan, remember
from dkfsim.config.sweep import canonical_json
from dkfsim.core.files import clip, shown
from dkfsim.core.params import (
    MAX_NS,
    MAX_SECONDS,
    Name,
    Probability,
    StrictBool,
    StrictInt,
    StrictModel,
    Text,
    custom_error,
    registered,
)
from dkfsim.core.registry import ESTIMATORS, GENERATORS, MEDIA, PROTOCOLS, SENSOR_KINDS

#: Largest ring of fusion cross-covariances a scenario may ask for (bytes).
FUSION_MEMORY_LIMIT = 2 << 30


#: A sensor (any registered kind; ``linear`` when ``kind`` is absent) and an estimator entry
#: (to a type checker: the base models, which every registered one subclasses).
if TYPE_CHECKING:
    SensorField = SensorParams
    EstimatorField = EstimatorParams
else:
    SensorField = registered(SensorParams, SENSOR_KINDS, "linear")
    EstimatorField = registered(EstimatorParams, ESTIMATORS)


def _registered(registry):
    """An ``AfterValidator``: the value must name a member of ``registry``."""
    def check(value: str) -> str:
        if value not in registry:
            raise custom_error(registry.unknown(value))
        return registry.canonical(value)
    return check


# =========================================================================== sub-models
class Topology(StrictModel):
    """How the sensors are linked (see :mod:`dkfsim.components.topology`)."""

    directed: StrictBool = False
    generator: Annotated[str, AfterValidator(_registered(GENERATORS))]
    params: dict[str, Any] = Field(default_factory=dict)
    edges: tuple[tuple[StrictInt, StrictInt], ...] | None = None

    @field_validator("params", mode="before")
    @classmethod
    def _params_none(cls, v):
        return {} if v is None else v


class _LinkFaults(StrictModel):
    latency: LatencyModel = Field(default_factory=lambda: Constant())
    loss: Probability = 0.0
    duplicate: Probability | None = None
    jitter: LatencyModel | None = None
    schedule: Schedule | None = None
    outages: tuple[Window, ...] | None = None


class LinkSettings(TrafficKeys, _LinkFaults):
    """A link's latency and faults (see :mod:`dkfsim.components.faults`; ``None`` = no such
    fault), then its traffic keys (:class:`~dkfsim.components.traffic.TrafficKeys`: the bases in
    this order keep the keys in this order)."""


class _OverrideFaults(StrictModel):
    link: tuple[StrictInt, StrictInt]
    latency: LatencyModel | None = None
    loss: Probability | None = None
    duplicate: Probability | None = None
    jitter: LatencyModel | None = None
    schedule: Schedule | None = None
    outages: tuple[Window, ...] | None = None


class LinkOverride(TrafficKeys, _OverrideFaults):
    """One link's keys over the default's (``link: [u, v]``, then what it replaces)."""


class Links(StrictModel):
    default: LinkSettings = Field(default_factory=LinkSettings)
    overrides: tuple[LinkOverride, ...] = ()
    d_t: Annotated[int, Field(strict=True, ge=0)] | None = None
    #: every estimator's packets through the same transmitters and queues (default: each
    #: estimator's own, as if it ran alone; docs/design.md §3)
    shared_queues: StrictBool | None = None


def _fusion_none(value: Any) -> Any:
    return "none" if value is None else value


# =========================================================================== scenario
class Scenario(StrictModel):
    """A validated, immutable scenario (see the module docstring)."""

    name: Name = "unnamed"
    seed: Annotated[int, Field(strict=True, ge=0)] = 0
    steps: Annotated[int, Field(strict=True, ge=1)] = 1000
    model: Model
    prior: Prior
    sensors: Annotated[tuple[SensorField, ...], Field(min_length=1)]
    topology: Topology
    links: Links = Field(default_factory=Links)
    protocol: Annotated[str, AfterValidator(_registered(PROTOCOLS))] = "tree"
    weights: Literal["unit", "paper"] = "unit"
    spanning_tree: StrictBool = False
    buffer_length: BufferLength = "auto"
    fusion: Annotated[Literal["matrix", "diagonal", "none"], BeforeValidator(_fusion_none)] = "matrix"
    #: The algorithms run beside the anti-delay DKF, on the same draws and network.
    estimators: tuple[EstimatorField, ...] = (CentralizedParams(),)
    #: Modules or .py files that register components (imported before validation).
    plugins: tuple[Text, ...] = ()
    #: Truth from a recorded track instead of the model (:mod:`dkfsim.model.trajectory`).
    truth: TruthParams | None = None
    #: Sensor faults (crash windows), see :mod:`dkfsim.components.faults`.
    faults: Faults | None = None
    #: Vehicles that move: links up only while in range (:mod:`dkfsim.components.mobility`).
    mobility: Mobility | None = None
    #: A shared radio channel (:mod:`dkfsim.components.medium`).
    medium: Medium | None = None

    _source: str | None = PrivateAttr(default=None)
    _base_dir: str | None = PrivateAttr(default=None)

    # ------------------------------------------------------------------ validation
    @field_validator("sensors", mode="before")
    @classmethod
    def _sensor_mappings(cls, v):
        # Checked here so that the message names sensors.<i>, not the kind's union tag.
        if isinstance(v, (list, tuple)):
            for i, s in enumerate(v):
                if not isinstance(s, (dict, BaseModel)):
                    raise custom_error(f"must be a mapping, got {type(s).__name__} {s!r}", str(i))
        return v

    @model_validator(mode="before")
    @classmethod
    def _mobility_topology(cls, data: Any) -> Any:
        """With ``mobility:`` the topology defaults to every pair (links then exist while in
        range): the complete graph, written as ``erdos_renyi`` with ``p: 1`` (decision 170)."""
        if isinstance(data, dict) and data.get("mobility") is not None and "topology" not in data:
            data = {**data, "topology": {"generator": "erdos_renyi", "params": {"p": 1.0, "seed": 0}}}
        return data

    @model_validator(mode="before")
    @classmethod
    def _old_spellings(cls, data: Any) -> Any:
        """``baselines: [names]`` (and ``consensus_rounds``) are the old spelling of
        ``estimators``: converted here, before ``estimators`` is validated.  With
        both keys the lists are joined, an explicit entry replacing a converted
        one of the same name."""
        if not isinstance(data, dict) or ("baselines" not in data and "consensus_rounds" not in data):
            return data
        data = dict(data)
        names = data.pop("baselines", None)
        rounds = data.pop("consensus_rounds", None)
        if rounds is not None and (not isinstance(rounds, int) or isinstance(rounds, bool) or rounds < 0):
            # Checked even when no ci_consensus runs: a key that applies to nothing is still read.
            raise custom_error(f"must be an integer >= 0 (consensus rounds per tick), got {clip(rounds)}",
                               "consensus_rounds")
        if names is None:
            names = [] if "estimators" in data else ["centralized"]
        if not isinstance(names, (list, tuple)):
            raise custom_error(f"must be a list of estimator kinds, got {clip(names)}", "baselines")
        entries = []
        for i, name in enumerate(names):
            if not isinstance(name, str):
                raise custom_error(f"must be an estimator kind, got {clip(name)}", f"baselines.{i}")
            if name not in ESTIMATORS:
                raise custom_error(ESTIMATORS.unknown(name), f"baselines.{i}")
            if name in names[:i]:
                raise custom_error(f"{name!r} is listed twice", f"baselines.{i}")
            entry: dict[str, Any] = {"kind": ESTIMATORS.canonical(name)}
            if entry["kind"] == "ci_consensus" and rounds is not None:
                entry["rounds"] = rounds
            entries.append(entry)
        explicit = data.get("estimators") or []
        if isinstance(explicit, (list, tuple)):
            # Both spellings (an old file with ``--set estimators=...``, or the other
            # way round): an explicit entry takes the place of the converted one of
            # the same name; the other explicit entries follow.
            by_name: dict[str | None, Any] = {}
            for e in explicit:
                name = (e.get("name") or ESTIMATORS.canonical(str(e.get("kind")))) \
                    if isinstance(e, dict) else None
                by_name.setdefault(name, e)
            joined = [by_name.get(e["kind"], e) for e in entries]
            data["estimators"] = joined + [e for e in explicit if not any(e is j for j in joined)]
        else:
            data["estimators"] = explicit       # (reported by the estimators validator)
        return data

    @model_validator(mode="after")
    def _check_consistency(self):
        nx_ = self.model.nx
        if len(self.prior.mean) != nx_:
            raise custom_error(f"has {len(self.prior.mean)} entries but the state has "
                               f"{nx_} (model)", "prior.mean")
        if len(self.prior.cov) != nx_:
            raise custom_error(f"must be {nx_} x {nx_}, got {len(self.prior.cov)} x "
                               f"{len(self.prior.cov)}", "prior.cov")
        names: dict[str, int] = {}
        for i, s in enumerate(self.sensors):
            s.check(nx_, f"sensors.{i}")
            if s.name in names:
                raise custom_error(f"{s.name!r} is already the name of sensors.{names[s.name]}",
                                   f"sensors.{i}.name")
            names[s.name] = i
        if self.truth is not None:
            self._check_truth(self.truth)
        self._index_overrides()
        plan = RunPlan(self)            # what the run would derive: checked here, never at its start
        remember(self, plan)            # (and the plan the run follows: RunPlan.of)
        places = self._link_places()
        self._check_network(plan, places)
        self._check_time_range(plan, places)
        self._check_estimators(plan)
        return self

    def _check_estimators(self, plan: RunPlan) -> None:
        taken = {"fused": "the anti-delay DKF's fused estimate", "local": "the DKF nodes' own estimates",
                 "final": "the DKF nodes' final estimates"}
        for i, p in enumerate(self.estimators):
            if p.label in taken:
                raise custom_error(f"the name {p.label!r} is taken ({taken[p.label]}); give it "
                                   "another name", f"estimators.{i}.name" if p.name else f"estimators.{i}")
            taken[p.label] = f"estimators.{i}"
            checks = [getattr(p, "check", None), getattr(p, "check_plan", None)]
            for check, arg in zip(checks, (self, plan)):
                if check is None:
                    continue
                try:
                    check(arg)
                except PydanticCustomError as err:
                    ctx = err.context or {}
                    key = f"estimators.{i}" + (f".{ctx['key']}" if ctx.get("key") else "")
                    raise custom_error(str(ctx.get("reason", err)), key) from None
        for dkf in plan.dkfs():
            over = plan.fusion_overflow(dkf, FUSION_MEMORY_LIMIT)
            if over is not None:
                L, need, exact = over
                least = "" if exact else "at least "
                S = min(L, self.steps) + 1
                raise custom_error(
                    f"{dkf.fusion} fusion keeps the cross-covariances of all {self.n} nodes for the "
                    f"{least}{S} window rows, {least}{need / 2**30:.1f} GiB of memory; use fusion: "
                    f"none for a network this large (or a shorter buffer_length)", dkf.key or "fusion")

    def _check_truth(self, truth: TruthParams) -> None:
        if self.model.kind != "constant_velocity" or self.model.nx != 4:
            raise custom_error("a recorded track gives the state [x, vx, y, vy]: needs model "
                               "kind: constant_velocity with dims: 2", "truth")
        need = truth.start + self.steps * self.model.T
        have = truth.track().duration
        if need > have + 1e-9:
            named = (f"truth.dataset {truth.dataset}" if truth.dataset is not None
                     else f"truth.file {truth.file}")
            raise custom_error(
                f"the run needs {need:g} s of track (truth.start {truth.start:g} s + "
                f"{self.steps} steps x {self.model.T:g} s) but {named} covers {have:g} s; use at "
                f"most {int((have - truth.start) / self.model.T + 1e-9)} steps", "steps")

    def _pair(self, u: int, v: int) -> tuple[int, int]:
        """The key of link ``u -> v`` in the override index (either direction on an undirected
        topology)."""
        return (u, v) if self.topology.directed else (min(u, v), max(u, v))

    def _index_overrides(self) -> None:
        """One override per link: a second one of the same link (or of its reverse, on an
        undirected topology) is refused naming both."""
        index: dict[tuple[int, int], int] = {}
        for i, ov in enumerate(self.links.overrides):
            key = self._pair(*ov.link)
            if key in index:
                j = index[key]
                raise custom_error(f"link {list(ov.link)} already has an override (links.overrides.{j}: "
                                   f"{list(self.links.overrides[j].link)}); give each link one override "
                                   "with every key it changes", f"links.overrides.{i}.link")
            index[key] = i

    def _override(self, u: int, v: int) -> int | None:
        """The index of the override of link ``u -> v``, if any: one look-up in the index of
        :func:`_override_index` (a scan of every override per link was quadratic: 8 000
        overrides took minutes to validate)."""
        return _override_index(self.links, self.topology.directed).get(self._pair(u, v))

    def _link_places(self) -> list[tuple[str, LinkSpec]]:
        """``(key, settings)`` of ``links.default`` and of each override's link as the run sees
        it (the default merged with every override matching that link): what the link checks walk."""
        return [("links.default", self.link_spec(-1, -1))] + [
            (f"links.overrides.{i}", self.link_spec(*ov.link)) for i, ov in enumerate(self.links.overrides)]

    def _check_network(self, plan: RunPlan, places: list[tuple[str, LinkSpec]]) -> None:
        top = self.topology
        tree = plan.protocol_graph == "tree"
        if self.weights == "paper" and not tree:
            raise custom_error(f"'paper' weights are not defined for protocol: {self.protocol} (the "
                               "paper weighs the messages of the tree exchange only); use weights: "
                               "unit, or protocol: tree", "weights")
        if tree and top.directed:
            raise custom_error(f"'{self.protocol}' needs an undirected topology (topology.directed is "
                               "true); use protocol: flood on a directed graph", "protocol")
        if self.spanning_tree and top.directed:
            raise custom_error("a spanning tree needs an undirected topology "
                               "(topology.directed is true)", "spanning_tree")
        n = self.n
        try:
            graph = plan.graph
            topo.check_connected(graph)
        except topo.GraphSpecError as err:
            key = "topology." + err.key if err.key else "topology"
            hint = ""
            if top.generator in ("random_regular", "erdos_renyi") and "connected" in err.reason:
                hint = " (try another params.seed or a denser graph)"
            raise custom_error(err.reason + hint, key) from None
        if tree and not self.spanning_tree and not topo.is_tree(graph):
            raise custom_error(
                f"'{self.protocol}' needs a tree but the topology has cycles ({n} nodes, "
                f"{graph.number_of_edges()} edges); set spanning_tree: true to run on a BFS "
                "spanning tree, or use protocol: flood", "protocol")
        for i, ov in enumerate(self.links.overrides):
            u, v = ov.link
            for node in (u, v):
                if not 0 <= node < n:
                    raise custom_error(f"node {node} is out of range 0..{n - 1}",
                                       f"links.overrides.{i}.link")
            if not graph.has_edge(u, v):
                what = "an arc" if graph.is_directed() else "an edge"
                raise custom_error(f"[{u}, {v}] is not {what} of the topology",
                                   f"links.overrides.{i}.link")
        self._check_traffic(places)
        if self.medium is not None:
            self._check_medium(plan)
        if self.faults is not None:
            self.faults.check(n)
        if self.mobility is not None:
            self._check_mobility(plan)
        self._check_sinr_track(plan, places)
        if self.buffer_length in ("auto", "paper") and plan.d_t is None:
            raise custom_error(
                f"{self.buffer_length!r} needs a delay bound, but latency model "
                f"{', '.join(plan.unbounded_models())} is unbounded; set an explicit links.d_t (delay bound "
                "in steps) or an integer buffer_length", "buffer_length")

    def _check_mobility(self, plan: RunPlan) -> None:
        """Every node a trajectory, a schedule that fits in memory, and what a changing graph
        cannot do: paper weights on a tree that changes; ``auto`` without a window ``B``."""
        assert self.mobility is not None
        self.mobility.check(self.n)
        size = (self.steps + 1) * len(plan.arcs)
        # a link quality from distance keeps each entry's distance too (8 more bytes)
        weight = 9 if self.mobility.links is not None else 1
        if size * weight > SCHEDULE_LIMIT:
            raise custom_error(f"the link schedule has one entry per tick and link, {self.steps + 1} x "
                               f"{len(plan.arcs)} = {size:.3g}"
                               + (" (9 bytes each with mobility.links)" if weight > 1 else "")
                               + f", more than the {SCHEDULE_LIMIT:.3g} bytes a run may "
                               "keep; use fewer steps or a sparser topology", "mobility")
        if not plan.graph_changes:
            return
        if self.weights == "paper":
            raise custom_error("'paper' weights are not defined on a graph that changes (mobility: links "
                               "come and go, and the weights follow the tree's degrees); use weights: "
                               "unit", "weights")
        if self.buffer_length == "auto" and plan.connect_window is None:
            raise custom_error(
                f"'auto' sizes the buffer from B, the length after which every interval of ticks has a "
                f"connected union graph; with these trajectories and range the union of all {self.steps} "
                "ticks is not connected, so no B exists: give an integer buffer_length", "buffer_length")

    def _check_sinr_track(self, plan: RunPlan, places: list[tuple[str, LinkSpec]]) -> None:
        """``cellular_sinr`` with ``sinr: track`` draws at the sender's recorded SINR: every
        sender on such a link is a ``track`` vehicle of ``mobility:`` (decision 181).  A refusal
        names the override whose latency the link takes (the last matching one that gives it)."""
        if not any(getattr(spec.latency, "sinr", None) == "track" for _, spec in places):
            return
        for u, v in plan.arcs:
            if getattr(self.link_spec(u, v).latency, "sinr", None) != "track":
                continue
            key = self._key_of(u, v, "latency") + ".latency.sinr"
            if self.mobility is None:
                raise custom_error("'track' takes the sender's recorded SINR, which needs a mobility: key "
                                   "with 'track' vehicles; give a number (dB)", key)
            if self.mobility.sinr_at(u) is None:
                raise custom_error(f"'track' takes the sender's recorded SINR, but node {u} (sender on link "
                                   f"{u} -> {v}) is not a 'track' vehicle of mobility:; give a number (dB)", key)

    def _check_medium(self, plan: RunPlan) -> None:
        """``medium.nodes`` are nodes, and a link on the channel has no transmitter of its own:
        no ``rate`` (nor ``queue``/``background``) on it, no rate from distance."""
        assert self.medium is not None
        self.medium.check(self.n)
        if self.medium.radio is not None and self.mobility is None:
            raise custom_error("a spatial radio decides each frame at each receiver from the pair's distance, "
                               "so it needs the vehicles' positions: give mobility: (waypoints, a track, SUMO FCD, "
                               "a road), or remove medium.radio for one collision domain", "medium.radio")
        if self.medium.radio is not None:
            rule = MEDIA.get(self.medium.access.kind).implementation
            if not getattr(getattr(rule, "on_radio", None) or rule, "spatial", False):
                raise custom_error(f"{self.medium.access.kind!r} is a rule for one collision "
                                   "domain; on a spatial radio (medium.radio) each radio runs the rule on its own "
                                   "view of the medium: give edca or csma, or remove medium.radio",
                                   "medium.access.kind")
        if self.medium.bystanders is not None and self.medium.radio is None:
            raise custom_error("bystanders are vehicles placed on the road beside the nodes: they need a spatial "
                               "radio (medium.radio); for one collision domain give the nodes background instead",
                               "medium.bystanders")
        if self.medium.generation_jitter and self.medium.generation_jitter > self.model.T:
            raise custom_error(f"a vehicle's frames of one tick reach its radio within the tick, so the jitter "
                               f"is at most the tick T = {self.model.T} s, got {self.medium.generation_jitter}",
                               "medium.generation_jitter")
        queue, background = self.medium.queue, self.medium.background
        if queue is not None and queue.packets == 0:
            raise custom_error("a frame waits in its radio's waiting room for its slot, so it must hold "
                               "at least one frame: give packets >= 1", "medium.queue.packets")
        if queue is not None and queue.bytes is not None:
            least = max(smallest_frame(self.nx), background.size if background is not None else 0)
            if queue.bytes < least:
                kinds = f"the estimators' smallest, {smallest_frame(self.nx)} bytes (a header and one state vector)"
                if background is not None:
                    kinds = f"the background's {background.size} bytes and {kinds}"
                raise custom_error(f"a frame waits in its radio's waiting room for its slot, so it must hold one "
                                   f"frame of every kind the channel carries: {kinds}; give bytes >= {least}",
                                   "medium.queue.bytes")
        if self.mobility is not None and self.mobility.rate_from_distance:
            raise custom_error("a link on the shared channel is sent at the channel's rate, so it cannot "
                               "take a rate from distance; remove mobility.links.rate or medium",
                               "mobility.links.rate")
        members = set(self.medium.members(self.n))
        entries = [("links.default", self.links.default, None)] + [
            (f"links.overrides.{i}", ov, ov) for i, ov in enumerate(self.links.overrides)]
        arcs_set = set(plan.arcs)
        for key, entry, override in entries:
            arcs = plan.arcs if override is None else [
                a for a in dict.fromkeys([tuple(override.link), tuple(override.link)[::-1]])
                if a in arcs_set and self.link_matches(override.link, *a)]
            on = next(((u, v) for u, v in arcs if u in members and v in members), None)
            what = next((w for w in ("rate", "queue", "background") if getattr(entry, w) is not None), None)
            if on is not None and what is not None:
                raise custom_error(f"link {on[0]} -> {on[1]} is on the shared channel (medium:), which "
                                   "sends its frames at the channel's rate through each node's radio; a "
                                   f"link on it takes no {what} of its own: remove it (the channel's are "
                                   f"medium.rate, medium.queue, medium.background)", f"{key}.{what}")

    def _check_traffic(self, places: list[tuple[str, LinkSpec]]) -> None:
        """A queue limit or background load acts through the transmitter: it needs a rate."""
        for key, spec in places:
            if spec.rate is None and not (self.mobility is not None and self.mobility.rate_from_distance):
                for what in ("queue", "background"):
                    if getattr(spec, what) is not None:
                        advice = (f"on the shared channel (medium:) frames wait in each node's radio, "
                                  f"whose {what} is medium.{what}: give it there (a link off the channel "
                                  "takes a rate first)" if self.medium is not None else
                                  "give rate here or in links.default")
                        raise custom_error(f"a {what} acts through the link's transmitter, but the link "
                                           f"has no rate (bits per second); {advice}", f"{key}.{what}")

    def _check_time_range(self, plan: RunPlan, places: list[tuple[str, LinkSpec]]) -> None:
        """Every time the run can reach fits the int64 nanosecond clock (:data:`MAX_NS`)."""
        T_ns = self.T_ns
        limit = f"the {MAX_SECONDS:.4g} s (2^62 ns, about 146 years) an int64 nanosecond clock can hold"
        if (self.steps + 1) * T_ns > MAX_NS:
            most = MAX_NS // T_ns - 1
            fix = f"use at most {most} steps" if most >= 1 else "T itself is too long"
            raise custom_error(f"{self.steps} steps of T = {self.model.T:g} s reach "
                               f"{(self.steps + 1) * self.model.T:.4g} s of simulated time, beyond {limit}; "
                               f"{fix}", "steps")
        extra = plan.distance_latency_ns()          # (mobility.links.latency_per_m at the range's radius)
        for key, spec in places:
            sup = spec.sup_ns(T_ns)
            if sup is not None and sup > MAX_NS:
                raise custom_error(f"the largest latency it can produce, {sup / 1e9:.4g} s (after "
                                   f"schedule factors and jitter), is beyond {limit}", key)
            if sup is not None and extra and sup + extra > MAX_NS:
                raise custom_error(f"with {key}'s largest latency, {sup / 1e9:.4g} s, a pair at the range's "
                                   f"radius waits {(sup + extra) / 1e9:.4g} s, beyond {limit}",
                                   "mobility.links.latency_per_m")
        d_t = plan.d_t
        if d_t is not None and d_t * T_ns > MAX_NS:
            raise custom_error(f"a delay bound of {d_t} steps of {self.model.T:g} s is beyond {limit}",
                               "links.d_t" if self.links.d_t is not None else "links")
        # L <= d_t (n - 1) + 1 (the diameter is below n): the exact L only when that bound is too large.
        if isinstance(self.buffer_length, int) or (d_t or 0) * (self.n - 1) * T_ns > MAX_NS \
                or plan.graph_changes:
            if plan.buffer_length() * T_ns > MAX_NS:
                raise custom_error(f"L = {plan.buffer_length()} rows of {self.model.T:g} s span "
                                   f"more than {limit}; use a smaller delay bound or buffer_length",
                                   "buffer_length")

    # ------------------------------------------------------------------ derived values

    @property
    def source(self) -> str | None:
        """The file this scenario was loaded from (None for a dict)."""
        return self._source

    def set_source(self, source: str | None, base_dir: str | None = None) -> None:
        """Remember the file this scenario was read from and the folder its relative ``file:``
        paths resolve against (None: keep it); neither is part of its data."""
        self._source = source
        if base_dir is not None:
            self._base_dir = base_dir

    @property
    def base_dir(self) -> str | None:
        """The folder relative ``file:`` paths resolved against (None: the working directory)."""
        return self._base_dir

    @property
    def nx(self) -> int:
        """State dimension."""
        return self.model.nx

    @property
    def n(self) -> int:
        """Number of sensors (= nodes)."""
        return len(self.sensors)

    @property
    def T_ns(self) -> int:
        """Sampling period in integer nanoseconds."""
        return self.model.T_ns

    def link_spec(self, u: int, v: int) -> LinkSpec:
        """Settings of the directed link ``u -> v``.

        The default merged with the link's override (a link has at most one); ``link: [u, v]``
        matches ``u -> v``, and also ``v -> u`` on an undirected topology.
        An override replaces the whole latency model, the loss, and each
        fault or traffic key it gives (duplicate, jitter, schedule, outages, rate, queue,
        background; a ``background`` replaces the default's whole).
        """
        keys = ("latency", "loss", "duplicate", "jitter", "schedule", "outages") + TRAFFIC_KEYS
        spec = {k: getattr(self.links.default, k) for k in keys}
        i = self._override(u, v)
        if i is not None:
            ov = self.links.overrides[i]
            spec.update({k: getattr(ov, k) for k in keys if getattr(ov, k) is not None})
        return LinkSpec(latency=spec["latency"], loss=float(spec["loss"]),
                        duplicate=float(spec["duplicate"] or 0.0), jitter=spec["jitter"],
                        schedule=tuple(spec["schedule"] or ()),
                        outages=tuple(spec["outages"] or ()), **{k: spec[k] for k in TRAFFIC_KEYS})

    def link_matches(self, pair, u: int, v: int) -> bool:
        """The link named ``pair`` (``[a, b]``, e.g. an override's ``link``) is ``u -> v``, or
        ``v -> u`` when the topology is undirected."""
        a, b = pair
        return (a, b) == (u, v) or (not self.topology.directed and (b, a) == (u, v))

    def _key_of(self, u: int, v: int, what: str) -> str:
        """Where link ``u -> v`` takes its ``what`` from (as :meth:`link_spec` merges): the last
        matching override that gives it (``links.overrides.I``), else ``links.default``."""
        i = self._override(u, v)
        return f"links.overrides.{i}" if i is not None and getattr(self.links.overrides[i], what) is not None \
            else "links.default"

    # ------------------------------------------------------------------ identity
    def to_dict(self) -> dict:
        """Plain data (lists, floats, str) that :func:`load_scenario` turns back
        into an equal scenario; ``source`` is not included."""
        return self.model_dump(mode="json", exclude_none=True)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Scenario):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(scenario_hash(self))


#: The override index of the last few ``links`` read: ``(links, directed) -> {pair: index}``,
#: keyed by the model's identity and holding it (so no id is reused while it is here).  The
#: scenario keeps no derived state; this memo lets :meth:`Scenario.link_spec` find a link's
#: override in one look-up for every link of a run.
_OVERRIDE_INDEX: OrderedDict[tuple[int, bool], tuple[Links, dict[tuple[int, int], int]]] = OrderedDict()


def _override_index(links: Links, directed: bool) -> dict[tuple[int, int], int]:
    key = (id(links), directed)
    hit = _OVERRIDE_INDEX.get(key)
    if hit is not None and hit[0] is links:
        _OVERRIDE_INDEX.move_to_end(key)
        return hit[1]
    index: dict[tuple[int, int], int] = {}
    for i, ov in enumerate(links.overrides):
        u, v = ov.link
        index.setdefault((u, v) if directed else (min(u, v), max(u, v)), i)
    _OVERRIDE_INDEX[key] = (links, index)
    while len(_OVERRIDE_INDEX) > 16:
        _OVERRIDE_INDEX.popitem(last=False)
    return index


def named(scenario: Scenario) -> str:
    """How a message names a scenario: its file (where the user can fix it), else its name."""
    return shown(scenario.source) if scenario.source else f"scenario {clip(scenario.name, 60)}"


def scenario_hash(scenario: Scenario) -> str:
    """sha256 hex digest of the canonical JSON of ``scenario.to_dict()``."""
    text = canonical_json(scenario.to_dict())
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


