"""Kernels of :mod:`dkfsim.protocols.tree_compiled`: the ``tree`` protocol's instants, compiled.

One call handles what one event of :class:`~dkfsim.protocols.tree.TreeExchange` and its
port would do at an instant: :func:`deliver` the packets due now (in the order they were
sent), :func:`measure` a new row, or :func:`flush_all` the nodes that gained something
(each flush's zero-latency packets delivered before the next node flushes).  Packets wait
in a binary heap ordered by (arrival instant, send order); their latencies are the links'
keyed draws (:func:`dkfsim.core.streams.keyed_uniform`, bit for bit) for ``constant`` and
``uniform_steps`` links.  New contributions are folded straight into the window filter's
ring, in the order the Python protocol reports them, so the sums are the same numbers.

The scalar state lives in one int64 array ``CT`` (indices below); origin sets are rows
of little-endian uint64 words.
"""

from __future__ import annotations

import numpy as np

from dkfsim.core.jit import LazyKernels

_KERNELS = ("keyed_uniform", "_bit", "_fold", "fold_masks", "_push", "_pop", "_enqueue", "_receive", "deliver", "measure",
            "flush_all")
_lazy = LazyKernels(__name__, _KERNELS)

# CT indices
HEAP, NFREE, QHEAD, QLEN, LO, HI, ORDER, LATE, STALE, NEWT, NTIMES = range(11)
#: Flag returned by :func:`flush_all` when the packet pool is full (grow it and call again).
NEED_ROOM = -2

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


def _fold(node, row, bits, A, omega, varying, theta, Omega, Theta, held, starts, t_s, arrival, logf):
    """Add origins ``bits`` (words) of ``row`` to ``node``'s sums, origins ascending; with
    ``logf``, log each origin's arrival at ``t_s`` seconds."""
    S = Omega.shape[0]
    nx = Omega.shape[2]
    slot = row % S
    r_om = row if varying else 0
    for w in range(bits.shape[0]):
        m = bits[w]
        while m != _ZERO:
            low = m & (~m + _ONE)
            m ^= low
            org = w * 64 + _bit(low)
            a = A[node, org]
            if held.shape[2]:                      # only kept when the fusion needs it
                held[slot, node, org] = True
            if logf:
                arrival[node, org, row] = t_s
            for p in range(nx):
                for q in range(nx):
                    Omega[slot, node, p, q] += a * omega[r_om, org, p, q]
                Theta[slot, node, p] += a * theta[row, org, p]
    if row < starts[node]:
        starts[node] = row


def fold_masks(i, r, words, A, omega, varying, theta, Omega, Theta, held, starts):
    """:func:`_fold` for many contributions, in order: ``words[k]`` holds the origins of node
    ``i[k]`` for row ``r[k]`` (the window filter's fold of what a Python protocol reported)."""
    nolog = np.empty((1, 1, 1))
    for k in range(i.shape[0]):
        _fold(i[k], r[k], words[k], A, omega, varying, theta, Omega, Theta, held, starts, 0.0, nolog, False)


def _push(CT, heap_t, heap_o, heap_p, t, p):
    """Put packet ``p`` due at ``t`` on the heap (ties: send order)."""
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


def _pop(CT, heap_t, heap_o, heap_p):
    """Remove the heap's first packet and return it."""
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


def _receive(p, now, CT, G, rowid, held, inbox, inseq, dirty, due, queue, pk, pk_rows, pk_masks, counts,
             late_node, A, omega, varying, theta, Omega, Theta, wheld, starts, new, arrival, logf, fheld,
             frow):
    """The Python protocol's ``receive`` for pooled packet ``p`` (then its slot is free).

    A row already final is late: one per (packet, row), or with the arrival log (``logf``) one
    per contribution the receiver did not hold when the row became final (``fheld``: the
    holdings of the last final rows, ``frow`` which), logged; older rows count every origin."""
    S = rowid.shape[0]
    W = held.shape[2]
    e = pk[p, 0]
    seq = pk[p, 1]
    j = G[e, 1]
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
            if not logf:
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
                        arrival[j, w * 64 + _bit(low), row] = t_s
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
            _fold(j, row, new, A, omega, varying, theta, Omega, Theta, wheld, starts, t_s, arrival, logf)
            dirty[j, slot] = 1
            gained = True
    if any_late:
        CT[LATE] += late
        late_node[j] += late
        counts[2, e] += 1                          # late packets
    if gained:
        _enqueue(j, CT, due, queue)


def _enqueue(j, CT, due, queue):
    """Node ``j``'s flush is due (once until it runs), after those due before it."""
    if not due[j]:
        due[j] = 1
        queue[(CT[QHEAD] + CT[QLEN]) % queue.shape[0]] = j
        CT[QLEN] += 1


