"""Kernels of :class:`dkfsim.network.port.RecordPort`: handing a batch of packets over at once.

For the links on which a packet leaves at its hand-over (a passive medium) and nothing but a
``constant`` or ``uniform_steps`` latency acts (:meth:`~dkfsim.components.latency.Sampler.vector`),
a packet's fate is one keyed draw; :func:`hand_over` numbers a batch's packets on their links
(per link and instant, in order), counts them and draws those fates, and :func:`peek` answers
the port's lookahead the same way without sending.  On a link whose medium is a FIFO
transmitter (:class:`~dkfsim.network.media.fifo.Fifo`, a :data:`QUEUED` link) the packet first
waits for its transmitter, run here too: the transmitters of one set of media are the columns
of one :data:`Fifos` table (the ``fifo_*`` functions below, which the medium itself calls one
packet at a time), so a packet's departure and its draw are one step of the same loop.  The draws are
:func:`dkfsim.core.streams.keyed_uniform` in uint64 arithmetic (the same bits).  Every other
packet is numbered and counted here and left to the port's Python path (its medium, its
faults).

On the numba path these functions are compiled; on the numpy path they run as Python.
"""

from __future__ import annotations

from collections import namedtuple
from types import ModuleType

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("keyed_uniform", "latency", "_down", "transmission_ns", "fifo_accept", "fifo_advance", "fifo_offer",
            "hand_over", "arrange", "tally", "peek")
_INLINE = ("keyed_uniform", "latency", "_down", "transmission_ns")
_lazy = LazyKernels(__name__, _KERNELS, inline=_INLINE)

#: A link's kind for the batch path: drawn here (a passive medium and a vector latency); its
#: latency drawn here and its departure left to the port's Python path (a synchronous medium);
#: left to the port's Python path; its departure from its FIFO transmitter (a column of the
#: :data:`Fifos` table) and its latency both worked out here.
DRAWN, LATENCY, PYTHON, QUEUED = 0, 1, 2, 3
#: :func:`hand_over`'s arrival instant of a packet that does not arrive (lost, out of range,
#: or delivered already by its sender), and of one left to the port's Python path.
NEVER, ASK = -1, -2
#: :func:`hand_over`'s flags: some packet is left to Python; some packet said to be delivered
#: at once does not arrive at once; it stopped before a packet whose transmitter needs Python
#: first (``halt``: the packet and the reason, :data:`NEED_BG` ...).
SOME_ASK, BROKEN_PROMISE, HALTED = 1, 2, 4
#: :func:`hand_over` writes a :data:`LATENCY` link's latency ``d`` as ``LATENCY_AT - d``.
LATENCY_AT = -3


def drawn_latency(at: int) -> int:
    """The latency :func:`hand_over` wrote as ``at`` for a :data:`LATENCY` link (-1: none)."""
    return LATENCY_AT - at if at <= LATENCY_AT else -1
#: Rows of ``Lanes.ints`` (per link id): its kind, its latency's vector form (0 a constant of
#: ``PAR`` ns, 1 uniform steps ``0 .. PAR`` times ``T_ns``), whether it goes down at some tick,
#: the instant ``SEQN`` counts from, the next sequence number, and its transmitter's column in
#: the :data:`Fifos` table (a :data:`QUEUED` link).
KIND, LKIND, PAR, CHANGES, SEQT, SEQN, SLOT = range(7)
#: Rows of ``Lanes.count`` (per link id): the counters the batch path writes.
SENT, BYTES, LOST, RANGE_LOST, DELIVERED, CRASH_DROPPED, QUEUE_DROPPED = range(7)
#: Columns of a batch's parts (what :meth:`~dkfsim.network.port.RecordPort.send_records` takes)
#: and of a delivery's rows: link id, tag, first and end row of its records; then its size in
#: bytes and whether its sender delivered it at once.
C_LID, C_TAG, C_START, C_STOP, C_BYTES, C_DONE = range(6)

#: The per-link arrays of the batch path: ``ints`` (the rows above), ``key`` (the latency's
#: draw key), ``up`` (``up[link, tick]``: the link's state, one column when no link changes) and
#: ``count`` (the rows above).
Lanes = namedtuple("Lanes", "ints key up count")

