"""Exchange protocols: how contributions travel from node to node.

Both protocols forward on receipt, not at ticks (docs/design.md §2), and
coalesce: everything a node learns at one instant leaves in one packet per
out-link, sent by a flush event that runs after every delivery at that
instant (zero-latency chains included) and before the tick update.

What a packet carries
---------------------
For each row it mentions, a packet carries an information-form aggregate
``(theta, omega)`` and the set of origins it includes, as a bitmask.  With
the fixed weights of both protocols the aggregate is a *linear function of
that set*: ``sum_o c_o * (theta_o, omega_o)`` with ``c_o`` the product of the
weights along the (unique, on a tree) path from ``o`` -- so it is exactly
determined by the bitmask, and we let the bitmask stand for it on the wire.
The receiving node's :class:`~dkfsim.estimators.window.WindowFilter` materialises the
numbers for every node at once when it updates.  Per-packet work is then a
few integer operations; the arithmetic is batched.

``tree`` (the paper's Algorithm 2, on a tree)
    Node ``i`` sends neighbour ``j`` the aggregate of its own contribution and
    the latest message from every other neighbour.  On a tree these
    subtrees are disjoint, so that set is ``held_i minus msg(j -> i)``.  It
    never uses the paper's ``Theta_i - msg(j -> i)`` update, which subtracts a
    stale message under asynchrony.  Messages carry a per-link sequence number;
    a message for a row supersedes the stored one only if its number is
    higher (links reorder).
``flood`` (strongly connected digraphs)
    Each contribution ``(origin, row)`` is relayed once along every out-link
    except back to the neighbour it came from; duplicates are dropped.

A contribution for a row that is already final at the receiver is *late*:
counted (once per receiver, origin and row) and discarded.  Nothing is
forwarded for a final row: every node finalises a row at the same tick.
"""

from __future__ import annotations


import numpy as np

from dkfsim.network.links import PRIORITY_FLUSH, Scheduled


#: Above this many origins in one mask, newly held contributions are unpacked with numpy.
_MANY_BITS = 12


