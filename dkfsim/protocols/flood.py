"""``flood``: every contribution relayed once along every out-link (strongly connected digraphs).

Each contribution ``(origin, row)`` goes on along every out-link except
back to the neighbour it came from; duplicates are dropped.  Exact on any
strongly connected digraph: the directed-graph case of the paper
(docs/design.md §5).
"""

from __future__ import annotations

from typing_extensions import override

from dkfsim.core.registry import PROTOCOLS
from dkfsim.protocols.base import Exchange


@PROTOCOLS.register("flood")
class FloodExchange(Exchange):
    """Relay every new contribution once along every out-link (digraphs)."""

    def attach(self, port, links) -> None:
        super().attach(port, links)
        self._pending = [dict() for _ in self.links]

    def _queue(self, j: int, row: int, bits: int, exclude: int) -> None:
        for link in self.out_links[j]:
            if link.dst != exclude:
                p = self._pending[self.lid[link.id]]
                p[row] = p.get(row, 0) | bits
        self.schedule_flush(j)

    def measure(self, row: int) -> None:
        st = self.rows[row]
        for i in self.measuring_nodes():
            self.gain(i, row, st, 1 << i)
            self._queue(i, row, 1 << i, -1)

    @override
    def accept(self, link, seq, row, st, mask) -> None:
        j = link.dst
        new = mask & ~st.held[j]
        if new != mask:
            self.duplicates += 1
        if new:
            self.gain(j, row, st, new)
            self._queue(j, row, new, link.src)

    def flush(self, j: int) -> None:
        for link in self.out_links[j]:
            p = self._pending[self.lid[link.id]]
            if p:
                items = tuple((row, m) for row, m in sorted(p.items()) if row in self.rows)
                p.clear()
                if items:
                    self.send(link, items)
