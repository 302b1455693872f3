"""Kernels of :mod:`dkfsim.protocols.tree`: the ``tree`` protocol's bookkeeping on origin sets.

The protocol's state is arrays (one row of little-endian uint64 words per origin set): per
window slot the origins each node holds (``held``), the last message and sequence number
received on each link (``inbox``, ``inseq``) and what each link last carried (``sent``);
the node-slots changed since each node's last flush (``dirty``); the nodes whose flush is due,
in the order they became due.  Three steps change it, each over many packets or nodes per
call: :func:`measure` (a row opens and every measuring node gains its own contribution),
:func:`receive` (the packets delivered at one instant, in the order they were sent) and
:func:`flush` (the due nodes, in order: each one's messages to its tree neighbours).  What a
node newly holds is written to the gains of the output (the caller reports it to the run's
:class:`~dkfsim.model.holdings.Holdings`, in order); what it sends, to its parts, frames and
records.  The network is not here: which packets reach their receiver at the instant they
are sent is the port's answer (:meth:`dkfsim.network.port.RecordPort.lookahead`), handed in as
a table; :func:`flush` delivers those at once, as the port would have, before the next node
flushes, and stops after a node whose packets the table cannot answer for.

The arrays travel in two namedtuples (:class:`Tree`, :class:`Out`), few and packed, because a
compiled call pays for each array it is handed.  On the numba path these functions are
compiled (:class:`~dkfsim.core.jit.LazyKernels`); on the numpy path the same functions run as
Python (docs/design.md §4, "Kernel paths").
"""

from __future__ import annotations

from collections import namedtuple
from types import ModuleType

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("_popcount", "_gain", "_schedule", "_count_late", "_receive_packet", "_close", "measure", "receive",
            "_flush_node", "flush", "receive_flush", "schedule")
#: Steps inlined into the kernels that call them per packet, item or word.
_INLINE = ("_popcount", "_gain", "_schedule", "_count_late", "_receive_packet", "_close", "_flush_node")
_lazy = LazyKernels(__name__, _KERNELS, inline=_INLINE)

# CT indices: the open rows (LO .. HI; none while HI < LO), the due queue (head, length), the
# outputs' fill (gains, parts, frames, items), late contributions, stale items, whether the
# arrival log is kept, a packet's header bytes, a row's bytes, a part's extra bytes in a frame,
# and the rows up to which (exclusive) the caller made rows final (applied at the next call).
LO, HI, QHEAD, QLEN, NG, NP, NF, NI, LATE, STALE, LOGON, HEADER, ROWB, PARTB, FINAL = range(15)
#: Rows of ``Tree.node`` (per node): whether its flush is due, the due queue, each node's
#: out-links ``Tree.link[OUT, node[OUTPTR, j]:node[OUTPTR, j + 1]]``, late contributions.
DUE, QUEUE, OUTPTR, LATE_NODE = range(4)
#: Rows of ``Tree.link`` (per local link): its source, destination, the link back (-1: none),
#: whether it is in the current tree, the out-links in node order, the number of the last
#: packet sent on it, late packets delivered on it, its id in the network.
SRC, DST, REV, INTREE, OUT, LSEQ, LATE_LINK, LID = range(8)
#: Columns of ``Out.parts`` (per part, what :meth:`~dkfsim.network.port.RecordPort.send_records`
#: takes): link id, tag (its number on the link), its items ``START .. STOP`` of ``Out.recs``,
#: its size in bytes, whether :func:`flush` delivered it at once; and the local link.
P_LID, P_TAG, P_START, P_STOP, P_BYTES, P_DONE, P_LINK = range(7)
#: :func:`flush` returns: every due node flushed; stopped after a node with a packet the
#: lookahead could not answer for (send what is out, deliver, call again); stopped before a node
#: for want of room in the output (send what is out, call again).
DONE, ASK, ROOM = 0, 1, 2
#: Lookahead answers: the packet does not reach its receiver at this instant; it does (and the
#: exchange delivers it itself); unknown.
LATER, NOW, UNKNOWN = 0, 1, 2

