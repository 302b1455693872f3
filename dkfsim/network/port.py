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
from typing import Any, Protocol

import numpy as np
from simpy.events import Event
from typing_extensions import override

from dkfsim.components.faults import CrashSchedule
from dkfsim.components.mobility import LinkSchedule
from dkfsim.core.backend import Backend
from dkfsim.core.jit import bind
from dkfsim.core.params import NS_PER_S
from dkfsim.network import port_kernels
from dkfsim.network.events import PRIORITY_DELIVER, Clock, Scheduled
from dkfsim.network.links import Link
from dkfsim.network.media.base import Frame, Medium
from dkfsim.network.media.fifo import FifoTable
from dkfsim.network.occupancy import per_tick


class Carrier(Protocol):
    """The network as a port sees it (:class:`~dkfsim.network.network.Network` is one): the
    clock, the links, the faults and the media a port's frames take."""

    env: Clock
    T_ns: int
    links: list[Link]
    crashes: CrashSchedule | None
    schedule: LinkSchedule | None
    members: frozenset[int]

    def media_store(self) -> dict[Any, Medium]: ...

    def channel_of(self, store: dict[Any, Medium]) -> Medium | None: ...

    def medium_of(self, link: Link, store: dict[Any, Medium]) -> Medium: ...

#: Counters of a port, per link:
#: ``sent + copies = delivered + lost + queue_dropped + crash_dropped + in_flight``.
COUNTERS = ("sent", "delivered", "lost", "copies", "crash_dropped", "outage_lost", "bytes", "queue_dropped")

#: The first per-link sequence number of a port that shares another's media
#: (:meth:`Network.port` ``share_with``): its keyed draws never equal the other port's, and
#: adding it changes none of them.
SHARED_SEQ0 = 1 << 32