def bit_indices(mask: int) -> np.ndarray:
    """Positions of the set bits of a non-negative int, ascending."""
    raw = np.frombuffer(mask.to_bytes((mask.bit_length() + 7) // 8, "little"), dtype=np.uint8)
    return np.flatnonzero(np.unpackbits(raw, bitorder="little"))


class _Row:
    """Per-row exchange state of all nodes (lives while the row is in the window)."""

    __slots__ = ("held", "inbox", "inseq", "sent")

    def __init__(self, n: int, n_links: int, tree: bool):
        self.held = [0] * n
        if tree:
            self.inbox = [0] * n_links
            self.inseq = [0] * n_links
            self.sent = [0] * n_links


class Exchange:
    """Common machinery: rows, holdings, late accounting, the arrival log, flushes.

    :param window: the :class:`~dkfsim.estimators.window.WindowFilter` told of every newly
        held contribution.
    :param arrival: optional (n, n, K) array filled with ``inf``: the arrival
        log of docs/design.md §8 (late arrivals are logged too).
    :param late_horizon: how many final rows keep their holdings so that a
        late contribution is counted once; older late bits are counted per
        packet.
    """

    tree = False

    def __init__(self, env, n, window, arrival=None, late_horizon=4096):
        self.env = env
        self.n = n
        self.window = window
        self.arrival = arrival
        self.late_horizon = late_horizon
        self.rows: dict[int, _Row] = {}
        self.final: dict[int, list[int]] = {}
        self.late = 0
        self.late_per_node = [0] * n
        self.duplicates = 0
        self.stale = 0
        self._flush_due = [False] * n
        self._flush_cb = [self._make_flush(j) for j in range(n)]

    # -- wiring ----------------------------------------------------------------
    def attach(self, network) -> None:
        self.net = network
        #: per link: delivered packets that carried a contribution for a row
        #: already final at the receiver.
        self.late_packets = [0] * len(network.links)
        self.out_links = [[] for _ in range(self.n)]
        for link in network.links:
            self.out_links[link.src].append(link)
        self.n_links = len(network.links)
        rev = [network.index.get((l.dst, l.src)) for l in network.links]
        self.reverse = [r.id if r is not None else None for r in rev]

    def _make_flush(self, j):
        def cb(_event, j=j):
            self._flush_due[j] = False
            self.flush(j)
        return cb

    def _schedule_flush(self, j: int) -> None:
        if not self._flush_due[j]:
            self._flush_due[j] = True
            Scheduled(self.env, self._flush_cb[j], PRIORITY_FLUSH)

    # -- rows ------------------------------------------------------------------
    def open_row(self, row: int) -> None:
        self.rows[row] = _Row(self.n, self.n_links, self.tree)

    def close_row(self, row: int) -> None:
        """``row`` became final: keep only its holdings, for late accounting."""
        st = self.rows.pop(row, None)
        if st is not None:
            self.final[row] = st.held
        self.final.pop(row - self.late_horizon, None)

    # -- holdings --------------------------------------------------------------
    def _gain(self, node: int, row: int, st: _Row, bits: int) -> None:
        st.held[node] |= bits
        if bits.bit_count() > _MANY_BITS:
            # Large networks: one numpy pass instead of a Python step per origin.
            origins = bit_indices(bits)
            self.window.add_many(node, origins, row)
            if self.arrival is not None:
                self.arrival[node, origins, row] = self.env.now / 1e9
            return
        add = self.window.add
        t = self.env.now / 1e9 if self.arrival is not None else None
        while bits:
            low = bits & -bits
            o = low.bit_length() - 1
            bits ^= low
            add(node, o, row)
            if t is not None:
                self.arrival[node, o, row] = t

    def _late(self, node: int, row: int, mask: int) -> None:
        held = self.final.get(row)
        if held is None:          # older than the horizon: cannot deduplicate
            c = mask.bit_count()
            self.late += c
            self.late_per_node[node] += c
            return
        new = mask & ~held[node]
        if not new:
            return
        held[node] |= new
        c = new.bit_count()
        self.late += c
        self.late_per_node[node] += c
        if self.arrival is not None:
            t = self.env.now / 1e9
            while new:
                low = new & -new
                self.arrival[node, low.bit_length() - 1, row] = t
                new ^= low

    # -- protocol hooks ----------------------------------------------------------
    #: :class:`dkfsim.components.faults.CrashSchedule` (set by the simulation) or None.  A
    #: node that is down does not measure; the network drops what arrives at
    #: it, so it never has anything to send while down.
    crashes = None

    def _measuring(self):
        """The nodes that measure now: all but those in a crash window."""
        if not self.crashes:
            return range(self.n)
        now = self.env.now
        return [i for i in range(self.n) if not self.crashes.down(i, now)]

    def measure(self, row: int) -> None:
        raise NotImplementedError

    def receive(self, link, payload) -> None:
        """Deliver a packet: late rows are counted, live ones go to :meth:`_accept`."""
        seq, items = payload
        late = False
        for row, mask in items:
            st = self.rows.get(row)
            if st is None:
                self._late(link.dst, row, mask)
                late = True
            else:
                self._accept(link, seq, row, st, mask)
        if late:
            self.late_packets[link.id] += 1

    def _accept(self, link, seq: int, row: int, st: _Row, mask: int) -> None:
        raise NotImplementedError

    def flush(self, node: int) -> None:
        raise NotImplementedError

    def counts(self) -> dict:
        return {"late": self.late, "late_per_node": list(self.late_per_node),
                "duplicates": self.duplicates, "stale": self.stale}


class TreeExchange(Exchange):
    """The paper's Algorithm 2 on a tree, asynchronous and exact (unit weights)."""

    tree = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._dirty: list[set[int]] = [set() for _ in range(self.n)]

    def measure(self, row: int) -> None:
        st = self.rows[row]
        for i in self._measuring():
            self._gain(i, row, st, 1 << i)
            self._dirty[i].add(row)
            self._schedule_flush(i)

    def _accept(self, link, seq, row, st, mask) -> None:
        j, e = link.dst, link.id
        if seq <= st.inseq[e]:
            self.stale += 1
            return
        st.inseq[e] = seq
        st.inbox[e] = mask
        new = mask & ~st.held[j]
        if new:
            self._gain(j, row, st, new)
            self._dirty[j].add(row)
            self._schedule_flush(j)

    def flush(self, j: int) -> None:
        rows = self._dirty[j]
        if not rows:
            return
        self._dirty[j] = set()
        links = self.out_links[j]
        items = [[] for _ in links]
        for row in sorted(rows):
            st = self.rows.get(row)
            if st is None:
                continue
            held = st.held[j]
            for idx, link in enumerate(links):
                # Everything j holds except what came from the receiver: on a
                # tree, own + the other neighbours' subtrees, disjoint sets.
                out = held & ~st.inbox[self.reverse[link.id]]
                if out != st.sent[link.id]:
                    st.sent[link.id] = out
                    items[idx].append((row, out))
        for link, its in zip(links, items):
            if its:
                link.seq += 1
                self.net.send(link, (link.seq, tuple(its)))


class FloodExchange(Exchange):
    """Relay every new contribution once along every out-link (digraphs)."""

    def attach(self, network) -> None:
        super().attach(network)
        self._pending = [dict() for _ in network.links]

    def _queue(self, j: int, row: int, bits: int, exclude: int) -> None:
        for link in self.out_links[j]:
            if link.dst != exclude:
                p = self._pending[link.id]
                p[row] = p.get(row, 0) | bits
        self._schedule_flush(j)

    def measure(self, row: int) -> None:
        st = self.rows[row]
        for i in self._measuring():
            self._gain(i, row, st, 1 << i)
            self._queue(i, row, 1 << i, -1)

    def _accept(self, link, seq, row, st, mask) -> None:
        j = link.dst
        new = mask & ~st.held[j]
        if new != mask:
            self.duplicates += 1
        if new:
            self._gain(j, row, st, new)
            self._queue(j, row, new, link.src)

    def flush(self, j: int) -> None:
        for link in self.out_links[j]:
            p = self._pending[link.id]
            if p:
                items = tuple((row, m) for row, m in sorted(p.items()) if row in self.rows)
                p.clear()
                if items:
                    link.seq += 1
                    self.net.send(link, (link.seq, items))


PROTOCOLS = {"tree": TreeExchange, "flood": FloodExchange}