#: The protocol's state (see the module): ``CT`` (scalars above); per slot ``rowid`` (the row
#: it holds, -1: none), ``held`` (slot x node x word), ``inbox`` and ``sent`` (slot x link x
#: word), ``inseq`` (slot x link); ``dirty`` (node x slot); ``node`` and ``link`` (the rows
#: above); with the arrival log the holdings of the last final rows (``fheld``, ``frow`` which
#: row each slot holds); two rows of scratch words ``word``.
Tree = namedtuple("Tree", "CT rowid held inbox inseq sent dirty node link fheld frow word")
#: What a call produced, in order: gains (``gain`` rows node, row, 1 for a late contribution
#: that goes to the arrival log only; ``gw`` its origin words); parts (``parts``,
#: the columns above); frames (``frames``: the end of its parts, its size); items (``recs``:
#: the row, then the origin words).
Out = namedtuple("Out", "gain gw parts frames recs")

_ONE = np.uint64(1)
_ZERO = np.uint64(0)


def compiled() -> ModuleType:
    """This module with its kernels compiled by numba (loaded from the disk cache after the
    first time)."""
    return _lazy.get()


def _popcount(m: np.uint64) -> int:
    """The number of set bits of the word ``m``."""
    c = 0
    while m != _ZERO:
        m &= m - _ONE
        c += 1
    return c


def _gain(X: Tree, O: Out, node: int, row: int | np.integer, bits: np.ndarray, log_only: int) -> None:
    """Record that ``node`` gained the origins ``bits`` of ``row`` (for the holdings and the
    arrival log, or, ``log_only``, the arrival log alone)."""
    g = X.CT[NG]
    X.CT[NG] = g + 1
    O.gain[0, g] = node
    O.gain[1, g] = row
    O.gain[2, g] = log_only
    for w in range(bits.shape[0]):
        O.gw[g, w] = bits[w]


def _schedule(X: Tree, node: int) -> None:
    """``node``'s flush is due (once until it runs), after those due before it."""
    if X.node[DUE, node] == 0:
        X.node[DUE, node] = 1
        q = X.CT[QLEN]
        if q == X.node.shape[1]:                   # full: drop the nodes already flushed
            h = X.CT[QHEAD]
            for k in range(h, q):
                X.node[QUEUE, k - h] = X.node[QUEUE, k]
            q -= h
            X.CT[QHEAD] = 0
        X.node[QUEUE, q] = node
        X.CT[QLEN] = q + 1


def _close(X: Tree) -> None:
    """Make final the rows the caller closed since the last call (their slots are free, and with
    the arrival log their holdings are kept for the late contributions to come)."""
    S = X.rowid.shape[0]
    while X.CT[LO] < X.CT[FINAL] and X.CT[LO] <= X.CT[HI]:
        row = X.CT[LO]
        slot = row % S
        if X.rowid[slot] == row:
            X.rowid[slot] = -1
            if X.CT[LOGON] != 0:
                h = row % X.frow.shape[0]
                X.frow[h] = row
                # element by element: a whole-array assignment compiles numba's shape-mismatch
                # message (about 6 s of the first run's compile)
                for i in range(X.held.shape[1]):
                    for w in range(X.held.shape[2]):
                        X.fheld[h, i, w] = X.held[slot, i, w]
        X.CT[LO] = row + 1


def _count_late(X: Tree, O: Out, node: int, row: int | np.integer, recs: np.ndarray, item: int) -> None:
    """Contributions ``recs[item, 1:]`` for ``row`` reached ``node`` after the row became final:
    one per (packet, row) without the arrival log; with it, one per contribution the node did
    not hold when the row became final (logged), every origin for a row older than the kept
    ones."""
    W = recs.shape[1] - 1
    if X.CT[LOGON] == 0:
        X.CT[LATE] += 1
        X.node[LATE_NODE, node] += 1
        return
    h = row % X.frow.shape[0]
    c = 0
    new = X.word[0]
    if X.frow[h] != row:
        for w in range(W):
            c += _popcount(recs[item, 1 + w])
    else:
        some = False
        for w in range(W):
            m = recs[item, 1 + w] & ~X.fheld[h, node, w]
            new[w] = m
            if m != _ZERO:
                some = True
                c += _popcount(m)
        if some:
            for w in range(W):
                X.fheld[h, node, w] |= new[w]
            _gain(X, O, node, row, new, 1)
    X.CT[LATE] += c
    X.node[LATE_NODE, node] += c


