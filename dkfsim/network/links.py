"""The SimPy network: directed links with per-packet latency, loss and faults, shared
by every estimator of a run.

Time is integer nanoseconds (docs/design.md §2), so "arrived by tick k" is an
exact integer comparison.  Every estimator of a run talks through its own
:class:`Port` of one :class:`Network`: a port sends packets over the links
and receives its own packets back; it counts them (per link and in total).

Draws are keyed, the common-random-numbers rule of docs/design.md §3: a
packet's latency, loss, duplication and jitter are pure functions of (the
link, the send instant, the packet's number among those its port put on the
link at that instant), drawn by :func:`dkfsim.core.streams.keyed_uniform`
from the link's named keys (``("link", u, v, "latency")``, ``"loss"``,
``"duplicate"``, ``"jitter"``, ...).  So two estimators that send over one
link at one instant see the same delay, adding loss or a fault leaves every
other draw unchanged, and adding a link changes no other link's draws.  A
schedule scales the latency by its factor at the send time; an outage drops
what is sent during it; a crash window drops what arrives at a node that
is down (``crash_dropped``).  Packets on one link overtake each other when a
later draw is shorter: links reorder.

A link with a ``rate`` (bits per second) has a first-in-first-out transmitter
(:mod:`dkfsim.network.transmitter`): a packet handed over at ``t`` waits for the packets
before it and the link's background load, is dropped when the waiting room (``queue``) is
full (``queue_dropped``), and otherwise arrives at the end of its transmission plus its
latency draw, still keyed by the hand-over instant ``t``; loss, outage and duplication are
decided at ``t`` too, and a lost packet occupies the transmitter.  Each port has its own
transmitters (an estimator sees the links as if it ran alone) unless the network shares
them (``links.shared_queues``).

Counting identity, per port, per link and in total::

    sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight

Beside these a port keeps ``late``, which only its estimator can decide (a packet
delivered after its last usable instant, a stale pair, ...): the estimator counts it
with :meth:`Port.count_late`, and ``counts()`` reports it.

Event priorities at one instant (SimPy pops ``(time, priority, id)``):
deliveries (``NORMAL``) first, then the protocols' flushes
(:data:`PRIORITY_FLUSH`), then the filters' tick update
(:data:`PRIORITY_UPDATE`), so a packet arriving exactly at ``t_k``, and any
chain of zero-latency relays it starts, counts for tick ``k``; last a fusion centre's
fusion (:data:`PRIORITY_FUSE`), after the packets the update sent and their relays.
"""

from __future__ import annotations

from array import array
from collections.abc import Sequence
from typing import Any, Callable, Protocol, cast

import numpy as np
import simpy
from simpy.events import NORMAL, Event

from dkfsim.components.faults import CrashSchedule, LinkSpec, ScaleSchedule, Windows
from dkfsim.components.latency import TrackSinrSampler
from dkfsim.components.medium import Medium
from dkfsim.components.mobility import LinkSchedule
from dkfsim.core.params import MAX_NS, NS_PER_S, seconds_to_ns
from dkfsim.core.streams import key64, keyed_uniform
from dkfsim.network.events import Scheduled
from dkfsim.network.medium import Channel, Frame
from dkfsim.network.occupancy import mean_waiting, per_tick
from dkfsim.network.transmitter import BackgroundArrivals, Transmitter, background_keys, link_stats

PRIORITY_DELIVER = NORMAL
PRIORITY_FLUSH = NORMAL + 1
PRIORITY_UPDATE = NORMAL + 2
#: A fusion centre fuses the tick's row after the update, its packets and their zero-latency
#: relays (docs/design.md §2).
PRIORITY_FUSE = NORMAL + 3

#: Counters of a port, per link:
#: ``sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight``.
COUNTERS = ("sent", "delivered", "lost", "copies", "crash_dropped", "outage_lost", "bytes", "queue_dropped")

#: The first per-link sequence number of a port that shares another's transmitters
#: (:meth:`Network.port` ``share_with``): its keyed draws never equal the other port's, and
#: adding it changes none of them.
SHARED_SEQ0 = 1 << 32

#: What a port hands its estimator: ``receive(link, payload)``.
Receive = Callable[["Link", Any], None]


class Clock(Protocol):
    """The run's SimPy environment as this module uses it: time in integer nanoseconds."""

    @property
    def now(self) -> int: ...

    def schedule(self, event: Event, priority: int = ..., delay: int = ...) -> None: ...


