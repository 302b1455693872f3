"""Kernels of :mod:`dkfsim.protocols.tree_compiled`: the ``tree`` protocol's instants, compiled.

One call, :func:`tick`, runs a tick of :class:`~dkfsim.protocols.tree.TreeExchange` and its
port: every instant since the last tick at which packets arrived (:func:`advance`: at each,
:func:`deliver` the packets due, in the order they were sent, then :func:`flush_all` the
nodes that gained something, each flush's zero-latency packets delivered before the next
node flushes), then the tick's own instant (its deliveries before or after :func:`measure`
opens the new row, as their SimPy events would have come, then the flushes).  Packets wait
in a binary heap ordered by (arrival instant, send order); their latencies are the links'
keyed draws (:func:`dkfsim.core.streams.keyed_uniform`, bit for bit) for ``constant`` and
``uniform_steps`` links.  New contributions are folded straight into the run's
:class:`~dkfsim.model.holdings.Holdings` (:func:`dkfsim.model.holdings_kernels.fold`, inlined
here; its file is pinned by sha256, :data:`BORROWS`), in the order the Python protocol
reports them, so the sums are the same numbers.

The kernels' arrays are grouped in the module-level namedtuples below (:class:`Rows` the
exchange's window rows, :class:`Links` the out-links, :class:`Pool` the packets in flight,
:class:`Log` the arrival log) and the holdings' :class:`~dkfsim.model.holdings_kernels.Fold`:
numba loads a kernel taking namedtuples from its disk cache like one taking arrays, and a
namedtuple type must be importable by name for that.  The steps a kernel runs per packet or contribution
are inlined into it (``_INLINE``) and read the namedtuples' fields in place (``X.held[...]``):
bound to locals at the top of a step, the fields left reference counting in the packet loop
that numba could not remove (docs/decisions.md 120).  The scalar state lives in one int64
array ``Rows.CT`` (indices below); origin sets are rows of little-endian uint64 words.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from dkfsim.core.jit import LazyKernels
from dkfsim.model import holdings_kernels as hk

_KERNELS = ("keyed_uniform", "_log_arrivals", "_push", "_pop", "_enqueue", "_receive", "deliver", "measure", "_pack",
            "_accept", "_next_background", "_background", "_send", "flush_all", "advance", "tick",
            "start_background", "traffic_until")
#: Steps inlined into the kernels that call them per packet or contribution.
_INLINE = ("_log_arrivals", "_push", "_pop", "_enqueue", "_receive", "deliver", "_pack", "_accept",
           "_next_background", "_background", "_send", "flush_all")
#: Kernel files of other modules whose steps these kernels inline, with the sha256 of the
#: file they were written against: numba's cache does not see an edit there, so after one
#: these kernels compile without the cache until the pin is updated (docs/decisions.md 131).
BORROWS = {"dkfsim.model.holdings_kernels": "f5ba9bd99b4d6598cc258c4188fda9f3e2d0e1645766f96dd735e008fe277ffd"}
_lazy = LazyKernels(__name__, _KERNELS, inline=_INLINE, borrows=BORROWS)

# CT indices: heap size, free packets, due queue (head, length), open rows (LO..HI), packets
# pushed so far (send order), late, stale, queueing delays kept, the instant being run between
# ticks, the tick's phase and its mark (:func:`tick`).
HEAP, NFREE, QHEAD, QLEN, LO, HI, ORDER, LATE, STALE, ND, NOW, PHASE, MARK = range(13)
#: Flag returned by :func:`flush_all`, :func:`advance` and :func:`tick` when the packet pool
#: (or the queueing delays' array) is full: grow it and call again (the call resumes).
NEED_ROOM = -2

#: The exchange's window rows (slot ``row % S``): which row a slot holds (``rowid``, -1 once
#: final), the origins each node holds (``held``, slot x node x word), the last message and
#: sequence number received on each link (``inbox``, ``inseq``), what each link last carried
#: (``sent``), the node-slots changed since the node's last flush (``dirty``), the nodes whose
#: flush is due and their order (``due``, ``queue``), the scalar counters ``CT``, and one
#: origin set of scratch each for folding (``new``) and sending (``out``).
Rows = namedtuple("Rows", "CT rowid held inbox inseq sent dirty due queue new out")
#: The links: ``G`` (source, destination, reverse link or -1, 0) per link, each node's out-links
#: (``out_idx[out_ptr[j]:out_ptr[j + 1]]``), the latency as ``kind`` (0: a constant ``par`` ns;
#: 1: uniform_steps, ``d_t = par``, drawn from ``key``), per link the last send instant, the
#: sends at it and the last sequence number (``dinst``, ``dcnt``, ``seq``), the counts (sent,
#: delivered, late packets, bytes) per link and the late contributions per node; a packet's
#: ``header`` and per-row bytes, and the tick ``T_ns``.
Links = namedtuple("Links", "G out_ptr out_idx kind key par dinst dcnt seq counts late_node header row_bytes T_ns")
#: The links' transmitters, passed as ``T`` (docs/design.md §3; the twin of
#: :class:`dkfsim.network.transmitter.Transmitter`), or None when no link has a rate: the kernels
#: are then compiled without them, the packet loop as it was before transmitters (docs/decisions.md
#: 159).  Per link ``rate`` (bits/s, 0: none), the waiting room ``qcap`` (packets, -1: unbounded)
#: and the start instants of the packets waiting in it (``ring`` from ``rhead``, ``rlen`` of them),
#: ``free_at`` and ``busy`` ns, the background (``bgk`` 0 none, 1 Poisson, 2 periodic; keys
#: ``bgkey``, ``bgskey``; ``bgper`` ns between packets, ``bgsize`` bytes, ``bgexp`` exponential
#: sizes, ``bgoff`` ns; the next packet's index, instant and size ``bgi``, ``bgt``, ``bgs``;
#: ``bgc`` sent and dropped) and ``qdrop``.
Tx = namedtuple("Tx", "rate qcap ring rhead rlen free_at busy bgk bgkey bgskey bgper bgsize bgexp bgoff bgi bgt bgs "
                      "bgc qdrop")
#: The packets in flight: the heap (arrival instant, send order, packet), the free packet slots,
#: per packet (link, sequence number, rows) in ``pk`` and its rows and origin sets, and the
#: packet being filled per out-link of the flushing node (``outp``, -1: none).
#: ``dly``/``dlk``: the queueing delay (ns) and link of every packet a transmitter accepted
#: (``CT[ND]`` of them), its hand-over instant ``dlt`` and size ``dls`` (bytes): the link's
#: interval log is replayed from them (:meth:`CompiledTreeExchange._link_stats`).
Pool = namedtuple("Pool", "heap_t heap_o heap_p free pk rows masks outp dly dlk dlt dls")
#: The arrival log (``on``: kept): ``arrival`` (node, origin, row) in seconds, and the holdings
#: ``fheld`` of the last final rows ``frow``, so that a late contribution counts once.
Log = namedtuple("Log", "on arrival fheld frow")

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_ONE = np.uint64(1)
_ZERO = np.uint64(0)
_SCALE = 1.0 / 9007199254740992.0
_MAX_NS = 1 << 62
_MAX_GAP_NS = 1 << 49
#: The latest instant (ns): a transmitter's background that never comes.
MAX_NS = _MAX_NS


def compiled():
    """This module with its kernels compiled by numba (loaded from the disk cache after the
    first time)."""
    return _lazy.get()


def keyed_uniform(key, t, seq):
    """:func:`dkfsim.core.streams.keyed_uniform` in uint64 arithmetic (the same bits)."""
    z = key + _GOLDEN * np.uint64(t)
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    z = (z ^ (z >> _S31)) + _GOLDEN * np.uint64(seq + 1)
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return (np.float64((z ^ (z >> _S31)) >> _S11) + 0.5) * _SCALE


def _log_arrivals(node, row, bits, t_s, log):
    """With the arrival log on, log that ``node`` gained the origins ``bits`` (words) of
    ``row`` at ``t_s`` seconds."""
    for w in range(bits.shape[0]):
        m = bits[w]
        while m != _ZERO:
            low = m & (~m + _ONE)
            m ^= low
            log.arrival[node, w * 64 + hk.bit_index(low), row] = t_s


def _push(CT, P, t, p):
    """Put packet ``p`` due at ``t`` on the heap (ties: send order)."""
    k = CT[HEAP]
    CT[HEAP] = k + 1
    o = CT[ORDER]
    CT[ORDER] = o + 1
    while k > 0:
        up = (k - 1) // 2
        if P.heap_t[up] < t or (P.heap_t[up] == t and P.heap_o[up] < o):
            break
        P.heap_t[k], P.heap_o[k], P.heap_p[k] = P.heap_t[up], P.heap_o[up], P.heap_p[up]
        k = up
    P.heap_t[k], P.heap_o[k], P.heap_p[k] = t, o, p


def _pop(CT, P):
    """Remove the heap's first packet and return it."""
    top = P.heap_p[0]
    n = CT[HEAP] - 1
    CT[HEAP] = n
    t, o, p = P.heap_t[n], P.heap_o[n], P.heap_p[n]
    k = 0
    while True:
        c = 2 * k + 1
        if c >= n:
            break
        if c + 1 < n and (P.heap_t[c + 1] < P.heap_t[c]
                          or (P.heap_t[c + 1] == P.heap_t[c] and P.heap_o[c + 1] < P.heap_o[c])):
            c += 1
        if t < P.heap_t[c] or (t == P.heap_t[c] and o < P.heap_o[c]):
            break
        P.heap_t[k], P.heap_o[k], P.heap_p[k] = P.heap_t[c], P.heap_o[c], P.heap_p[c]
        k = c
    P.heap_t[k], P.heap_o[k], P.heap_p[k] = t, o, p
    return top


