"""The network of one run: its links, which medium each one's frames take, its ports.

One :class:`Network` per run, shared by every estimator (each talks through its own
:class:`~dkfsim.network.port.Port`).  It holds one :class:`~dkfsim.network.links.Link` per arc
of the topology (and the links an estimator adds outside the graph, e.g. each sensor's direct
link to ``centralized_delayed``'s centre) and decides, once, each link's medium
(:mod:`dkfsim.network.media`): the shared channel when both ends are on it (``medium:``), a
first-in-first-out transmitter when the link has a rate (``links.<...>.rate``, or
``mobility.links.rate``), else ``direct``.  With ``mobility:`` it hands each link its state
over time and its distance-dependent quality (:class:`~dkfsim.components.mobility.LinkSchedule`),
so a link answers :meth:`~dkfsim.network.links.Link.is_up` and draws its loss and latency at
the pair's distance.
"""

from __future__ import annotations

from typing import Any, Callable, cast

import simpy

from dkfsim.components.faults import CrashSchedule
from dkfsim.components.medium import Medium as MediumSpec
from dkfsim.components.mobility import LinkSchedule
from dkfsim.core.backend import Backend
from dkfsim.core.registry import MEDIA
from dkfsim.network.events import Clock
from dkfsim.network.links import Link
from dkfsim.network.media import csma, sidelink, slotted  # noqa: F401  (registers the access rules)
from dkfsim.network.media.base import Medium
from dkfsim.network.media.channel import Channel
from dkfsim.network.media.direct import DIRECT
from dkfsim.network.media.fifo import Fifo, FifoTable
from dkfsim.network.media.radio import RadioChannel, SpatialChannel
from dkfsim.network.port import Port, Receive, RecordPort

#: The key of a media store's shared channel (link ids are ints).
_CHANNEL = "channel"


