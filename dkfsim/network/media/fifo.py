"""``fifo``: a link with a ``rate``: one packet at a time, first in first out, with a waiting
room and the link's background load (docs/design.md §3, "Links that carry the traffic").

The transmitter is lazy: it is not a SimPy process but a few numbers -- the instant it is
free (``free_at``) and the start instants of the packets still waiting -- brought up to date
when a packet is handed over (:meth:`Transmitter.offer`): the link's background packets that
arrived up to and including that instant go first
(:class:`~dkfsim.network.media.background.BackgroundArrivals`, keyed draws, so every
estimator's transmitter sees the same ones), then the packet either waits, starts at once, or
is dropped because the waiting room is full (drop-tail; the packet in transmission is not in
the waiting room).  Transmission of ``size`` bytes takes
:func:`~dkfsim.components.traffic.transmission_ns`.  The medium (:class:`Fifo`) keeps what the
transmitter measures -- busy time, background packets offered and dropped -- and the
(hand-over, start, end) of every packet of each port, for the queueing delays and the per-tick
series of ``run.npz``.  A packet's propagation is drawn at its hand-over instant, its arrival
counted from the end of its transmission (a lost packet occupies the transmitter too).
"""

from __future__ import annotations

from array import array
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
from typing_extensions import override

from dkfsim.components.traffic import Queue, transmission_ns
from dkfsim.core.params import MAX_NS, NS_PER_S
from dkfsim.core.registry import MEDIA
from dkfsim.network.links import Link
from dkfsim.network.media.background import BackgroundArrivals
from dkfsim.network.media.base import Frame, Medium
from dkfsim.network.occupancy import mean_waiting


def busy_within(busy_ns: int, free_at: int, end_ns: int) -> int:
    """ns of ``[0, end_ns]`` a transmitter was busy, from the ns of work it accepted (``busy_ns``)
    and the instant it is free: what is accepted and not yet sent at ``end_ns`` is one busy
    stretch, so it is cut off."""
    return busy_ns - max(0, free_at - end_ns)


class Transmitter:
    """The FIFO transmitter of one directed link (the engine of a :class:`Fifo` medium).

    :param rate: bits per second.
    :param queue: the waiting room (None: unbounded).
    :param background: the link's :class:`BackgroundArrivals` (None: none).
    :param rate_at: the rate (bit/s) at a packet's transmission start instant (ns), when it
        changes with the pair's distance (``mobility.links.rate``); None: ``rate`` throughout.
    :param record: keep every background packet's (instant, start, end), start and end -1
        when dropped (for the queueing-theory checks; 24 bytes a packet): :meth:`log`.
    """

    def __init__(self, rate: float, queue: Queue | None = None,
                 background: BackgroundArrivals | None = None, record: bool = False,
                 rate_at: Callable[[int], float] | None = None):
        self.rate = float(rate)
        #: the rate at a packet's start instant (ns -> bit/s), when it changes (``mobility.links``)
        self.rate_at = rate_at
        self.max_packets = queue.packets if queue is not None else None
        self.max_bytes = queue.bytes if queue is not None else None
        self.background = background
        #: when the packet last accepted ends (ns)
        self.free_at = 0
        #: (start, size) of accepted packets not yet started at the last instant seen
        self._waiting: deque[tuple[int, int]] = deque()
        self._waiting_bytes = 0
        #: ns the transmitter has been or will be busy with the packets accepted so far
        self.busy_ns = 0
        self.background_sent = 0
        self.background_dropped = 0
        self._log: array | None = array("q") if record else None
        self._seen = -1          # background taken up to this instant
        #: the instant of the next background packet not yet taken (MAX_NS: none)
        self._next_bg = background.next_time() if background is not None else MAX_NS

    def _accept(self, t: int, size: int) -> tuple[int, int] | None:
        """A packet of ``size`` bytes handed over at ``t`` (not before the last one): its
        (start, end) ns, or None when the waiting room is full."""
        waiting = self._waiting
        while waiting and waiting[0][0] <= t:
            self._waiting_bytes -= waiting.popleft()[1]
        start = self.free_at if self.free_at > t else t
        if start > t:
            if self.max_packets is not None and len(waiting) >= self.max_packets:
                return None
            if self.max_bytes is not None and self._waiting_bytes + size > self.max_bytes:
                return None
        tx = transmission_ns(size, self.rate if self.rate_at is None else self.rate_at(start))
        end = start + tx
        if end > MAX_NS:
            end = MAX_NS
        self.free_at = end
        self.busy_ns += end - start
        if start > t:
            waiting.append((start, size))
            self._waiting_bytes += size
        return start, end

    def advance(self, t_ns: int) -> None:
        """Take the background packets that arrived up to and including ``t_ns``."""
        bg = self.background
        if bg is None or t_ns <= self._seen:
            return
        self._seen = t_ns
        if t_ns < self._next_bg:
            return
        times, sizes = bg.until(t_ns)
        self._next_bg = bg.next_time()
        log = self._log
        for t, size in zip(times, sizes):
            got = self._accept(t, size)
            if got is None:
                self.background_dropped += 1
                if log is not None:
                    log.extend((t, -1, -1))
            else:
                self.background_sent += 1
                if log is not None:
                    log.extend((t, got[0], got[1]))

    def log(self) -> np.ndarray:
        """(packets, 3) int64: each background packet's instant, start and end (ns; -1 when
        dropped), with ``record``."""
        if self._log is None:
            raise ValueError("this transmitter keeps no log (record=False)")
        return np.frombuffer(self._log, dtype=np.int64).reshape(-1, 3).copy()

    def offer(self, t_ns: int, size: int) -> tuple[int, int] | None:
        """Hand over a packet of ``size`` bytes at ``t_ns`` (after the background up to it):
        its (start, end) of transmission in ns, or None when dropped (the waiting room full)."""
        self.advance(t_ns)
        return self._accept(t_ns, size)

    def waiting(self, t_ns: int) -> int:
        """Packets waiting at ``t_ns`` (after the background up to it), not counting the one
        in transmission."""
        self.advance(t_ns)
        return sum(1 for start, _ in self._waiting if start > t_ns)

    def busy_until(self, t_ns: int) -> int:
        """ns of ``[0, t_ns]`` the transmitter was busy (background up to ``t_ns`` taken;
        :func:`busy_within`)."""
        self.advance(t_ns)
        return busy_within(self.busy_ns, self.free_at, t_ns)