def _as_spec(spec: Any) -> LinkSpec:
    """A :class:`LinkSpec` from anything with ``.latency`` and ``.loss``."""
    if isinstance(spec, LinkSpec):
        return spec
    return LinkSpec(latency=spec.latency, loss=float(spec.loss),
                    duplicate=float(getattr(spec, "duplicate", 0.0) or 0.0),
                    jitter=getattr(spec, "jitter", None),
                    schedule=tuple(getattr(spec, "schedule", None) or ()),
                    outages=tuple(getattr(spec, "outages", None) or ()))


class Recipe:
    """The latency of a packet on one link: model draw, times the schedule's factor at the
    send time, plus jitter; and whether the model lost it (``gilbert_elliott``)."""

    __slots__ = ("_model", "_sched", "_jitter")

    def __init__(self, spec: LinkSpec, prefix: tuple, seed: int, T_ns: int):
        self._model = spec.latency.sampler(prefix, seed, T_ns)
        self._sched = ScaleSchedule(spec.schedule) if spec.schedule else None
        self._jitter = spec.jitter.sampler(prefix + ("jitter",), seed, T_ns) \
            if spec.jitter is not None else None

    def set_sinr(self, sinr_at: Any) -> None:
        """Hand the sender's SINR to a model that draws at it (``cellular_sinr``, ``sinr: track``)."""
        if isinstance(self._model, TrackSinrSampler):
            self._model.sinr_at = sinr_at

    def draw(self, t_ns: int, seq: int) -> tuple[int, bool]:
        lat, lost = self._model.draw(t_ns, seq)
        if self._sched is not None:
            f = self._sched.factor(t_ns)
            if f != 1.0:
                scaled = lat * f
                lat = MAX_NS if scaled >= MAX_NS else int(round(scaled))
        if self._jitter is not None:
            lat = min(lat + self._jitter.draw(t_ns, seq)[0], MAX_NS)
        return lat, lost