#: What a port hands its estimator: ``receive(link, payload)`` (or, a batch port,
#: ``receive(links, payloads)``).
Receive = Callable[..., None]


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

    def __init__(self, network: Carrier, name: str, receive: Receive, links: list[Link] | None = None,
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
        of one part (:meth:`send_frames`)."""
        self.send_frames([link], [payload], [nbytes], [1], [nbytes])

    def send_frame(self, parts: Sequence[tuple[Link, Any, int]], frame_bytes: int) -> None:
        """Hand over now one flush of one sender carrying ``parts``, each ``(link, payload,
        nbytes)`` (:meth:`send_frames`)."""
        links, payloads, nbytes = zip(*parts) if parts else ((), (), ())
        self.send_frames(links, payloads, nbytes, [len(parts)], [frame_bytes])

    def send_frames(self, links: Sequence[Link], payloads: Sequence[Any], nbytes: Sequence[int],
                    ends: Sequence[int], frame_bytes: Sequence[int]) -> None:
        """Hand over now flushes of senders, in order: flush ``f`` carries the parts ``ends[f-1]
        .. ends[f]`` (part ``p``: ``payloads[p]`` of ``nbytes[p]`` bytes on ``links[p]``, every
        part of a flush from one sender).  Each part is numbered and counted on its link
        (``sent``, ``bytes`` += its ``nbytes``); nothing is sent on a link that is down
        (``range_lost``).  On a broadcast medium (the shared channel) the parts of a flush on it
        go as one frame of ``frame_bytes[f]`` (a broadcast of one message of ``n`` bytes to
        ``k`` neighbours: ``k`` parts of ``n`` and a frame of ``n``; a combined frame of
        different messages: the sum of their sizes), offered after the flush's other parts; on
        any other medium each part is a frame of its own ``nbytes``, offered in order."""
        now = self.env.now
        if now != self._instant:
            self._instant, self._seq = now, {}
        count, seqs, seq0 = self._count, self._seq, self._seq0
        sent, sent_bytes = count["sent"], count["bytes"]     # (_grow extends these in place)
        if len(sent) < len(self.net.links):                 # (a link added after the port: rare)
            self._grow()
        media, medium_of = self._media, self.net.medium_of
        p = 0
        for f, end in enumerate(ends):
            shared: dict[Medium, list[tuple[Link, Any, int]]] | None = None
            while p < end:
                link, payload, size = links[p], payloads[p], nbytes[p]
                p += 1
                lid = link.id
                seq = seqs.get(lid, seq0)
                seqs[lid] = seq + 1
                sent[lid] += 1
                sent_bytes[lid] += size
                if link.changes and not link.is_up(now):
                    count["lost"][lid] += 1          # the pair is out of range: nothing leaves
                    count["range_lost"][lid] += 1
                    continue
                medium = media.get(lid)
                if medium is None:
                    medium = medium_of(link, media)
                if medium.passive:                  # (leaves at once, nothing to offer)
                    plain = link.plain
                    if plain is None:
                        for lat in count_fate(link, now, seq, count):
                            self._enqueue(now, lat, link, payload)
                        continue
                    lat, lost = plain(now, seq)     # (the fast path: nothing but the latency model acts)
                    if lost:
                        count["lost"][lid] += 1
                        continue
                    at = now + lat
                    due = self._due.get(at)
                    if due is None:
                        due = self._due[at] = []
                        Scheduled(self.env, self.deliver_now, PRIORITY_DELIVER, lat)
                    due.append(link)
                    due.append(payload)
                elif medium.synchronous:            # (its departure is known now)
                    leaves = medium.depart(self, size, now)
                    if leaves is None:
                        count["queue_dropped"][lid] += 1
                        continue
                    for lat in count_fate(link, now, seq, count):    # (a lost one occupied it)
                        self._enqueue(now, leaves - now + lat, link, payload)
                elif medium.broadcast:              # (gathered: one frame per flush and medium)
                    if shared is None:
                        shared = {medium: [(link, payload, seq)]}
                    else:
                        shared.setdefault(medium, []).append((link, payload, seq))
                elif not medium.offer(Frame(link.src, size, now, ((link, payload, seq),), self._left, self)):
                    count["queue_dropped"][lid] += 1
            if shared:
                self._offer_shared(shared, int(frame_bytes[f]), now)

    def _offer(self, medium: Medium, link: Link, payload: Any, seq: int, nbytes: int, now: int,
               shared: dict[Medium, list[tuple[Link, Any, int]]] | None
               ) -> dict[Medium, list[tuple[Link, Any, int]]] | None:
        """One part handed to a medium that decides later (neither passive nor synchronous): a
        broadcast medium's parts are gathered into ``shared`` (made on first use; returned) to
        leave as one frame (:meth:`_offer_shared`), any other's leave as a frame of their own;
        a frame the medium refuses counts ``queue_dropped``."""
        if medium.broadcast:
            if shared is None:
                shared = {}
            shared.setdefault(medium, []).append((link, payload, seq))
        elif not medium.offer(Frame(link.src, nbytes, now, ((link, payload, seq),), self._left, self)):
            self._count["queue_dropped"][link.id] += 1
        return shared

    def _offer_shared(self, shared: dict[Medium, list[tuple[Link, Any, int]]], nbytes: int, now: int) -> None:
        """The parts :meth:`_offer` gathered, one frame of ``nbytes`` per broadcast medium; every
        part of a refused frame counts ``queue_dropped``."""
        count = self._count
        for medium, held in shared.items():
            if not medium.offer(Frame(held[0][0].src, nbytes, now, held, self._left, self)):
                for link, _, _ in held:
                    count["queue_dropped"][link.id] += 1

    def _left(self, frame: Frame, ok: bool) -> None:
        """A frame of this port has left its sender (at ``frame.end``, now or later), or was lost
        on the air (``ok`` false: a collision, lost for every receiver).  Each part's fate is
        drawn on its link as for any packet (keyed by the hand-over instant and its number), its
        arrivals counted from the frame's end."""
        count = self._count
        if not ok:
            if frame.start < 0:                 # (held back by generation jitter, then refused)
                for link, _, _ in frame.parts:
                    count["queue_dropped"][link.id] += 1
                return
            for link, _, _ in frame.parts:
                count["lost"][link.id] += 1
                count["collision_lost"][link.id] += 1
            return
        handed, wait = frame.handed, frame.end - frame.handed
        lost_at = frame.lost_at
        for link, payload, seq in frame.parts:
            if lost_at is not None and link.dst in lost_at:     # (a spatial radio's receiver lost it)
                count["lost"][link.id] += 1
                if lost_at[link.dst]:
                    count["collision_lost"][link.id] += 1
                continue
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
        """Deliver ``payload`` at ``now + lat`` (``now``: its hand-over, not before the present):
        the one place a delivery is scheduled (one event per arrival instant)."""
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

    def channel_series(self, T_ns: int, K: int) -> dict[str, np.ndarray]:
        """The shared channel's per-tick arrays as this port's copy saw it
        (:meth:`~dkfsim.network.media.base.Medium.series`); empty without a channel."""
        return self.channel.series(self, T_ns, K) if self.channel is not None else {}

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
        totals: dict[str, Any] = {k: int(sum(c)) for k, c in count.items()}
        totals["in_flight"] = (totals["sent"] + totals["copies"] - totals["delivered"]
                               - totals["lost"] - totals["queue_dropped"] - totals["crash_dropped"])
        per_link = []
        end = self._end()
        for i in self._reported():
            link = self.net.links[i]
            row: dict[str, Any] = {"link": (link.src, link.dst), **{k: int(c[i]) for k, c in count.items()}}
            row["in_flight"] = (row["sent"] + row["copies"] - row["delivered"] - row["lost"]
                                - row["queue_dropped"] - row["crash_dropped"])
            row.update(self.medium(link).link_report(self, link, end))
            per_link.append(row)
        totals["per_link"] = per_link
        totals["late"] = self._late
        if self.channel is not None:
            totals["channel"] = self.channel.report(self, end)
        return totals



class RecordPort(Port):
    """A port whose packets are records: each packet carries a tag (one int of its sender's,
    e.g. its own number) and rows of a fixed number of int64 words, and packets are handed over
    and delivered in batches, as arrays -- for an exchange whose bookkeeping runs in kernels
    (the ``tree`` protocol).  The same path as :class:`Port` (numbering, media, links, counts),
    with the per-packet work of the links whose medium is passive and whose latency has a
    vector form (:meth:`~dkfsim.network.links.Link.vector_latency`) done in one compiled loop
    per batch (:mod:`dkfsim.network.port_kernels`), and the records of packets in flight in one
    arena: a delivery hands ``receive(batch, records)`` -- per packet its link id, tag and rows
    ``records[batch[k, 2]:batch[k, 3]]`` -- once per instant, in the order sent.

    :param width: int64 words per record.
    :param backend: the run's (numba or numpy: the kernels compiled or not).
    """

    def __init__(self, network: Carrier, name: str, receive: Receive, links: list[Link] | None = None,
                 until: int | None = None, share_with: Port | None = None, *, width: int,
                 backend: Backend):
        self._kernels = port_kernels.compiled() if backend.compiled else port_kernels
        #: the table of the FIFO transmitters its :data:`~dkfsim.network.port_kernels.QUEUED` links
        #: run in (none: an empty one)
        self._fifos = FifoTable(backend)
        super().__init__(network, name, receive, links, until, share_with)
        self._grow()
        self.width = int(width)
        #: the records of the packets in flight, ``_arena[:_top]`` (the chunks due refer to their
        #: rows there)
        self._arena = np.zeros((256, self.width), dtype=np.int64)
        self._top = 0
        self._plans: dict[int, tuple] = {}
        self._halt = np.zeros(2, dtype=np.int64)

    def _grow(self) -> None:
        """The per-link arrays of the batch kernels (:class:`~dkfsim.network.port_kernels.Lanes`)
        for every link of the network now -- the counters are rows of ``Lanes.count`` -- and
        the kernels bound to their types."""
        if not hasattr(self, "_media"):
            super()._grow()                     # (the base constructor's call: media come next)
            return
        links, pk = self.net.links, port_kernels
        E = len(links)
        old = getattr(self, "B", None)
        if old is not None and old.ints.shape[1] == E:
            return
        ints = np.zeros((7, E), dtype=np.int64)
        ints[pk.KIND], ints[pk.SEQT], ints[pk.SLOT] = pk.PYTHON, -1, -1
        key = np.zeros(E, np.uint64)
        states = [l.up_per_tick() for l in links]
        ints[pk.CHANGES] = [l.changes for l in links]
        K1 = max((len(u) for u in states if u is not None), default=1)
        up = np.ones((E, K1) if ints[pk.CHANGES].any() else (E, 1), dtype=np.uint8)
        tables = set()
        for i, link in enumerate(links):
            form = link.vector_latency()
            medium = self.medium(link)
            lane = medium.lane()
            if form is not None and (medium.passive or medium.synchronous or lane is not None):
                ints[pk.KIND, i] = pk.DRAWN if medium.passive else pk.LATENCY if lane is None else pk.QUEUED
                ints[pk.LKIND, i], key[i], ints[pk.PAR, i] = form
                if lane is not None:
                    self._fifos, ints[pk.SLOT, i] = lane
                    tables.add(id(lane[0]))
        if len(tables) > 1:
            raise RuntimeError(f"port {self.name!r}: its FIFO transmitters are not of one table")
            u = states[i]
            if ints[pk.CHANGES, i] and u is not None:
                up[i, :len(u)] = u
        names = list(self._count)
        order = ["sent", "bytes", "lost", "range_lost", "delivered", "crash_dropped", "queue_dropped"]
        rows = order + [k for k in names if k not in order]
        count = np.zeros((len(rows), E), dtype=np.int64)
        if old is not None:
            ints[pk.SEQT:pk.SEQN + 1, :old.ints.shape[1]] = old.ints[pk.SEQT:pk.SEQN + 1]
        for r, name in enumerate(rows):
            c = self._count.get(name)
            if c is not None and len(c):
                count[r, :len(c)] = c
        self._count = {name: count[rows.index(name)] for name in names}
        self.B = B = pk.Lanes(ints, key, up, count)
        k, v, m = self._kernels, np.zeros(1, np.int64), np.zeros((1, 6), np.int64)
        self._hand_over = bind(k.hand_over, B, self._fifos.F, 0, 0, 0, 0, 1, m, v, v, v)
        self._arrange = bind(k.arrange, v, m, 0, np.zeros((1, 4), np.int64), v, v)
        self._tally = bind(k.tally, B, 0, np.zeros((1, 4), np.int64))
        self._peek = bind(k.peek, B, 0, 0, 1, v, np.zeros((1, 1), np.int8))

    # -- the arena of records in flight -------------------------------------------------
    def records(self) -> np.ndarray:
        """The arena a delivery's ``records`` are rows of (its current array; read only)."""
        return self._arena

    def _store(self, records: np.ndarray) -> int:
        """Keep ``records`` until delivered; the arena row of the first."""
        n = len(records)
        if self._top + n > len(self._arena):
            self._compact(n)
        at = self._top
        self._arena[at:at + n] = records
        self._top = at + n
        return at

    def _compact(self, need: int) -> None:
        """Drop the rows no packet in flight refers to (before the oldest one still due: the
        chunks due are moved down with them), and grow the arena if what is left and ``need``
        more do not fit."""
        for due in self._due.values():          # (single packets as arrays: moved in place below)
            for k, e in enumerate(due):
                if type(e) is tuple:
                    due[k] = np.array([e], dtype=np.int64)
        chunks = [chunk for due in self._due.values() for chunk in due if len(chunk)]
        live = min((int(chunk[:, port_kernels.C_START].min()) for chunk in chunks), default=self._top)
        keep = self._arena[live:self._top].copy()
        size = len(self._arena)
        while len(keep) + need > size // 4:          # (a quarter: compactions stay rare)
            size *= 2
        if size != len(self._arena):
            self._arena = np.zeros((size, self.width), dtype=np.int64)
        self._arena[:len(keep)] = keep
        self._top = len(keep)
        for chunk in chunks:
            chunk[:, port_kernels.C_START:port_kernels.C_STOP + 1] -= live

    # -- sending ---------------------------------------------------------------------------
    @override
    def send_frames(self, links: Sequence[Link], payloads: Sequence[Any], nbytes: Sequence[int],
                    ends: Sequence[int], frame_bytes: Sequence[int]) -> None:
        raise TypeError(f"port {self.name!r} carries records: send with send_records")

    def send_records(self, parts: np.ndarray, records: np.ndarray, frames: np.ndarray) -> None:
        """Hand over now flushes of senders, in order, as :meth:`Port.send_frames`: flush ``f``
        carries the parts up to ``frames[f, 0]`` (exclusive) and is ``frames[f, 1]`` bytes; part
        ``p`` (the columns of :mod:`~dkfsim.network.port_kernels`, ``C_LID`` ... ``C_DONE``)
        goes on link id ``parts[p, 0]`` with tag ``parts[p, 1]`` and rows ``records[parts[p,
        2]:parts[p, 3]]``, ``parts[p, 4]`` bytes.  A part with ``parts[p, 5]`` reached its
        receiver at this instant already: its sender delivered it itself, as :meth:`lookahead`
        said it would arrive now; it is counted delivered (after checking it does arrive now),
        not delivered again (int64 C-ordered arrays)."""
        now = int(self.env.now)
        if self.B.ints.shape[1] < len(self.net.links):
            self._grow()
        P = len(parts)
        seqs = np.empty(P, dtype=np.int64)
        at = np.empty(P, dtype=np.int64)
        table, halt = self._fifos, self._halt
        owner = table.owner(self)
        flags = self._hand_over(self.B, table.F, owner, 0, now, self._seq0, self.net.T_ns, parts, seqs, at, halt)
        while flags & port_kernels.HALTED:      # (a transmitter needs its next background block, more room)
            table.provide(int(self.B.ints[port_kernels.SLOT, parts[halt[0], 0]]), int(halt[1]))
            flags = (flags & ~port_kernels.HALTED) | self._hand_over(
                self.B, table.F, owner, int(halt[0]), now, self._seq0, self.net.T_ns, parts, seqs, at, halt)
        if flags & port_kernels.BROKEN_PROMISE:
            raise RuntimeError(f"port {self.name!r}: a packet was handed over as delivered at once, but it "
                               "does not arrive at once (its sender did not follow the port's lookahead)")
        base = self._store(records)
        if not flags & port_kernels.SOME_ASK:
            self._schedule(at, parts, base)
            return
        self._send_in_order(parts, records, base, frames, seqs, at)

    def _schedule(self, at: np.ndarray, parts: np.ndarray, base: int) -> None:
        """Schedule the deliveries of the parts with ``at >= 0``, one chunk per arrival instant
        in send order (their rows offset by ``base`` into the arena)."""
        P = len(at)
        rows, times, cuts = np.empty((P, 4), dtype=np.int64), np.empty(P, dtype=np.int64), np.empty(P, np.int64)
        runs = self._arrange(at, parts, base, rows, times, cuts)
        lo = 0
        for hi in cuts[:runs].tolist():
            self._chunk(int(times[lo]), rows[lo:hi])
            lo = hi

    def _chunk(self, t: int, chunk: np.ndarray | tuple[int, int, int, int]) -> None:
        """Deliver the packets of ``chunk`` (rows: link id, tag, first and end row in the arena;
        or one packet's as a tuple) at ``t``."""
        due = self._due.get(t)
        if due is None:
            due = self._due[t] = []
            Scheduled(self.env, self.deliver_now, PRIORITY_DELIVER, t - self.env.now)
        due.append(chunk)

    def _send_in_order(self, parts: np.ndarray, records: np.ndarray, base: int, frames: np.ndarray,
                       seqs: np.ndarray, at: np.ndarray) -> None:
        """A batch with parts the kernel left to Python (a medium that is not passive, a latency
        drawn one packet at a time): every part in send order, as :meth:`Port.send_frames`."""
        count, media, medium_of, now = self._count, self._media, self.net.medium_of, self.env.now
        links, pk = self.net.links, port_kernels
        p = 0
        for end, size in frames.tolist():
            shared: dict[Medium, list[tuple[Link, Any, int]]] | None = None
            while p < end:
                k = p
                p += 1
                lid, tag, i0, i1, nbytes, done = parts[k, :6].tolist()
                drawn = pk.drawn_latency(int(at[k]))        # (a transmitter's link: its latency drawn)
                if at[k] != pk.ASK and drawn < 0:
                    if at[k] >= 0:
                        self._chunk(int(at[k]), (lid, tag, i0 + base, i1 + base))
                    continue
                link, seq = links[lid], int(seqs[k])
                if link.changes and not link.is_up(now):
                    count["lost"][lid] += 1
                    count["range_lost"][lid] += 1
                    continue
                medium = media.get(lid)
                if medium is None:
                    medium = medium_of(link, media)
                if done:
                    arrivals, why = link.transmit(now, seq)
                    if not medium.passive or why is not None or arrivals != (0,):
                        raise RuntimeError(f"port {self.name!r}: a packet on link {link.src} -> {link.dst} was "
                                           "handed over as delivered at once, but it does not arrive at once")
                    count["delivered"][lid] += 1
                    continue
                if medium.passive or medium.synchronous:      # (its rows are in the arena already)
                    wait = 0
                    if medium.synchronous:
                        leaves = medium.depart(self, nbytes, now)
                        if leaves is None:
                            count["queue_dropped"][lid] += 1
                            continue
                        wait = leaves - now
                    for lat in ((drawn,) if drawn >= 0 else count_fate(link, now, seq, count)):
                        self._chunk(now + wait + lat, (lid, tag, i0 + base, i1 + base))
                    continue
                payload = (tag, records[i0:i1].copy())       # (kept by the medium until it leaves)
                shared = self._offer(medium, link, payload, seq, nbytes, now, shared)
            if shared:
                self._offer_shared(shared, size, now)

    def _enqueue(self, now: int, lat: int, link: Link, payload: Any) -> None:
        tag, rows = payload
        offset = self._store(rows)
        self._chunk(now + lat, (link.id, tag, offset, offset + len(rows)))

    # -- receiving -------------------------------------------------------------------------
    def deliver_now(self, _event: Event | None = None) -> None:
        now = self.env.now
        due = self._due.pop(now, None)
        if due is None:
            return
        if self.until is not None and now > self.until:
            return                            # after the port's last instant: in flight
        first = due[0]
        if len(due) == 1 and type(first) is not tuple:
            batch = first
        elif all(type(e) is tuple for e in due):
            batch = np.array(due, dtype=np.int64)
        else:
            batch = np.concatenate([np.array([e], dtype=np.int64) if type(e) is tuple else e for e in due])
        crashes = self.net.crashes
        if crashes is not None:
            links = self.net.links
            down = np.array([links[lid].dst >= 0 and crashes.down(links[lid].dst, now)
                             for lid in batch[:, 0].tolist()], dtype=bool)
            if down.any():
                self._tally(self.B, port_kernels.CRASH_DROPPED, np.ascontiguousarray(batch[down]))
                batch = batch[~down]
                if not len(batch):
                    return
        self._tally(self.B, port_kernels.DELIVERED, batch)
        self._receive(batch, self._arena)

    def lookahead(self, links: list[Link], q: int, nbytes: int) -> np.ndarray:
        """``(len(links), q)`` int8: the fate at this instant of the next ``q`` packets this port
        would hand each of ``links`` now, of at least ``nbytes`` bytes: ``0`` they do not reach
        their receiver at this instant (they arrive later, or never), ``1`` they do (and the
        receiver is up), ``2`` the port cannot say before they are sent (their medium's state
        or their link's faults decide).  Draws are pure functions of (link, instant, number), so
        the answer is what sending them will do; a sender that delivers a ``1`` packet itself
        hands it over as done (:meth:`send_records`)."""
        now = int(self.env.now)
        if self.until is not None and now > self.until:
            return np.zeros((len(links), q), dtype=np.int8)   # (nothing is delivered after the port's end)
        if self.B.ints.shape[1] < len(self.net.links):
            self._grow()
        plan = self._plans.get(id(links))
        if plan is None or plan[0] is not links:
            plan = self._plan(links, q, nbytes)
        _, lids, others, dsts, fixed, later = plan
        if fixed is not None:
            return fixed                        # (the same answer at every instant: read only)
        table = np.full((len(links), q), 2, dtype=np.int8)
        table[later] = 0
        self._peek(self.B, now, self._seq0, self.net.T_ns, lids, table)
        for e, medium in others:
            link = links[e]
            if (link.changes and not link.is_up(now)) or not medium.leaves_at_once(nbytes):
                table[e] = 0
            # (else 2: its waiting room, or its latency drawn in Python, decides.  Drawing here
            # cost a Python draw per link and packet at every flush, most never sent: 19x the
            # run's time on exponential latency; an unknown part is sent and delivered instead.)
        crashes = self.net.crashes
        if crashes is not None:                 # a receiver that is down drops what arrives
            for e, d in dsts:
                if crashes.down(d, now):
                    table[e] = 0
        return table

    def never_now(self, links: list[Link], q: int, nbytes: int) -> bool:
        """Whether :meth:`lookahead` answers "not at this instant" (``0``) for every packet on
        ``links`` at every instant: then a sender need not ask before it flushes."""
        plan = self._plans.get(id(links))
        if plan is None or plan[0] is not links:
            plan = self._plan(links, q, nbytes)
        fixed = plan[4]
        return fixed is not None and not fixed.any()

    def _plan(self, links: list[Link], q: int, nbytes: int) -> tuple:
        """What :meth:`lookahead` works out once for a list of links: their ids, the links it
        answers for in Python (with their media) -- but those whose packets cannot arrive at
        once, by their medium or their smallest latency -- and the receivers that can crash; and
        the answer when no instant can change it (no packet of any of them can arrive at once,
        or each is answered "unknown" or "later" whatever the instant)."""
        lids = np.array([l.id for l in links], dtype=np.int64)
        kind = self.B.ints[port_kernels.KIND]
        at_once = [self.medium(l).leaves_at_once(nbytes) and l.min_latency_ns() == 0 for l in links]
        # (a link on a passive medium that never changes is always 2: nothing to answer per instant)
        others = [(e, self.medium(l)) for e, l in enumerate(links) if kind[l.id] != port_kernels.DRAWN and at_once[e]
                  and (l.changes or not self.medium(l).passive)]
        dsts = [(e, l.dst) for e, l in enumerate(links) if l.dst >= 0] if self.net.crashes is not None else []
        later = np.array([e for e, l in enumerate(links) if kind[l.id] != port_kernels.DRAWN and not at_once[e]],
                         dtype=np.intp)
        fixed = None                            # (an answer that no instant changes)
        if not any(at_once):
            fixed = np.zeros((len(links), q), dtype=np.int8)
        elif not others and not dsts and not any(kind[l.id] == port_kernels.DRAWN for l in links):
            fixed = np.full((len(links), q), 2, dtype=np.int8)
            fixed[later] = 0
        plan = (links, lids, others, dsts, fixed, later)
        self._plans[id(links)] = plan
        return plan
