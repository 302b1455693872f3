"""The SimPy network: directed links with per-packet latency, loss and faults.

Time is kept in integer nanoseconds (docs/design.md §2), so "arrived by
tick k" is an exact integer comparison, never one of accumulated floats.

A packet is handed to a :class:`Link` with :meth:`Network.send`; the link
draws whether it is lost and, if not, its latency, and a single SimPy
``Timeout`` carries it to the receiver's callback.  No process per packet:
per-packet Python work is a couple of list pops and one event.  Latency and
loss are drawn in blocks from the link's own streams ``("link", u, v,
"latency")`` and ``("link", u, v, "loss")``, so adding a link changes no
other draw, and changing the loss probability leaves the latencies alone
(common random numbers across scenarios).  Packets on one link may overtake
each other whenever a later draw is shorter: links reorder.

The link faults of :mod:`dkfsim.components.faults` (duplication, jitter, a latency
schedule, outages) and stateful latency models (``empirical`` replay,
``gilbert_elliott``, which also loses packets) draw from further streams of
the same link (``("link", u, v, "duplicate")``, ``("link", u, v, "jitter",
...)``, ...).  Every draw is taken per packet whatever the packet's fate, so
adding a fault leaves the other draws unchanged; a link with none of them
runs exactly the code (and draws) it always did.  Crash windows
(:class:`dkfsim.components.faults.CrashSchedule`) drop every packet that arrives at a
node while it is down (``crash_dropped``).

Counting identity, per link and in total (see :mod:`dkfsim.components.faults`)::

    sent + copies = delivered + lost + crash_dropped + in_flight

Event priorities at one instant (SimPy pops ``(time, priority, id)``):
deliveries (``NORMAL``) first, then the protocols' flushes
(:data:`PRIORITY_FLUSH`), then the filters' tick update
(:data:`PRIORITY_UPDATE`), so a packet arriving exactly at ``t_k``, and any
chain of zero-latency relays it starts, counts for tick ``k``.
"""

from __future__ import annotations

import numpy as np
import simpy
from simpy.events import NORMAL, Event, Timeout

from dkfsim.components.faults import LinkSpec, ScaleSchedule, Windows
from dkfsim.components.latency import _MAX_NS, LatencyBase
from dkfsim.core.streams import stream

PRIORITY_DELIVER = NORMAL
PRIORITY_FLUSH = NORMAL + 1
PRIORITY_UPDATE = NORMAL + 2

_BLOCK = 256


class Scheduled(Event):
    """An event that fires at ``now + delay`` with a given priority and callback."""

    def __init__(self, env, callback, priority, delay=0):
        super().__init__(env)
        self._ok = True
        self._value = None
        self.callbacks.append(callback)
        env.schedule(self, priority, delay)


def _as_spec(spec) -> LinkSpec:
    """A :class:`LinkSpec` from anything with ``.latency`` and ``.loss``."""
    if isinstance(spec, LinkSpec):
        return spec
    return LinkSpec(latency=spec.latency, loss=float(spec.loss),
                    duplicate=float(getattr(spec, "duplicate", 0.0) or 0.0),
                    jitter=getattr(spec, "jitter", None),
                    schedule=tuple(getattr(spec, "schedule", None) or ()),
                    outages=tuple(getattr(spec, "outages", None) or ()))


