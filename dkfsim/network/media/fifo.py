"""``fifo``: a link with a ``rate``: one packet at a time, first in first out, with a waiting
room and the link's background load (docs/design.md §3, "Links that carry the traffic").

The transmitter is lazy: it is not a SimPy process but a few numbers -- the instant it is
free and the start instants of the packets still waiting -- brought up to date when a packet is
handed over: the link's background packets that arrived up to and including that instant go
first (:class:`~dkfsim.network.media.background.BackgroundArrivals`, keyed draws, so every
estimator's transmitter sees the same ones), then the packet either waits, starts at once, or
is dropped because the waiting room is full (drop-tail; the packet in transmission is not in
the waiting room).  Transmission of ``size`` bytes takes
:func:`~dkfsim.components.traffic.transmission_ns`.  A packet's propagation is drawn at its
hand-over instant, its arrival counted from the end of its transmission (a lost packet
occupies the transmitter too).

The transmitters of one set of media (a port's own copies, or the copies ports share) are the
columns of one :class:`FifoTable`, and the arithmetic is one set of functions
(:mod:`dkfsim.network.port_kernels`, ``fifo_*``): a record port runs them inside its compiled
loop for a whole batch (the medium's :meth:`Fifo.lane`), anything else one packet at a time
through :meth:`Fifo.depart` -- the same code either way.  The table logs every packet a
transmitter takes -- each port's and the background, (hand-over, start, end) -- for the
queueing delays and the per-tick series of ``run.npz``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from typing_extensions import override

from dkfsim.components.traffic import Queue, transmission_ns
from dkfsim.core.backend import Backend
from dkfsim.core.jit import bind
from dkfsim.core.params import NS_PER_S
from dkfsim.core.registry import MEDIA
from dkfsim.network import port_kernels as pk
from dkfsim.network.links import Link
from dkfsim.network.media.background import BLOCK, BackgroundArrivals
from dkfsim.network.media.base import Frame, Medium
from dkfsim.network.occupancy import mean_waiting


def busy_within(busy_ns: int, free_at: int, end_ns: int) -> int:
    """ns of ``[0, end_ns]`` a transmitter was busy, from the ns of work it accepted (``busy_ns``)
    and the instant it is free: what is accepted and not yet sent at ``end_ns`` is one busy
    stretch, so it is cut off."""
    return busy_ns - max(0, free_at - end_ns)


class FifoTable:
    """The FIFO transmitters of one set of media, a column each
    (:data:`~dkfsim.network.port_kernels.Fifos`), with what the kernels ask of Python: the next
    block of a column's background, a longer ring of waiting packets, a longer log.

    :param backend: the run's (the ``fifo_*`` functions compiled or not).
    """

    def __init__(self, backend: Backend | None = None):
        backend = backend if backend is not None else Backend.from_environment()
        self.k = pk.compiled() if backend.compiled else pk
        z = np.zeros
        #: the table the kernels read and write (its arrays are replaced when they grow)
        self.F = pk.Fifos(z((pk.NST, 0), np.int64), z((0, 1), np.float64), z((0, 16, 2), np.int64),
                          z((0, 2, BLOCK), np.int64), z((1024, 5), np.int64), z(1, np.int64))
        self._backgrounds: list[BackgroundArrivals | None] = []
        self._owners: dict[int, int] = {}
        F = self.F
        self._offer = bind(self.k.fifo_offer, F, 0, 0, 0, 0)
        self._advance = bind(self.k.fifo_advance, F, 0, 0)

    def add(self, rates: list[float], T_ns: int, queue: Queue | None, background: BackgroundArrivals | None) -> int:
        """A new transmitter, its column: ``rates`` (bit/s) at ticks ``0, 1, ...`` of ``T_ns``
        ns (the last for every later tick; one rate: throughout).  The table's arrays hold
        twice the columns they need when they grow, so adding many links costs linear time.
        The rings of waiting packets start short whatever the waiting room (``queue.packets``
        may be 2**40): a full ring asks for a longer one (:data:`~dkfsim.network.port_kernels.NEED_RING`,
        doubled by :meth:`provide`), so their memory follows the packets that do wait."""
        m = len(self._backgrounds)
        maxp = queue.packets if queue is not None and queue.packets is not None else -1
        F = self.F
        C = F.ring.shape[1]
        R = max(F.rate.shape[1], len(rates))
        cap = F.st.shape[1]
        if m == cap or R > F.rate.shape[1]:
            new = max(cap, 2 * (m + 1)) if m == cap else cap
            st = np.zeros((pk.NST, new), np.int64)
            st[:, :cap] = F.st
            rate = np.zeros((new, R), np.float64)
            rate[:cap, :F.rate.shape[1]] = F.rate
            ring = np.zeros((new, C, 2), np.int64)
            ring[:cap] = F.ring                  # the rings keep their places (and heads)
            bg = np.zeros((new, 2, BLOCK), np.int64)
            bg[:cap] = F.bg
            F = self.F = pk.Fifos(st, rate, ring, bg, F.log, F.top)
        col = F.st[:, m]
        col[pk.SEEN] = -1
        col[pk.MAXP] = maxp
        col[pk.MAXB] = queue.bytes if queue is not None and queue.bytes is not None else -1
        col[pk.NRATE], col[pk.TNS], col[pk.HASBG] = len(rates), max(1, int(T_ns)), background is not None
        F.rate[m, :len(rates)] = rates
        self._backgrounds.append(background)
        return m

    @staticmethod
    def _unrolled(ring: np.ndarray, st: np.ndarray, C: int) -> np.ndarray:
        """The rings of every column, each from its head at position 0, in ``C`` places."""
        out = np.zeros((ring.shape[0], C, 2), np.int64)
        old = ring.shape[1]
        for m in range(ring.shape[0]):
            n = int(st[pk.QLEN, m])
            idx = (int(st[pk.HEAD, m]) + np.arange(n)) % max(old, 1)
            out[m, :n] = ring[m, idx]
        return out

    def owner(self, who: Any) -> int:
        """The number ``who`` (a port) logs its packets under."""
        return self._owners.setdefault(id(who), len(self._owners))

    def provide(self, m: int, need: int) -> None:
        """What column ``m``'s transmitter needs (:data:`~dkfsim.network.port_kernels.NEED_BG`, ...)."""
        F = self.F
        if need == pk.NEED_BG:
            background = self._backgrounds[m]
            assert background is not None
            times, sizes = background.next_block()
            F.bg[m, 0, :len(times)], F.bg[m, 1, :len(sizes)] = times, sizes
            F.st[pk.POS, m], F.st[pk.BLEN, m] = 0, len(times)
        elif need == pk.NEED_RING:
            C = 2 * F.ring.shape[1]
            ring = self._unrolled(F.ring, F.st, C)
            F.st[pk.HEAD] = 0
            self.F = F._replace(ring=ring)
        elif need == pk.NEED_LOG:
            log = np.zeros((2 * len(F.log), 5), np.int64)
            log[:len(F.log)] = F.log
            self.F = F._replace(log=log)
        else:
            raise ValueError(f"a FIFO transmitter asked for {need}")

    def offer(self, m: int, t: int, size: int, owner: int) -> int:
        """``fifo_offer`` until done: the packet's start (its end: :meth:`free_at`), or
        :data:`~dkfsim.network.port_kernels.DROPPED`."""
        while True:
            got = int(self._offer(self.F, m, t, size, owner))
            if got >= pk.DROPPED:
                return got
            self.provide(m, -got)

    def advance(self, m: int, t: int) -> None:
        """Column ``m`` takes its background up to and including ``t``."""
        while True:
            need = int(self._advance(self.F, m, t))
            if not need:
                return
            self.provide(m, need)

    def state(self, m: int, row: int) -> int:
        """``F.st[row, m]``."""
        return int(self.F.st[row, m])

    def rows(self, m: int) -> np.ndarray:
        """The log rows of column ``m`` (owner, hand-over, start, end), in the order taken."""
        log = self.F.log[:int(self.F.top[0])]
        return log[log[:, 0] == m, 1:]


