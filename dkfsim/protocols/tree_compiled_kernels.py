"""Kernels of :mod:`dkfsim.protocols.tree_compiled`: the ``tree`` protocol's instants, compiled.

One call handles what one event of :class:`~dkfsim.protocols.tree.TreeExchange` and its
port would do at an instant: :func:`deliver` the packets due now (in the order they were
sent), :func:`measure` a new row, or :func:`flush_all` the nodes that gained something
(each flush's zero-latency packets delivered before the next node flushes).  Packets wait
in a binary heap ordered by (arrival instant, send order); their latencies are the links'
keyed draws (:func:`dkfsim.core.streams.keyed_uniform`, bit for bit) for ``constant`` and
``uniform_steps`` links.  New contributions are folded straight into the window filter's
ring, in the order the Python protocol reports them, so the sums are the same numbers.

The kernels' arrays are grouped in the module-level namedtuples below (:class:`Rows` the
exchange's window rows, :class:`Links` the out-links, :class:`Pool` the packets in flight,
:class:`Fold` the window filter they fold into, :class:`Log` the arrival log): numba loads a
kernel taking namedtuples from its disk cache like one taking arrays, and a namedtuple type
must be importable by name for that.  The scalar state lives in one int64 array ``Rows.CT``
(indices below); origin sets are rows of little-endian uint64 words.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("keyed_uniform", "_bit", "_fold", "fold_masks", "_push", "_pop", "_enqueue", "_receive", "deliver",
            "measure", "_pack", "_send", "flush_all")
_lazy = LazyKernels(__name__, _KERNELS)

# CT indices
HEAP, NFREE, QHEAD, QLEN, LO, HI, ORDER, LATE, STALE, NEWT, NTIMES = range(11)
#: Flag returned by :func:`flush_all` when the packet pool is full (grow it and call again).
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
#: The packets in flight: the heap (arrival instant, send order, packet), the free packet slots,
#: per packet (link, sequence number, rows) in ``pk`` and its rows and origin sets; the future
#: arrival instants that have an event (``times``), those new since the flush began (``newt``),
#: and the packet being filled per out-link of the flushing node (``outp``, -1: none).
Pool = namedtuple("Pool", "heap_t heap_o heap_p free pk rows masks times newt outp")
#: Where contributions are folded: the window filter's weights ``A`` (node x origin), the
#: information ``omega`` (1 or K, origin, nx, nx; per row when ``varying``) and ``theta``, and its
#: ring: ``Omega``, ``Theta``, ``held`` (slot x node x origin; no origin axis when the fusion
#: does not need it) and ``starts`` (each node's earliest changed row).
Fold = namedtuple("Fold", "A omega varying theta Omega Theta held starts")
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
#: De Bruijn multiplication: the index of a word's lowest set bit without scanning the others.
_DEBRUIJN = 0x03F79D71B4CB0A89
_BIT_INDEX = np.zeros(64, dtype=np.int64)
for _i in range(64):
    _BIT_INDEX[(((1 << _i) * _DEBRUIJN) & ((1 << 64) - 1)) >> 58] = _i
_DB = np.uint64(_DEBRUIJN)
_S58 = np.uint64(58)


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


def _bit(low):
    """The index of the one set bit of ``low`` (a word's lowest set bit, ``m & -m``)."""
    return _BIT_INDEX[(low * _DB) >> _S58]


def _fold(node, row, bits, F, t_s, log):
    """Add origins ``bits`` (words) of ``row`` to ``node``'s sums, origins ascending; with the
    log on, log each origin's arrival at ``t_s`` seconds."""
    A, omega, theta, Omega, Theta, held = F.A, F.omega, F.theta, F.Omega, F.Theta, F.held
    S = Omega.shape[0]
    nx = Omega.shape[2]
    slot = row % S
    r_om = row if F.varying else 0
    for w in range(bits.shape[0]):
        m = bits[w]
        while m != _ZERO:
            low = m & (~m + _ONE)
            m ^= low
            org = w * 64 + _bit(low)
            a = A[node, org]
            if held.shape[2]:                      # only kept when the fusion needs it
                held[slot, node, org] = True
            if log.on:
                log.arrival[node, org, row] = t_s
            for p in range(nx):
                for q in range(nx):
                    Omega[slot, node, p, q] += a * omega[r_om, org, p, q]
                Theta[slot, node, p] += a * theta[row, org, p]
    if row < F.starts[node]:
        F.starts[node] = row


def fold_masks(i, r, words, F):
    """:func:`_fold` for many contributions, in order: ``words[k]`` holds the origins of node
    ``i[k]`` for row ``r[k]`` (the window filter's fold of what a Python protocol reported)."""
    nolog = Log(False, np.empty((1, 1, 1)), np.empty((1, 1, 1), dtype=np.uint64), np.empty(1, dtype=np.int64))
    for k in range(i.shape[0]):
        _fold(i[k], r[k], words[k], F, 0.0, nolog)


def _push(CT, P, t, p):
    """Put packet ``p`` due at ``t`` on the heap (ties: send order)."""
    heap_t, heap_o, heap_p = P.heap_t, P.heap_o, P.heap_p
    k = CT[HEAP]
    CT[HEAP] = k + 1
    o = CT[ORDER]
    CT[ORDER] = o + 1
    while k > 0:
        up = (k - 1) // 2
        if heap_t[up] < t or (heap_t[up] == t and heap_o[up] < o):
            break
        heap_t[k], heap_o[k], heap_p[k] = heap_t[up], heap_o[up], heap_p[up]
        k = up
    heap_t[k], heap_o[k], heap_p[k] = t, o, p


def _pop(CT, P):
    """Remove the heap's first packet and return it."""
    heap_t, heap_o, heap_p = P.heap_t, P.heap_o, P.heap_p
    top = heap_p[0]
    n = CT[HEAP] - 1
    CT[HEAP] = n
    t, o, p = heap_t[n], heap_o[n], heap_p[n]
    k = 0
    while True:
        c = 2 * k + 1
        if c >= n:
            break
        if c + 1 < n and (heap_t[c + 1] < heap_t[c] or (heap_t[c + 1] == heap_t[c] and heap_o[c + 1] < heap_o[c])):
            c += 1
        if t < heap_t[c] or (t == heap_t[c] and o < heap_o[c]):
            break
        heap_t[k], heap_o[k], heap_p[k] = heap_t[c], heap_o[c], heap_p[c]
        k = c
    heap_t[k], heap_o[k], heap_p[k] = t, o, p
    return top


def _receive(p, now, X, L, P, F, log):
    """The Python protocol's ``receive`` for pooled packet ``p`` (then its slot is free).

    A row already final is late: one per (packet, row), or with the arrival log one per
    contribution the receiver did not hold when the row became final (``log.fheld``: the
    holdings of the last final rows, ``log.frow`` which), logged; older rows count every origin."""
    CT, rowid, held, inbox, inseq, new = X.CT, X.rowid, X.held, X.inbox, X.inseq, X.new
    counts = L.counts
    pk, pk_rows, pk_masks = P.pk, P.rows, P.masks
    fheld, frow = log.fheld, log.frow
    S = rowid.shape[0]
    W = held.shape[2]
    e = pk[p, 0]
    seq = pk[p, 1]
    j = L.G[e, 1]
    counts[1, e] += 1                              # delivered
    late = 0
    any_late = False
    gained = False
    t_s = now / 1e9
    for q in range(pk[p, 2]):
        row = pk_rows[p, q]
        slot = row % S
        if rowid[slot] != row:
            any_late = True
            if not log.on:
                late += 1
                continue
            h = row % frow.shape[0]
            for w in range(W):
                m = pk_masks[p, q, w]
                if frow[h] == row:
                    m &= ~fheld[h, j, w]
                    fheld[h, j, w] |= m
                while m != _ZERO:
                    low = m & (~m + _ONE)
                    m ^= low
                    late += 1
                    if frow[h] == row:
                        log.arrival[j, w * 64 + _bit(low), row] = t_s
            continue
        if seq <= inseq[slot, e]:
            CT[STALE] += 1
            continue
        inseq[slot, e] = seq
        some = False
        for w in range(W):
            m = pk_masks[p, q, w]
            inbox[slot, e, w] = m
            new[w] = m & ~held[slot, j, w]
            if new[w] != _ZERO:
                some = True
        if some:
            for w in range(W):
                held[slot, j, w] |= new[w]
            _fold(j, row, new, F, t_s, log)
            X.dirty[j, slot] = 1
            gained = True
    if any_late:
        CT[LATE] += late
        L.late_node[j] += late
        counts[2, e] += 1                          # late packets
    if gained:
        _enqueue(j, X)


def _enqueue(j, X):
    """Node ``j``'s flush is due (once until it runs), after those due before it."""
    CT, queue = X.CT, X.queue
    if not X.due[j]:
        X.due[j] = 1
        queue[(CT[QHEAD] + CT[QLEN]) % queue.shape[0]] = j
        CT[QLEN] += 1


def deliver(now, X, L, P, F, log):
    """Deliver every packet due at ``now`` (send order).  Returns the heap's next instant or -1.

    ``P.times[:CT[NTIMES]]`` are the future arrival instants that have an event: ``now`` leaves."""
    CT, times, heap_t = X.CT, P.times, P.heap_t
    k = 0
    for h in range(CT[NTIMES]):
        if times[h] > now:
            times[k] = times[h]
            k += 1
    CT[NTIMES] = k
    while CT[HEAP] > 0 and heap_t[0] <= now:
        p = _pop(CT, P)
        _receive(p, now, X, L, P, F, log)
        P.free[CT[NFREE]] = p
        CT[NFREE] += 1
    return heap_t[0] if CT[HEAP] > 0 else -1


def measure(row, now, X, F, log):
    """Open ``row`` and give every node its own contribution (the Python ``measure``)."""
    held, new, dirty = X.held, X.new, X.dirty
    n = held.shape[1]
    S = X.rowid.shape[0]
    slot = row % S
    X.rowid[slot] = row
    held[slot] = _ZERO
    X.inbox[slot] = _ZERO
    X.inseq[slot] = 0
    X.sent[slot] = _ZERO
    for i in range(n):
        dirty[i, slot] = 0
    X.CT[HI] = row
    for i in range(n):
        new[:] = _ZERO
        new[i // 64] = _ONE << np.uint64(i % 64)
        held[slot, i, i // 64] |= new[i // 64]
        _fold(i, row, new, F, now / 1e9, log)
        dirty[i, slot] = 1
        _enqueue(i, X)


def _pack(j, deg, X, L, P):
    """Node ``j``'s flush: for each open row it changed, each out-link whose message would
    differ from the last one sent gets the row (what ``j`` holds minus what that neighbour
    sent it) in its packet ``P.outp[k]``, taken from the pool when the link has none yet."""
    CT, rowid, held, inbox, sent, dirty, out = X.CT, X.rowid, X.held, X.inbox, X.sent, X.dirty, X.out
    pk, pk_rows, pk_masks, outp = P.pk, P.rows, P.masks, P.outp
    S = rowid.shape[0]
    W = held.shape[2]
    lo = max(CT[LO], CT[HI] - S + 1)
    for row in range(lo, CT[HI] + 1):
        s = row % S
        if rowid[s] != row or not dirty[j, s]:
            continue
        dirty[j, s] = 0
        for k in range(deg):
            e = L.out_idx[L.out_ptr[j] + k]
            r = L.G[e, 2]
            changed = False
            for w in range(W):
                out[w] = held[s, j, w] & ~inbox[s, r, w]
                if out[w] != sent[s, e, w]:
                    changed = True
            if not changed:
                continue
            p = outp[k]
            if p < 0:
                CT[NFREE] -= 1
                p = P.free[CT[NFREE]]
                outp[k] = p
                pk[p, 2] = 0
            q = pk[p, 2]
            pk[p, 2] = q + 1
            pk_rows[p, q] = row
            for w in range(W):
                sent[s, e, w] = out[w]
                pk_masks[p, q, w] = out[w]


def _send(j, deg, now, X, L, P):
    """Send node ``j``'s filled packets: stamp link and sequence number, draw the latency
    (the link's keyed draw), count, and put each on the heap; a new arrival instant with a
    latency is listed in ``P.newt`` (it needs an event)."""
    CT, times, outp, pk = X.CT, P.times, P.outp, P.pk
    counts, dinst, dcnt, par = L.counts, L.dinst, L.dcnt, L.par
    for k in range(deg):
        p = outp[k]
        if p < 0:
            continue
        outp[k] = -1
        e = L.out_idx[L.out_ptr[j] + k]
        L.seq[e] += 1
        pk[p, 0] = e
        pk[p, 1] = L.seq[e]
        if dinst[e] != now:
            dinst[e] = now
            dcnt[e] = 0
        d = dcnt[e]
        dcnt[e] = d + 1
        if L.kind[e] == 0:
            lat = par[e]
        else:
            v = int(keyed_uniform(L.key[e], now, d) * (par[e] + 1))
            lat = min(v, par[e]) * L.T_ns
        counts[0, e] += 1
        counts[3, e] += L.header + pk[p, 2] * L.row_bytes
        t = now + lat
        if lat > 0:                            # a new arrival instant needs an event
            fresh = True
            for h in range(CT[NTIMES]):
                if times[h] == t:
                    fresh = False
                    break
            if fresh:
                times[CT[NTIMES]] = t
                CT[NTIMES] += 1
                P.newt[CT[NEWT]] = t
                CT[NEWT] += 1
        _push(CT, P, t, p)


def flush_all(now, until, X, L, P, F, log):
    """Flush the due nodes, first due first; after each flush the zero-latency packets are
    delivered (they may make more nodes due).  Packets with a latency go on the heap and a
    new arrival instant is listed in ``P.newt``.  Returns :data:`NEED_ROOM` if the pool has
    fewer free packets than the next node has out-links (nothing of that node done yet)."""
    CT, queue = X.CT, X.queue
    while CT[QLEN] > 0:
        j = queue[CT[QHEAD]]
        deg = L.out_ptr[j + 1] - L.out_ptr[j]
        if CT[NFREE] < deg:
            return NEED_ROOM
        CT[QHEAD] = (CT[QHEAD] + 1) % queue.shape[0]
        CT[QLEN] -= 1
        X.due[j] = 0
        _pack(j, deg, X, L, P)
        _send(j, deg, now, X, L, P)
        if now <= until:
            deliver(now, X, L, P, F, log)
    return 0
