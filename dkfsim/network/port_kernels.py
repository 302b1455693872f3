"""Kernels of :class:`dkfsim.network.port.RecordPort`: handing a batch of packets over at once.

For the links on which a packet leaves at its hand-over (a passive medium) and nothing but a
``constant`` or ``uniform_steps`` latency acts (:meth:`~dkfsim.components.latency.Sampler.vector`),
a packet's fate is one keyed draw; :func:`hand_over` numbers a batch's packets on their links
(per link and instant, in order), counts them and draws those fates, and :func:`peek` answers
the port's lookahead the same way without sending.  The draws are
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

_KERNELS = ("keyed_uniform", "latency", "_down", "hand_over", "arrange", "tally", "peek")
_INLINE = ("keyed_uniform", "latency", "_down")
_lazy = LazyKernels(__name__, _KERNELS, inline=_INLINE)

#: A link's kind for the batch path: drawn here (a passive medium and a vector latency); its
#: latency drawn here and its departure left to the port's Python path (a synchronous medium,
#: a transmitter); or left to the port's Python path.
DRAWN, LATENCY, PYTHON = 0, 1, 2
#: :func:`hand_over`'s arrival instant of a packet that does not arrive (lost, out of range,
#: or delivered already by its sender), and of one left to the port's Python path.
NEVER, ASK = -1, -2
#: :func:`hand_over`'s flags: some packet is left to Python; some packet said to be delivered
#: at once does not arrive at once.
SOME_ASK, BROKEN_PROMISE = 1, 2
#: :func:`hand_over` writes a :data:`LATENCY` link's latency ``d`` as ``LATENCY_AT - d``.
LATENCY_AT = -3


def drawn_latency(at: int) -> int:
    """The latency :func:`hand_over` wrote as ``at`` for a :data:`LATENCY` link (-1: none)."""
    return LATENCY_AT - at if at <= LATENCY_AT else -1
#: Rows of ``Lanes.ints`` (per link id): its kind, its latency's vector form (0 a constant of
#: ``PAR`` ns, 1 uniform steps ``0 .. PAR`` times ``T_ns``), whether it goes down at some tick,
#: the instant ``SEQN`` counts from and the next sequence number.
KIND, LKIND, PAR, CHANGES, SEQT, SEQN = range(6)
#: Rows of ``Lanes.count`` (per link id): the counters the batch path writes.
SENT, BYTES, LOST, RANGE_LOST, DELIVERED, CRASH_DROPPED = range(6)
#: Columns of a batch's parts (what :meth:`~dkfsim.network.port.RecordPort.send_records` takes)
#: and of a delivery's rows: link id, tag, first and end row of its records; then its size in
#: bytes and whether its sender delivered it at once.
C_LID, C_TAG, C_START, C_STOP, C_BYTES, C_DONE = range(6)

#: The per-link arrays of the batch path: ``ints`` (the rows above), ``key`` (the latency's
#: draw key), ``up`` (``up[link, tick]``: the link's state, one column when no link changes) and
#: ``count`` (the rows above).
Lanes = namedtuple("Lanes", "ints key up count")

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


def hand_over(B: Lanes, now: int, seq0: int, T_ns: int, parts: np.ndarray, seqs: np.ndarray, at: np.ndarray) -> int:
    """Number and count the packets handed over now, in order (packet ``p``: the columns of
    ``parts[p]``): ``seqs[p]`` its number on its link at this instant; for a :data:`DRAWN` link
    ``at[p]`` its arrival instant (:data:`NEVER`: the link is down), for a :data:`LATENCY` link
    that is up ``LATENCY_AT - latency`` (:func:`drawn_latency`), else :data:`ASK`.  A packet its
    sender delivered at once
    (``C_DONE``) is counted delivered when it does arrive now, :data:`NEVER` as its instant.
    Returns the flags :data:`SOME_ASK`, :data:`BROKEN_PROMISE`."""
    flags = 0
    for p in range(parts.shape[0]):
        lid = parts[p, C_LID]
        if B.ints[SEQT, lid] != now:
            B.ints[SEQT, lid] = now
            B.ints[SEQN, lid] = seq0
        s = B.ints[SEQN, lid]
        B.ints[SEQN, lid] = s + 1
        seqs[p] = s
        B.count[SENT, lid] += 1
        B.count[BYTES, lid] += parts[p, C_BYTES]
        kind = B.ints[KIND, lid]
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