class Network:
    """The links of one run inside a SimPy environment, shared by every estimator.

    :param arcs: directed ``(u, v)`` pairs; link ids are their positions.
    :param link_spec: ``link_spec(u, v)`` -> a :class:`~dkfsim.components.faults.LinkSpec`.
    :param crashes: optional :class:`~dkfsim.components.faults.CrashSchedule`; a packet
        arriving at a node that is down is dropped (``crash_dropped``).
    :param shared_queues: every port's packets through the same copy of each medium (default:
        each port its own, the same background and draws in each).
    :param schedule: a :class:`~dkfsim.components.mobility.LinkSchedule` of ``arcs``
        (``mobility:``): which links are up at each tick; None: every link always up.
    :param medium: the shared radio channel (``medium:``): a link between two of its nodes is
        on it.
    :param n: the number of nodes (default: the largest node of ``arcs`` plus one).
    :param backend: the run's (the FIFO transmitters' kernels compiled or not; default: the
        environment's).
    :param positions: every node's position (m) at ticks ``0 .. K``, ``(K + 1, n, 2)``: what a
        spatial radio (``medium.radio``) needs; ``presence``: whether each is on the road at each
        tick (``(K + 1, n)`` bool; None: always).
    """

    def __init__(self, env: simpy.Environment, arcs: list[tuple[int, int]],
                 link_spec: Callable[[int, int], Any], seed: int, T_ns: int,
                 crashes: CrashSchedule | None = None, shared_queues: bool = False,
                 schedule: LinkSchedule | None = None, medium: MediumSpec | None = None, n: int | None = None,
                 backend: Backend | None = None, positions: Any = None, presence: Any = None):
        self.env = cast(Clock, env)         # (SimPy types time as int | float; here it is ns)
        self.backend = backend if backend is not None else Backend.from_environment()
        self.seed, self.T_ns = int(seed), int(T_ns)
        self.medium = medium
        #: every node's position at ticks 0 .. K, for a spatial radio (``medium.radio``), and
        #: whether each is on the road then (None: always)
        self.positions, self.presence = positions, presence
        if medium is not None and medium.radio is not None and positions is None:
            raise ValueError("a spatial radio (medium.radio) needs the vehicles' positions (mobility:)")
        if n is None:
            n = 1 + max((max(u, v) for u, v in arcs), default=-1)
        #: the nodes on the channel, in increasing order (none without ``medium``), and as a set
        self._member_order: tuple[int, ...] = medium.members(n) if medium is not None else ()
        self.members: frozenset[int] = frozenset(self._member_order)
        #: the media every port uses, with shared queues (else each port keeps its own)
        self._shared_media: dict[Any, Medium] | None = {} if shared_queues else None
        #: per set of media (by its id; the set itself kept with it): the table of its FIFO transmitters
        self._fifo_tables: dict[int, tuple[dict[Any, Medium], FifoTable]] = {}
        self.links = [Link(i, u, v, link_spec(u, v), seed, T_ns) for i, (u, v) in enumerate(arcs)]
        self.index = {(l.src, l.dst): l for l in self.links}
        #: link id -> its rate (bit/s) at each tick when it follows the pair's distance
        self._rates: dict[int, list[float]] = {}
        #: which links are up at each tick (None: all, always)
        self.schedule = schedule
        if schedule is not None:
            for i, link in enumerate(self.links):
                link.set_schedule(schedule.up[:, i])
                if schedule.distance is not None and schedule.quality is not None:
                    loss, extra, rates = schedule.quality.per_tick(schedule.distance[:, i])
                    link.set_distance(loss, extra)
                    if rates is not None:
                        self._rates[i] = rates
                if link.src in schedule.sinr:
                    link.set_sinr(schedule.sinr[link.src])
        self.crashes = crashes if crashes else None
        self.ports: list[Port] = []

    def link(self, u: int, v: int) -> Link:
        return self.index[(u, v)]

    def extra_link(self, key: tuple, spec: Any, src: int, dst: int) -> Link:
        """A link outside the graph (e.g. a sensor's direct link to a fusion centre),
        its draws named ``key``; it joins the network's link list."""
        link = Link(len(self.links), src, dst, spec, self.seed, self.T_ns, key=key)
        self.links.append(link)
        return link

    def port(self, name: str, receive: Receive, links: list[Link] | None = None,
             until: int | None = None, share_with: Port | None = None) -> Port:
        """A new port for an estimator: ``receive(link, payload)`` gets its deliveries; ``links``
        are the links it reports on (default: those it uses); deliveries after ``until`` ns
        (default: the run's last tick) stay in flight.  With ``share_with`` its packets take
        that port's copies of the media (:class:`~dkfsim.network.port.Port`)."""
        p = Port(self, name, receive, links, until, share_with)
        self.ports.append(p)
        return p

    def record_port(self, name: str, receive: Receive, links: list[Link], *, width: int, backend: Backend,
                    until: int | None = None) -> RecordPort:
        """A new port whose packets are records of ``width`` int64 words, handed over and
        delivered in batches (:class:`~dkfsim.network.port.RecordPort`)."""
        p = RecordPort(self, name, receive, links, until, width=width, backend=backend)
        self.ports.append(p)
        return p

    # -- media -------------------------------------------------------------------------
    def on_channel(self, link: Link) -> bool:
        """Whether ``link`` is on the shared channel (its packets go as frames): it joins two of
        its nodes, or goes from one of them to a centre outside the graph (``dst < 0``, e.g.
        ``centralized_delayed``'s, which listens on the channel; decision 216)."""
        return link.src in self.members and (link.dst in self.members or link.dst < 0)

    def media_store(self) -> dict[Any, Medium]:
        """Where a new port keeps its copies of the media: its own, or with shared queues the
        network's (every port the same)."""
        return self._shared_media if self._shared_media is not None else {}

    def channel_of(self, store: dict[Any, Medium]) -> Medium | None:
        """The shared channel's copy in ``store`` (made now if it has none); None without
        ``medium:``."""
        if self.medium is None:
            return None
        channel = store.get(_CHANNEL)
        if channel is None:
            if self.medium.radio is not None:
                # (an access that is a spatial channel of its own, the sidelink's, or the 802.11p radio's rules)
                impl = MEDIA.get(self.medium.access.kind).implementation
                kind = impl if isinstance(impl, type) and issubclass(impl, SpatialChannel) else RadioChannel
                channel = kind(self.env, self.medium, self._member_order, self.seed, self.positions, self.T_ns,
                               backend=self.backend, presence=self.presence)
            else:
                channel = Channel(self.env, self.medium, self._member_order, self.seed, T_ns=self.T_ns,
                                  backend=self.backend)
            store[_CHANNEL] = channel
        return channel

    def medium_of(self, link: Link, store: dict[Any, Medium]) -> Medium:
        """``link``'s medium in ``store`` (made now if it has none there, and kept)."""
        medium: Medium | None
        if self.on_channel(link):
            medium = self.channel_of(store)
        elif link.spec.rate is not None or link.id in self._rates:
            held = self._fifo_tables.get(id(store))
            if held is None:
                held = self._fifo_tables[id(store)] = (store, FifoTable(self.backend))
            medium = Fifo(link, self._rates.get(link.id), held[1])
        else:
            medium = DIRECT
        assert medium is not None
        store[link.id] = medium
        return medium
