"""``tick_flood``: a protocol for docs/extending.md -- flooding that relays only at ticks.

``flood`` relays a new contribution at the instant it arrives; ``tick_flood``
collects what a node learned and relays it at the node's next tick (a node
that can only transmit on a slot grid).  It changes one thing of its parent,
when a flush happens, and the DKF stays exact (each node's estimate is still
the information filter of what it holds: the tests check it against the
arrival log).
"""

from __future__ import annotations

from dkfsim.core.registry import PROTOCOLS
from dkfsim.network.links import PRIORITY_FLUSH, Scheduled
from dkfsim.protocols.flood import FloodExchange


@PROTOCOLS.register("tick_flood")
class TickFlood(FloodExchange):
    """Flooding whose relays wait for the sender's next tick."""

    def _schedule_flush(self, j: int) -> None:
        if not self._flush_due[j]:
            self._flush_due[j] = True
            now, T = self.env.now, self.T_ns
            wait = (-now) % T                       # 0 at a tick: its own measurement goes now
            Scheduled(self.env, self._flush_cb[j], PRIORITY_FLUSH, wait)