#: The FIFO transmitters of one set of media, a column ``m`` each: ``st`` (the rows below, one
#: column per transmitter), ``rate`` (``rate[m, k]``: bit/s at tick ``k``, the last row for
#: every later tick), ``ring`` (``ring[m, j]``: (start, size) of the packets accepted and not
#: started at the last instant seen, a ring from ``st[HEAD, m]``), ``bg`` (``bg[m, 0|1, i]``: the
#: instants and sizes of the current block of background packets) and ``log`` (one row per
#: packet taken: column, owner (-1: background), hand-over, start, end; start and end -1:
#: dropped), ``log[:top[0]]``.
Fifos = namedtuple("Fifos", "st rate ring bg log top")
#: Rows of ``Fifos.st``: when the packet last accepted ends, the busy ns accepted so far, the
#: ring's head, length and bytes, the last instant whose background is taken, the position and
#: length of the background block, the background packets sent and dropped, the waiting room
#: (packets, bytes; -1: no bound), the number of ``rate`` rows, the tick length, and whether it
#: has background.
(FREE_AT, BUSY, HEAD, QLEN, QBYTES, SEEN, POS, BLEN, BG_SENT, BG_DROPPED, MAXP, MAXB, NRATE, TNS,
 HASBG) = range(15)
NST = 15
#: :func:`fifo_accept`'s answer for a packet the waiting room has no room for.
DROPPED = -1
#: What a transmitter needs from Python before it can go on: the next block of background
#: packets, a longer ring, a longer log (:func:`fifo_advance`'s and ``halt``'s reasons; as
#: answers of :func:`fifo_accept` and :func:`fifo_offer`, negated: ``-NEED_RING`` ...).
NEED_BG, NEED_RING, NEED_LOG = 2, 3, 4
NS_PER_S = 1_000_000_000
MAX_NS = 2**62

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_SCALE = 1.0 / 9007199254740992.0


def compiled() -> ModuleType:
    """This module with its kernels compiled by numba (loaded from the disk cache after the
    first time)."""
    return _lazy.get()


def keyed_uniform(key: np.uint64, t: int, seq: int) -> float:
    """:func:`dkfsim.core.streams.keyed_uniform` in uint64 arithmetic (the same bits)."""
    z = key + _GOLDEN * np.uint64(t)
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    z = (z ^ (z >> _S31)) + _GOLDEN * np.uint64(seq + 1)
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return (np.float64((z ^ (z >> _S31)) >> _S11) + 0.5) * _SCALE


def latency(B: Lanes, lid: int, t: int, seq: int, T_ns: int) -> int | np.integer:
    """The latency (ns) of packet number ``seq`` handed to link ``lid`` at ``t``."""
    d = B.ints[PAR, lid]
    if B.ints[LKIND, lid] == 0:
        return d
    k = np.int64(keyed_uniform(B.key[lid], t, seq) * (d + 1))
    if k > d:
        k = d
    return k * T_ns


def _down(B: Lanes, lid: int, now: int, T_ns: int) -> bool:
    """Whether link ``lid`` is down at ``now``."""
    if B.ints[CHANGES, lid] == 0:
        return False
    k = now // T_ns
    if k > B.up.shape[1] - 1:
        k = B.up.shape[1] - 1
    return B.up[lid, k] == 0


def transmission_ns(nbytes: int, rate: float) -> int:
    """:func:`dkfsim.components.traffic.transmission_ns` (the same float operations)."""
    ns = nbytes * 8.0 * NS_PER_S / rate
    if ns >= MAX_NS:
        return MAX_NS
    return int(ns + 0.5)


def fifo_accept(F: Fifos, m: int, t: int, size: int) -> int:
    """A packet of ``size`` bytes handed to transmitter ``m`` at ``t`` (not before the last
    one, its background up to ``t`` taken): its start of transmission (it ends at
    ``F.st[FREE_AT, m]``), :data:`DROPPED` when the waiting room is full (drop-tail; the packet
    in transmission is not in the room), or ``-NEED_RING`` (nothing changed but the packets
    that started by ``t`` leaving the ring)."""
    st, ring = F.st, F.ring
    C = ring.shape[1]
    while st[QLEN, m] > 0 and ring[m, st[HEAD, m], 0] <= t:
        st[QBYTES, m] -= ring[m, st[HEAD, m], 1]
        st[HEAD, m] = (st[HEAD, m] + 1) % C
        st[QLEN, m] -= 1
    free = st[FREE_AT, m]
    start = free if free > t else t
    if start > t:
        if st[MAXP, m] >= 0 and st[QLEN, m] >= st[MAXP, m]:
            return DROPPED
        if st[MAXB, m] >= 0 and st[QBYTES, m] + size > st[MAXB, m]:
            return DROPPED
        if st[QLEN, m] == C:
            return -NEED_RING
    k = start // st[TNS, m]
    if k > st[NRATE, m] - 1:
        k = st[NRATE, m] - 1
    tx = transmission_ns(size, F.rate[m, k])
    end = MAX_NS if tx >= MAX_NS - start else start + tx
    st[FREE_AT, m] = end
    st[BUSY, m] += end - start
    if start > t:
        j = (st[HEAD, m] + st[QLEN, m]) % C
        ring[m, j, 0] = start
        ring[m, j, 1] = size
        st[QLEN, m] += 1
        st[QBYTES, m] += size
    return start


