"""A port: one estimator's attachment to the network -- what it sends, what it receives, counts.

Every packet takes one path (docs/design.md §3, "The network layer"): the port numbers it on
its link (its sequence number among the packets the port hands that link at that instant, the
key of its draws) and counts it; a link that is down takes nothing (``range_lost``); the
link's medium (:mod:`dkfsim.network.media`) decides when the frame carrying it leaves the
sender, or why it never does (``queue_dropped``, ``collision_lost``); the link draws its
propagation at the hand-over instant (:meth:`~dkfsim.network.links.Link.transmit`: loss,
copies, latency), counted from when it left; the port delivers it to its estimator at the
arrival instant, unless the receiving node is down then (``crash_dropped``).  A frame on a
broadcast medium (the shared channel) carries every part of one flush of one sender on it;
on any other medium each part is a frame of its own.

Packets due at one instant are delivered by one SimPy event (in the order they were sent),
not one event each: at an instant every delivery runs before the flushes and the tick update
anyway (their priorities), so the order of a port's deliveries is all that matters, and that
is kept.

Counting identity, per port, per link and in total::

    sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight

Beside these a port keeps ``late``, which only its estimator can decide (a packet delivered
after its last usable instant, a stale pair, ...): the estimator counts it with
:meth:`Port.count_late`, and ``counts()`` reports it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from simpy.events import Event

from dkfsim.core.params import NS_PER_S
from dkfsim.network.events import PRIORITY_DELIVER, Clock, Scheduled
from dkfsim.network.links import Link
from dkfsim.network.media.base import Frame, Medium
from dkfsim.network.occupancy import per_tick

if TYPE_CHECKING:
    from dkfsim.network.network import Network

#: Counters of a port, per link:
#: ``sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight``.
COUNTERS = ("sent", "delivered", "lost", "copies", "crash_dropped", "outage_lost", "bytes", "queue_dropped")

#: The first per-link sequence number of a port that shares another's media
#: (:meth:`Network.port` ``share_with``): its keyed draws never equal the other port's, and
#: adding it changes none of them.
SHARED_SEQ0 = 1 << 32

#: What a port hands its estimator: ``receive(link, payload)``.
Receive = Callable[[Link, Any], None]


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
    """One estimator's attachment to the network (see the module).

    A port made ``share_with`` another shares that port's copies of the media (its packets wait
    in the same queues, behind the other's and the background, and contend on the same
    channel) but keeps its own counters, its own receiver and its own keyed sequence space: its
    per-link sequence numbers start at :data:`SHARED_SEQ0`, so its draws never equal the other
    port's, and adding it changes none of the other port's draws (it can change their
    queueing, which is the point).
    """

    def __init__(self, network: Network, name: str, receive: Receive | None, links: list[Link] | None = None,
                 until: int | None = None, share_with: Port | None = None):
        self.net = network
        self.env: Clock = network.env
        self.name = name
        #: deliveries after this instant (ns) stay in flight (the engine sets it to the run's end)
        self.until = until
        self._receive = receive
        self._links = None if links is None else [l.id for l in links]
        #: ``range_lost`` (a part of ``lost``) only on a network whose links come and go,
        #: ``collision_lost`` (a part of ``lost``) only on one with a shared channel
        names = COUNTERS + (("range_lost",) if network.schedule is not None else ()) \
            + (("collision_lost",) if network.members else ())
        self._count: dict[str, list[int]] = {k: [] for k in names}
        self._late = 0
        self._grow()
        self._instant = -1
        self._seq: dict[int, int] = {}
        #: the first per-link sequence number at an instant (:data:`SHARED_SEQ0` when sharing)
        self._seq0 = 0 if share_with is None else SHARED_SEQ0
        #: arrival instant (ns) -> [link, payload, link, payload, ...] still to deliver
        self._due: dict[int, list[Any]] = {}
        #: this port's copies of the media (link id -> medium), shared with ``share_with``'s or,
        #: with shared queues, the network's
        self._media: dict[Any, Medium] = share_with._media if share_with is not None else network.media_store()
        #: the shared channel as this port sees it (None without one)
        self.channel: Medium | None = network.channel_of(self._media)

    def _grow(self) -> None:
        """One counter slot per link of the network (links may be added after the port)."""
        size = len(self.net.links)
        for c in self._count.values():
            c.extend([0] * (size - len(c)))

    def medium(self, link: Link) -> Medium:
        """This port's copy of ``link``'s medium."""
        m = self._media.get(link.id)
        return m if m is not None else self.net.medium_of(link, self._media)

    # -- sending -------------------------------------------------------------------
    def send(self, link: Link, payload: Any, nbytes: int = 0) -> None:
        """Hand ``payload`` to ``link`` now (``nbytes``: its nominal size, for traffic): a frame
        of one part (:meth:`send_frame`)."""
        self.send_frame(((link, payload, nbytes),), nbytes)

    def send_frame(self, parts: Sequence[tuple[Link, Any, int]], frame_bytes: int) -> None:
        """Hand over now one flush of one sender carrying ``parts``, each ``(link, payload,
        nbytes)``: each part numbered and counted on its link (``sent``, ``bytes`` += its
        ``nbytes``) and nothing sent on a link that is down (``range_lost``); on a broadcast
        medium (the shared channel) the parts on it go as one frame of ``frame_bytes`` (a
        broadcast of one message of ``n`` bytes to ``k`` neighbours: ``k`` parts of ``n`` and a
        frame of ``n``; a combined frame of different messages: the sum of their sizes),
        offered after the other parts; on any other medium each part is a frame of its own
        ``nbytes``, offered in order."""
        now = self.env.now
        if now != self._instant:
            self._instant, self._seq = now, {}
        count, seqs, seq0 = self._count, self._seq, self._seq0
        sent, sent_bytes = count["sent"], count["bytes"]     # (_grow extends these in place)
        media = self._media
        shared: dict[Medium, list[tuple[Link, Any, int]]] | None = None
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
            if link.changes and not link.is_up(now):
                count["lost"][lid] += 1          # the pair is out of range: nothing leaves
                count["range_lost"][lid] += 1
                continue
            medium = media.get(lid)
            if medium is None:
                medium = self.net.medium_of(link, media)
            if medium.broadcast:
                if shared is None:
                    shared = {}
                shared.setdefault(medium, []).append((link, payload, seq))
            elif not medium.offer(Frame(link.src, nbytes, now, ((link, payload, seq),), self._left, self)):
                count["queue_dropped"][lid] += 1
        if shared:
            for medium, held in shared.items():
                if not medium.offer(Frame(held[0][0].src, int(frame_bytes), now, held, self._left, self)):
                    for link, _, _ in held:
                        count["queue_dropped"][link.id] += 1

    def _left(self, frame: Frame, ok: bool) -> None:
        """A frame of this port has left its sender (at ``frame.end``, now or later), or was lost
        on the air (``ok`` false: a collision, lost for every receiver).  Each part's fate is
        drawn on its link as for any packet (keyed by the hand-over instant and its number), its
        arrivals counted from the frame's end."""
        count = self._count
        if not ok:
            for link, _, _ in frame.parts:
                count["lost"][link.id] += 1
                count["collision_lost"][link.id] += 1
            return
        handed, wait = frame.handed, frame.end - frame.handed
        for link, payload, seq in frame.parts:
            plain = link.plain
            if plain is None:
                for lat in count_fate(link, handed, seq, count):    # (a lost one occupied the medium)
                    self._enqueue(handed, wait + lat, link, payload)
                continue
            lat, lost = plain(handed, seq)      # (the fast path: nothing but the latency model acts)
            if lost:
                count["lost"][link.id] += 1
            else:
                self._enqueue(handed, wait + lat, link, payload)

    def _enqueue(self, now: int, lat: int, link: Link, payload: Any) -> None:
        """Deliver ``payload`` at ``now + lat`` (``now``: its hand-over, not before the present)."""
        at = now + lat
        due = self._due.get(at)
        if due is None:
            due = self._due[at] = []
            Scheduled(self.env, self.deliver_now, PRIORITY_DELIVER, at - self.env.now)
        due.append(link)
        due.append(payload)

    # -- receiving -----------------------------------------------------------------
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
            raise RuntimeError(f"port {self.name!r} has no receiver")
        pairs = iter(due)                   # (link, payload, link, payload, ...)
        for link, payload in zip(pairs, pairs):
            if crashes is not None and link.dst >= 0 and crashes.down(link.dst, now):
                self._count["crash_dropped"][link.id] += 1
                continue
            delivered[link.id] += 1
            receive(link, payload)

    def count_late(self, n: int = 1) -> None:
        """Count ``n`` late items: what is late is the estimator's to decide (e.g. a message
        delivered after its last usable instant, dropped unused); ``counts()["late"]``."""
        self._late += int(n)

    # -- what it counted ---------------------------------------------------------------
    def _end(self) -> int:
        return self.until if self.until is not None else self.env.now

    def link_log(self, link: Link) -> np.ndarray:
        """``(packets, 3)`` int64: (hand-over, start, end) ns of every packet the waiting room of
        ``link``'s medium held as this port saw it -- its own, the background and, with shared
        queues, the other ports' -- in no particular order (``start < 0``: dropped); empty for a
        medium without a waiting room."""
        log = self.medium(link).interval_log(self, self._end())
        return log if log is not None else np.zeros((0, 3), dtype=np.int64)

    def link_series(self, T_ns: int, K: int) -> dict[str, np.ndarray]:
        """Per tick, each link this port reports on whose medium has a waiting room: the
        time-averaged number of packets waiting and the utilisation
        (:func:`~dkfsim.network.occupancy.per_tick`), as ``run.npz`` keeps them: ``rated_links``
        (E, 2), ``queue_length`` and ``utilisation`` (K, E), and ``queueing_delay_quantiles``
        (E, 101): the percentiles 0, 1, ..., 100 of this port's queueing delays on each link,
        seconds (NaN without a packet).  Empty without such a link."""
        end = self._end()
        links, logs = [], []
        for i in self._reported():
            link = self.net.links[i]
            log = self.medium(link).interval_log(self, end)
            if log is not None:
                links.append(link)
                logs.append(log)
        if not links:
            return {}
        queue, busy = zip(*(per_tick(log, T_ns, K) for log in logs))
        quantiles = np.full((len(links), 101), np.nan)
        for e, link in enumerate(links):
            d = self.medium(link).own_delays(self)
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

    def counts(self) -> dict[str, Any]:
        """Totals, ``per_link`` (links this port used) and ``late`` (:meth:`count_late`);
        ``in_flight`` by the identity (packets still waiting in a queue included).  A link's
        row adds what its medium reports (a rate-limited link: its utilisation of ``[0,
        until]``, this port's queueing delays, the background); the shared channel's block is
        ``channel``."""
        self._grow()
        count = self._count
        totals: dict[str, Any] = {k: sum(c) for k, c in count.items()}
        totals["in_flight"] = (totals["sent"] + totals["copies"] - totals["delivered"]
                               - totals["lost"] - totals["queue_dropped"] - totals["crash_dropped"])
        per_link = []
        end = self._end()
        for i in self._reported():
            link = self.net.links[i]
            row: dict[str, Any] = {"link": (link.src, link.dst), **{k: c[i] for k, c in count.items()}}
            row["in_flight"] = (row["sent"] + row["copies"] - row["delivered"] - row["lost"]
                                - row["queue_dropped"] - row["crash_dropped"])
            row.update(self.medium(link).link_report(self, link, end))
            per_link.append(row)
        totals["per_link"] = per_link
        totals["late"] = self._late
        if self.channel is not None:
            totals["channel"] = self.channel.report(self, end)
        return totals
