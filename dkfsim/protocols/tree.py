"""``tree``: the paper's Algorithm 2 on a tree, asynchronous and exact (unit weights).

Node ``i`` sends neighbour ``j`` the aggregate of its own contribution and
the latest message from every other neighbour.  On a tree these subtrees
are disjoint, so that set is ``held_i minus msg(j -> i)``.  It never uses
the paper's ``Theta_i - msg(j -> i)`` update, which subtracts a stale
message under asynchrony (docs/design.md §5).  Messages carry a per-link
sequence number; a message for a row supersedes the stored one only if its
number is higher (links reorder).
"""

from __future__ import annotations

from dkfsim.core.registry import PROTOCOLS
from dkfsim.protocols.base import PACKET_HEADER, Exchange


@PROTOCOLS.register("tree")
class TreeExchange(Exchange):
    """The paper's Algorithm 2 on a tree, asynchronous and exact (unit weights)."""

    tree = True
    graph = "tree"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._dirty: list[set[int]] = [set() for _ in range(self.n)]

    def attach(self, port, links) -> None:
        super().attach(port, links)
        #: per node: its out-links as (local index, local index of the reverse link, link)
        self._outs = [tuple((self.lid[l.id], self.reverse[self.lid[l.id]], l) for l in self.out_links[j])
                      for j in range(self.n)]
        self._local = [-1] * (max(self.lid, default=-1) + 1)
        for lid, e in self.lid.items():
            self._local[lid] = e

    def measure(self, row: int) -> None:
        st = self.rows[row]
        for i in self.measuring_nodes():
            self.gain(i, row, st, 1 << i)
            self._dirty[i].add(row)
            self.schedule_flush(i)

    def receive(self, link, payload) -> None:
        """:meth:`Exchange.receive` with the tree's acceptance in one loop (the per-packet path)."""
        seq, items = payload
        j, e = link.dst, self._local[link.id]
        rows = self.rows
        gained = late = False
        for row, mask in items:
            st = rows.get(row)
            if st is None:
                self.count_late(j, row, mask)
                late = True
                continue
            if seq <= st.inseq[e]:
                self.stale += 1
                continue
            st.inseq[e] = seq
            st.inbox[e] = mask
            new = mask & ~st.held[j]
            if new:
                self.gain(j, row, st, new)
                self._dirty[j].add(row)
                gained = True
        if gained:
            self.schedule_flush(j)
        if late:
            self.late_packets[e] += 1

    def flush(self, j: int) -> None:
        rows = self._dirty[j]
        if not rows:
            return
        self._dirty[j] = set()
        outs = self._outs[j]
        items = [[] for _ in outs]
        live = self.rows
        for row in sorted(rows):
            st = live.get(row)
            if st is None:
                continue
            held, inbox, sent = st.held[j], st.inbox, st.sent
            for k, (e, rev, _link) in enumerate(outs):
                # Everything j holds except what came from the receiver: on a
                # tree, own + the other neighbours' subtrees, disjoint sets.
                out = held & ~inbox[rev]
                if out != sent[e]:
                    sent[e] = out
                    items[k].append((row, out))
        send, seq, size, header = self.port.send, self.seq, self.row_bytes, PACKET_HEADER
        for (e, _rev, link), its in zip(outs, items):
            if its:
                seq[e] += 1
                send(link, (seq[e], its), header + len(its) * size)
