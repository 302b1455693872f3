"""An event of the run's SimPy environment that fires at ``now + delay`` with a given priority
and callback: what the network schedules (deliveries, flushes, the channel's wake-ups)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from simpy.events import Event


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
