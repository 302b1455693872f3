"""The run's clock as the network uses it: event priorities at one instant, and an event that
fires at ``now + delay`` with a given priority and callback (deliveries, flushes, the channel's
wake-ups).

Time is integer nanoseconds (docs/design.md §2), so "arrived by tick k" is an exact integer
comparison.  SimPy pops ``(time, priority, id)``: at one instant, deliveries (``NORMAL``)
first, then the protocols' flushes (:data:`PRIORITY_FLUSH`), then the filters' tick update
(:data:`PRIORITY_UPDATE`), so a packet arriving exactly at ``t_k``, and any chain of
zero-latency relays it starts, counts for tick ``k``; last a fusion centre's fusion
(:data:`PRIORITY_FUSE`), after the packets the update sent and their relays.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from simpy.events import NORMAL, Event

PRIORITY_DELIVER = NORMAL
PRIORITY_FLUSH = NORMAL + 1
PRIORITY_UPDATE = NORMAL + 2
#: A fusion centre fuses the tick's row after the update, its packets and their zero-latency
#: relays (docs/design.md §2).
PRIORITY_FUSE = NORMAL + 3


class Clock(Protocol):
    """The run's SimPy environment as the network uses it: time in integer nanoseconds."""

    @property
    def now(self) -> int: ...

    def schedule(self, event: Event, priority: int = ..., delay: int = ...) -> None: ...

    def peek(self) -> float: ...


class Scheduled(Event):
    """An event that fires at ``now + delay`` with a given priority and callback."""

    def __init__(self, env: Any, callback: Callable[[Event], None], priority: int, delay: int = 0):
        # (Event.__init__'s two attributes set here: one call less per event, the network
        # schedules one or two per packet)
        self.env = env
        self.callbacks = [callback]
        self._ok = True
        self._value = None
        env.schedule(self, priority, delay)