class Link:
    """Directed link ``src -> dst``: its settings and its keyed draws.

    :param spec: a :class:`~dkfsim.components.faults.LinkSpec` (or anything
        with ``.latency`` and ``.loss``).
    :param key: the prefix of the link's draw names, ``("link", src, dst)`` by default.
    """

    __slots__ = ("id", "src", "dst", "spec", "loss", "duplicate", "plain", "rate", "up", "changes", "T_ns", "on_channel",
                 "near", "_near_loss", "_near_extra", "_near_rate", "_main", "_copy", "_loss_key", "_dup_key", "_outages", "_prefix", "_seed", "_faultless")

    def __init__(self, link_id: int, src: int, dst: int, spec: Any, seed: int, T_ns: int,
                 key: tuple | None = None):
        spec = _as_spec(spec)
        self.id, self.src, self.dst, self.spec = link_id, src, dst, spec
        self.T_ns = int(T_ns)
        #: per tick ``0 .. K``, 1 while the link is up (:meth:`set_schedule`); None: always up
        self.up: bytes | None = None
        #: whether the link is down at some tick ``1 .. K``
        self.changes = False
        #: whether its quality follows its pair's distance (:meth:`set_distance`); per tick
        #: ``0 .. K``: loss probability, extra latency ns, rate bit/s (each None when not given)
        self.near = False
        #: whether its packets go as frames on the shared channel (set by its :class:`Network`)
        self.on_channel = False
        self._near_loss: list[float] | None = None
        self._near_extra: list[int] | None = None
        self._near_rate: list[float] | None = None
        self.loss = float(spec.loss)
        self.duplicate = float(spec.duplicate)
        prefix = ("link", src, dst) if key is None else tuple(key)
        self._prefix, self._seed = prefix, int(seed)
        #: bits per second (None: no transmitter, a packet leaves when handed over)
        self.rate = None if spec.rate is None else float(spec.rate)
        self._main = Recipe(spec, prefix, seed, T_ns)
        self._loss_key = key64(seed, *prefix, "loss") if self.loss > 0 else None
        self._dup_key = key64(seed, *prefix, "duplicate") if self.duplicate > 0 else None
        self._copy = Recipe(spec, prefix + ("duplicate",), seed, T_ns) if self.duplicate > 0 else None
        self._outages = Windows(spec.outages) if spec.outages else None
        #: nothing but the latency model acts on a packet's fate (no loss, duplication, outage,
        #: schedule or jitter)
        self._faultless = spec.plain and not self.loss > 0
        #: The latency model's own ``draw(t_ns, seq) -> (ns, lost)`` when nothing else acts
        #: on the link (faultless, no transmitter): the per-packet fast path of
        #: :meth:`Port.send`, equal to :meth:`transmit`.  None otherwise.
        self.plain = self._main._model.draw if self._faultless and self.rate is None else None

    def set_schedule(self, up: bytes) -> None:
        """The link comes and goes: ``up[k]`` is 1 while it is up at tick ``k`` (docs/design.md
        §3); a packet handed to it while it is down is lost (``range_lost``)."""
        self.up = up
        self.changes = 0 in up[1:]

    def set_distance(self, distance: np.ndarray, quality: Any) -> None:
        """The link's quality follows its pair's distance (``distance[k]`` m at tick ``k``)
        through ``quality`` (:class:`~dkfsim.components.mobility.DistanceLinks`, decision 176):
        loss and latency at the hand-over tick, the rate at the transmission's start tick."""
        loss, extra, rate = quality.per_tick(distance)
        self.near = True
        self._near_loss, self._near_extra, self._near_rate = loss, extra, rate
        if loss is not None and self._loss_key is None:
            self._loss_key = key64(self._seed, *self._prefix, "loss")
        if rate is not None:
            self.rate = float(rate[0])
        self._faultless = False
        self.plain = None

    def set_sinr(self, sinr_at: Any) -> None:
        """The sender's SINR (run seconds -> dB) for a ``cellular_sinr`` latency with ``sinr:
        track`` (decision 181); nothing for any other model."""
        for recipe in (self._main, self._copy):
            if recipe is not None:
                recipe.set_sinr(sinr_at)

    def _tick(self, t_ns: int, size: int) -> int:
        return min(t_ns // self.T_ns, size - 1)

    def rate_at(self, t_ns: int) -> float:
        """The rate (bit/s) at instant ``t_ns``: from the distance of its tick
        (``mobility.links.rate``), else the link's ``rate``."""
        rate = self._near_rate
        if rate is None:
            return float(self.rate) if self.rate is not None else 0.0
        return rate[self._tick(t_ns, len(rate))]

    def is_up(self, t_ns: int) -> bool:
        """Whether the link is up at instant ``t_ns`` (the state of the tick ``t_ns`` is in)."""
        up = self.up
        return up is None or bool(up[self._tick(t_ns, len(up))])

    def compiled_latency(self) -> tuple[int, int, int] | None:
        """The latency model's :meth:`~dkfsim.components.latency.Sampler.compiled_form` when
        nothing else acts on the link but a transmitter with no queue or a queue counted in
        packets, and the link never goes down, else None (a compiled protocol cannot draw it)."""
        spec = self.spec
        if self.changes or self.near or not self._faultless:
            return None
        if spec.queue is not None and spec.queue.packets is None:
            return None
        return self._main._model.compiled_form()

    def compiled_traffic(self) -> tuple | None:
        """The transmitter as the compiled tree draws it, None without a rate: ``(rate, queue
        packets or -1, background kind (0 none, 1 poisson, 2 periodic), arrival key, size
        key, ns between packets, size, exponential sizes, offset ns)``."""
        if self.rate is None:
            return None
        spec = self.spec
        qcap = -1 if spec.queue is None or spec.queue.packets is None else int(spec.queue.packets)
        bg = spec.background
        if bg is None:
            return (self.rate, qcap, 0, 0, 0, 0.0, 0.0, False, 0)
        gap_key, size_key = background_keys(self._prefix, self._seed)
        return (self.rate, qcap, 1 if bg.arrivals == "poisson" else 2, gap_key, size_key,
                NS_PER_S / bg.packets_per_second, float(bg.size), bg.sizes == "exponential",
                seconds_to_ns(bg.offset))

    def transmitter(self, record: bool = False) -> Transmitter:
        """A new transmitter of this rate-limited link, with its queue and background."""
        if self.rate is None:
            raise ValueError(f"link {self.src} -> {self.dst} has no rate: no transmitter")
        spec = self.spec
        bg = BackgroundArrivals(spec.background, self._prefix, self._seed) \
            if spec.background is not None else None
        return Transmitter(self.rate, spec.queue, bg, record=record,
                           rate_at=self.rate_at if self._near_rate is not None else None)

    def transmit(self, t_ns: int, seq: int = 0) -> tuple[tuple[int, ...], str | None]:
        """The arrivals of a packet sent at ``t_ns`` as number ``seq`` of its sender at
        that instant: ``(latencies, why lost)`` -- ``()`` and ``"lost"`` or
        ``"outage"`` when it is lost, one latency, or two when it is duplicated."""
        lat, lost = self._main.draw(t_ns, seq)
        loss = self.loss
        near = self.near
        if near and self._near_loss is not None:
            loss = 1.0 - (1.0 - loss) * (1.0 - self._near_loss[self._tick(t_ns, len(self._near_loss))])
        if self._loss_key is not None and keyed_uniform(self._loss_key, t_ns, seq) < loss:
            lost = True
        if self._outages is not None and t_ns in self._outages:
            return (), "outage"
        if lost:
            return (), "lost"
        extra = 0
        if near and self._near_extra is not None:
            extra = self._near_extra[self._tick(t_ns, len(self._near_extra))]
        if self._dup_key is not None and self._copy is not None \
                and keyed_uniform(self._dup_key, t_ns, seq) < self.duplicate:
            return (min(lat + extra, MAX_NS), min(self._copy.draw(t_ns, seq)[0] + extra, MAX_NS)), None
        if extra:
            lat = min(lat + extra, MAX_NS)
        return (lat,), None


class Network:
    """The links of one run inside a SimPy environment, shared by every estimator.

    :param arcs: directed ``(u, v)`` pairs; link ids are their positions.
    :param link_spec: ``link_spec(u, v)`` -> a :class:`~dkfsim.components.faults.LinkSpec`.
    :param crashes: optional :class:`~dkfsim.components.faults.CrashSchedule`; a packet
        arriving at a node that is down is dropped (``crash_dropped``).
    :param shared_queues: every port's packets through the same transmitter of a
        rate-limited link (default: each port its own, the same background in each).
    :param schedule: a :class:`~dkfsim.components.mobility.LinkSchedule` of ``arcs``
        (``mobility:``): which links are up at each tick; None: every link always up.
    :param medium: the shared radio channel (``medium:``, :mod:`dkfsim.network.medium`): a
        link between two of its nodes is on it.  Each port has its own copy of it (the same
        background and draws in each) unless ``shared_queues``.
    """

    def __init__(self, env: simpy.Environment, arcs: list[tuple[int, int]],
                 link_spec: Callable[[int, int], Any], seed: int, T_ns: int,
                 crashes: CrashSchedule | None = None, shared_queues: bool = False,
                 schedule: LinkSchedule | None = None, medium: Medium | None = None, n: int | None = None):
        self.env = cast(Clock, env)         # (SimPy types time as int | float; here it is ns)
        #: link id -> the transmitter every port uses, when queues are shared (else each port
        #: keeps its own)
        self.shared_transmitters: dict[int, Transmitter] | None = {} if shared_queues else None
        self.medium = medium
        if n is None:
            n = 1 + max((max(u, v) for u, v in arcs), default=-1)
        #: the nodes on the channel, in increasing order (none without ``medium``), and as a set
        self._member_order: tuple[int, ...] = medium.members(n) if medium is not None else ()
        self.members: frozenset[int] = frozenset(self._member_order)
        self._shared_channel: Channel | None = None
        self._shared_queues = shared_queues
        self.seed, self.T_ns = int(seed), int(T_ns)
        self.links = [Link(i, u, v, link_spec(u, v), seed, T_ns) for i, (u, v) in enumerate(arcs)]
        self.index = {(l.src, l.dst): l for l in self.links}
        for link in self.links:
            link.on_channel = self.on_channel(link)
        #: which links are up at each tick (None: all, always)
        self.schedule = schedule
        if schedule is not None:
            for i, link in enumerate(self.links):
                link.set_schedule(schedule.column(i))
                if schedule.distance is not None:
                    link.set_distance(schedule.distance[:, i], schedule.quality)
                if link.src in schedule.sinr:
                    link.set_sinr(schedule.sinr[link.src])
        self.crashes = crashes if crashes else None
        self.ports: list[Port] = []

    def link(self, u: int, v: int) -> Link:
        return self.index[(u, v)]

    def on_channel(self, link: Link) -> bool:
        """Whether ``link`` is on the shared channel (its packets go as frames): it joins two of
        its nodes, or goes from one of them to a centre outside the graph (``dst < 0``, e.g.
        ``centralized_delayed``'s, which listens on the channel; decision 216)."""
        return link.src in self.members and (link.dst in self.members or link.dst < 0)

    def channel(self) -> Channel | None:
        """A copy of the shared channel for a new port (the one copy with ``shared_queues``);
        None without ``medium``."""
        if self.medium is None:
            return None
        if self._shared_queues and self._shared_channel is not None:
            return self._shared_channel
        channel = Channel(self.env, self.medium, self._member_order, self.seed)
        if self._shared_queues:
            self._shared_channel = channel
        return channel

    def extra_link(self, key: tuple, spec: Any, src: int, dst: int) -> Link:
        """A link outside the graph (e.g. a sensor's direct link to a fusion centre),
        its draws named ``key``; it joins the network's link list."""
        link = Link(len(self.links), src, dst, spec, self.seed, self.T_ns, key=key)
        link.on_channel = self.on_channel(link)
        self.links.append(link)
        return link

    def port(self, name: str, receive: Receive | None, links: list[Link] | None = None,
             until: int | None = None, share_with: Port | None = None) -> Port:
        """A new port for an estimator: ``receive(link, payload)`` gets its deliveries (None:
        its owner moves its packets itself and reports their counts, :meth:`Port.set_counts`);
        ``links`` are the links it reports on (default: those it uses); deliveries after
        ``until`` ns (default: the run's last tick) stay in flight.  With ``share_with`` its
        packets wait in that port's transmitters (:class:`Port`)."""
        p = Port(self, name, receive, links, until, share_with)
        self.ports.append(p)
        return p


def count_fate(link: Link, now: int, seq: int, count: dict[str, list[int]]) -> tuple[int, ...]:
    """The latencies of the arrivals of a packet handed to ``link`` at ``now`` as number
    ``seq`` (:meth:`Link.transmit`; none when it is lost), counting its loss (``lost``,
    ``outage_lost``) or copy (``copies``) in ``count`` (counter name -> per link id)."""
    lid = link.id
    arrivals, why = link.transmit(now, seq)
    if why is not None:
        count["lost"][lid] += 1
        if why == "outage":
            count["outage_lost"][lid] += 1
        return ()
    if len(arrivals) > 1:
        count["copies"][lid] += 1
    return arrivals


class Port:
    """One estimator's attachment to the network: what it sends, what it receives, counts.

    Packets due at one instant are delivered by one SimPy event (in the order
    they were sent), not one event each: at an instant every delivery runs
    before the flushes and the tick update anyway (their priorities), so the
    order of a port's deliveries is all that matters, and that is kept.

    A port made ``share_with`` another shares that port's transmitters (its packets wait in
    the same queues, behind the other's and the background) but keeps its own counters, its
    own receiver and its own keyed sequence space: its per-link sequence numbers start at
    :data:`SHARED_SEQ0`, so its draws never equal the other port's, and adding it changes
    none of the other port's draws (it can change their queueing, which is the point).
    """

    def __init__(self, network: Network, name: str, receive: Receive | None, links: list[Link] | None = None,
                 until: int | None = None, share_with: Port | None = None):
        self.net = network
        self.env = network.env
        self.name = name
        self.until = until
        self._receive = receive
        self._links = None if links is None else [l.id for l in links]
        #: ``range_lost`` (a part of ``lost``) only on a network whose links come and go,
        #: ``collision_lost`` (a part of ``lost``) only on one with a shared channel
        names = COUNTERS + (("range_lost",) if network.schedule is not None else ()) \
            + (("collision_lost",) if network.medium is not None else ())
        self._count: dict[str, list[int]] = {k: [] for k in names}
        self._late = 0
        self._grow()
        self._instant = -1
        self._seq: dict[int, int] = {}
        #: the first per-link sequence number at an instant (:data:`SHARED_SEQ0` when sharing)
        self._seq0 = 0 if share_with is None else SHARED_SEQ0
        #: arrival instant (ns) -> [link, payload, link, payload, ...] still to deliver
        self._due: dict[int, list[Any]] = {}
        #: link id -> transmitter of a rate-limited link (the network's when shared)
        shared = network.shared_transmitters if share_with is None else share_with._tx
        self._tx: dict[int, Transmitter] = shared if shared is not None else {}
        #: link id -> the link's statistics as its owner reported them (:meth:`set_link_stats`)
        self._stats: dict[int, dict[str, Any]] = {}
        #: link id -> (hand-over, start, end) ns of this port's packets its transmitter accepted
        self._own: dict[int, array] = {}
        #: link id -> (own, background) interval logs as the port's owner reported them
        #: (:meth:`set_link_log`)
        self._logs: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        #: the shared channel as this port sees it (``share_with``'s copy; None without one)
        self.channel: Channel | None = share_with.channel if share_with is not None else network.channel()
        #: this port's frames on the channel that ended: (end, collided, hand-over to start ns),
        #: flat; and how many a full waiting room dropped
        self._ended = array("q")
        self._frames_dropped = 0

    def _grow(self) -> None:
        """One counter slot per link of the network (links may be added after the port)."""
        size = len(self.net.links)
        for c in self._count.values():
            c.extend([0] * (size - len(c)))

    def send(self, link: Link, payload: Any, nbytes: int = 0) -> None:
        """Hand ``payload`` to ``link`` now (``nbytes``: its nominal size, for traffic); on
        the shared channel, a frame of one part (:meth:`send_frame`)."""
        if self.channel is not None and link.on_channel:
            self._send_on_channel(((link, payload, nbytes),), nbytes)
            return
        now = self.env.now
        if now != self._instant:
            self._instant, self._seq = now, {}
        lid = link.id
        seq = self._seq.get(lid, self._seq0)
        self._seq[lid] = seq + 1
        count = self._count
        if lid >= len(count["sent"]):
            self._grow()
        count["sent"][lid] += 1
        count["bytes"][lid] += nbytes
        if link.up is not None and not link.is_up(now):
            count["lost"][lid] += 1          # the pair is out of range: nothing leaves
            count["range_lost"][lid] += 1
            return
        if link.rate is not None:
            self._send_rated(now, seq, link, payload, nbytes)
            return
        plain = link.plain
        if plain is not None:
            lat, lost = plain(now, seq)
            if lost:
                count["lost"][lid] += 1
                return
            self._enqueue(now, lat, link, payload)
            return
        self._fly(now, 0, link, seq, payload)

    def send_frame(self, parts: Sequence[tuple[Link, Any, int]], frame_bytes: int) -> None:
        """Hand one frame now carrying ``parts``, each ``(link, payload, nbytes)``, all links
        from one sender; ``frame_bytes`` is the frame's size (a broadcast of one message of
        ``n`` bytes to ``k`` neighbours: ``k`` parts of ``n`` and a frame of ``n``; a combined
        frame of different messages: the sum of their sizes).  Each part is counted on its link
        (``sent``, ``bytes`` += its ``nbytes``).  The parts on the shared channel go as one frame
        of ``frame_bytes`` (:mod:`dkfsim.network.medium`); every other part (no channel, or a
        link off it) is sent on its own link, :meth:`send`."""
        channel = self.channel
        if channel is None:
            for link, payload, nbytes in parts:
                self.send(link, payload, nbytes)
            return
        framed = []
        for part in parts:
            if part[0].on_channel:
                framed.append(part)
            else:                               # (sent before the frame is offered, in order)
                self.send(*part)
        if framed:
            self._send_on_channel(framed, frame_bytes)

    def _send_on_channel(self, parts: Sequence[tuple[Link, Any, int]], frame_bytes: int) -> None:
        """One frame of ``frame_bytes`` on the shared channel carrying ``parts``: each part
        counted and numbered on its link; a part whose link is down is lost at once
        (``range_lost``); the rest offered as one frame (dropped as a whole by a full waiting
        room, ``queue_dropped`` per part)."""
        now = self.env.now
        if now != self._instant:
            self._instant, self._seq = now, {}
        count, seqs, seq0 = self._count, self._seq, self._seq0
        sent, sent_bytes = count["sent"], count["bytes"]     # (_grow extends these in place)
        held = []
        for link, payload, nbytes in parts:
            lid = link.id
            seq = seqs.get(lid, seq0)
            seqs[lid] = seq + 1
            try:
                sent[lid] += 1
            except IndexError:                  # (a link added after the port: rare)
                self._grow()
                sent[lid] += 1
            sent_bytes[lid] += nbytes
            if link.up is not None and not link.is_up(now):
                count["lost"][lid] += 1
                count["range_lost"][lid] += 1
                continue
            held.append((link, payload, seq))
        if not held:
            return
        assert self.channel is not None
        if not self.channel.offer(Frame(held[0][0].src, int(frame_bytes), now, held, self._frame_done)):
            self._frames_dropped += 1
            for link, _, _ in held:
                count["queue_dropped"][link.id] += 1

    def _frame_done(self, frame: Frame, ok: bool) -> None:
        """A frame of this port ended at ``frame.end`` (now): lost in a collision, or each part's
        fate drawn on its link as for any packet (keyed by the hand-over instant and its seq),
        its arrivals counted from the frame's end."""
        self._ended.extend((frame.end, not ok, frame.start - frame.handed))
        count = self._count
        if not ok:
            for link, _, _ in frame.parts:
                count["lost"][link.id] += 1
                count["collision_lost"][link.id] += 1
            return
        handed, end = frame.handed, frame.end
        for link, payload, seq in frame.parts:
            plain = link.plain
            if plain is None:
                self._fly(handed, end - handed, link, seq, payload)
                continue
            lat, lost = plain(handed, seq)      # (the fast path of send: nothing else acts)
            if lost:
                count["lost"][link.id] += 1
            else:
                self._enqueue(handed, end - handed + lat, link, payload)

    def _fly(self, now: int, wait: int, link: Link, seq: int, payload: Any) -> None:
        """A packet handed over ``now`` and leaving the sender ``wait`` ns later: its fate
        (loss, outage, copies, latencies) drawn at ``now``, its arrivals ``wait`` later."""
        for lat in count_fate(link, now, seq, self._count):   # (a lost one occupied the transmitter)
            self._enqueue(now, wait + lat, link, payload)

    def _transmitter(self, link: Link) -> Transmitter:
        tx = self._tx.get(link.id)
        if tx is None:
            tx = self._tx[link.id] = link.transmitter(record=True)
        return tx

    def _send_rated(self, now: int, seq: int, link: Link, payload: Any, nbytes: int) -> None:
        """:meth:`send` on a link with a transmitter: dropped when the waiting room is full;
        else its fate (loss, outage, copies, latencies) drawn as on any link at the hand-over
        instant, its arrivals counted from the end of its transmission."""
        lid, count = link.id, self._count
        got = self._transmitter(link).offer(now, nbytes)
        if got is None:
            count["queue_dropped"][lid] += 1
            return
        start, end = got
        own = self._own.get(lid)
        if own is None:
            own = self._own[lid] = array("q")
        own.extend((now, start, end))
        self._fly(now, end - now, link, seq, payload)

    def _enqueue(self, now: int, lat: int, link: Link, payload: Any) -> None:
        """Deliver ``payload`` at ``now + lat`` (``now``: its hand-over, not before the present)."""
        at = now + lat
        due = self._due.get(at)
        if due is None:
            due = self._due[at] = []
            Scheduled(self.env, self.deliver_now, PRIORITY_DELIVER, at - self.env.now)
        due.append(link)
        due.append(payload)

    def deliver_now(self, _event: Event | None = None) -> None:
        """Deliver what is due now (the instant's event finds nothing left afterwards; it calls
        this with itself as ``_event``, unused: one call less per delivery instant)."""
        now = self.env.now
        due = self._due.pop(now, None)
        if due is None:
            return
        if self.until is not None and now > self.until:
            return                            # after the port's last instant: in flight
        crashes = self.net.crashes
        delivered = self._count["delivered"]
        receive = self._receive
        if receive is None:
            raise RuntimeError(f"port {self.name!r} has no receiver: its owner delivers its own packets")
        pairs = iter(due)                   # (link, payload, link, payload, ...)
        for link, payload in zip(pairs, pairs):
            if crashes is not None and link.dst >= 0 and crashes.down(link.dst, now):
                self._count["crash_dropped"][link.id] += 1
                continue
            delivered[link.id] += 1
            receive(link, payload)

    def set_counts(self, link: Link, **counts: int) -> None:
        """Set counters of ``link`` (names of :data:`COUNTERS`): for a protocol whose packets
        travel outside the port (the compiled ``tree``, whose kernels count them)."""
        self._grow()
        for key, value in counts.items():
            self._count[key][link.id] = value

    def set_link_stats(self, link: Link, stats: dict[str, Any]) -> None:
        """The statistics of a rate-limited ``link``
        (:func:`~dkfsim.network.transmitter.link_stats`), for a protocol whose packets travel
        outside the port (the compiled ``tree``)."""
        self._stats[link.id] = dict(stats)

    def set_link_log(self, link: Link, own: np.ndarray, background: np.ndarray) -> None:
        """The interval logs of a rate-limited ``link``'s transmitter (hand-over, start, end ns;
        :mod:`~dkfsim.network.occupancy`): this port's accepted packets and the background, for
        a protocol whose packets travel outside the port (the compiled ``tree``)."""
        self._logs[link.id] = (np.asarray(own, dtype=np.int64).reshape(-1, 3),
                               np.asarray(background, dtype=np.int64).reshape(-1, 3))

    def link_log(self, link: Link) -> np.ndarray:
        """``(packets, 3)`` int64: (hand-over, start, end) ns of every packet the transmitter of
        rate-limited ``link`` carried as this port saw it -- its own, the background and, with
        shared queues, the other ports' -- in no particular order (``start < 0``: dropped)."""
        if link.id in self._logs:
            return np.concatenate(self._logs[link.id])
        tx = self._transmitter(link)
        tx.advance(self.until if self.until is not None else self.env.now)
        parts = [tx.log()]
        ports = [p for p in self.net.ports if p._tx is self._tx] if self in self.net.ports else [self]
        for port in ports:
            own = port.own_log(link)
            if own is not None and len(own):
                parts.append(np.frombuffer(own, dtype=np.int64).reshape(-1, 3))
        return np.concatenate(parts)

    def own_log(self, link: Link) -> array | None:
        """(hand-over, start, end) ns of this port's accepted packets on ``link``, flat."""
        return self._own.get(link.id)

    def _own_delays(self, link: Link) -> np.ndarray:
        """This port's accepted packets' queueing delays on ``link`` (ns)."""
        if link.id in self._logs:
            own = self._logs[link.id][0]
        else:
            flat = self._own.get(link.id)
            own = np.frombuffer(flat, dtype=np.int64).reshape(-1, 3) if flat else np.zeros((0, 3), np.int64)
        return own[:, 1] - own[:, 0]

    def link_series(self, T_ns: int, K: int) -> dict[str, np.ndarray]:
        """Per tick, each rate-limited link this port reports on: the time-averaged number of
        packets waiting and the utilisation (:func:`~dkfsim.network.occupancy.per_tick`), as
        ``run.npz`` keeps them: ``rated_links`` (E, 2), ``queue_length`` and ``utilisation``
        (K, E), and ``queueing_delay_quantiles`` (E, 101): the percentiles 0, 1, ..., 100 of
        this port's queueing delays on each link, seconds (NaN without a packet).  Empty without
        a rate-limited link."""
        links = [self.net.links[i] for i in self._reported() if self.net.links[i].rate is not None]
        if not links:
            return {}
        queue, busy = zip(*(per_tick(self.link_log(link), T_ns, K) for link in links))
        quantiles = np.full((len(links), 101), np.nan)
        for e, link in enumerate(links):
            d = self._own_delays(link)
            if len(d):
                quantiles[e] = np.percentile(d / NS_PER_S, np.arange(101))
        return {"rated_links": np.array([(l.src, l.dst) for l in links], dtype=np.int64),
                "queue_length": np.stack(queue, axis=1), "utilisation": np.stack(busy, axis=1),
                "queueing_delay_quantiles": quantiles}

    def _reported(self) -> list[int]:
        """The ids of the links this port reports on (given, or those it used)."""
        count = self._count
        return self._links if self._links is not None else \
            [i for i in range(len(self.net.links)) if any(count[k][i] for k in COUNTERS)]

    def count_late(self, n: int = 1) -> None:
        """Count ``n`` late items: what is late is the estimator's to decide (e.g. a message
        delivered after its last usable instant, dropped unused); ``counts()["late"]``."""
        self._late += int(n)

    def counts(self) -> dict[str, Any]:
        """Totals, ``per_link`` (links this port used) and ``late`` (:meth:`count_late`);
        ``in_flight`` by the identity (packets still waiting in a queue included).  A
        rate-limited link's row adds its utilisation of ``[0, until]`` and this port's
        queueing delays (:func:`~dkfsim.network.transmitter.link_stats`)."""
        self._grow()
        count = self._count
        totals: dict[str, Any] = {k: sum(c) for k, c in count.items()}
        totals["in_flight"] = (totals["sent"] + totals["copies"] - totals["delivered"]
                               - totals["lost"] - totals["queue_dropped"] - totals["crash_dropped"])
        per_link = []
        end = self.until if self.until is not None else self.env.now
        for i in self._reported():
            link = self.net.links[i]
            row: dict[str, Any] = {"link": (link.src, link.dst), **{k: c[i] for k, c in count.items()}}
            row["in_flight"] = (row["sent"] + row["copies"] - row["delivered"] - row["lost"]
                                - row["queue_dropped"] - row["crash_dropped"])
            if i in self._stats:
                row.update(self._stats[i])
            elif link.rate is not None:
                tx = self._transmitter(link)
                row.update(link_stats(self._own_delays(link), tx.busy_until(end), tx.background_sent,
                                      tx.background_dropped, end))
            if link.rate is not None:
                row["queue_length_mean"] = mean_waiting(self.link_log(link), end)
            per_link.append(row)
        totals["per_link"] = per_link
        totals["late"] = self._late
        if self.channel is not None:
            totals["channel"] = self.channel_stats(end)
        return totals

    def channel_stats(self, end: int) -> dict[str, Any]:
        """The shared channel over ``[0, end]`` as this port saw it (:meth:`Channel.stats`:
        every frame, background included) and this port's frames that ended by ``end``:
        ``frames`` (collided or not), ``frames_collided`` and ``access_delay_mean`` (s, hand-over
        to start of transmission); ``frames_dropped``: those a full waiting room refused."""
        assert self.channel is not None
        stats: dict[str, Any] = dict(self.channel.stats(end))
        done = np.frombuffer(self._ended, dtype=np.int64).reshape(-1, 3)
        done = done[done[:, 0] <= end]
        stats.update(frames=len(done), frames_collided=int(done[:, 1].sum()), frames_dropped=self._frames_dropped,
                     access_delay_mean=float(done[:, 2].mean()) / NS_PER_S if len(done) else 0.0)
        return stats