class Recipe:
    """The latency of successive packets on one link: model draw, times the
    schedule's factor at the send time, plus jitter.

    ``rng_for(*name)`` gives the link's named streams.  :meth:`next` also
    returns whether the latency model lost the packet (``gilbert_elliott``).
    Usable without SimPy (e.g. for a baseline's direct links).
    """

    __slots__ = ("_sampler", "_lat", "_mlost", "_sched", "_jsampler", "_jit")

    def __init__(self, spec: LinkSpec, rng_for, T_ns: int):
        self._sampler = spec.latency.sampler(rng_for, T_ns)
        self._sched = ScaleSchedule(spec.schedule) if spec.schedule else None
        self._jsampler = (spec.jitter.sampler(lambda *name: rng_for("jitter", *name), T_ns)
                          if spec.jitter is not None else None)
        self._lat: list[int] = []
        self._mlost: list[bool] | None = None
        self._jit: list[int] = []

    def next(self, now_ns: int) -> tuple[int, bool]:
        """``(latency in ns, lost by the model)`` of the next packet, sent at ``now_ns``."""
        if not self._lat:
            lat, lost = self._sampler.block(_BLOCK)
            self._lat = np.asarray(lat, dtype=np.int64)[::-1].tolist()
            self._mlost = None if lost is None else np.asarray(lost, dtype=bool)[::-1].tolist()
        lat = self._lat.pop()
        mlost = self._mlost.pop() if self._mlost is not None else False
        if self._sched is not None:
            f = self._sched.factor(now_ns)
            if f != 1.0:
                lat = min(int(round(lat * f)), _MAX_NS)
        if self._jsampler is not None:
            if not self._jit:
                j, _ = self._jsampler.block(_BLOCK)
                self._jit = np.asarray(j, dtype=np.int64)[::-1].tolist()
            lat = min(lat + self._jit.pop(), _MAX_NS)
        return lat, mlost


class Link:
    """Directed link ``src -> dst``: its draws, faults and counters.

    :param spec: a :class:`~dkfsim.components.faults.LinkSpec` (or anything with
        ``.latency`` and ``.loss``).
    :param key: prefix of the link's stream names, ``("link", src, dst)`` by default.
    """

    __slots__ = ("id", "src", "dst", "spec", "latency", "loss", "duplicate", "plain", "_T_ns",
                 "_lat_rng", "_loss_rng", "_lat", "_u", "_main", "_copy", "_dup_rng", "_du",
                 "_outages", "sent", "delivered", "lost", "copies", "crash_dropped",
                 "outage_lost", "seq")

    def __init__(self, link_id, src, dst, spec, seed, T_ns, key=None):
        spec = _as_spec(spec)
        self.id = link_id
        self.src = src
        self.dst = dst
        self.spec = spec
        self.latency = spec.latency
        self.loss = float(spec.loss)
        self.duplicate = float(spec.duplicate)
        self._T_ns = int(T_ns)
        prefix = ("link", src, dst) if key is None else tuple(key)

        def rng_for(*name, _seed=seed, _prefix=prefix):
            return stream(_seed, *_prefix, *name)

        self._lat_rng = self._main = self._copy = self._dup_rng = self._outages = None
        self._loss_rng = rng_for("loss")
        self._lat: list[int] = []
        self._u: list[float] = []
        self._du: list[float] = []
        # A plain link: an i.i.d. model, no faults -- the original fast path.
        self.plain = spec.plain and type(spec.latency).sampler is LatencyBase.sampler
        if self.plain:
            self._lat_rng = rng_for("latency")
        else:
            self._main = Recipe(spec, rng_for, self._T_ns)
            if self.duplicate > 0.0:
                self._dup_rng = rng_for("duplicate")
                self._copy = Recipe(spec, lambda *name: rng_for("duplicate", *name), self._T_ns)
            if spec.outages:
                self._outages = Windows(spec.outages)
        self.sent = self.delivered = self.lost = 0
        self.copies = self.crash_dropped = self.outage_lost = 0
        self.seq = 0

    def draw(self, now_ns: int):
        """Latency in ns of the next packet, or ``None`` if it is lost (plain links;
        the copy of a duplicated packet is not reported here: see :meth:`transmit`)."""
        if not self.plain:
            lats = self.transmit(now_ns, count=False)
            return lats[0] if lats else None
        if not self._lat:
            block = self.latency.sample_ns(self._lat_rng, _BLOCK, self._T_ns)
            self._lat = np.asarray(block, dtype=np.int64)[::-1].tolist()
        lat = self._lat.pop()
        if self.loss > 0.0:
            if not self._u:
                self._u = self._loss_rng.random(_BLOCK)[::-1].tolist()
            if self._u.pop() < self.loss:
                return None
        return lat

    def transmit(self, now_ns: int, count: bool = True) -> tuple[int, ...]:
        """Latencies of the arrivals a packet sent at ``now_ns`` makes: ``()`` if
        it is lost, one, or two when it is duplicated.  Counts ``lost``,
        ``outage_lost`` and ``copies`` (not ``sent``)."""
        if self.plain:
            lat = self.draw(now_ns)
            if lat is None:
                if count:
                    self.lost += 1
                return ()
            return (lat,)
        lat, lost = self._main.next(now_ns)
        if self.loss > 0.0:
            if not self._u:
                self._u = self._loss_rng.random(_BLOCK)[::-1].tolist()
            if self._u.pop() < self.loss:
                lost = True
        dup = False
        if self._dup_rng is not None:
            if not self._du:
                self._du = self._dup_rng.random(_BLOCK)[::-1].tolist()
            dup = self._du.pop() < self.duplicate
        if self._outages is not None and now_ns in self._outages:
            if count:
                self.lost += 1
                self.outage_lost += 1
            return ()
        if lost:
            if count:
                self.lost += 1
            return ()
        if dup:
            if count:
                self.copies += 1
            return (lat, self._copy.next(now_ns)[0])
        return (lat,)