def _receive(p, now, X, L, P, F, log):
    """The Python protocol's ``receive`` for pooled packet ``p`` (then its slot is free).

    A row already final is late: one per (packet, row), or with the arrival log one per
    contribution the receiver did not hold when the row became final (``log.fheld``: the
    holdings of the last final rows, ``log.frow`` which), logged; older rows count every origin."""
    S = X.rowid.shape[0]
    W = X.held.shape[2]
    e = P.pk[p, 0]
    seq = P.pk[p, 1]
    j = L.G[e, 1]
    L.counts[1, e] += 1                            # delivered
    late = 0
    any_late = False
    gained = False
    t_s = now / 1e9
    for q in range(P.pk[p, 2]):
        row = P.rows[p, q]
        slot = row % S
        if X.rowid[slot] != row:
            any_late = True
            if not log.on:
                late += 1
                continue
            h = row % log.frow.shape[0]
            for w in range(W):
                m = P.masks[p, q, w]
                if log.frow[h] == row:
                    m &= ~log.fheld[h, j, w]
                    log.fheld[h, j, w] |= m
                while m != _ZERO:
                    low = m & (~m + _ONE)
                    m ^= low
                    late += 1
                    if log.frow[h] == row:
                        log.arrival[j, w * 64 + hk.bit_index(low), row] = t_s
            continue
        if seq <= X.inseq[slot, e]:
            X.CT[STALE] += 1
            continue
        X.inseq[slot, e] = seq
        some = False
        for w in range(W):
            m = P.masks[p, q, w]
            X.inbox[slot, e, w] = m
            X.new[w] = m & ~X.held[slot, j, w]
            if X.new[w] != _ZERO:
                some = True
        if some:
            for w in range(W):
                X.held[slot, j, w] |= X.new[w]
            hk.fold(j, row, X.new, F)
            if log.on:
                _log_arrivals(j, row, X.new, t_s, log)
            X.dirty[j, slot] = 1
            gained = True
    if any_late:
        X.CT[LATE] += late
        L.late_node[j] += late
        L.counts[2, e] += 1                        # late packets
    if gained:
        _enqueue(j, X)