def _receive_packet(X: Tree, O: Out, e: int, seq: int, i0: int, i1: int, recs: np.ndarray) -> None:
    """Packet number ``seq`` on local link ``e`` carrying items ``i0 .. i1`` of ``recs``: a final
    row is late; an item older than the link's last for that row is stale; else it becomes the
    link's message for the row, and what is new to the receiver is gained (its flush is then
    due)."""
    S = X.rowid.shape[0]
    W = X.held.shape[2]
    j = X.link[DST, e]
    new = X.word[0]
    gained = False
    late = False
    for item in range(i0, i1):
        row = np.int64(recs[item, 0])
        slot = row % S
        if row < X.CT[LO] or row > X.CT[HI] or X.rowid[slot] != row:
            _count_late(X, O, j, row, recs, item)
            late = True
            continue
        if seq <= X.inseq[slot, e]:
            X.CT[STALE] += 1
            continue
        X.inseq[slot, e] = seq
        some = False
        for w in range(W):
            m = recs[item, 1 + w]
            X.inbox[slot, e, w] = m
            new[w] = m & ~X.held[slot, j, w]
            if new[w] != _ZERO:
                some = True
        if some:
            for w in range(W):
                X.held[slot, j, w] |= new[w]
            _gain(X, O, j, row, new, 0)
            X.dirty[j, slot] = 1
            gained = True
    if gained:
        _schedule(X, j)
    if late:
        X.link[LATE_LINK, e] += 1


def measure(X: Tree, O: Out, row: int, nodes: np.ndarray, fresh: np.ndarray) -> None:
    """``row`` opens (newer than every open row: its slot is cleared); on each local link of
    ``fresh`` (links new to the tree, whose senders are up, in order) the sender forgets what it
    last sent and has every open row to send; then every node of ``nodes`` (those that measure
    now, in order) gains its own contribution to the row.  The flushes of all of them are due."""
    _close(X)
    S = X.rowid.shape[0]
    slot = row % S
    X.rowid[slot] = row
    X.held[slot] = _ZERO
    X.inbox[slot] = _ZERO
    X.inseq[slot] = 0
    X.sent[slot] = _ZERO
    for i in range(X.dirty.shape[0]):
        X.dirty[i, slot] = 0
    if X.CT[HI] < X.CT[LO]:
        X.CT[LO] = row
    X.CT[HI] = row
    for k in range(fresh.shape[0]):
        e = fresh[k]
        j = X.link[SRC, e]
        for r in range(X.CT[LO], X.CT[HI] + 1):
            s = r % S
            X.sent[s, e] = _ZERO
            X.dirty[j, s] = 1
        _schedule(X, j)
    new = X.word[0]
    for k in range(nodes.shape[0]):
        i = nodes[k]
        new[:] = _ZERO
        new[i >> 6] = _ONE << np.uint64(i & 63)
        X.held[slot, i, i >> 6] |= new[i >> 6]
        _gain(X, O, i, row, new, 0)
        X.dirty[i, slot] = 1
        _schedule(X, i)


def receive(X: Tree, O: Out, batch: np.ndarray, recs: np.ndarray, local: np.ndarray) -> None:
    """The packets delivered now, in the order they were sent: packet ``k`` came over link id
    ``batch[k, 0]`` (local link ``local[id]``) as number ``batch[k, 1]`` and carries the items
    ``batch[k, 2] .. batch[k, 3]`` of ``recs``."""
    _close(X)
    for k in range(batch.shape[0]):
        _receive_packet(X, O, local[batch[k, 0]], batch[k, 1], batch[k, 2], batch[k, 3], recs)


def schedule(X: Tree, node: int) -> None:
    """:func:`_schedule` (for the caller: a node with news outside the kernels)."""
    _schedule(X, node)