def fifo_advance(F: Fifos, m: int, t: int) -> int:
    """Transmitter ``m`` takes its background packets up to and including ``t``, each logged:
    0, or what it needs first (:data:`NEED_BG`, :data:`NEED_RING`, :data:`NEED_LOG`; the
    packets before it are taken, so calling again goes on)."""
    st, bg, log = F.st, F.bg, F.log
    if t <= st[SEEN, m]:
        return 0
    if st[HASBG, m]:
        while True:
            p = st[POS, m]
            if p >= st[BLEN, m]:
                return NEED_BG
            tb = bg[m, 0, p]
            if tb > t:
                break
            r = F.top[0]
            if r >= log.shape[0]:
                return NEED_LOG
            got = fifo_accept(F, m, tb, bg[m, 1, p])
            if got == -NEED_RING:
                return NEED_RING
            log[r, 0] = m
            log[r, 1] = -1
            log[r, 2] = tb
            if got == DROPPED:
                st[BG_DROPPED, m] += 1
                log[r, 3] = -1
                log[r, 4] = -1
            else:
                st[BG_SENT, m] += 1
                log[r, 3] = got
                log[r, 4] = st[FREE_AT, m]
            F.top[0] = r + 1
            st[POS, m] = p + 1
    st[SEEN, m] = t
    return 0


def fifo_offer(F: Fifos, m: int, t: int, size: int, owner: int) -> int:
    """Hand a packet of ``owner`` of ``size`` bytes to transmitter ``m`` at ``t`` (after its
    background up to ``t``), logged when taken: its start (its end: ``F.st[FREE_AT, m]``),
    :data:`DROPPED`, or ``-NEED_...`` (nothing of this packet done: call again once provided)."""
    need = fifo_advance(F, m, t)
    if need:
        return -need
    r = F.top[0]
    if r >= F.log.shape[0]:
        return -NEED_LOG
    got = fifo_accept(F, m, t, size)
    if got >= 0:
        F.log[r, 0] = m
        F.log[r, 1] = owner
        F.log[r, 2] = t
        F.log[r, 3] = got
        F.log[r, 4] = F.st[FREE_AT, m]
        F.top[0] = r + 1
    return got


