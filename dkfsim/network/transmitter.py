"""A directed link's transmitter: one packet at a time, first in first out, with a waiting
room and the link's background load (docs/design.md §3, "Links that carry the traffic").

The transmitter is lazy: it is not a SimPy process but a few numbers -- the instant it is
free (``free_at``) and the start instants of the packets still waiting -- brought up to date
when a packet is handed over (:meth:`Transmitter.offer`): the link's background packets that
arrived up to and including that instant go first (:class:`BackgroundArrivals`, keyed draws,
so every estimator's transmitter sees the same ones), then the packet either waits, starts
at once, or is dropped because the waiting room is full (drop-tail; the packet in
transmission is not in the waiting room).  Transmission of ``size`` bytes takes
:func:`~dkfsim.components.traffic.transmission_ns`.  What the transmitter measures --
busy time, background packets offered and dropped -- it keeps; a packet's own queueing delay
is its sender's to record (the port's log of hand-over, start and end).
"""

from __future__ import annotations

import math
from array import array
from collections import deque
from collections.abc import Callable

import numpy as np

from dkfsim.components.traffic import Background, Queue, transmission_ns
from dkfsim.core.params import MAX_NS, NS_PER_S, seconds_to_ns
from dkfsim.core.streams import key64, keyed_uniforms

#: Background packets drawn at once (a block of keyed draws).  The instants are integer sums of
#: rounded gaps, so the block size changes no value; 512 keeps a link's first block, which
#: every port and the compiled tree's interval log draw, cheap (one math.log per packet).
BLOCK = 512
#: Longest gap between two Poisson background packets (ns), about 6.5 days.
MAX_GAP_NS = 1 << 49


def _log(u: np.ndarray) -> np.ndarray:
    """``log`` of each entry by the C library's ``log`` (``math.log``), the function the compiled
    tree's kernels call: numpy's vectorised ``log`` may differ in the last bit."""
    return np.array([math.log(x) for x in u.tolist()], dtype=np.float64)


def background_keys(prefix: tuple, seed: int) -> tuple[int, int]:
    """The keys of a link's background draws: its arrival gaps' and its sizes' (``prefix`` is
    the link's, ``("link", u, v)``)."""
    return key64(seed, *prefix, "background", "arrival"), key64(seed, *prefix, "background", "size")


def busy_within(busy_ns: int, free_at: int, end_ns: int) -> int:
    """ns of ``[0, end_ns]`` a transmitter was busy, from the ns of work it accepted (``busy_ns``)
    and the instant it is free: what is accepted and not yet sent at ``end_ns`` is one busy
    stretch, so it is cut off."""
    return busy_ns - max(0, free_at - end_ns)


class BackgroundArrivals:
    """The background packets of one link, in order: ``(instant ns, size bytes)``, keyed draws.

    Packet ``i``'s draws are pure functions of (the link's key, ``i``): a Poisson process's
    gaps ``round(-ln(u_i) / lambda)`` ns (the first from 0), a periodic one's instants
    ``offset + round(i / lambda)``; exponential sizes ``max(1, round(-ln(v_i) * size))``.
    """

    def __init__(self, spec: Background, prefix: tuple, seed: int):
        self.spec = spec
        #: the keys of the arrival gaps (or nothing, periodic) and of the sizes
        self.gap_key, self.size_key = background_keys(prefix, seed)
        self._times = np.empty(0, dtype=np.int64)
        self._sizes = np.empty(0, dtype=np.int64)
        self._drawn = 0          # packets drawn so far
        self._last = 0           # instant of the last packet drawn (the Poisson gaps' origin)
        self._pos = 0            # position of the next packet in the block

    def _draw_block(self) -> None:
        spec, lo = self.spec, self._drawn
        idx = np.arange(lo, lo + BLOCK, dtype=np.int64)
        zeros = np.zeros(BLOCK, dtype=np.int64)
        period = NS_PER_S / spec.packets_per_second
        if spec.arrivals == "poisson":
            gaps = np.floor(-_log(keyed_uniforms(self.gap_key, idx, zeros)) * period + 0.5)
            # a gap is at most 2^49 ns (6.5 days), so a block's sum cannot overflow
            times = self._last + np.cumsum(np.minimum(gaps, MAX_GAP_NS).astype(np.int64))
        else:
            times = seconds_to_ns(spec.offset) + np.floor(np.minimum(idx * period + 0.5, MAX_NS))
        times = np.minimum(times, MAX_NS).astype(np.int64)
        if spec.sizes == "exponential":
            sizes = np.maximum(1, np.floor(-_log(keyed_uniforms(self.size_key, idx, zeros)) * spec.size + 0.5))
        else:
            sizes = np.full(BLOCK, spec.size)
        self._times, self._sizes = times, sizes.astype(np.int64)
        self._last, self._drawn, self._pos = int(times[-1]), lo + BLOCK, 0

    def next_time(self) -> int:
        """The instant of the next packet not yet taken."""
        if self._pos >= len(self._times):
            self._draw_block()
        return int(self._times[self._pos])

    def until(self, t_ns: int) -> tuple[list[int], list[int]]:
        """The packets not yet taken whose instant is ``<= t_ns``: (instants, sizes), in order."""
        times_out: list[int] = []
        sizes_out: list[int] = []
        while True:
            if self._pos >= len(self._times):
                self._draw_block()
            times = self._times
            end = int(np.searchsorted(times, t_ns, side="right"))
            if end > self._pos:
                times_out.extend(times[self._pos:end].tolist())
                sizes_out.extend(self._sizes[self._pos:end].tolist())
                self._pos = end
            if end < len(times):
                return times_out, sizes_out


class Transmitter:
    """The FIFO transmitter of one directed link (one per estimator port, or one shared).

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
    the background packets sent and dropped.  The Python port's and the compiled tree's."""
    d = np.asarray(delays, dtype=np.float64) / NS_PER_S
    return {"utilisation": busy_ns / end_ns if end_ns > 0 else 0.0,
            "queueing_delay_mean": float(d.mean()) if len(d) else 0.0,
            "queueing_delay_p95": float(np.percentile(d, 95)) if len(d) else 0.0,
            "background_sent": background_sent,
            "background_dropped": background_dropped}
