"""The SimPy network: directed links with per-packet latency and loss.

Time is kept in integer nanoseconds (DESIGN.md section 2), so "arrived by
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

from .streams import stream

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


class Link:
    """Directed link ``src -> dst`` with its latency model, loss and counters."""

    __slots__ = ("id", "src", "dst", "latency", "loss", "_T_ns", "_lat_rng", "_loss_rng",
                 "_lat", "_u", "sent", "delivered", "lost", "seq")

    def __init__(self, link_id, src, dst, latency, loss, seed, T_ns):
        self.id = link_id
        self.src = src
        self.dst = dst
        self.latency = latency
        self.loss = float(loss)
        self._T_ns = int(T_ns)
        self._lat_rng = stream(seed, "link", src, dst, "latency")
        self._loss_rng = stream(seed, "link", src, dst, "loss")
        self._lat: list[int] = []
        self._u: list[float] = []
        self.sent = self.delivered = self.lost = 0
        self.seq = 0

    def draw(self, now_ns: int):
        """Latency in ns of the next packet, or ``None`` if it is lost."""
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


class Network:
    """Links of one exchange graph inside a SimPy environment.

    :param arcs: directed ``(u, v)`` pairs; link ids are their positions.
    :param link_spec: ``link_spec(u, v)`` -> object with ``.latency`` and ``.loss``.
    :param receive: ``receive(link, payload)`` called on each delivery.
    """

    def __init__(self, env: simpy.Environment, arcs, link_spec, seed, T_ns, receive):
        self.env = env
        self.links = []
        for i, (u, v) in enumerate(arcs):
            spec = link_spec(u, v)
            self.links.append(Link(i, u, v, spec.latency, spec.loss, seed, T_ns))
        self.index = {(l.src, l.dst): l for l in self.links}
        self._receive = receive

    def send(self, link: Link, payload) -> None:
        link.sent += 1
        lat = link.draw(self.env.now)
        if lat is None:
            link.lost += 1
            return
        ev = Timeout(self.env, lat, (link, payload))
        ev.callbacks.append(self._deliver)

    def _deliver(self, event) -> None:
        link, payload = event._value
        link.delivered += 1
        self._receive(link, payload)

    def counts(self) -> dict:
        sent = sum(l.sent for l in self.links)
        delivered = sum(l.delivered for l in self.links)
        lost = sum(l.lost for l in self.links)
        return {
            "sent": sent,
            "delivered": delivered,
            "lost": lost,
            "in_flight": sent - delivered - lost,
            "per_link": [
                {"link": (l.src, l.dst), "sent": l.sent, "delivered": l.delivered,
                 "lost": l.lost, "in_flight": l.sent - l.delivered - l.lost}
                for l in self.links
            ],
        }
