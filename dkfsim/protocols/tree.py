"""``tree``: the paper's Algorithm 2 on a tree, asynchronous and exact (unit weights).

Node ``i`` sends neighbour ``j`` the aggregate of its own contribution and
the latest message from every other neighbour.  On a tree these subtrees
are disjoint, so that set is ``held_i minus msg(j -> i)``.  It never uses
the paper's ``Theta_i - msg(j -> i)`` update, which subtracts a stale
message under asynchrony (docs/design.md §5).  Messages carry a per-link
sequence number; a message for a row supersedes the stored one only if its
number is higher (links reorder).

On a graph that changes (``mobility:``) the tree is rebuilt whenever the links up change
(:attr:`TreeExchange.tree_changes`, worked out by the run plan): from that tick on node
``i`` sends only on the arcs of the new spanning forest, and on each arc new to it sends
at once everything it holds for the window's rows but what came from that neighbour (the
arc's last sent message is forgotten).  Holdings are sets, so nothing is counted twice
whatever the tree was; packets in flight on an arc that left the tree are still accepted
(docs/design.md §5).

On a shared channel (``medium:``) a node's flush is one combined frame carrying every
neighbour's message (each different: a message to ``j`` leaves out ``j``'s subtree) behind
one header, each part with its receiver and number (:data:`~dkfsim.protocols.base.PART_HEADER`):
one contention and one preamble per flush instead of one per neighbour (decision 228).
"""

from __future__ import annotations

from dkfsim.core.registry import PROTOCOLS
from dkfsim.protocols.base import PACKET_HEADER, PART_HEADER, Exchange


@PROTOCOLS.register("tree")
class TreeExchange(Exchange):
    """The paper's Algorithm 2 on a tree, asynchronous and exact (unit weights)."""

    tree = True
    graph = "tree"
    #: tick -> the arcs of the tree from that tick on (a graph that changes), else None:
    #: set by the estimator before :meth:`attach`
    tree_changes: dict[int, list[tuple[int, int]]] | None = None

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
        if self.tree_changes is not None:
            self._by_arc = {(l.src, l.dst): self.lid[l.id] for l in self.links}
            self._in_tree: set[int] = set()
            self._outs = [() for _ in range(self.n)]     # the first tree comes at tick 1

    def retree(self, arcs) -> None:
        """The tree is now ``arcs``: send only on them, and on each arc new to it everything
        the sender holds for the window's rows (its last sent message is forgotten)."""
        tree = {self._by_arc[a] for a in arcs}
        new = tree - self._in_tree
        self._in_tree = tree
        self._outs = [tuple((e, rev, l) for e, rev, l in
                            ((self.lid[l.id], self.reverse[self.lid[l.id]], l) for l in self.out_links[j])
                            if e in tree) for j in range(self.n)]
        now = self.env.now
        for e in sorted(new):
            j = self.links[e].src
            if self.crashes is not None and self.crashes.down(j, now):
                continue                        # a node that is down sends nothing
            for row, st in self.rows.items():
                st.sent[e] = 0
                self._dirty[j].add(row)
            self.schedule_flush(j)

    def measure(self, row: int) -> None:
        if self.tree_changes is not None:
            arcs = self.tree_changes.get(row + 1)          # row's tick: a new tree from now on
            if arcs is not None:
                self.retree(arcs)
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
        # One combined frame: every neighbour's message, each with its own number (decision 228).
        size = self.row_bytes
        parts = []
        frame = PACKET_HEADER
        for (_e, _rev, link), its in zip(outs, items):
            if its:
                parts.append((link, its))
                frame += PART_HEADER + len(its) * size
        if parts:
            self.send_frame(parts, frame)