def link_stats(delays: list[int] | np.ndarray, busy_ns: int, background_sent: int, background_dropped: int,
               end_ns: int) -> dict[str, float | int]:
    """A rate-limited link's statistics in ``summary.json``: utilisation of ``[0, end_ns]`` from
    the busy ns in it (every packet the transmitter carried, background included), the queueing
    delay's mean and 95th percentile (s, over one port's ``delays`` in ns; 0 without any), and
    the background packets sent and dropped."""
    d = np.asarray(delays, dtype=np.float64) / NS_PER_S
    return {"utilisation": busy_ns / end_ns if end_ns > 0 else 0.0,
            "queueing_delay_mean": float(d.mean()) if len(d) else 0.0,
            "queueing_delay_p95": float(np.percentile(d, 95)) if len(d) else 0.0,
            "background_sent": background_sent,
            "background_dropped": background_dropped}


@MEDIA.register("fifo", description="a link with a rate: a first-in-first-out transmitter with a waiting room "
                "and background load (links.<default|overrides>.rate, queue, background)")
class Fifo(Medium):
    """A rate-limited link's transmitter as a medium: one per link and port (or shared).

    :param link: the link (its ``spec`` gives ``rate``, ``queue`` and ``background``; the
        background's draws are keyed under the link's prefix).
    :param rates: the rate (bit/s) at each tick ``0 .. K`` when it follows the pair's
        distance (``mobility.links.rate``), taken at a packet's transmission start; None: the
        link's ``rate`` throughout.
    """

    kind = "fifo"
    synchronous = True
    #: The parameter keys it reads (``dkfsim list media``).
    required = ("rate",)
    optional = ("queue", "background")

    def __init__(self, link: Link, rates: list[float] | None = None):
        spec = link.spec
        self.link = link
        rate = float(rates[0]) if rates is not None else float(spec.rate) if spec.rate is not None else 0.0
        if not rate > 0:
            raise ValueError(f"link {link.src} -> {link.dst} has no rate: it is not a fifo medium")
        self._rates = rates
        bg = BackgroundArrivals(spec.background, link.prefix, link.seed) if spec.background is not None else None
        #: the link's transmitter
        self.tx = Transmitter(rate, spec.queue, bg, record=True,
                              rate_at=self._rate_at if rates is not None else None)
        #: per owner (port): (hand-over, start, end) ns of each of its packets the transmitter took
        self._own: dict[Any, array] = {}
        #: the fastest rate the link can have, for :meth:`leaves_at_once`
        self._fastest = max(rates) if rates is not None else rate
        self._started = -1                  # (the start of the last transmission it took)

    def _rate_at(self, t_ns: int) -> float:
        rates = self._rates
        assert rates is not None
        return rates[self.link.tick_of(t_ns, len(rates))]

    def offer(self, frame: Frame) -> bool:
        end = self.depart(frame.owner, frame.size, frame.handed)
        if end is None:
            return False
        frame.start, frame.end = self._started, end
        if frame.done is not None:
            frame.done(frame, True)
        return True

    @override
    def depart(self, owner: Any, nbytes: int, handed: int) -> int | None:
        got = self.tx.offer(handed, nbytes)
        if got is None:
            return None
        start, end = got
        self._started = start
        own = self._own.get(owner)
        if own is None:
            own = self._own[owner] = array("q")
        own.extend((handed, start, end))
        return end

    def leaves_at_once(self, nbytes: int) -> bool:
        return transmission_ns(nbytes, self._fastest) == 0

    @override
    def own_delays(self, owner: Any) -> np.ndarray:
        flat = self._own.get(owner)
        own = np.frombuffer(flat, dtype=np.int64).reshape(-1, 3) if flat else np.zeros((0, 3), np.int64)
        return own[:, 1] - own[:, 0]

    @override
    def interval_log(self, owner: Any, end: int) -> np.ndarray:
        """Every packet the transmitter carried up to ``end``: the background (dropped ones
        with ``start < 0``) and every owner's, whoever asks (with shared queues, the others'
        packets are part of what ``owner``'s packets waited behind)."""
        tx = self.tx
        tx.advance(end)
        parts = [tx.log()]
        for flat in self._own.values():
            if len(flat):
                parts.append(np.frombuffer(flat, dtype=np.int64).reshape(-1, 3))
        return np.concatenate(parts)

    @override
    def link_report(self, owner: Any, link: Any, end: int) -> dict[str, Any]:
        """Utilisation, ``owner``'s queueing delays, the background sent and dropped
        (:func:`link_stats`) and the time-averaged number of packets waiting."""
        tx = self.tx
        row: dict[str, Any] = dict(link_stats(self.own_delays(owner), tx.busy_until(end), tx.background_sent,
                                              tx.background_dropped, end))
        row["queue_length_mean"] = mean_waiting(self.interval_log(owner, end), end)
        return row
