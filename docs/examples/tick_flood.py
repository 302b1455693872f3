"""``tick_flood``: a protocol for docs/extending.md -- flooding that relays only at ticks.

``flood`` relays a new contribution at the instant it arrives; ``tick_flood``
collects what a node learned and relays it at the node's next tick (a node
that can only transmit on a slot grid).  It changes one thing of its parent,
when a flush happens -- the :meth:`~dkfsim.protocols.base.Exchange.schedule_flush`
hook -- and the DKF stays exact (each node's estimate is still the information
filter of what it holds: the tests check it against the arrival log).
"""

from __future__ import annotations

from dkfsim.core.registry import PROTOCOLS
from dkfsim.protocols.flood import FloodExchange


@PROTOCOLS.register("tick_flood")
class TickFlood(FloodExchange):
    """Flooding whose relays wait for the sender's next tick."""

    def schedule_flush(self, node: int) -> None:
        wait = (-self.env.now) % self.T_ns          # 0 at a tick: its own measurement goes now
        self.flush_later(node, wait)
