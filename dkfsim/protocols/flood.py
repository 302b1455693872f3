"""``flood``: every contribution relayed once along every out-link (strongly connected digraphs).

Each contribution ``(origin, row)`` goes on along every out-link except
back to the neighbour it came from; duplicates are dropped.  Exact on any
strongly connected digraph: the directed-graph case of the paper
(docs/design.md §5).

On a graph that changes (``mobility:``) nothing is sent on a link that is down, and a
link that comes up at tick ``k`` carries, at ``t_k``, everything its sender holds for the
window's rows: a contribution is relayed once, when first held, so without this resend a
link that appears later would never carry it (docs/design.md §5, §6 "Time-varying graphs").

On a shared channel (``medium:``) a node's flush is one broadcast frame: its pending
contributions once, each neighbour taking the part addressed to it (docs/design.md §5).
"""

from __future__ import annotations

from collections.abc import Sequence

from typing_extensions import override

from dkfsim.core.registry import PROTOCOLS
from dkfsim.network.links import Link
from dkfsim.network.port import Port
from dkfsim.protocols.base import PACKET_HEADER, Exchange, RowState


@PROTOCOLS.register("flood")
class FloodExchange(Exchange):
    """Relay every new contribution once along every out-link (digraphs)."""

    def attach(self, port: Port, links: Sequence[Link]) -> None:
        super().attach(port, links)
        self._pending: list[dict[int, int]] = [{} for _ in self.links]

    def _queue(self, j: int, row: int, bits: int, exclude: int) -> None:
        for link in self.out_links[j]:
            if link.dst != exclude:
                p = self._pending[self.lid[link.id]]
                p[row] = p.get(row, 0) | bits
        self.schedule_flush(j)

    def measure(self, row: int) -> None:
        for link in self.came_up.get(row + 1, ()):        # row's tick: links that came up
            self._resend(link)
        st = self.rows[row]
        for i in self.measuring_nodes():
            self.gain(i, row, st, 1 << i)
            self._queue(i, row, 1 << i, -1)

    @override
    def accept(self, link: Link, seq: int, row: int, st: RowState, mask: int) -> None:
        j = link.dst
        new = mask & ~st.held[j]
        if new != mask:
            self.duplicates += 1
        if new:
            self.gain(j, row, st, new)
            self._queue(j, row, new, link.src)

    def _resend(self, link: Link) -> None:
        """``link`` came up: queue on it everything its sender holds for the window's rows."""
        j = link.src
        if self.crashes is not None and self.crashes.down(j, self.env.now):
            return                              # a node that is down sends nothing
        p = self._pending[self.lid[link.id]]
        for row, st in self.rows.items():
            if st.held[j]:
                p[row] = p.get(row, 0) | st.held[j]
        self.schedule_flush(j)

    def flush(self, j: int) -> None:
        """Send ``j``'s pending contributions: one flush whose parts are each out-link's
        (the union minus what came from that neighbour, which it holds already); on a broadcast
        medium one frame carrying their union, on any other one packet per out-link (decision
        227)."""
        now = self.env.now
        parts = []
        union: dict[int, int] = {}            # (the frame's rows: what a broadcast medium carries)
        for link in self.out_links[j]:
            p = self._pending[self.lid[link.id]]
            if p and link.changes and not link.is_up(now):
                p.clear()                       # out of range: its link-up resend carries it
            if p:
                items = tuple((row, m) for row, m in sorted(p.items()) if row in self.rows)
                p.clear()
                if items:
                    parts.append((link, items))
                    for row, m in items:
                        union[row] = union.get(row, 0) | m
        if parts:
            self.send_frame(parts, PACKET_HEADER + len(union) * self.row_bytes)