def _flush_node(X: Tree, O: Out, j: int, ahead: np.ndarray, used: np.ndarray) -> bool:
    """Node ``j``'s flush: for each open row it changed (ascending), each out-link in the tree
    whose message -- what ``j`` holds but what came from that neighbour -- differs from the
    last one it carried gets the row; the links with rows make one frame.  Returns whether a
    part's fate at this instant is unknown (:data:`UNKNOWN`); otherwise the parts that reach
    their receiver now are delivered, in order."""
    S = X.rowid.shape[0]
    W = X.held.shape[2]
    lo, hi = X.CT[LO], X.CT[HI]
    any_row = False
    for row in range(lo, hi + 1):
        if X.dirty[j, row % S]:
            any_row = True
            break
    if not any_row:
        return False
    p0 = X.CT[NP]
    i = X.CT[NI]
    out = X.word[1]
    # (parts are built link by link, one pass over the rows per out-link, which keeps the items
    # of a part together; each (row, link) is computed as a row-major pass would)
    for k in range(X.node[OUTPTR, j], X.node[OUTPTR, j + 1]):
        e = X.link[OUT, k]
        if X.link[INTREE, e] == 0:
            continue
        r = X.link[REV, e]
        i0 = i
        for row in range(lo, hi + 1):
            s = row % S
            if not X.dirty[j, s]:
                continue
            changed = False
            for w in range(W):
                m = X.held[s, j, w]
                if r >= 0:
                    m &= ~X.inbox[s, r, w]
                out[w] = m
                if m != X.sent[s, e, w]:
                    changed = True
            if not changed:
                continue
            O.recs[i, 0] = np.uint64(row)
            for w in range(W):
                X.sent[s, e, w] = out[w]
                O.recs[i, 1 + w] = out[w]
            i += 1
        if i > i0:
            p = X.CT[NP]
            X.CT[NP] = p + 1
            X.link[LSEQ, e] += 1
            O.parts[p, P_LID] = X.link[LID, e]
            O.parts[p, P_TAG] = X.link[LSEQ, e]
            O.parts[p, P_START] = i0
            O.parts[p, P_STOP] = i
            O.parts[p, P_BYTES] = X.CT[HEADER] + (i - i0) * X.CT[ROWB]
            O.parts[p, P_DONE] = 0
            O.parts[p, P_LINK] = e
    for row in range(lo, hi + 1):
        X.dirty[j, row % S] = 0
    X.CT[NI] = i
    p1 = X.CT[NP]
    if p1 == p0:
        return False
    f = X.CT[NF]
    X.CT[NF] = f + 1
    O.frames[f, 0] = p1
    size = X.CT[HEADER]
    unknown = False
    for p in range(p0, p1):
        size += X.CT[PARTB] + (O.parts[p, P_STOP] - O.parts[p, P_START]) * X.CT[ROWB]
        e = O.parts[p, P_LINK]
        u = used[e]
        used[e] = u + 1
        state = ahead[e, u] if u < ahead.shape[1] else UNKNOWN
        if state == UNKNOWN:
            unknown = True
        elif state == NOW:
            O.parts[p, P_DONE] = 1
    O.frames[f, 1] = size
    if unknown:                       # the port delivers this flush's packets in the order sent
        for p in range(p0, p1):
            O.parts[p, P_DONE] = 0
        return True
    for p in range(p0, p1):
        if O.parts[p, P_DONE]:
            _receive_packet(X, O, O.parts[p, P_LINK], O.parts[p, P_TAG], O.parts[p, P_START], O.parts[p, P_STOP],
                            O.recs)
    return False


def flush(X: Tree, O: Out, ahead: np.ndarray, used: np.ndarray) -> int:
    """Flush the due nodes from the head of the queue, in order (each flush's packets that
    reach their receiver now delivered before the next node flushes, as the port would); stop
    after a node with a packet whose fate at this instant ``ahead`` cannot answer for
    (:data:`ASK`), or before a node for want of room (:data:`ROOM`).  ``ahead[e, u]``: the fate
    of the ``u``-th packet from now on local link ``e`` (:data:`LATER`, :data:`NOW`,
    :data:`UNKNOWN`), ``used[e]`` how many of them this call sent."""
    _close(X)
    S = X.rowid.shape[0]
    span = X.CT[HI] - X.CT[LO] + 1
    if span < 0:
        span = 0
    if span > S:
        span = S
    while X.CT[QHEAD] < X.CT[QLEN]:
        j = X.node[QUEUE, X.CT[QHEAD]]
        deg = X.node[OUTPTR, j + 1] - X.node[OUTPTR, j]
        # room for this node's parts, items and the gains of delivering them at once
        if (X.CT[NP] + deg > O.parts.shape[0] or X.CT[NI] + deg * span > O.recs.shape[0]
                or X.CT[NG] + deg * span > O.gain.shape[1] or X.CT[NF] + 1 > O.frames.shape[0]):
            if X.CT[NP] == 0 and X.CT[NG] == 0:
                return -1                            # (the output cannot hold one node: a bug)
            return ROOM
        X.CT[QHEAD] += 1
        X.node[DUE, j] = 0
        if _flush_node(X, O, j, ahead, used):
            return ASK
    X.CT[QHEAD] = 0
    X.CT[QLEN] = 0
    return DONE


def receive_flush(X: Tree, O: Out, batch: np.ndarray, recs: np.ndarray, local: np.ndarray, ahead: np.ndarray,
                  used: np.ndarray) -> int:
    """:func:`receive`, then :func:`flush`: the packets delivered now, and the flushes they made
    due at this instant, in one call (what the two calls do one after the other)."""
    receive(X, O, batch, recs, local)
    return flush(X, O, ahead, used)