class Network:
    """Links of one exchange graph inside a SimPy environment.

    :param arcs: directed ``(u, v)`` pairs; link ids are their positions.
    :param link_spec: ``link_spec(u, v)`` -> a :class:`~dkfsim.components.faults.LinkSpec`
        (or any object with ``.latency`` and ``.loss``).
    :param receive: ``receive(link, payload)`` called on each delivery.
    :param crashes: optional :class:`~dkfsim.components.faults.CrashSchedule`; a packet
        arriving at a node that is down is dropped (``crash_dropped``).
    """

    def __init__(self, env: simpy.Environment, arcs, link_spec, seed, T_ns, receive,
                 crashes=None):
        self.env = env
        self.links = []
        for i, (u, v) in enumerate(arcs):
            self.links.append(Link(i, u, v, link_spec(u, v), seed, T_ns))
        self.index = {(l.src, l.dst): l for l in self.links}
        self._receive = receive
        self._crashes = crashes if crashes else None

    def send(self, link: Link, payload) -> None:
        link.sent += 1
        if link.plain:
            lat = link.draw(self.env.now)
            if lat is None:
                link.lost += 1
                return
            ev = Timeout(self.env, lat, (link, payload))
            ev.callbacks.append(self._deliver)
            return
        for lat in link.transmit(self.env.now):
            ev = Timeout(self.env, lat, (link, payload))
            ev.callbacks.append(self._deliver)

    def _deliver(self, event) -> None:
        link, payload = event._value
        if self._crashes is not None and self._crashes.down(link.dst, self.env.now):
            link.crash_dropped += 1
            return
        link.delivered += 1
        self._receive(link, payload)

    @staticmethod
    def _in_flight(l: Link) -> int:
        return l.sent + l.copies - l.delivered - l.lost - l.crash_dropped

    def counts(self) -> dict:
        """Packet counts; ``sent + copies = delivered + lost + crash_dropped + in_flight``."""
        keys = ("sent", "delivered", "lost", "copies", "crash_dropped", "outage_lost")
        out = {k: sum(getattr(l, k) for l in self.links) for k in keys}
        out["in_flight"] = sum(self._in_flight(l) for l in self.links)
        out["per_link"] = [
            {"link": (l.src, l.dst), **{k: getattr(l, k) for k in keys},
             "in_flight": self._in_flight(l)}
            for l in self.links
        ]
        return out