class Transmitter:
    """The FIFO transmitter of one directed link: column ``m`` of ``table`` as an object (the
    queueing-theory checks and ``centralized_delayed``'s closed form use it on its own)."""

    def __init__(self, table: FifoTable, m: int):
        self.table, self.m = table, m

    @property
    def free_at(self) -> int:
        """When the packet last accepted ends (ns)."""
        return self.table.state(self.m, pk.FREE_AT)

    @property
    def busy_ns(self) -> int:
        """ns the transmitter has been or will be busy with the packets accepted so far."""
        return self.table.state(self.m, pk.BUSY)

    @property
    def background_sent(self) -> int:
        return self.table.state(self.m, pk.BG_SENT)

    @property
    def background_dropped(self) -> int:
        return self.table.state(self.m, pk.BG_DROPPED)

    def advance(self, t_ns: int) -> None:
        """Take the background packets that arrived up to and including ``t_ns``."""
        self.table.advance(self.m, t_ns)

    def offer(self, t_ns: int, size: int, owner: int = -2) -> tuple[int, int] | None:
        """Hand over a packet of ``size`` bytes at ``t_ns`` (after the background up to it):
        its (start, end) of transmission in ns, or None when dropped (the waiting room full)."""
        start = self.table.offer(self.m, t_ns, size, owner)
        return None if start == pk.DROPPED else (start, self.free_at)

    def log(self) -> np.ndarray:
        """(packets, 3) int64: each background packet's instant, start and end (ns; -1 when
        dropped)."""
        rows = self.table.rows(self.m)
        return rows[rows[:, 0] == -1, 1:].copy()

    def waiting(self, t_ns: int) -> int:
        """Packets waiting at ``t_ns`` (after the background up to it), not counting the one
        in transmission."""
        self.advance(t_ns)
        F, m = self.table.F, self.m
        n, head = int(F.st[pk.QLEN, m]), int(F.st[pk.HEAD, m])
        starts = F.ring[m, (head + np.arange(n)) % F.ring.shape[1], 0]
        return int(np.count_nonzero(starts > t_ns))

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
    :param table: the :class:`FifoTable` its transmitter is a column of (the other media of the
        same set's; None: a table of its own, on the environment's backend).
    """

    kind = "fifo"
    synchronous = True
    #: The parameter keys it reads (``dkfsim list media``).
    required = ("rate",)
    optional = ("queue", "background")

    def __init__(self, link: Link, rates: list[float] | None = None, table: FifoTable | None = None):
        spec = link.spec
        self.link = link
        rate = float(rates[0]) if rates is not None else float(spec.rate) if spec.rate is not None else 0.0
        if not rate > 0:
            raise ValueError(f"link {link.src} -> {link.dst} has no rate: it is not a fifo medium")
        bg = BackgroundArrivals(spec.background, link.prefix, link.seed) if spec.background is not None else None
        self.table = table if table is not None else FifoTable()
        self.slot = self.table.add([float(r) for r in rates] if rates is not None else [rate],
                                   link.T_ns, spec.queue, bg)
        #: the link's transmitter
        self.tx = Transmitter(self.table, self.slot)
        #: the fastest rate the link can have, for :meth:`leaves_at_once`
        self._fastest = max(rates) if rates is not None else rate
        self._started = -1                  # (the start of the last transmission it took)

    @override
    def lane(self) -> tuple[FifoTable, int]:
        return self.table, self.slot

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
        table = self.table
        start = table.offer(self.slot, handed, nbytes, table.owner(owner))
        if start == pk.DROPPED:
            return None
        self._started = start
        return table.state(self.slot, pk.FREE_AT)

    def leaves_at_once(self, nbytes: int) -> bool:
        return transmission_ns(nbytes, self._fastest) == 0

    @override
    def own_delays(self, owner: Any) -> np.ndarray:
        rows = self.table.rows(self.slot)
        own = rows[rows[:, 0] == self.table.owner(owner)]
        return own[:, 2] - own[:, 1]

    @override
    def interval_log(self, owner: Any, end: int) -> np.ndarray:
        """Every packet the transmitter carried up to ``end``: the background (dropped ones
        with ``start < 0``) and every owner's, whoever asks (with shared queues, the others'
        packets are part of what ``owner``'s packets waited behind)."""
        self.tx.advance(end)
        return self.table.rows(self.slot)[:, 1:].copy()

    @override
    def link_report(self, owner: Any, link: Any, end: int) -> dict[str, Any]:
        """Utilisation, ``owner``'s queueing delays, the background sent and dropped
        (:func:`link_stats`) and the time-averaged number of packets waiting."""
        tx = self.tx
        row: dict[str, Any] = dict(link_stats(self.own_delays(owner), tx.busy_until(end), tx.background_sent,
                                              tx.background_dropped, end))
        row["queue_length_mean"] = mean_waiting(self.interval_log(owner, end), end)
        return row

