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
from dkfsim.protocols.base import Exchange


@PROTOCOLS.register("tree")
class TreeExchange(Exchange):
    """The paper's Algorithm 2 on a tree, asynchronous and exact (unit weights)."""

    tree = True
    graph = "tree"

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
        j, e = link.dst, self.lid[link.id]
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
                e = self.lid[link.id]
                # Everything j holds except what came from the receiver: on a
                # tree, own + the other neighbours' subtrees, disjoint sets.
                out = held & ~st.inbox[self.reverse[e]]
                if out != st.sent[e]:
                    st.sent[e] = out
                    items[idx].append((row, out))
        for link, its in zip(links, items):
            if its:
                self._send(link, tuple(its))