def hand_over(B: Lanes, F: Fifos, owner: int, first: int, now: int, seq0: int, T_ns: int, parts: np.ndarray,
              seqs: np.ndarray, at: np.ndarray, halt: np.ndarray) -> int:
    """Number and count the packets handed over now, in order, from packet ``first`` (packet
    ``p``: the columns of ``parts[p]``): ``seqs[p]`` its number on its link at this instant; for
    a :data:`DRAWN` link ``at[p]`` its arrival instant (:data:`NEVER`: the link is down), for a
    :data:`QUEUED` link the same after its transmitter (``owner``'s packet in column
    ``ints[SLOT]`` of ``F``; :data:`NEVER`: down or dropped, ``queue_dropped``), for a
    :data:`LATENCY` link that is up ``LATENCY_AT - latency`` (:func:`drawn_latency`), else
    :data:`ASK`.  A packet its sender delivered at once (``C_DONE``) is counted delivered when
    it does arrive now, :data:`NEVER` as its instant.  Returns the flags :data:`SOME_ASK`,
    :data:`BROKEN_PROMISE` and :data:`HALTED`: it stopped before packet ``halt[0]``, whose
    transmitter needs ``halt[1]`` (call again from there once it is provided)."""
    flags = 0
    for p in range(first, parts.shape[0]):
        lid = parts[p, C_LID]
        kind = B.ints[KIND, lid]
        if kind == QUEUED and not _down(B, lid, now, T_ns):
            m = B.ints[SLOT, lid]
            need = fifo_advance(F, m, now)
            if need == 0 and F.top[0] >= F.log.shape[0]:
                need = NEED_LOG
            if need == 0 and F.st[QLEN, m] == F.ring.shape[1]:
                need = NEED_RING
            if need:
                halt[0] = p
                halt[1] = need
                return flags | HALTED
        if B.ints[SEQT, lid] != now:
            B.ints[SEQT, lid] = now
            B.ints[SEQN, lid] = seq0
        s = B.ints[SEQN, lid]
        B.ints[SEQN, lid] = s + 1
        seqs[p] = s
        B.count[SENT, lid] += 1
        B.count[BYTES, lid] += parts[p, C_BYTES]
        if kind == QUEUED:
            if parts[p, C_DONE]:
                flags |= BROKEN_PROMISE
            if _down(B, lid, now, T_ns):
                B.count[LOST, lid] += 1
                B.count[RANGE_LOST, lid] += 1
                at[p] = NEVER
                continue
            got = fifo_offer(F, B.ints[SLOT, lid], now, parts[p, C_BYTES], owner)
            if got < 0:                   # (dropped: room was made for anything else above)
                B.count[QUEUE_DROPPED, lid] += 1
                at[p] = NEVER
                continue
            at[p] = F.st[FREE_AT, B.ints[SLOT, lid]] + latency(B, lid, now, s, T_ns)
            continue
        if kind != DRAWN:
            flags |= SOME_ASK
            if kind == LATENCY and not _down(B, lid, now, T_ns):
                at[p] = LATENCY_AT - latency(B, lid, now, s, T_ns)
            else:
                at[p] = ASK
            continue
        if _down(B, lid, now, T_ns):
            B.count[LOST, lid] += 1
            B.count[RANGE_LOST, lid] += 1
            at[p] = NEVER
            if parts[p, C_DONE]:
                flags |= BROKEN_PROMISE
            continue
        t = now + latency(B, lid, now, s, T_ns)
        if parts[p, C_DONE]:
            if t != now:
                flags |= BROKEN_PROMISE
            B.count[DELIVERED, lid] += 1
            t = NEVER
        at[p] = t
    return flags


def arrange(at: np.ndarray, parts: np.ndarray, base: int, rows: np.ndarray, times: np.ndarray,
            cuts: np.ndarray) -> int:
    """The packets with ``at >= 0``, stably ordered by arrival instant: ``rows[m]`` (link id,
    tag, first and end row, those offset by ``base``) and ``times[m]`` its instant; ``cuts[c]``
    the end of the ``c``-th run of one instant.  Returns the number of runs."""
    idx = np.flatnonzero(at >= 0)
    order = idx[np.argsort(at[idx], kind="mergesort")]
    runs = 0
    for m in range(order.shape[0]):
        p = order[m]
        if m > 0 and at[p] != times[m - 1]:
            cuts[runs] = m
            runs += 1
        times[m] = at[p]
        rows[m, C_LID] = parts[p, C_LID]
        rows[m, C_TAG] = parts[p, C_TAG]
        rows[m, C_START] = parts[p, C_START] + base
        rows[m, C_STOP] = parts[p, C_STOP] + base
    if order.shape[0] > 0:
        cuts[runs] = order.shape[0]
        runs += 1
    return runs


def tally(B: Lanes, row: int, batch: np.ndarray) -> None:
    """``B.count[row, lid] += 1`` for the link id of each row of ``batch``."""
    for k in range(batch.shape[0]):
        B.count[row, batch[k, C_LID]] += 1


def peek(B: Lanes, now: int, seq0: int, T_ns: int, lids: np.ndarray, table: np.ndarray) -> None:
    """The port's lookahead for the :data:`DRAWN` links of ``lids``: ``table[e, u]`` is 1 when
    the ``u``-th packet from now on link ``lids[e]`` arrives at this instant, 0 when it does not
    (later, or the link is down); rows of other links are left as they are."""
    q = table.shape[1]
    for e in range(lids.shape[0]):
        lid = lids[e]
        if B.ints[KIND, lid] != DRAWN:
            continue
        base = B.ints[SEQN, lid] if B.ints[SEQT, lid] == now else seq0
        if _down(B, lid, now, T_ns):
            for u in range(q):
                table[e, u] = 0
            continue
        for u in range(q):
            table[e, u] = 1 if latency(B, lid, now, base + u, T_ns) == 0 else 0