def _enqueue(j, X):
    """Node ``j``'s flush is due (once until it runs), after those due before it."""
    if not X.due[j]:
        X.due[j] = 1
        X.queue[(X.CT[QHEAD] + X.CT[QLEN]) % X.queue.shape[0]] = j
        X.CT[QLEN] += 1


def deliver(now, X, L, P, F, log):
    """Deliver every packet due at ``now`` (send order)."""
    while X.CT[HEAP] > 0 and P.heap_t[0] <= now:
        p = _pop(X.CT, P)
        _receive(p, now, X, L, P, F, log)
        P.free[X.CT[NFREE]] = p
        X.CT[NFREE] += 1


def measure(row, now, X, F, log):
    """Open ``row`` and give every node its own contribution (the Python ``measure``)."""
    n = X.held.shape[1]
    S = X.rowid.shape[0]
    slot = row % S
    X.rowid[slot] = row
    X.held[slot] = _ZERO
    X.inbox[slot] = _ZERO
    X.inseq[slot] = 0
    X.sent[slot] = _ZERO
    for i in range(n):
        X.dirty[i, slot] = 0
    X.CT[HI] = row
    for i in range(n):
        X.new[:] = _ZERO
        X.new[i // 64] = _ONE << np.uint64(i % 64)
        X.held[slot, i, i // 64] |= X.new[i // 64]
        hk.fold(i, row, X.new, F)
        if log.on:
            _log_arrivals(i, row, X.new, now / 1e9, log)
        X.dirty[i, slot] = 1
        _enqueue(i, X)


def _pack(j, deg, X, L, P):
    """Node ``j``'s flush: for each open row it changed, each out-link whose message would
    differ from the last one sent gets the row (what ``j`` holds minus what that neighbour
    sent it) in its packet ``P.outp[k]``, taken from the pool when the link has none yet."""
    S = X.rowid.shape[0]
    W = X.held.shape[2]
    lo = max(X.CT[LO], X.CT[HI] - S + 1)
    for row in range(lo, X.CT[HI] + 1):
        s = row % S
        if X.rowid[s] != row or not X.dirty[j, s]:
            continue
        X.dirty[j, s] = 0
        for k in range(deg):
            e = L.out_idx[L.out_ptr[j] + k]
            r = L.G[e, 2]
            changed = False
            for w in range(W):
                X.out[w] = X.held[s, j, w] & ~X.inbox[s, r, w]
                if X.out[w] != X.sent[s, e, w]:
                    changed = True
            if not changed:
                continue
            p = P.outp[k]
            if p < 0:
                X.CT[NFREE] -= 1
                p = P.free[X.CT[NFREE]]
                P.outp[k] = p
                P.pk[p, 2] = 0
            q = P.pk[p, 2]
            P.pk[p, 2] = q + 1
            P.rows[p, q] = row
            for w in range(W):
                X.sent[s, e, w] = X.out[w]
                P.masks[p, q, w] = X.out[w]


def _accept(e, t, size, T):
    """:meth:`Transmitter._accept <dkfsim.network.transmitter.Transmitter>`: a packet of
    ``size`` bytes handed to link ``e``'s transmitter at ``t``; its start ns, or -1 (dropped)."""
    cap = T.qcap[e]
    if cap > 0:
        while T.rlen[e] > 0 and T.ring[e, T.rhead[e]] <= t:
            T.rhead[e] = (T.rhead[e] + 1) % cap
            T.rlen[e] -= 1
    start = T.free_at[e] if T.free_at[e] > t else t
    if start > t and cap >= 0 and T.rlen[e] >= cap:
        return -1
    ns = size * 8.0 * 1e9 / T.rate[e]
    tx = _MAX_NS if ns >= _MAX_NS else int(ns + 0.5)
    end = start + tx
    if end > _MAX_NS:
        end = _MAX_NS
    T.free_at[e] = end
    T.busy[e] += end - start
    if start > t and cap > 0:
        T.ring[e, (T.rhead[e] + T.rlen[e]) % cap] = start
        T.rlen[e] += 1
    return start


def _next_background(e, T):
    """Draw link ``e``'s next background packet (index ``bgi + 1``, after the one at ``bgt``;
    the first from ``bgi = -1``, ``bgt = 0``) as
    :class:`~dkfsim.network.transmitter.BackgroundArrivals` draws it."""
    i = T.bgi[e] + 1
    T.bgi[e] = i
    if T.bgk[e] == 1:
        g = np.floor(-np.log(keyed_uniform(T.bgkey[e], i, 0)) * T.bgper[e] + 0.5)
        if g > _MAX_GAP_NS:
            g = _MAX_GAP_NS
        t = T.bgt[e] + np.int64(g)
    else:
        f = i * T.bgper[e] + 0.5
        if f > _MAX_NS:
            f = _MAX_NS
        f = T.bgoff[e] + np.floor(f)
        t = _MAX_NS if f >= _MAX_NS else np.int64(f)
    T.bgt[e] = _MAX_NS if t > _MAX_NS else t
    if T.bgexp[e]:
        sz = np.floor(-np.log(keyed_uniform(T.bgskey[e], i, 0)) * T.bgsize[e] + 0.5)
        T.bgs[e] = 1 if sz < 1 else np.int64(sz)
    else:
        T.bgs[e] = np.int64(T.bgsize[e])


def _background(e, now, T):
    """Link ``e``'s background packets up to and including ``now`` into its transmitter."""
    while T.bgk[e] != 0 and T.bgt[e] <= now:
        if _accept(e, T.bgt[e], T.bgs[e], T) < 0:
            T.bgc[1, e] += 1
        else:
            T.bgc[0, e] += 1
        _next_background(e, T)


def start_background(T):
    """Draw every background's first packet (``bgi = -1``, ``bgt = 0`` before)."""
    for e in range(T.bgk.shape[0]):
        if T.bgk[e] != 0:
            _next_background(e, T)


def traffic_until(now, T):
    """Every transmitter's background up to ``now`` (the end of the run, for the statistics)."""
    for e in range(T.rate.shape[0]):
        if T.rate[e] > 0:
            _background(e, now, T)


def _send(j, deg, now, X, L, T, P):
    """Send node ``j``'s filled packets: stamp link and sequence number, draw the latency
    (the link's keyed draw), count, and put each on the heap (after its transmission on a
    rate-limited link, unless the waiting room drops it)."""
    for k in range(deg):
        p = P.outp[k]
        if p < 0:
            continue
        P.outp[k] = -1
        e = L.out_idx[L.out_ptr[j] + k]
        L.seq[e] += 1
        P.pk[p, 0] = e
        P.pk[p, 1] = L.seq[e]
        if L.dinst[e] != now:
            L.dinst[e] = now
            L.dcnt[e] = 0
        d = L.dcnt[e]
        L.dcnt[e] = d + 1
        size = L.header + P.pk[p, 2] * L.row_bytes
        L.counts[0, e] += 1
        L.counts[3, e] += size
        base = now
        if T is not None and T.rate[e] > 0:    # (no transmitters: compiled away)
            _background(e, now, T)
            start = _accept(e, now, size, T)
            if start < 0:                      # the waiting room is full: dropped
                T.qdrop[e] += 1
                P.free[X.CT[NFREE]] = p
                X.CT[NFREE] += 1
                continue
            P.dly[X.CT[ND]] = start - now
            P.dlk[X.CT[ND]] = e
            P.dlt[X.CT[ND]] = now
            P.dls[X.CT[ND]] = size
            X.CT[ND] += 1
            base = T.free_at[e]
        if L.kind[e] == 0:
            lat = L.par[e]
        else:
            v = int(keyed_uniform(L.key[e], now, d) * (L.par[e] + 1))
            lat = min(v, L.par[e]) * L.T_ns
        _push(X.CT, P, base + lat, p)


def flush_all(now, until, X, L, T, P, F, log):
    """Deliver the packets due at ``now``, then flush the due nodes, first due first; after
    each flush the zero-latency packets are delivered (they may make more nodes due).  Packets
    with a latency go on the heap.  Returns :data:`NEED_ROOM` if the pool has fewer free
    packets than the next node has out-links (nothing of that node done yet; call again)."""
    while True:
        if now <= until:
            deliver(now, X, L, P, F, log)
        if X.CT[QLEN] == 0:
            return 0
        j = X.queue[X.CT[QHEAD]]
        deg = L.out_ptr[j + 1] - L.out_ptr[j]
        if X.CT[NFREE] < deg or X.CT[ND] + deg > P.dly.shape[0]:
            return NEED_ROOM
        X.CT[QHEAD] = (X.CT[QHEAD] + 1) % X.queue.shape[0]
        X.CT[QLEN] -= 1
        X.due[j] = 0
        _pack(j, deg, X, L, P)
        _send(j, deg, now, X, L, T, P)


def advance(limit, until, mark, X, L, T, P, F, log):
    """Every instant before ``limit`` (and not after ``until``) at which packets arrive, in
    order: deliver them, then flush the nodes that gained something (what the port's delivery
    event and the flush event of that instant did; :func:`flush_all`).  Then, if the first
    packet due at ``limit`` was sent before ``mark`` (the send order when the tick began),
    deliver the packets due at ``limit`` now: their SimPy event was made before the tick's
    measure was scheduled, so it came first.  Returns :data:`NEED_ROOM` (call again after
    growing the pool) or 0."""
    while True:
        if X.CT[QLEN] == 0:                    # (else: an instant a full pool interrupted)
            if X.CT[HEAP] == 0:
                return 0
            t = P.heap_t[0]
            if t > until:
                return 0
            if t >= limit:
                if t == limit and P.heap_o[0] < mark:
                    deliver(t, X, L, P, F, log)
                return 0
            X.CT[NOW] = t
        if flush_all(X.CT[NOW], until, X, L, T, P, F, log) == NEED_ROOM:
            return NEED_ROOM


def tick(row, now, until, X, L, T, P, F, log):
    """The tick at ``now`` that opens ``row``: :func:`advance` to ``now``, then :func:`measure`,
    then :func:`flush_all` (the packets due at ``now`` not delivered yet first).  Returns
    :data:`NEED_ROOM` (grow the pool and call again with the same arguments: the tick resumes
    where it stopped, ``CT[PHASE]``) or 0.  ``row < 0``: nothing (the entry point's first call)."""
    if row < 0:
        return 0
    if X.CT[PHASE] == 0:
        X.CT[MARK] = X.CT[ORDER]
        X.CT[PHASE] = 1
    if X.CT[PHASE] == 1:
        if advance(now, until, X.CT[MARK], X, L, T, P, F, log) == NEED_ROOM:
            return NEED_ROOM
        measure(row, now, X, F, log)
        X.CT[PHASE] = 2
    if flush_all(now, until, X, L, T, P, F, log) == NEED_ROOM:
        return NEED_ROOM
    X.CT[PHASE] = 0
    return 0