def deliver(now, CT, G, rowid, held, inbox, inseq, dirty, due, queue, heap_t, heap_o, heap_p, free,
            pk, pk_rows, pk_masks, counts, late_node, times, A, omega, varying, theta, Omega, Theta,
            wheld, starts, new, arrival, logf, fheld, frow):
    """Deliver every packet due at ``now`` (send order).  Returns the heap's next instant or -1.

    ``times[:CT[NTIMES]]`` are the future arrival instants that have an event: ``now`` leaves."""
    k = 0
    for h in range(CT[NTIMES]):
        if times[h] > now:
            times[k] = times[h]
            k += 1
    CT[NTIMES] = k
    while CT[HEAP] > 0 and heap_t[0] <= now:
        p = _pop(CT, heap_t, heap_o, heap_p)
        _receive(p, now, CT, G, rowid, held, inbox, inseq, dirty, due, queue, pk, pk_rows, pk_masks, counts,
                 late_node, A, omega, varying, theta, Omega, Theta, wheld, starts, new, arrival, logf, fheld,
                 frow)
        free[CT[NFREE]] = p
        CT[NFREE] += 1
    return heap_t[0] if CT[HEAP] > 0 else -1


def measure(row, now, CT, rowid, held, inbox, inseq, sent, dirty, due, queue, A, omega, varying, theta,
            Omega, Theta, wheld, starts, new, arrival, logf, fheld, frow):
    """Open ``row`` and give every node its own contribution (the Python ``measure``)."""
    n = held.shape[1]
    S = rowid.shape[0]
    slot = row % S
    rowid[slot] = row
    held[slot] = _ZERO
    inbox[slot] = _ZERO
    inseq[slot] = 0
    sent[slot] = _ZERO
    for i in range(n):
        dirty[i, slot] = 0
    CT[HI] = row
    for i in range(n):
        new[:] = _ZERO
        new[i // 64] = _ONE << np.uint64(i % 64)
        held[slot, i, i // 64] |= new[i // 64]
        _fold(i, row, new, A, omega, varying, theta, Omega, Theta, wheld, starts, now / 1e9, arrival, logf)
        dirty[i, slot] = 1
        _enqueue(i, CT, due, queue)


def flush_all(now, until, header, row_bytes, T_ns, CT, G, out_ptr, out_idx, lkind, lkey, lpar, dinst, dcnt, lseq,
              rowid, held, inbox, inseq, sent, dirty, due, queue, heap_t, heap_o, heap_p, free, pk,
              pk_rows, pk_masks, counts, late_node, times, newt, outp, out, A, omega, varying, theta,
              Omega, Theta, wheld, starts, new, arrival, logf, fheld, frow):
    """Flush the due nodes, first due first; after each flush the zero-latency packets are
    delivered (they may make more nodes due).  Packets with a latency go on the heap and a
    new arrival instant is listed in ``newt``.  Returns :data:`NEED_ROOM` if the pool has
    fewer free packets than the next node has out-links (nothing of that node done yet)."""
    S = rowid.shape[0]
    W = held.shape[2]
    while CT[QLEN] > 0:
        j = queue[CT[QHEAD]]
        deg = out_ptr[j + 1] - out_ptr[j]
        if CT[NFREE] < deg:
            return NEED_ROOM
        CT[QHEAD] = (CT[QHEAD] + 1) % queue.shape[0]
        CT[QLEN] -= 1
        due[j] = 0
        lo = max(CT[LO], CT[HI] - S + 1)
        for row in range(lo, CT[HI] + 1):
            s = row % S
            if rowid[s] != row or not dirty[j, s]:
                continue
            dirty[j, s] = 0
            for k in range(deg):
                e = out_idx[out_ptr[j] + k]
                r = G[e, 2]
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
                    p = free[CT[NFREE]]
                    outp[k] = p
                    pk[p, 2] = 0
                q = pk[p, 2]
                pk[p, 2] = q + 1
                pk_rows[p, q] = row
                for w in range(W):
                    sent[s, e, w] = out[w]
                    pk_masks[p, q, w] = out[w]
        for k in range(deg):
            p = outp[k]
            if p < 0:
                continue
            outp[k] = -1
            e = out_idx[out_ptr[j] + k]
            lseq[e] += 1
            pk[p, 0] = e
            pk[p, 1] = lseq[e]
            if dinst[e] != now:
                dinst[e] = now
                dcnt[e] = 0
            d = dcnt[e]
            dcnt[e] = d + 1
            if lkind[e] == 0:
                lat = lpar[e]
            else:
                v = int(keyed_uniform(lkey[e], now, d) * (lpar[e] + 1))
                lat = min(v, lpar[e]) * T_ns
            counts[0, e] += 1
            counts[3, e] += header + pk[p, 2] * row_bytes
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
                    newt[CT[NEWT]] = t
                    CT[NEWT] += 1
            _push(CT, heap_t, heap_o, heap_p, t, p)
        if now <= until:
            deliver(now, CT, G, rowid, held, inbox, inseq, dirty, due, queue, heap_t, heap_o, heap_p, free,
                    pk, pk_rows, pk_masks, counts, late_node, times, A, omega, varying, theta, Omega, Theta,
                    wheld, starts, new, arrival, logf, fheld, frow)
    return 0
