"""The fusion centre's compiled steps: the fold of what its packets taught it (decision 233)
and the relay of its packets (decision 232), hop by hop what
:class:`~dkfsim.network.links.Port` does with them on links whose only act on a packet is
their keyed latency draw (``constant`` or ``uniform_steps``, no loss, no transmitter, no
channel, no crash), in one kernel call per tick instead of Python per hop.

A packet is an id (the caller keeps its payload); the heap orders the hops in flight by
arrival instant, then by the order they were sent: the port's order (its packets due at one
instant are delivered in the order sent, those sent at that instant with zero latency after
them).  Each link numbers its packets per hand-over instant from ``SEQ0`` (the centre's port
shares the DKF's: :data:`~dkfsim.network.links.SHARED_SEQ0`) and draws their latency with the
compiled tree's :func:`~dkfsim.protocols.tree_compiled_kernels.keyed_uniform` (the same bits as
:meth:`Link.plain`).
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from dkfsim.core.jit import LazyKernels
from dkfsim.model import holdings_kernels as hk
from dkfsim.protocols import tree_compiled_kernels as tck

_KERNELS = ("_push", "_pop", "_hop", "_accept", "_deliver", "tick", "_fold_origins", "fold_new", "fold_ring")
_INLINE = ("_push", "_pop", "_hop", "_accept", "_deliver", "_fold_origins")
#: :func:`tck.keyed_uniform` and :func:`hk.fold` are called from here (docs/decisions.md 131).
BORROWS = {"dkfsim.protocols.tree_compiled_kernels": "7bd833072cbd7c854c046d3f59d276c2dc09d31825f7f06b20d97a59bda530d9",
           "dkfsim.model.holdings_kernels": "f5ba9bd99b4d6598cc258c4188fda9f3e2d0e1645766f96dd735e008fe277ffd"}
_lazy = LazyKernels(__name__, _KERNELS, inline=_INLINE, borrows=BORROWS)

#: ``CT`` indices: hops on the heap, hops pushed so far (the send order), packets that reached
#: the centre, packets it ignored (older than its newest of that node, or a node left out).
SIZE, ORDER, RECEIVED, IGNORED = range(4)
#: Returned by :func:`tick` when the heap would overflow (its bound was wrong).
FULL = -1

#: The relay's state.  Per link ``l``: ``kind`` (0 constant ``par`` ns, 1 uniform steps
#: ``0..par`` times ``T_ns``), ``key`` (uint64), ``dst``, the instant its sequence numbers
#: were last counted from (``seq_t``) and the next one (``seq``), counts ``sent``, ``nbytes``,
#: ``delivered``.  Per node ``out``: the link toward the centre (-1: none).  The heap:
#: arrival ``ht``, send order ``ho``, packet ``hp``, link ``hl``, size ``hb``.  A packet is
#: ``row * n + node``: node's estimate of ``row``; what the centre took of it: per node the
#: newest row (``newest``, -1: none), whether that packet is still to fold (``pend``), and
#: ``excluded`` (the centre's own array: a node left out).
Relay = namedtuple("Relay", "CT kind key par T_ns dst out at n seq0 seq_t seq sent nbytes delivered "
                            "ht ho hp hl hb newest pend excluded")


def compiled():
    """This module with its kernels compiled (loaded from numba's disk cache)."""
    return _lazy.get()


def _push(R, t, p, link, size):
    """Put packet ``p`` arriving over ``link`` at ``t`` on the heap (ties: send order)."""
    k = R.CT[SIZE]
    R.CT[SIZE] = k + 1
    o = R.CT[ORDER]
    R.CT[ORDER] = o + 1
    while k > 0:
        up = (k - 1) // 2
        if R.ht[up] < t or (R.ht[up] == t and R.ho[up] < o):
            break
        R.ht[k], R.ho[k], R.hp[k], R.hl[k], R.hb[k] = R.ht[up], R.ho[up], R.hp[up], R.hl[up], R.hb[up]
        k = up
    R.ht[k], R.ho[k], R.hp[k], R.hl[k], R.hb[k] = t, o, p, link, size


def _pop(R):
    """Remove the heap's first hop; its ``(packet, link, size)``."""
    top = (R.hp[0], R.hl[0], R.hb[0])
    n = R.CT[SIZE] - 1
    R.CT[SIZE] = n
    t, o, p, link, size = R.ht[n], R.ho[n], R.hp[n], R.hl[n], R.hb[n]
    k = 0
    while True:
        c = 2 * k + 1
        if c >= n:
            break
        if c + 1 < n and (R.ht[c + 1] < R.ht[c] or (R.ht[c + 1] == R.ht[c] and R.ho[c + 1] < R.ho[c])):
            c += 1
        if t < R.ht[c] or (t == R.ht[c] and o < R.ho[c]):
            break
        R.ht[k], R.ho[k], R.hp[k], R.hl[k], R.hb[k] = R.ht[c], R.ho[c], R.hp[c], R.hl[c], R.hb[c]
        k = c
    R.ht[k], R.ho[k], R.hp[k], R.hl[k], R.hb[k] = t, o, p, link, size
    return top


def _hop(R, now, link, p, size):
    """Hand packet ``p`` to ``link`` at ``now``: its number at this instant, its count, its
    keyed latency; False when the heap is full."""
    if R.CT[SIZE] >= R.ht.shape[0]:
        return False
    if R.seq_t[link] != now:
        R.seq_t[link] = now
        R.seq[link] = R.seq0
    seq = R.seq[link]
    R.seq[link] = seq + 1
    R.sent[link] += 1
    R.nbytes[link] += size
    if R.kind[link] == 0:
        lat = R.par[link]
    else:
        v = int(tck.keyed_uniform(R.key[link], now, seq) * (R.par[link] + 1))
        lat = min(v, R.par[link]) * R.T_ns
    _push(R, now + lat, p, link, size)
    return True


def _accept(R, p):
    """The centre takes packet ``p`` (``FusionCentre.accept`` without radars): a node's newer
    row replaces what it had; an older one, or one of a node left out, is ignored."""
    i = p % R.n
    row = p // R.n
    if R.excluded[i] or row <= R.newest[i]:
        R.CT[IGNORED] += 1
        return
    R.newest[i] = row
    R.pend[i] = True


def _deliver(R, limit):
    """Deliver every hop due up to ``limit``; a relay forwards at once.  False when full."""
    while R.CT[SIZE] > 0 and R.ht[0] <= limit:
        now = R.ht[0]
        p, link, size = _pop(R)
        R.delivered[link] += 1
        node = R.dst[link]
        if node == R.at:
            R.CT[RECEIVED] += 1
            _accept(R, p)
        elif R.out[node] >= 0:
            if not _hop(R, now, R.out[node], p, size):
                return False
    return True


def tick(R, now, row, senders, size):
    """The centre's packets at the tick ``now`` whose update computed ``row``: deliver what is
    due up to ``now`` (the port's deliveries come before the update), the centre's own
    estimate, then each of ``senders`` sends its packet (``size`` bytes) on its link toward the
    centre, then their zero-latency hops are delivered.  0, or :data:`FULL`."""
    if not _deliver(R, now):
        return FULL
    _accept(R, row * R.n + R.at)
    for j in range(senders.shape[0]):
        i = senders[j]
        if not _hop(R, now, R.out[i], row * R.n + i, size):
            return FULL
    if not _deliver(R, now):
        return FULL
    return 0


def _fold_origins(i, row, have, known, bits, F):
    """Fold the origins flagged in ``have`` that ``known`` (the centre's ring of what each node
    holds) lacks for node ``i`` and ``row`` into the shadow's sums (:func:`hk.fold`, origins
    ascending), and mark them known."""
    slot = row % known.shape[0]
    new = False
    for o in range(have.shape[0]):
        if have[o] and not known[slot, i, o]:
            if not new:
                bits[:] = 0
                new = True
            known[slot, i, o] = True
            bits[o >> 6] |= np.uint64(1) << np.uint64(o & 63)
    if new:
        hk.fold(i, row, bits, F)


def fold_new(stack, nodes, k0, known, F):
    """The centre's fold (``FusionCentre._fold`` without radars): ``stack[a, j]`` are the
    origins node ``nodes[j]``'s newest packet holds of row ``k0 + a``; what the centre did not
    know is folded (:func:`_fold_origins`; each (row, node) once, so the order of the
    contributions changes no sum)."""
    rows, m, no = stack.shape
    bits = np.zeros((no + 63) // 64, dtype=np.uint64)
    for a in range(rows):
        for j in range(m):
            _fold_origins(nodes[j], k0 + a, stack[a, j], known, bits, F)


def fold_ring(ring, pend, newest, k0, W, known, F):
    """:func:`fold_new` for the packets the compiled relay accepted: node ``i`` with
    ``pend[i]`` holds what its packet of row ``r = newest[i]`` says, the masks of rows
    ``max(r - W + 1, 0) .. r`` in ``ring[r % len(ring)]`` (the tick's masks, kept while such a
    packet can be in flight); rows before ``k0`` are final in the shadow and skipped."""
    bits = np.zeros((known.shape[2] + 63) // 64, dtype=np.uint64)
    for i in range(pend.shape[0]):
        if not pend[i]:
            continue
        pend[i] = False
        r = newest[i]
        lo = max(r - W + 1, 0)
        masks = ring[r % ring.shape[0]]
        for row in range(max(lo, k0), r + 1):
            _fold_origins(i, row, masks[row - lo, i], known, bits, F)
